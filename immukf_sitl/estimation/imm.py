"""The Interacting Multiple Model estimator over a bank of mode-matched UKFs.

Mixing (eqs. 6-8), mode-matched filtering (eqs. 9-25, one batched UKF step for the whole bank),
mode probabilities (eq. 26) in log space, and the combined estimate (eqs. 27-28). Mixing,
probabilities and combination are kernels of :mod:`immukf_sitl.estimation.kernels`, run the
way the bank's filter runs its own (``ukf.kernels``: compiled or interpreted).

Convention (eq. 3), checked on construction: ``transition[i, j] = P(M(k+1) = j | M(k) = i)``;
every row sums to one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from immukf_sitl.estimation.angles import angle_mask
from immukf_sitl.estimation.diagnostics import FilterDiagnostics
from immukf_sitl.estimation.fault_modes import N_IMU, DeadOrAnyEvidence, ObservabilityGate
from immukf_sitl.estimation.kernels import LOG_2PI
from immukf_sitl.estimation.models import Measurement, ProcessModel
from immukf_sitl.estimation.ukf import UnscentedKalmanFilter


def rescored_log_likelihood(
    log_likelihood: np.ndarray, innovation: np.ndarray, innovation_cov: np.ndarray,
    extra_var: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """``log N(nu; 0, S + diag(extra_var))`` of each mode (eq. 25), and that covariance.

    ``extra_var`` ``(m,)`` is added to the first ``m`` outputs. A mode the filter scored at
    ``-inf`` (reset this step) stays there; if a covariance does not factor, the scores are
    returned as they were.
    """
    cov = innovation_cov.copy()
    m = extra_var.shape[0]
    idx = np.arange(m)
    cov[:, idx, idx] += extra_var
    try:
        factor = np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        return log_likelihood, innovation_cov
    white = np.linalg.solve(factor, innovation[:, :, None])[:, :, 0]
    half_log_det = np.sum(np.log(np.diagonal(factor, axis1=1, axis2=2)), axis=1)
    nz = innovation.shape[1]
    scored = -0.5 * (np.sum(white * white, axis=1) + 2.0 * half_log_det + nz * LOG_2PI)  # eq. (25)
    if not np.all(np.isfinite(scored[np.isfinite(log_likelihood)])):
        return log_likelihood, innovation_cov
    return np.where(np.isfinite(log_likelihood), scored, log_likelihood), cov


def rest_log_likelihood_ratios(
    innovation: np.ndarray, innovation_cov: np.ndarray, left_out: np.ndarray
) -> tuple[np.ndarray, np.ndarray, int]:
    """Each mode's log-likelihood over the outputs it does not leave out, less the first's.

    ``left_out`` ``(r, m)`` flags, per mode, the leading outputs it leaves out; every flagged
    mode leaves out the same number. Mode ``j`` and mode 0 are both scored (eq. 25) on the
    Gaussian marginal of the outputs ``j`` keeps, so the two are densities of the same data:
    where a mode that leaves a channel out predicts the *other* sensors better than the base
    that reads it, the channel is corrupting the base (a drift the base follows). Returns the
    ratios ``(r,)``, each mode's normalised innovation squared over the outputs it keeps
    ``(r,)`` (whether its own model fits them) and how many those are. Modes that leave nothing
    out score 0 and 0; so does a mode whose covariance does not factor.
    """
    r, nz = innovation.shape
    slots = np.flatnonzero(left_out.any(axis=1))
    ratios = np.zeros(r)
    nis = np.zeros(r)
    if slots.size == 0:
        return ratios, nis, 0
    kept = np.ones((slots.size, nz), dtype=bool)
    kept[:, : left_out.shape[1]] = ~left_out[slots]
    keep = np.array([np.flatnonzero(row) for row in kept])  # (s, nz - n_out)
    if keep.shape[1] == 0:
        return ratios, nis, 0
    pairs = np.concatenate([slots, np.zeros(slots.size, dtype=np.intp)])  # mode j, then base
    rows = np.concatenate([keep, keep])
    cov = innovation_cov[pairs[:, None, None], rows[:, :, None], rows[:, None, :]]
    nu = innovation[pairs[:, None], rows]
    try:
        factor = np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        return ratios, nis, 0
    white = np.linalg.solve(factor, nu[:, :, None])[:, :, 0]
    squared = np.sum(white * white, axis=1)
    half_log_det = np.sum(np.log(np.diagonal(factor, axis1=1, axis2=2)), axis=1)
    marginal = -0.5 * squared - half_log_det  # eq. (25); 2 pi cancels in the ratio
    ratio = marginal[: slots.size] - marginal[slots.size :]
    finite = np.isfinite(ratio)
    ratios[slots] = np.where(finite, ratio, 0.0)
    nis[slots] = np.where(finite, squared[: slots.size], 0.0)
    return ratios, nis, keep.shape[1]


def sticky_transition(n_modes: int, stay_probability: float) -> np.ndarray:
    """Markov matrix with ``stay_probability`` on the diagonal, the rest spread evenly."""
    if not 0.0 < stay_probability <= 1.0:
        raise ValueError(f"stay_probability must be in (0, 1], got {stay_probability}")
    if n_modes == 1:
        return np.ones((1, 1))
    off = (1.0 - stay_probability) / (n_modes - 1)
    matrix = np.full((n_modes, n_modes), off)
    np.fill_diagonal(matrix, stay_probability)
    return matrix


@dataclass(frozen=True)
class ImmEstimate:
    """State of the IMM at one time; what :meth:`ImmEstimator.step` returns.

    Attributes
    ----------
    t_s : float
        Time of the estimate: the ``t_next_s`` of the step that made it.
    mean, cov : ndarray, shapes (nx,), (nx, nx)
        Combined estimate ``x(k+1|k+1)``, ``P(k+1|k+1)`` (eqs. 27-28).
    mode_probabilities : ndarray, shape (r,)
        ``mu_j(k+1)`` (eq. 26).
    log_mode_probabilities : ndarray, shape (r,)
        Their logarithms (what the recursion carries; may be ``-inf`` without a floor).
    mode_means, mode_covs : ndarray, shapes (r, nx), (r, nx, nx)
        Mode-matched estimates ``x^j(k+1|k+1)``, ``P^j(k+1|k+1)``.
    log_likelihoods : ndarray, shape (r,)
        ``log Lambda_j(k+1)`` (eq. 25) as scored (after the ``evidence`` gate), zeros on a
        predict-only step.
    innovations : ndarray or None, shape (r, nz)
        Mode-matched innovations, None on a predict-only step.
    nis : ndarray, shape (r,)
        Mode-matched normalised innovation squared.
    updated : bool
        Whether a measurement was used.
    innovation_var : ndarray or None, shape (r, nz)
        Variances of the innovations (the diagonals of ``P_zz``), None on a predict-only step.
    failure_weights : ndarray or None, shape (r, 6, w)
        Each mode's weights of how each channel failed (dead, stuck, offset, anything, noisy at
        each factor: :data:`~.fault_modes.FAILURE_WAYS`), when the
        ``evidence`` carries them (:meth:`DeadOrAnyEvidence.score`); None otherwise.
    predicted_means : ndarray or None, shape (r, nx)
        Each mode's ``x(k+1|k)``, the state its innovations were taken against; None before
        the first step.
    outliers : ndarray of bool or None, shape (r, 6)
        The IMU samples each mode kept out of its update as outliers of a failed channel's
        learnt offset (:meth:`DeadOrAnyEvidence.outlier_gate`); None without a gate.
    rest_ratios : ndarray or None, shape (r,)
        Each mode's log-likelihood ratio to mode 0 over the outputs other than the channels it
        leaves out (:func:`rest_log_likelihood_ratios`); None where the estimator computes
        none (no ``rest_left_out``, or a step without an update).
    rest_nis : ndarray or None, shape (r,)
        Each mode's normalised innovation squared over those outputs, ``rest_dof`` of them.
    """

    t_s: float
    mean: np.ndarray
    cov: np.ndarray
    mode_probabilities: np.ndarray
    log_mode_probabilities: np.ndarray
    mode_means: np.ndarray
    mode_covs: np.ndarray
    log_likelihoods: np.ndarray
    innovations: np.ndarray | None
    nis: np.ndarray
    updated: bool
    innovation_var: np.ndarray | None = None
    failure_weights: np.ndarray | None = None
    predicted_means: np.ndarray | None = None
    outliers: np.ndarray | None = None
    rest_ratios: np.ndarray | None = None
    rest_nis: np.ndarray | None = None
    rest_dof: int = 0

    @property
    def most_likely_mode(self) -> int:
        """Index of the most probable mode."""
        return int(np.argmax(self.log_mode_probabilities))


class ImmEstimator:
    """IMM over a bank of ``r`` mode-matched filters run as one batched UKF.

    Parameters
    ----------
    ukf : UnscentedKalmanFilter
        The filter of every mode; modes differ through the (mode-batched) measurement model
        passed to :meth:`step`, e.g. one built by ``fault_mode_output``. Its ``kernels`` run
        the IMM's arithmetic too.
    transition : ndarray, shape (r, r)
        ``transition[i, j] = P(M(k+1)=j | M(k)=i)`` (eq. 3).
    probability_floor : float
        Lower bound on every mode probability after eq. (26), so that a mode ruled out can come
        back; 0 disables it (see :func:`immukf_sitl.estimation.kernels.floor_probabilities`).
    evidence : ObservabilityGate or DeadOrAnyEvidence, optional
        Adjusts the mode-matched log-likelihoods before eq. (26) (e.g. so that a failed channel
        scores its mode only while observable); None uses them as they are.
    history_floor : float
        Where eqs. (6)-(8) mix the states ``history_states``, every mode but the first (the
        bank's base) is weighted as if its probability were at least this (0: the textbook
        mixing). A fault mode at the floor then takes ``onset / history_floor`` of its start
        from the base each step and keeps the rest of its own history: a filter that has not
        read the channel for about ``history_floor / onset`` steps, which tests a failure that
        grows slowly (a drift) where a mode re-seeded from the base each step cannot (the base
        has followed it). Its probability (eq. 26) and the other states are mixed as the
        textbook does.
    history_states : slice, optional
        The states that keep the floored history (default: all).
    history_slots : ndarray of bool, optional
        ``(r,)``: the modes that keep it (default: all but the first).
    rest_left_out : ndarray of bool, optional
        ``(r, m)``: the leading outputs each mode leaves out; with it every updated step also
        gives each mode's evidence over the other outputs (:attr:`ImmEstimate.rest_ratios`).
    scored_beyond : ndarray of bool, optional
        ``(r, m)``: modes whose evidence is their likelihood of the outputs beyond the leading
        ``m`` alone (the rows flag all ``m``; the first mode's row none). Over the leading
        outputs such a mode is given the first mode's log-likelihood, so eq. (26) moves it
        only on the rest (:func:`rest_log_likelihood_ratios`): a mode that trusts a channel
        its state follows explains that channel's readings as well as any, whether the channel
        is sound or not, and only the other outputs tell.
    """

    def __init__(
        self,
        ukf: UnscentedKalmanFilter,
        transition: np.ndarray,
        probability_floor: float = 0.0,
        evidence: ObservabilityGate | DeadOrAnyEvidence | None = None,
        history_floor: float = 0.0,
        history_states: slice | None = None,
        history_slots: np.ndarray | None = None,
        rest_left_out: np.ndarray | None = None,
        scored_beyond: np.ndarray | None = None,
    ) -> None:
        transition = np.array(transition, dtype=float)
        if transition.ndim != 2 or transition.shape[0] != transition.shape[1]:
            raise ValueError(f"transition must be square, got shape {transition.shape}")
        if np.any(transition < 0.0) or not np.allclose(transition.sum(axis=1), 1.0, atol=1e-9):
            raise ValueError("transition must be non-negative with rows summing to 1 (eq. 3)")
        n_modes = transition.shape[0]
        if not 0.0 <= probability_floor * n_modes < 1.0:
            raise ValueError(f"probability_floor must be in [0, 1/r), got {probability_floor}")
        self.ukf = ukf
        self.transition = transition
        with np.errstate(divide="ignore"):
            self.log_transition = np.log(transition)
        self.probability_floor = float(probability_floor)
        self.evidence = evidence
        if not 0.0 <= history_floor < 1.0:
            raise ValueError(f"history_floor must be in [0, 1), got {history_floor}")
        self.history_floor = float(history_floor)
        self._history = slice(None) if history_states is None else history_states
        slots = np.arange(n_modes) > 0 if history_slots is None else np.asarray(history_slots)
        if slots.shape != (n_modes,) or slots[0]:
            raise ValueError("history_slots: one flag per mode, the base's False")
        self._history_slots = np.flatnonzero(slots)
        self._rest_left_out = None
        if rest_left_out is not None:
            left_out = np.asarray(rest_left_out, dtype=bool)
            counts = left_out.sum(axis=1)
            if left_out.ndim != 2 or left_out.shape[0] != n_modes or counts[0]:
                raise ValueError("rest_left_out: one row per mode, the base's leaving nothing out")
            if len(set(counts[counts > 0].tolist())) > 1:
                raise ValueError("rest_left_out: every mode that leaves outputs out leaves as many")
            self._rest_left_out = left_out
        self._scored_beyond = None
        if scored_beyond is not None:
            beyond = np.asarray(scored_beyond, dtype=bool)
            if beyond.ndim != 2 or beyond.shape[0] != n_modes or beyond[0].any():
                raise ValueError("scored_beyond: one row per mode, the first mode's flagging none")
            if not all(row.all() or not row.any() for row in beyond):
                raise ValueError("scored_beyond: a row flags all leading outputs or none")
            self._scored_beyond = beyond if beyond.any() else None
        # a step with no more outputs than every scored mode leaves out scores nothing
        self._rest_from = 0
        if self._rest_left_out is not None and self._rest_left_out[1:].all():
            self._rest_from = self._rest_left_out.shape[1]
        self.angle_idx = ukf.process.angle_idx
        self._angle_mask = angle_mask(ukf.process.nx, self.angle_idx)

    @property
    def n_modes(self) -> int:
        """Number of modes ``r``."""
        return self.transition.shape[0]

    @property
    def diagnostics(self) -> FilterDiagnostics:
        """The bank's safeguard counters."""
        return self.ukf.diagnostics

    def _beyond_scores(
        self, log_likelihood: np.ndarray, innovation: np.ndarray, innovation_cov: np.ndarray
    ) -> np.ndarray:
        """``log_likelihood`` with the ``scored_beyond`` modes scored on the outputs beyond."""
        assert self._scored_beyond is not None
        beyond = self._scored_beyond
        slots = beyond.any(axis=1)
        gained = np.zeros(len(log_likelihood))
        if innovation.shape[1] > beyond.shape[1]:  # a step of the leading outputs alone: none
            gained = rest_log_likelihood_ratios(innovation, innovation_cov, beyond)[0]
        out = np.array(log_likelihood, dtype=float)
        out[slots] = out[0] + gained[slots]  # eq. (25) over the outputs beyond, as a ratio
        return out

    def initial_estimate(
        self,
        t_s: float,
        mean: np.ndarray,
        cov: np.ndarray,
        mode_probabilities: np.ndarray | None = None,
    ) -> ImmEstimate:
        """Every mode-matched filter starts from the same ``mean``, ``cov`` (paper, sec. 2.A)."""
        r = self.n_modes
        if mode_probabilities is None:
            mode_probabilities = np.full(r, 1.0 / r)
        probs = np.asarray(mode_probabilities, dtype=float)
        if probs.shape != (r,) or np.any(probs < 0) or not np.isclose(probs.sum(), 1.0):
            raise ValueError(f"mode_probabilities must be {r} non-negative numbers summing to 1")
        mean = np.asarray(mean, dtype=float)
        cov = np.asarray(cov, dtype=float)
        with np.errstate(divide="ignore"):
            log_probs = np.log(probs)
        weights = None if self.evidence is None else self.evidence.prior_weights(r)
        return ImmEstimate(
            float(t_s),
            mean.copy(),
            cov.copy(),
            probs,
            log_probs,
            np.repeat(mean[None], r, axis=0),
            np.repeat(cov[None], r, axis=0),
            np.zeros(r),
            None,
            np.zeros(r),
            False,
            None,
            weights,
        )

    def _mix_weights(self, previous: ImmEstimate, log_c: np.ndarray) -> np.ndarray | None:
        """The failure weights each mode starts the step from, mixed as its state is (eq. 6)."""
        if previous.failure_weights is None:
            return None
        with np.errstate(divide="ignore"):
            log_mix = (
                self.log_transition + previous.log_mode_probabilities[:, None] - log_c[None, :]
            )  # log mu_{i|j}
        mix = np.exp(log_mix)
        weights = previous.failure_weights
        return (mix.T @ weights.reshape(len(weights), -1)).reshape(weights.shape)

    def _mix(self, previous: ImmEstimate) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``log c_j``, the mixed means and covariances of every mode (eqs. 6-8).

        With a :attr:`history_floor`, the states ``history_states`` of the ``history_slots`` are
        mixed with those modes' probabilities floored; ``log c_j`` stays the textbook's.
        """
        log_mu = np.ascontiguousarray(previous.log_mode_probabilities, dtype=float)
        log_c, mixed_mean, mixed_cov = self._mix_with(previous, log_mu)  # eqs. (6)-(8)
        slots = self._history_slots
        if self.history_floor > 0.0 and slots.size:
            floored = log_mu.copy()
            floored[slots] = np.maximum(floored[slots], np.log(self.history_floor))
            _, kept_mean, kept_cov = self._mix_with(previous, floored)
            rows = self._history
            mixed_mean[slots, rows] = kept_mean[slots, rows]
            mixed_cov[slots, rows, rows] = kept_cov[slots, rows, rows]
        return log_c, mixed_mean, mixed_cov

    def _mix_with(
        self, previous: ImmEstimate, log_mu: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Eqs. (6)-(8) of ``previous``'s filters weighted by ``log_mu``."""
        means = np.ascontiguousarray(previous.mode_means, dtype=float)
        covs = np.ascontiguousarray(previous.mode_covs, dtype=float)
        r, nx = means.shape
        log_c = np.empty(r)
        mixed_mean = np.empty((r, nx))
        mixed_cov = np.empty((r, nx, nx))
        self.ukf.kernels.imm_mix(
            self.log_transition, log_mu, means, covs, self._angle_mask, log_c, mixed_mean,
            mixed_cov,
        )  # fmt: skip
        return log_c, mixed_mean, mixed_cov

    def step(
        self,
        previous: ImmEstimate,
        t_next_s: float,
        u: np.ndarray,
        measurement: Measurement | None,
        process: ProcessModel | None = None,
        previous_z: np.ndarray | None = None,
        score_var: np.ndarray | None = None,
        held_beyond_chance: np.ndarray | None = None,
    ) -> ImmEstimate:
        """One IMM cycle from ``previous`` (time ``k``) to ``t_next_s`` (``k+1``), control ``u``.

        The arguments are those of :meth:`UnscentedKalmanFilter.step`, with ``previous`` the
        bank's estimate at ``k`` (from :meth:`initial_estimate` or the previous step): mixing
        (eqs. 6-8), the mode-matched filters (eqs. 9-25), the mode probabilities (eq. 26) and
        the combination (eqs. 27-28). ``previous_z`` (the measurement at ``k``, if known) lets
        the evidence tell a reading that did not move, and ``held_beyond_chance`` (per IMU
        channel, :class:`~immukf_sitl.estimation.held_readings.RepeatRuns`) one that has not
        moved for longer than chance explains. ``score_var`` (one variance per leading
        output) is what the model's innovations show beyond their covariance: added to ``S``
        where the modes are scored (eq. 25 and the evidence), not in the gain. Returns the
        bank's estimate at ``t_next_s``.
        """
        kern = self.ukf.kernels
        r, nx = previous.mode_means.shape
        log_c, mixed_mean, mixed_cov = self._mix(previous)  # eqs. (6)-(8)
        weights = self._mix_weights(previous, log_c)
        widths = None
        if weights is not None and measurement is not None and self.evidence is not None:
            widths = self.evidence.widths(weights)  # (r, 6): the IMU channels lead the output
            if widths is not None:
                extra = np.zeros((r, measurement.model.nz))
                if measurement.extra_var is not None:
                    extra += measurement.extra_var
                extra[:, : widths.shape[1]] += widths
                gate = self.evidence.outlier_gate(weights)
                measurement = Measurement(measurement.z, measurement.model, extra, gate)
        prior = self.ukf.initial_estimate(previous.t_s, mixed_mean, mixed_cov)
        filtered = self.ukf.step(prior, t_next_s, u, measurement, process)  # eqs. (9)-(25)

        log_likelihood = filtered.log_likelihood
        scored_cov = filtered.innovation_cov
        if score_var is not None and filtered.updated and np.any(score_var > 0.0):
            assert filtered.innovation is not None and scored_cov is not None
            log_likelihood, scored_cov = rescored_log_likelihood(
                log_likelihood, filtered.innovation, scored_cov, score_var
            )
        if self.evidence is not None and filtered.updated:
            assert measurement is not None and filtered.innovation is not None
            if widths is not None and filtered.gated is not None:
                widths = widths + filtered.gated[:, : widths.shape[1]]  # what the update read
            log_likelihood, weights = self.evidence.score(
                t_next_s, filtered.predicted_mean, filtered.innovation,
                scored_cov, measurement.z, u, log_likelihood, weights, previous_z,
                widths, held_beyond_chance,
            )  # fmt: skip
        rest: tuple[np.ndarray | None, np.ndarray | None, int] = (None, None, 0)
        if (
            self._rest_left_out is not None
            and filtered.updated
            and filtered.innovation is not None
            and filtered.innovation.shape[1] > self._rest_from
        ):
            assert scored_cov is not None
            rest = rest_log_likelihood_ratios(filtered.innovation, scored_cov, self._rest_left_out)
        if self._scored_beyond is not None and filtered.updated:
            assert filtered.innovation is not None and scored_cov is not None
            log_likelihood = self._beyond_scores(log_likelihood, filtered.innovation, scored_cov)
        log_mu = np.empty(r)
        probs = np.empty(r)
        kern.imm_posterior(log_likelihood, log_c, self.probability_floor, log_mu, probs)  # eq. (26)
        mean = np.empty(nx)
        cov = np.empty((nx, nx))
        kern.imm_combine(
            filtered.mean, filtered.cov, probs, self._angle_mask, mean, cov
        )  # eqs. (27)-(28)
        return ImmEstimate(
            filtered.t_s,
            mean,
            cov,
            probs,
            log_mu,
            filtered.mean,
            filtered.cov,
            log_likelihood,
            filtered.innovation,
            filtered.nis,
            filtered.updated,
            None
            if filtered.innovation_cov is None
            else np.diagonal(filtered.innovation_cov, axis1=1, axis2=2).copy(),
            weights,
            filtered.predicted_mean,
            None if filtered.gated is None else filtered.gated[:, :N_IMU] > 0.0,
            *rest,
        )
