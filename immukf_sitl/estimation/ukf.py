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

Two backends compute the same step: the numpy code in this module (the reference) and, when
numba is installed, compiled kernels (:mod:`immukf_sitl.estimation._kernels_numba`) that do the
filter's own arithmetic in four calls per step; ``f`` and ``g`` are called the same way by both.
Their results differ by rounding only; the safeguard counters count the same events.
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
from immukf_sitl.estimation.models import Measurement, MeasurementModel, ProcessModel
from immukf_sitl.estimation.sigma_points import (
    JulierSigmaPoints,
    SigmaPointScheme,
    SigmaWeights,
    sigma_points,
    unscented_transform,
)

NoiseForm = Literal["augmented", "additive"]
#: ``"auto"``: the compiled kernels when numba is installed, else numpy (the reference).
Backend = Literal["auto", "numpy", "numba"]
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


@lru_cache(maxsize=64)
def _process_column_source(n_xv: int, n_aug: int) -> np.ndarray:
    """For each of the ``2 n_aug + 1`` columns, its index among the distinct (x, v) columns."""
    source = np.zeros(2 * n_aug + 1, dtype=np.int64)  # the w-only columns repeat the centre
    distinct = _distinct_process_columns(n_xv, n_aug)
    source[distinct] = np.arange(distinct.size)
    return source  # writeable like every kernel argument: one compiled signature


@lru_cache(maxsize=64)
def _zeros(n: int) -> np.ndarray:
    zeros = np.zeros((n, n))
    zeros.setflags(write=False)
    return zeros


@lru_cache(maxsize=64)
def _identity_source(n_sigma: int) -> np.ndarray:
    return np.arange(n_sigma, dtype=np.int64)


def _angle_mask(n: int, angle_idx: tuple[int, ...]) -> np.ndarray:
    mask = np.zeros(n, dtype=np.bool_)
    mask[list(angle_idx)] = True
    mask.setflags(write=False)
    return mask


def _load_kernels(backend: str):
    """The compiled-kernel module for ``backend``, or None for the numpy reference."""
    if backend not in ("auto", "numpy", "numba"):
        raise ValueError(f"backend must be 'auto', 'numpy' or 'numba', not {backend!r}")
    if backend == "numpy":
        return None
    try:
        from immukf_sitl.estimation import _kernels_numba
    except ImportError:
        if backend == "numba":
            raise
        return None
    return _kernels_numba


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
    backend : {"auto", "numpy", "numba"}
        Implementation of the filter's arithmetic: numpy (the reference) or compiled kernels;
        ``"auto"`` takes the kernels when numba is installed. See the module docstring.

    Attributes
    ----------
    diagnostics : FilterDiagnostics
        Counts of every safeguard applied so far.
    backend : {"numpy", "numba"}
        The backend in use.
    """

    def __init__(
        self,
        process: ProcessModel,
        scheme: SigmaPointScheme | None = None,
        noise_form: NoiseForm = "augmented",
        backend: Backend = "auto",
    ) -> None:
        if noise_form not in ("augmented", "additive"):
            raise ValueError(f"noise_form must be 'augmented' or 'additive', not {noise_form!r}")
        if noise_form == "additive" and process.additive_noise_cov is None:
            raise ValueError("the additive form needs process.additive_noise_cov")
        self.process = process
        self.scheme: SigmaPointScheme = scheme if scheme is not None else JulierSigmaPoints()
        self.noise_form: NoiseForm = noise_form
        self.diagnostics = FilterDiagnostics()
        self._kernels = _load_kernels(backend)
        self.backend: str = "numpy" if self._kernels is None else "numba"
        self._x_angle = _angle_mask(process.nx, process.angle_idx)
        # per measurement model: (model, angle mask, R as added by the compiled update); and the
        # augmented form's constant measurement-noise sigma points per (model, batch)
        self._output_constants: dict[int, tuple] = {}
        self._w_points: dict[tuple[int, int], tuple] = {}

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
        batch = mean.shape[0]
        if measurement is not None and not np.isfinite(measurement.z).all():
            diag.skipped_nonfinite_measurement += 1
            measurement = None
        if self._kernels is not None:
            return self._step_compiled(t_s, mean, cov, u, measurement)

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

        if measurement is None:
            zero = np.zeros(batch)
            return UkfEstimate(
                t_s, pred_mean, pred_cov, pred_mean, pred_cov, None, None, zero, zero, False
            )
        return self._update(
            t_s, mean, cov, pred_mean, pred_cov, x_res, z_points, weights, measurement
        )

    def _update(
        self,
        t_s: float,
        mean: np.ndarray,
        cov: np.ndarray,
        pred_mean: np.ndarray,
        pred_cov: np.ndarray,
        x_res: np.ndarray,
        z_points: np.ndarray,
        weights: SigmaWeights,
        measurement: Measurement,
    ) -> UkfEstimate:
        """Eqs. (19)-(25) in numpy, from the transformed points (the reference update)."""
        diag = self.diagnostics
        proc = self.process
        model = measurement.model
        z_mean, z_cov, z_res = unscented_transform(z_points, weights, model.angle_idx)  # eq. (17)
        if self.noise_form == "additive":
            z_cov = z_cov + model.noise_cov
        z_cov = symmetrise(z_cov, diag)  # eq. (20)
        cross_cov = (x_res * weights.cov_weights) @ z_res.transpose(0, 2, 1)  # eq. (19)

        innovation = measurement.z[None, :] - z_mean  # eq. (21)
        if model.angle_idx:
            idx = list(model.angle_idx)
            innovation[:, idx] = wrap_angle(innovation[:, idx])

        z_chol = robust_cholesky(z_cov, diag)
        # K = P_xz P_zz^-1 (eq. 24) through the Cholesky factor L of P_zz, never inv:
        # K z~ = (P_xz L^-T)(L^-1 z~) and K P_zz K' = (P_xz L^-T)(P_xz L^-T)'
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
        return self._finish(
            t_s, mean, cov, pred_mean, pred_cov, new_mean, new_cov, innovation, z_cov, nis,
            log_det, model.nz,
        )  # fmt: skip

    def _finish(
        self,
        t_s: float,
        mean: np.ndarray,
        cov: np.ndarray,
        pred_mean: np.ndarray,
        pred_cov: np.ndarray,
        new_mean: np.ndarray,
        new_cov: np.ndarray,
        innovation: np.ndarray,
        z_cov: np.ndarray,
        nis: np.ndarray,
        log_det: np.ndarray,
        nz: int,
    ) -> UkfEstimate:
        """Likelihood (eq. 25), outlier count and the non-finite reset, shared by both backends."""
        diag = self.diagnostics
        # eq. (25) in log space; its printed exponent lacks the minus sign
        log_likelihood = -0.5 * (nis + log_det + nz * LOG_2PI)
        diag.outlier_innovations += int(np.count_nonzero(nis > outlier_nis_threshold(nz)))

        if np.isfinite(new_mean).all() and np.isfinite(new_cov).all():
            bad = None
        else:
            bad = ~(np.isfinite(new_mean).all(axis=1) & np.isfinite(new_cov).all(axis=(1, 2)))
        if bad is not None and bad.any():
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

    # -- the compiled backend ------------------------------------------------------------------

    def _step_compiled(
        self,
        t_s: float,
        mean: np.ndarray,
        cov: np.ndarray,
        u: np.ndarray,
        measurement: Measurement | None,
    ) -> UkfEstimate:
        """The step of :meth:`step` with the filter's arithmetic in compiled kernels.

        Same equations, same calls of ``f`` and ``g`` (on the same points), same safeguards:
        a factor the kernels are unsure of goes to :func:`robust_cholesky`, and an update whose
        ``P_zz`` they cannot factor is redone by the numpy :meth:`_update`.
        """
        kernels = self._kernels
        diag = self.diagnostics
        proc = self.process
        augmented = self.noise_form == "augmented"
        mean = np.ascontiguousarray(mean, dtype=float)
        cov = np.ascontiguousarray(cov, dtype=float)
        batch, nx = mean.shape

        sym = np.empty_like(cov)
        chol = np.empty_like(cov)
        diag.symmetrised += batch
        if not kernels.factor(cov, sym, chol):
            chol = robust_cholesky(sym, diag)
        if augmented:
            nv = proc.nv
            n_aug = nx + nv + (measurement.model.nz if measurement is not None else 0)
            weights = self.scheme.weights(n_aug)
            n_distinct = 1 + 2 * (nx + nv)
            x_distinct = np.empty((nx, batch, n_distinct))
            v_distinct = np.empty((nv, batch, n_distinct))
            kernels.augmented_process_points(
                mean, chol, proc.noise_sqrt, weights.spread, x_distinct, v_distinct
            )  # eqs. (9)-(11), (13)
            moved = proc.f(t_s, x_distinct, u, v_distinct)  # eq. (14)
            source = _process_column_source(nx + nv, n_aug)
            added_cov = _zeros(nx)
        else:
            weights = self.scheme.weights(nx)
            points = np.empty((nx, batch, 2 * nx + 1))
            kernels.state_points(mean, chol, weights.spread, points)
            moved = proc.f(t_s, points, u, None)
            source = _identity_source(2 * nx + 1)
            added_cov = proc.additive_noise_cov
        n_sigma = source.size
        x_points = np.empty((nx, batch, n_sigma))
        pred_mean = np.empty((batch, nx))
        pred_cov = np.empty((batch, nx, nx))
        x_res = np.empty((batch, nx, n_sigma))
        # eqs. (16)-(18)
        kernels.predict_moments(
            np.ascontiguousarray(moved, dtype=float), source, weights.mean_weights,
            weights.cov_weights, self._x_angle, added_cov, x_points, pred_mean, pred_cov, x_res,
        )  # fmt: skip
        diag.symmetrised += batch if augmented else 2 * batch  # as the numpy path counts
        if measurement is None:
            zero = np.zeros(batch)
            return UkfEstimate(
                t_s, pred_mean, pred_cov, pred_mean, pred_cov, None, None, zero, zero, False
            )

        model = measurement.model
        z_angle, added_r = self._output_constants_of(model)
        if augmented:
            w_points = self._measurement_noise_points(model, weights, nx + proc.nv, batch)
            z_points = model.g(t_s, x_points, u, w_points)  # eq. (15)
        else:
            # redraw about the prediction so that Q reaches P_xz and P_zz (as filterpy does)
            chol_pred = np.empty_like(pred_cov)
            if not kernels.factor(pred_cov, np.empty_like(pred_cov), chol_pred):
                chol_pred = robust_cholesky(pred_cov, diag)
            kernels.state_points(pred_mean, chol_pred, weights.spread, x_points)
            kernels.centred(x_points, pred_mean, self._x_angle, x_res)
            z_points = model.g(t_s, x_points, u, None)
        z_points = np.ascontiguousarray(z_points, dtype=float)
        nz = model.nz
        z_cov = np.empty((batch, nz, nz))
        innovation = np.empty((batch, nz))
        new_mean = np.empty((batch, nx))
        new_cov = np.empty((batch, nx, nx))
        nis = np.empty(batch)
        log_det = np.empty(batch)
        # eqs. (19)-(24)
        solved = kernels.update(
            pred_mean, pred_cov, x_res, z_points, weights.mean_weights, weights.cov_weights,
            z_angle, self._x_angle, np.ascontiguousarray(measurement.z), added_r, z_cov,
            innovation, new_mean, new_cov, nis, log_det,
        )  # fmt: skip
        if not solved:
            return self._update(
                t_s, mean, sym, pred_mean, pred_cov, x_res, z_points, weights, measurement
            )
        diag.symmetrised += 2 * batch  # P_zz and P(k+1|k+1), symmetric by construction
        return self._finish(
            t_s, mean, sym, pred_mean, pred_cov, new_mean, new_cov, innovation, z_cov, nis,
            log_det, nz,
        )  # fmt: skip

    def _output_constants_of(self, model: MeasurementModel) -> tuple[np.ndarray, np.ndarray]:
        """Angle mask of the output and the ``R`` the update adds (zeros when augmented)."""
        entry = self._output_constants.get(id(model))
        if entry is None or entry[0] is not model:
            added_r = model.noise_cov if self.noise_form == "additive" else _zeros(model.nz)
            entry = (
                model,
                _angle_mask(model.nz, model.angle_idx),
                np.ascontiguousarray(added_r, dtype=float),
            )
            self._output_constants[id(model)] = entry
        return entry[1], entry[2]

    def _measurement_noise_points(
        self, model: MeasurementModel, weights: SigmaWeights, n_xv: int, batch: int
    ) -> np.ndarray:
        """The w rows of the augmented sigma points (eq. 11): constant for a model and batch."""
        key = (id(model), batch)
        entry = self._w_points.get(key)
        if entry is None or entry[0] is not model:
            nw = model.nz
            n_aug = n_xv + nw
            points = np.zeros((nw, batch, 2 * n_aug + 1))
            offsets = weights.spread * model.noise_sqrt
            points[:, :, 1 + n_xv : 1 + n_aug] = (0.0 + offsets)[:, None, :]
            points[:, :, 1 + n_aug + n_xv :] = (0.0 - offsets)[:, None, :]
            points.setflags(write=False)
            entry = (model, points)
            self._w_points[key] = entry
        return entry[1]

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
            moved = proc.f(
                t_s, points[:nx, :, distinct], u, points[nx : nx + nv, :, distinct]
            )  # eq. (14)
            x_points = np.empty((nx, batch, 2 * n_aug + 1))
            x_points[:, :, distinct] = moved
            x_points[:, :, _w_only_columns(nx + nv, n_aug)] = moved[:, :, :1]
        else:
            x_points = proc.f(t_s, points[:nx], u, points[nx : nx + nv])  # eq. (14)
        pred_mean, pred_cov, x_res = unscented_transform(
            x_points, weights, proc.angle_idx
        )  # (16), (18)
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
