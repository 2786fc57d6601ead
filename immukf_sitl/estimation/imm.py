"""The Interacting Multiple Model estimator over a bank of mode-matched UKFs.

Mixing (eqs. 6-8), mode-matched filtering (eqs. 9-25, one batched UKF step for the whole bank),
mode probabilities (eq. 26) in log space, and the combined estimate (eqs. 27-28). Mixing and
combination run in the UKF's backend: numpy (the reference, below) or the compiled kernels of
:mod:`immukf_sitl.estimation._kernels_numba`.

Convention (eq. 3), checked on construction: ``transition[i, j] = P(M(k+1) = j | M(k) = i)``;
every row sums to one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from immukf_sitl.estimation.angles import weighted_mean, wrap_angle
from immukf_sitl.estimation.diagnostics import FilterDiagnostics
from immukf_sitl.estimation.linalg import symmetrise
from immukf_sitl.estimation.models import Measurement
from immukf_sitl.estimation.ukf import UnscentedKalmanFilter


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


def logsumexp(values: np.ndarray, axis: int | None = None) -> np.ndarray:
    """``log(sum(exp(values)))`` without overflow (scipy's version costs ~50 us a call)."""
    peak = np.max(values, axis=axis, keepdims=True)
    peak = np.where(np.isfinite(peak), peak, 0.0)
    total = np.log(np.sum(np.exp(values - peak), axis=axis, keepdims=True)) + peak
    return total.squeeze() if axis is None else np.squeeze(total, axis=axis)


def floor_probabilities(probs: np.ndarray, floor: float) -> np.ndarray:
    """Raise every probability to at least ``floor``, taking the mass from the others pro rata.

    Probabilities below the floor are set to it; the rest are scaled to share what is left,
    repeated until none falls below (at most ``r`` rounds). The result sums to one.
    """
    fixed = probs < floor
    scaled = probs
    for _ in range(probs.size):
        free_mass = 1.0 - floor * np.count_nonzero(fixed)
        scaled = probs * (free_mass / probs[~fixed].sum())
        now_fixed = fixed | (scaled < floor)
        if np.array_equal(now_fixed, fixed):
            break
        fixed = now_fixed
    return np.where(fixed, floor, scaled)


@dataclass(frozen=True)
class ImmEstimate:
    """State of the IMM after a step.

    Attributes
    ----------
    t_s : float
        Time of the estimate.
    mean, cov : ndarray, shapes (nx,), (nx, nx)
        Combined estimate ``x(k+1|k+1)``, ``P(k+1|k+1)`` (eqs. 27-28).
    mode_probabilities : ndarray, shape (r,)
        ``mu_j(k+1)`` (eq. 26).
    log_mode_probabilities : ndarray, shape (r,)
        Their logarithms (what the recursion carries; may be ``-inf`` without a floor).
    mode_means, mode_covs : ndarray, shapes (r, nx), (r, nx, nx)
        Mode-matched estimates ``x^j(k+1|k+1)``, ``P^j(k+1|k+1)``.
    log_likelihoods : ndarray, shape (r,)
        ``log Lambda_j(k+1)`` (eq. 25), zeros on a predict-only step.
    innovations : ndarray or None, shape (r, nz)
        Mode-matched innovations, None on a predict-only step.
    nis : ndarray, shape (r,)
        Mode-matched normalised innovation squared.
    updated : bool
        Whether a measurement was used.
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
        passed to :meth:`step`, e.g. one built by ``fault_masked_output``.
    transition : ndarray, shape (r, r)
        ``transition[i, j] = P(M(k+1)=j | M(k)=i)`` (eq. 3).
    probability_floor : float
        Lower bound on every mode probability after eq. (26), so that a mode ruled out can come
        back; 0 disables it (see :func:`floor_probabilities`).
    """

    def __init__(
        self,
        ukf: UnscentedKalmanFilter,
        transition: np.ndarray,
        probability_floor: float = 0.0,
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
        self.angle_idx = ukf.process.angle_idx
        self._kernels = ukf._kernels
        self._angle_mask = ukf._x_angle

    @property
    def n_modes(self) -> int:
        """Number of modes ``r``."""
        return self.transition.shape[0]

    @property
    def diagnostics(self) -> FilterDiagnostics:
        """The bank's safeguard counters."""
        return self.ukf.diagnostics

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
        return ImmEstimate(
            t_s,
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
        )

    def step(
        self,
        previous: ImmEstimate,
        t_s: float,
        u: np.ndarray,
        measurement: Measurement | None,
    ) -> ImmEstimate:
        """One IMM cycle from ``previous`` (time k) to ``k+1`` with control ``u``."""
        log_mu = previous.log_mode_probabilities
        if self._kernels is not None:
            log_c, mixed_mean, mixed_cov = self._mix_compiled(previous)
        else:
            # eq. (6): c_j = sum_i p_ij mu_i and mu_{i|j} = p_ij mu_i / c_j, in log space
            log_joint = self.log_transition + log_mu[:, None]
            log_c = logsumexp(log_joint, axis=0)
            mixing = np.exp(log_joint - log_c[None, :])  # [i, j] = mu_{i|j}
            mixed_mean, mixed_cov = self._mix(previous.mode_means, previous.mode_covs, mixing)

        filtered = self.ukf.step(t_s, mixed_mean, mixed_cov, u, measurement)

        if self._kernels is not None:
            log_mu_new, probs = self._posterior_compiled(filtered.log_likelihood, log_c)
            mean, cov = self._combine_compiled(filtered.mean, filtered.cov, probs)
        else:
            log_mu_new, probs = self._posterior(filtered.log_likelihood, log_c)
            mean, cov = self._combine(filtered.mean, filtered.cov, probs)
        return ImmEstimate(
            filtered.t_s,
            mean,
            cov,
            probs,
            log_mu_new,
            filtered.mean,
            filtered.cov,
            filtered.log_likelihood,
            filtered.innovation,
            filtered.nis,
            filtered.updated,
        )

    def _posterior(self, log_lik: np.ndarray, log_c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Log and linear mode probabilities after eq. (26) and the probability floor."""
        # eq. (26) in log space: mu_j proportional to Lambda_j c_j. The common factor
        # max_j Lambda_j is divided out first so that huge log-likelihoods keep their precision.
        best = np.max(log_lik)
        if not np.isfinite(best):  # every mode rejected the data: keep the predicted odds
            log_post = log_c.copy()
        else:
            log_post = (log_lik - best) + log_c
        log_mu_new = log_post - logsumexp(log_post)
        probs = np.exp(log_mu_new)
        if self.probability_floor > 0.0 and probs.min() < self.probability_floor:
            probs = floor_probabilities(probs, self.probability_floor)
            log_mu_new = np.log(probs)
        return log_mu_new, probs

    def _mix(
        self, means: np.ndarray, covs: np.ndarray, mixing: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Mixed initial conditions of eqs. (7)-(8) for every mode j at once."""
        mixed_mean = mixing.T @ means  # eq. (7): row j is x^0j
        if self.angle_idx:  # circular mean for angles
            idx = list(self.angle_idx)
            mixed_mean[:, idx] = np.arctan2(
                mixing.T @ np.sin(means[:, idx]), mixing.T @ np.cos(means[:, idx])
            )
        spread = means[None, :, :] - mixed_mean[:, None, :]  # [j, i] = x^i - x^0j
        if self.angle_idx:
            idx = list(self.angle_idx)
            spread[:, :, idx] = wrap_angle(spread[:, :, idx])
        weighted = spread * mixing.T[:, :, None]
        mixed_cov = np.einsum("ij,iab->jab", mixing, covs) + np.einsum(
            "jia,jib->jab", weighted, spread
        )  # eq. (8)
        return mixed_mean, mixed_cov

    def _combine(
        self, means: np.ndarray, covs: np.ndarray, probs: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Combined estimate, eqs. (27)-(28).

        Eq. (28) as printed sums over ``j`` but uses ``x^i`` and ``x^0j``; the standard IMM
        combination, used here, is ``sum_j mu_j [P^j + (x^j - x)(x^j - x)']``.
        """
        mean = weighted_mean(means.T, probs, self.angle_idx)  # eq. (27)
        spread = means - mean[None, :]
        if self.angle_idx:
            idx = list(self.angle_idx)
            spread[:, idx] = wrap_angle(spread[:, idx])
        cov = np.einsum("j,jab->ab", probs, covs) + (spread.T * probs) @ spread
        return mean, symmetrise(cov)

    def _mix_compiled(self, previous: ImmEstimate) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``log c_j`` (eq. 6) and the mixed initial conditions (eqs. 7-8), compiled."""
        means = np.ascontiguousarray(previous.mode_means, dtype=float)
        covs = np.ascontiguousarray(previous.mode_covs, dtype=float)
        r, nx = means.shape
        log_c = np.empty(r)
        mixed_mean = np.empty((r, nx))
        mixed_cov = np.empty((r, nx, nx))
        self._kernels.imm_mix(
            self.log_transition,
            np.ascontiguousarray(previous.log_mode_probabilities, dtype=float),
            means,
            covs,
            self._angle_mask,
            log_c,
            mixed_mean,
            mixed_cov,
        )
        return log_c, mixed_mean, mixed_cov

    def _posterior_compiled(
        self, log_lik: np.ndarray, log_c: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_posterior` compiled."""
        log_mu = np.empty(log_c.size)
        probs = np.empty(log_c.size)
        self._kernels.imm_posterior(
            np.ascontiguousarray(log_lik, dtype=float), log_c, self.probability_floor, log_mu, probs
        )
        return log_mu, probs

    def _combine_compiled(
        self, means: np.ndarray, covs: np.ndarray, probs: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Eqs. (27)-(28) compiled (the covariance is symmetric by construction)."""
        nx = means.shape[1]
        mean = np.empty(nx)
        cov = np.empty((nx, nx))
        self._kernels.imm_combine(
            np.ascontiguousarray(means, dtype=float),
            np.ascontiguousarray(covs, dtype=float),
            np.ascontiguousarray(probs, dtype=float),
            self._angle_mask,
            mean,
            cov,
        )
        return mean, cov
