"""The Unscented Kalman Filter of the paper (eqs. 9-25), batched over a leading axis.

One call of :meth:`UnscentedKalmanFilter.step` runs predict and update for ``B`` filters at once
(the IMM's mode-matched bank, or ``B = 1``): the sigma points of all of them go through the model
functions as one ``(n, B, sigma)`` array.

Two noise forms:

- ``"augmented"`` (the paper's reference form): state, process noise and measurement noise are
  stacked (eqs. 9-10) and ``2 n_a + 1`` sigma points are pushed through ``f(x, u, v)`` and
  ``g(x, u, w)`` (eqs. 13-15).
- ``"additive"``: sigma points over the state only; ``Q`` and ``R`` are added to the transformed
  covariances, and the measurement step redraws sigma points about the prediction (so that
  ``Q`` reaches ``P_xz`` and ``P_zz``, as in filterpy and in the linear Kalman filter).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Literal

import numpy as np
import scipy.stats

from immukf_sitl.estimation.angles import wrap_angle, wrap_rows
from immukf_sitl.estimation.diagnostics import FilterDiagnostics
from immukf_sitl.estimation.linalg import block_diagonal, robust_cholesky, symmetrise
from immukf_sitl.estimation.models import Measurement, ProcessModel
from immukf_sitl.estimation.sigma_points import (
    JulierSigmaPoints,
    SigmaPointScheme,
    SigmaWeights,
    sigma_points,
    unscented_transform,
)

NoiseForm = Literal["augmented", "additive"]
LOG_2PI = float(np.log(2.0 * np.pi))
#: Tail probability beyond which an innovation is counted as an outlier (it is still used).
OUTLIER_TAIL_PROBABILITY = 1e-9


@lru_cache(maxsize=64)
def outlier_nis_threshold(nz: int) -> float:
    """NIS above which an ``nz``-dimensional innovation counts as an outlier."""
    return float(scipy.stats.chi2.isf(OUTLIER_TAIL_PROBABILITY, nz))


@lru_cache(maxsize=64)
def _distinct_process_columns(n_xv: int, n_aug: int) -> np.ndarray:
    """Sigma-point columns whose (x, v) part differs: the centre and the x/v perturbations."""
    return np.concatenate([[0], np.arange(1, 1 + n_xv), np.arange(1 + n_aug, 1 + n_aug + n_xv)])


@lru_cache(maxsize=64)
def _w_only_columns(n_xv: int, n_aug: int) -> np.ndarray:
    """Sigma-point columns that perturb only the measurement noise w."""
    return np.concatenate(
        [np.arange(1 + n_xv, 1 + n_aug), np.arange(1 + n_aug + n_xv, 1 + 2 * n_aug)]
    )


@dataclass(frozen=True)
class UkfEstimate:
    """Result of one predict/update step of ``B`` filters (batch axis first).

    Attributes
    ----------
    t_s : float
        Time of the estimate (end of the step).
    mean, cov : ndarray, shapes (B, nx), (B, nx, nx)
        ``x(k+1|k+1)`` and ``P(k+1|k+1)`` (eqs. 22-23); the prediction when not updated.
    predicted_mean, predicted_cov : ndarray
        ``x(k+1|k)`` and ``P(k+1|k)`` (eqs. 16, 18).
    innovation, innovation_cov : ndarray or None, shapes (B, nz), (B, nz, nz)
        ``z~(k+1)`` and ``P_zz(k+1|k)`` (eqs. 20-21), None without update.
    log_likelihood : ndarray, shape (B,)
        ``log Lambda(k+1)`` (eq. 25), zero without update.
    nis : ndarray, shape (B,)
        Normalised innovation squared ``z~' P_zz^-1 z~``, zero without update.
    updated : bool
        Whether a measurement was used.
    """

    t_s: float
    mean: np.ndarray
    cov: np.ndarray
    predicted_mean: np.ndarray
    predicted_cov: np.ndarray
    innovation: np.ndarray | None
    innovation_cov: np.ndarray | None
    log_likelihood: np.ndarray
    nis: np.ndarray
    updated: bool


class UnscentedKalmanFilter:
    """Augmented (or additive-noise) UKF over a batch of estimates.

    Parameters
    ----------
    process : ProcessModel
        ``f`` and ``Q``.
    scheme : SigmaPointScheme
        Sigma-point weights; default the paper's kappa form with ``kappa = 0``.
    noise_form : {"augmented", "additive"}
        See the module docstring.

    Attributes
    ----------
    diagnostics : FilterDiagnostics
        Counts of every safeguard applied so far.
    """

    def __init__(
        self,
        process: ProcessModel,
        scheme: SigmaPointScheme | None = None,
        noise_form: NoiseForm = "augmented",
    ) -> None:
        if noise_form not in ("augmented", "additive"):
            raise ValueError(f"noise_form must be 'augmented' or 'additive', not {noise_form!r}")
        if noise_form == "additive" and process.additive_noise_cov is None:
            raise ValueError("the additive form needs process.additive_noise_cov")
        self.process = process
        self.scheme: SigmaPointScheme = scheme if scheme is not None else JulierSigmaPoints()
        self.noise_form: NoiseForm = noise_form
        self.diagnostics = FilterDiagnostics()

    def step(
        self,
        t_s: float,
        mean: np.ndarray,
        cov: np.ndarray,
        u: np.ndarray,
        measurement: Measurement | None,
    ) -> UkfEstimate:
        """Predict from ``k`` to ``k+1`` with control ``u``, then update with ``measurement``.

        Parameters
        ----------
        t_s : float
            Time at the start of the step (passed to ``f``; ``g`` gets it too).
        mean, cov : ndarray, shapes (B, nx), (B, nx, nx)
            ``x(k|k)``, ``P(k|k)`` of each filter in the batch.
        u : ndarray
            Control held over the step, passed to ``f`` and ``g`` unchanged.
        measurement : Measurement or None
            ``z(k+1)``; ``None`` (or a non-finite ``z``) gives a predict-only step.
        """
        diag = self.diagnostics
        diag.steps += 1
        proc = self.process
        batch, nx = mean.shape
        if measurement is not None and not np.all(np.isfinite(measurement.z)):
            diag.skipped_nonfinite_measurement += 1
            measurement = None

        cov = symmetrise(cov, diag)
        chol = robust_cholesky(cov, diag)
        if self.noise_form == "augmented":
            weights, pred_mean, pred_cov, x_res, z_points = self._propagate_augmented(
                t_s, mean, chol, u, measurement
            )
        else:
            weights, pred_mean, pred_cov, x_res, z_points = self._propagate_additive(
                t_s, mean, chol, u, measurement
            )
        pred_cov = symmetrise(pred_cov, diag)

        zero = np.zeros(batch)
        if measurement is None:
            return UkfEstimate(
                t_s, pred_mean, pred_cov, pred_mean, pred_cov, None, None, zero, zero, False
            )

        model = measurement.model
        z_mean, z_cov, z_res = unscented_transform(z_points, weights, model.angle_idx)
        if self.noise_form == "additive":
            z_cov = z_cov + model.noise_cov
        z_cov = symmetrise(z_cov, diag)  # eq. (20)
        cross_cov = (x_res * weights.cov_weights) @ z_res.transpose(0, 2, 1)  # eq. (19)

        innovation = measurement.z[None, :] - z_mean  # eq. (21)
        if model.angle_idx:
            idx = list(model.angle_idx)
            innovation[:, idx] = wrap_angle(innovation[:, idx])

        z_chol = robust_cholesky(z_cov, diag)
        # K = P_xz P_zz^-1 (eq. 24) by two triangular solves on the Cholesky factor, never inv
        white_cross = np.linalg.solve(z_chol, cross_cov.transpose(0, 2, 1))  # L^-1 P_zx
        white_innov = np.linalg.solve(z_chol, innovation[:, :, None])[:, :, 0]  # L^-1 z~
        gain_white = white_cross.transpose(0, 2, 1)  # K L = P_xz L^-T
        new_mean = pred_mean + (gain_white @ white_innov[:, :, None])[:, :, 0]  # eq. (22)
        if proc.angle_idx:
            idx = list(proc.angle_idx)
            new_mean[:, idx] = wrap_angle(new_mean[:, idx])
        # eq. (23) as printed adds K P_zz K'; the Kalman update subtracts it: P - (K L)(K L)'
        new_cov = pred_cov - gain_white @ white_cross
        new_cov = symmetrise(new_cov, diag)

        nis = np.einsum("bi,bi->b", white_innov, white_innov)
        log_det = 2.0 * np.log(np.diagonal(z_chol, axis1=1, axis2=2)).sum(axis=1)
        # eq. (25) in log space; its printed exponent lacks the minus sign
        log_likelihood = -0.5 * (nis + log_det + model.nz * LOG_2PI)
        diag.outlier_innovations += int(np.count_nonzero(nis > outlier_nis_threshold(model.nz)))

        bad = ~(np.all(np.isfinite(new_mean), axis=1) & np.all(np.isfinite(new_cov), axis=(1, 2)))
        if np.any(bad):
            diag.nonfinite_state_reset += int(np.count_nonzero(bad))
            new_mean[bad] = np.where(np.isfinite(mean[bad]), mean[bad], 0.0)
            new_cov[bad] = np.where(np.isfinite(cov[bad]), cov[bad], 0.0)
            log_likelihood[bad] = -np.inf
        return UkfEstimate(
            t_s,
            new_mean,
            new_cov,
            pred_mean,
            pred_cov,
            innovation,
            z_cov,
            log_likelihood,
            nis,
            True,
        )

    # -- the two noise forms -------------------------------------------------------------------

    def _propagate_augmented(
        self,
        t_s: float,
        mean: np.ndarray,
        chol: np.ndarray,
        u: np.ndarray,
        measurement: Measurement | None,
    ) -> tuple[SigmaWeights, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        proc = self.process
        batch, nx = mean.shape
        nv = proc.nv
        blocks = [chol, proc.noise_sqrt]
        nw = 0
        if measurement is not None:
            nw = measurement.model.nz
            blocks.append(measurement.model.noise_sqrt)
        n_aug = nx + nv + nw
        mean_aug = np.zeros((batch, n_aug))  # eq. (9): noise means are zero
        mean_aug[:, :nx] = mean
        sqrt_aug = block_diagonal(blocks, batch)  # eq. (10)
        weights = self.scheme.weights(n_aug)
        points = sigma_points(mean_aug, sqrt_aug, weights.spread)  # eqs. (11), (13)
        if nw:
            # the 2 nw points that perturb only w share x and v = 0 with the centre point:
            # f is evaluated once for them (an exact saving of 2 nw / (2 n_a + 1) of the work)
            distinct = _distinct_process_columns(nx + nv, n_aug)
            moved = proc.f(t_s, points[:nx, :, distinct], u, points[nx : nx + nv, :, distinct])
            x_points = np.empty((nx, batch, 2 * n_aug + 1))
            x_points[:, :, distinct] = moved
            x_points[:, :, _w_only_columns(nx + nv, n_aug)] = moved[:, :, :1]
        else:
            x_points = proc.f(t_s, points[:nx], u, points[nx : nx + nv])  # eq. (14)
        pred_mean, pred_cov, x_res = unscented_transform(x_points, weights, proc.angle_idx)
        z_points = None
        if measurement is not None:
            z_points = measurement.model.g(t_s, x_points, u, points[nx + nv :])  # eq. (15)
        return weights, pred_mean, pred_cov, x_res, z_points

    def _propagate_additive(
        self,
        t_s: float,
        mean: np.ndarray,
        chol: np.ndarray,
        u: np.ndarray,
        measurement: Measurement | None,
    ) -> tuple[SigmaWeights, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        proc = self.process
        nx = mean.shape[1]
        weights = self.scheme.weights(nx)
        points = sigma_points(mean, chol, weights.spread)
        x_points = proc.f(t_s, points, u, None)
        pred_mean, pred_cov, x_res = unscented_transform(x_points, weights, proc.angle_idx)
        pred_cov = symmetrise(pred_cov + proc.additive_noise_cov, self.diagnostics)
        z_points = None
        if measurement is not None:
            # redraw about the prediction so that Q reaches P_xz and P_zz (as filterpy does)
            chol_pred = robust_cholesky(pred_cov, self.diagnostics)
            redrawn = sigma_points(pred_mean, chol_pred, weights.spread)
            x_res = redrawn - pred_mean.T[:, :, None]
            wrap_rows(x_res, proc.angle_idx)
            x_res = x_res.transpose(1, 0, 2)
            z_points = measurement.model.g(t_s, redrawn, u, None)
        return weights, pred_mean, pred_cov, x_res, z_points
