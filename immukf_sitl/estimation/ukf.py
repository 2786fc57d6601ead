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

The filter's arithmetic is in :mod:`immukf_sitl.estimation.kernels`, four calls per step in
the augmented form, seven in the additive one; this module calls ``f`` and ``g`` between them,
applies the safeguards and counts them in :class:`FilterDiagnostics`. The kernels run compiled
(``compiled=True``, the default) or, for debugging and for the tests that compare the two,
uncompiled (``compiled=False``, the same source run by Python; hundreds of times slower).
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from functools import cache, lru_cache
from types import ModuleType
from typing import Literal

import numba
import numpy as np
import scipy.stats

from immukf_sitl.estimation import kernels
from immukf_sitl.estimation.angles import angle_mask
from immukf_sitl.estimation.diagnostics import FilterDiagnostics
from immukf_sitl.estimation.linalg import robust_cholesky
from immukf_sitl.estimation.models import Measurement, MeasurementModel, ProcessModel
from immukf_sitl.estimation.sigma_points import JulierSigmaPoints, SigmaPointScheme, SigmaWeights

NoiseForm = Literal["augmented", "additive"]
#: Tail probability beyond which an innovation is counted as an outlier (it is still used).
OUTLIER_TAIL_PROBABILITY = 1e-9
#: an updated variance may fall below zero by this share of its prediction (round-off of
#: ``P - K P_zz K'`` in double precision, with room), not more
_ROUND_OFF = 1e-6


@lru_cache(maxsize=64)
def outlier_nis_threshold(nz: int) -> float:
    """NIS above which an ``nz``-dimensional innovation counts as an outlier."""
    return float(scipy.stats.chi2.isf(OUTLIER_TAIL_PROBABILITY, nz))


@cache
def load_kernels(compiled: bool = True) -> ModuleType:
    """The kernels module, compiled or not.

    Uncompiled loads a second copy of :mod:`immukf_sitl.estimation.kernels` with
    ``numba.config.DISABLE_JIT`` set while its decorators run, so that every kernel, and every
    helper it calls, is the plain Python function. (The flag is numba's global: load the
    interpreted copy before other threads define numba functions; it is cached afterwards.)
    """
    if not isinstance(compiled, bool):
        raise ValueError(f"compiled: expected True or False, got {compiled!r}")
    if compiled:
        return kernels
    spec = importlib.util.find_spec(kernels.__name__)
    module = importlib.util.module_from_spec(spec)
    disabled = numba.config.DISABLE_JIT
    numba.config.DISABLE_JIT = True
    try:
        spec.loader.exec_module(module)
    finally:
        numba.config.DISABLE_JIT = disabled
    return module


@lru_cache(maxsize=64)
def _process_column_source(n_xv: int, n_aug: int) -> np.ndarray:
    """For each of the ``2 n_aug + 1`` augmented columns, its index among the distinct ones.

    The distinct columns are those whose ``(x, v)`` part differs: the centre, then the ``+`` and
    the ``-`` directions of ``x`` and ``v``. The ``2 nw`` columns that perturb only the
    measurement noise ``w`` repeat the centre (index 0), so ``f`` runs once for them: an exact
    saving of ``2 nw / (2 n_a + 1)`` of the work.
    """
    source = np.zeros(2 * n_aug + 1, dtype=np.int64)
    distinct = np.concatenate([[0], np.arange(1, 1 + n_xv), np.arange(1 + n_aug, 1 + n_aug + n_xv)])
    source[distinct] = np.arange(distinct.size)
    return source  # writeable like every kernel argument: one compiled signature


@lru_cache(maxsize=64)
def _identity_source(n_sigma: int) -> np.ndarray:
    return np.arange(n_sigma, dtype=np.int64)


@lru_cache(maxsize=64)
def _zeros(n: int) -> np.ndarray:
    zeros = np.zeros((n, n))
    zeros.setflags(write=False)
    return zeros


@dataclass(frozen=True)
class UkfEstimate:
    """Estimate of ``B`` filters at one time (batch axis first); what :meth:`step` returns.

    Attributes
    ----------
    t_s : float
        Time of the estimate: the ``t_next_s`` of the step that made it.
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
    gated : ndarray or None, shape (B, nz)
        The variance the measurement's gate added to each output at this sample (None: no
        gate).
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
    gated: np.ndarray | None = None


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
    compiled : bool
        How the kernels run: compiled (True, the default) or uncompiled (False); see
        :func:`load_kernels`.

    Attributes
    ----------
    diagnostics : FilterDiagnostics
        Counts of every safeguard applied so far.
    kernels : module
        The kernels this filter runs (:mod:`immukf_sitl.estimation.kernels` or its interpreted
        copy); an :class:`~immukf_sitl.estimation.imm.ImmEstimator` runs its mixing and
        combination in the same ones.
    compiled : bool
        Which of the two.
    """

    def __init__(
        self,
        process: ProcessModel,
        scheme: SigmaPointScheme | None = None,
        noise_form: NoiseForm = "augmented",
        compiled: bool = True,
    ) -> None:
        if noise_form not in ("augmented", "additive"):
            raise ValueError(f"noise_form must be 'augmented' or 'additive', not {noise_form!r}")
        if noise_form == "additive" and process.additive_noise_cov is None:
            raise ValueError("the additive form needs process.additive_noise_cov")
        self.process = process
        self.scheme: SigmaPointScheme = scheme if scheme is not None else JulierSigmaPoints()
        self.noise_form: NoiseForm = noise_form
        self.diagnostics = FilterDiagnostics()
        self.kernels: ModuleType = load_kernels(compiled)
        self.compiled: bool = compiled
        self._x_angle = angle_mask(process.nx, process.angle_idx)
        self._consider = np.array(process.consider_idx, dtype=np.int64)
        # per measurement model: (model, angle mask, R as added by the update); and the
        # augmented form's constant measurement-noise sigma points per (model, batch)
        self._output_constants: dict[tuple[int, int], tuple] = {}
        self._w_points: dict[tuple[int, int], tuple] = {}

    def initial_estimate(self, t_s: float, mean: np.ndarray, cov: np.ndarray) -> UkfEstimate:
        """An estimate at ``t_s`` to start :meth:`step` from (not updated, zero likelihood).

        Parameters
        ----------
        t_s : float
            Time of the estimate.
        mean, cov : ndarray, shapes (B, nx), (B, nx, nx), or (nx,), (nx, nx) for ``B = 1``
            ``x(0|0)``, ``P(0|0)`` of each filter; the arrays are used, not copied (no step
            writes into an estimate's arrays).
        """
        mean = np.asarray(mean, dtype=float)
        cov = np.asarray(cov, dtype=float)
        if mean.ndim == 1:
            mean, cov = mean[None], cov[None]
        nx = self.process.nx
        if mean.ndim != 2 or mean.shape[1] != nx or cov.shape != (mean.shape[0], nx, nx):
            raise ValueError(
                f"mean and cov must be (B, {nx}) and (B, {nx}, {nx}), got {mean.shape}, {cov.shape}"
            )
        zero = np.zeros(mean.shape[0])
        return UkfEstimate(float(t_s), mean, cov, mean, cov, None, None, zero, zero, False)

    def step(
        self,
        previous: UkfEstimate,
        t_next_s: float,
        u: np.ndarray,
        measurement: Measurement | None,
        process: ProcessModel | None = None,
    ) -> UkfEstimate:
        """Predict from ``k`` to ``k+1`` with control ``u``, then update with ``measurement``.

        Parameters
        ----------
        previous : UkfEstimate
            ``x(k|k)``, ``P(k|k)`` of each filter at time ``previous.t_s`` (from
            :meth:`initial_estimate` or the previous step); ``f`` is called with that time.
        t_next_s : float
            Time of ``k+1``: of ``measurement``, of the estimate returned; ``g`` is called with
            it.
        u : ndarray
            Control held over the step, passed to ``f`` and ``g`` unchanged.
        measurement : Measurement or None
            ``z(k+1)``; ``None`` (or a non-finite ``z``) gives a predict-only step.
        process : ProcessModel, optional
            The process model of this step, when its noise differs from the filter's (an
            adaptive noise level); it must have the filter's ``f``, dimensions, angles and
            consider states. Default: the filter's own.

        Returns
        -------
        UkfEstimate
            ``x(k+1|k+1)``, ``P(k+1|k+1)`` and the step's intermediate results, at ``t_next_s``.
        """
        diag = self.diagnostics
        diag.steps += 1
        if measurement is not None and not np.isfinite(measurement.z).all():
            diag.skipped_nonfinite_measurement += 1
            measurement = None
        mean = np.ascontiguousarray(previous.mean, dtype=float)
        cov = np.ascontiguousarray(previous.cov, dtype=float)
        batch = mean.shape[0]
        proc = self.process if process is None else process
        sym, weights, x_points, pred_mean, pred_cov, x_res = self._predict(
            proc, previous.t_s, mean, cov, u, measurement
        )
        if measurement is None:
            zero = np.zeros(batch)
            return UkfEstimate(
                t_next_s, pred_mean, pred_cov, pred_mean, pred_cov, None, None, zero, zero, False
            )
        return self._update(
            proc, t_next_s, u, measurement, mean, sym, weights, x_points, pred_mean, pred_cov,
            x_res,
        )  # fmt: skip

    def _predict(
        self,
        proc: ProcessModel,
        t_s: float,
        mean: np.ndarray,
        cov: np.ndarray,
        u: np.ndarray,
        measurement: Measurement | None,
    ) -> tuple[np.ndarray, SigmaWeights, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Eqs. (9)-(18): sigma points of ``x(k|k)`` through ``f``; their mean and covariance.

        Returns the symmetrised ``P(k|k)``, the weights, the propagated points, ``x(k+1|k)``,
        ``P(k+1|k)`` and the points' residuals about it.
        """
        kern = self.kernels
        diag = self.diagnostics
        batch, nx = mean.shape

        # P(k|k) symmetrised and factored; a factor the kernel doubts goes to the repairs
        sym = np.empty_like(cov)
        chol = np.empty_like(cov)
        diag.symmetrised += batch
        augmented = self.noise_form == "augmented"
        # the slow states' driving noise rides on the sigma points (referred to the step's
        # start), so that it reaches P_xz and P_zz of the update, not only P(k+1|k)
        drawn = cov if not augmented or proc.state_noise_cov is None else cov + proc.state_noise_cov
        if not kern.factor(drawn, sym, chol):
            chol = robust_cholesky(sym, diag)
        if augmented:
            nv = proc.nv
            n_aug = nx + nv + (measurement.model.nz if measurement is not None else 0)
            weights = self.scheme.weights(n_aug)
            n_distinct = 1 + 2 * (nx + nv)
            x_distinct = np.empty((nx, batch, n_distinct))
            v_distinct = np.empty((nv, batch, n_distinct))
            kern.augmented_process_points(
                mean, chol, proc.noise_sqrt, weights.spread, x_distinct, v_distinct
            )  # eqs. (9)-(11), (13)
            moved = proc.f(t_s, x_distinct, u, v_distinct)  # eq. (14)
            source = _process_column_source(nx + nv, n_aug)
            added_cov = _zeros(nx)
        else:
            weights = self.scheme.weights(nx)
            points = np.empty((nx, batch, 2 * nx + 1))
            kern.state_points(mean, chol, weights.spread, points)  # eq. (11)
            moved = proc.f(t_s, points, u, None)  # eq. (14)
            source = _identity_source(2 * nx + 1)
            added_cov = proc.additive_noise_cov
        n_sigma = source.size
        x_points = np.empty((nx, batch, n_sigma))
        pred_mean = np.empty((batch, nx))
        pred_cov = np.empty((batch, nx, nx))
        x_res = np.empty((batch, nx, n_sigma))
        # eqs. (16)-(18)
        kern.predict_moments(
            np.ascontiguousarray(moved, dtype=float),
            source,
            (weights.mean_weights, weights.cov_weights),  # MomentWeights
            self._x_angle,
            added_cov,
            (x_points, pred_mean, pred_cov, x_res),  # Moments
        )
        # P(k+1|k) is symmetric by construction; counted as symmetrised (twice in the additive
        # form: the transformed covariance and the sum with Q)
        diag.symmetrised += batch if augmented else 2 * batch
        return sym, weights, x_points, pred_mean, pred_cov, x_res

    def _update(
        self,
        proc: ProcessModel,
        t_next_s: float,
        u: np.ndarray,
        measurement: Measurement,
        mean: np.ndarray,
        sym: np.ndarray,
        weights: SigmaWeights,
        x_points: np.ndarray,
        pred_mean: np.ndarray,
        pred_cov: np.ndarray,
        x_res: np.ndarray,
    ) -> UkfEstimate:
        """Eqs. (15), (17), (19)-(25): the measurement update and the likelihood."""
        kern = self.kernels
        diag = self.diagnostics
        augmented = self.noise_form == "augmented"
        batch, nx = pred_mean.shape
        model = measurement.model
        z_angle, added_r = self._output_constants_of(model, batch)
        if measurement.extra_var is not None:
            idx = np.arange(model.nz)
            added_r = added_r.copy()
            added_r[:, idx, idx] += measurement.extra_var
        if augmented:
            w_points = self._measurement_noise_points(model, weights.spread, nx + proc.nv, batch)
            z_points = model.g(t_next_s, x_points, u, w_points)  # eq. (15)
        else:
            # redraw about the prediction so that Q reaches P_xz and P_zz (as filterpy does)
            chol_pred = np.empty_like(pred_cov)
            if not kern.factor(pred_cov, np.empty_like(pred_cov), chol_pred):
                chol_pred = robust_cholesky(pred_cov, diag)
            kern.state_points(pred_mean, chol_pred, weights.spread, x_points)
            kern.centred(x_points, pred_mean, self._x_angle, x_res)
            z_points = model.g(t_next_s, x_points, u, None)  # eq. (15)
        z_points = np.ascontiguousarray(z_points, dtype=float)
        nz = model.nz
        gated = None
        if measurement.gate is not None:
            gated = self._gated(measurement, z_points, weights, added_r)
            added_r = added_r.copy()
            idx = np.arange(nz)
            added_r[:, idx, idx] += gated
        out = (  # Updated
            np.empty((batch, nz, nz)),  # P_zz
            np.empty((batch, nz, nx)),  # P_zx
            np.empty((batch, nz)),  # innovation
            np.empty((batch, nz, nz)),  # factors of P_zz
            np.empty((batch, nx)),  # x(k+1|k+1)
            np.empty((batch, nx, nx)),  # P(k+1|k+1)
            np.empty(batch),  # NIS
            np.empty(batch),  # log Lambda
        )
        pred = (pred_mean, pred_cov, x_res)  # Prediction
        # eqs. (17), (19)-(25)
        n_nonfinite = kern.update(
            pred,
            z_points,
            (weights.mean_weights, weights.cov_weights),  # MomentWeights
            (np.ascontiguousarray(measurement.z), added_r, z_angle),  # Observed
            self._x_angle,
            out,
        )
        z_cov, _, innovation, _, new_mean, new_cov, nis, log_likelihood = out
        if n_nonfinite < 0:  # a P_zz the kernel doubts: LAPACK and the repairs factor (and count)
            out = (*out[:3], robust_cholesky(z_cov, diag), *out[4:])
            n_nonfinite = kern.gain_update(pred, self._x_angle, out)
        if self._consider.size:  # eqs. (22)-(23), consider rows of K zeroed: x_c, P_cc kept
            kern.keep_consider(self._consider, pred_mean, pred_cov, new_mean, new_cov)
        if proc.symmetry is not None:  # the unobserved direction moved with the mean
            proc.symmetry.carry(pred_mean, new_mean, new_cov)
        diag.symmetrised += 2 * batch  # P_zz and P(k+1|k+1), symmetric by construction
        diag.outlier_innovations += int(np.count_nonzero(nis > outlier_nis_threshold(nz)))

        bad = np.zeros(batch, dtype=bool)
        if n_nonfinite:
            bad = ~(np.isfinite(new_mean).all(axis=1) & np.isfinite(new_cov).all(axis=(1, 2)))
            diag.nonfinite_state_reset += int(np.count_nonzero(bad))
        # an update only takes variance away: one below zero beyond round-off is a filter far
        # from its measurement (traced: a heading half a turn off at a GPS fix)
        new_var = np.diagonal(new_cov, axis1=1, axis2=2)
        pred_var = np.diagonal(pred_cov, axis1=1, axis2=2)
        lost = ~bad & ~(new_var >= -_ROUND_OFF * np.abs(pred_var)).all(axis=1)
        if lost.any():
            diag.indefinite_state_reset += int(np.count_nonzero(lost))
            bad |= lost
        if bad.any():  # reset those filters to x(k|k), P(k|k); their likelihood is zero
            new_mean[bad] = np.where(np.isfinite(mean[bad]), mean[bad], 0.0)
            new_cov[bad] = np.where(np.isfinite(sym[bad]), sym[bad], 0.0)
            log_likelihood[bad] = -np.inf
        return UkfEstimate(
            t_next_s, new_mean, new_cov, pred_mean, pred_cov, innovation, z_cov, log_likelihood,
            nis, True, gated,
        )  # fmt: skip

    def _gated(
        self,
        measurement: Measurement,
        z_points: np.ndarray,
        weights: SigmaWeights,
        added_r: np.ndarray,
    ) -> np.ndarray:
        """What the measurement's gate adds to each filter's output variances at this sample.

        The gate sees the innovation (eq. 21) of each of its ``(filter, output)`` pairs and its
        variance, the diagonal of ``P_zz`` (eq. 20) before anything it adds; angle outputs are
        not wrapped, so a gate reads only the others.
        """
        gate = measurement.gate
        assert gate is not None
        innovation = np.empty(gate.filters.shape[0])
        variance = np.empty(gate.filters.shape[0])
        self.kernels.pair_moments(
            z_points, gate.filters, gate.outputs, weights.mean_weights, weights.cov_weights,
            added_r, measurement.z, innovation, variance,
        )  # fmt: skip
        gated = np.zeros(added_r.shape[:2])
        gated[gate.filters, gate.outputs] = gate.widths(innovation, variance)
        return gated

    def _output_constants_of(
        self, model: MeasurementModel, batch: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """Angle mask of the output and what each filter adds to ``P_zz`` (``(batch, nz, nz)``)."""
        key = (id(model), batch)
        entry = self._output_constants.get(key)
        if entry is None or entry[0] is not model:
            added = model.added_cov(batch, additive=self.noise_form == "additive")
            entry = (model, angle_mask(model.nz, model.angle_idx), np.ascontiguousarray(added))
            self._output_constants[key] = entry
        return entry[1], entry[2]

    def _measurement_noise_points(
        self, model: MeasurementModel, spread: float, n_xv: int, batch: int
    ) -> np.ndarray:
        """The w rows of the augmented sigma points (eq. 11): constant for a model and batch."""
        key = (id(model), batch)
        entry = self._w_points.get(key)
        if entry is None or entry[0] is not model:
            nw = model.nz
            points = np.empty((nw, batch, 2 * (n_xv + nw) + 1))
            self.kernels.measurement_noise_points(model.noise_sqrt, spread, n_xv, points)
            points.setflags(write=False)
            entry = (model, points)
            self._w_points[key] = entry
        return entry[1]
