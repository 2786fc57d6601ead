"""The untrusted modes' scoring of their failed channels, as loop kernels numba compiles.

:class:`~immukf_sitl.estimation.fault_modes.DeadOrAnyEvidence` scores each failed
``(mode, channel)`` pair of the bank by the ways it may have failed (dead, stuck, offset,
anything, noisy). The pairs are a handful (six in the paper's bank, up to a dozen in a re-based
one), so the arithmetic is a few dozen flops and numpy's dispatch of some sixty array calls was most
of its cost (156 µs of a 1.1 ms real-air step). These kernels do the same per pair in one call.
They are plain Python in the subset numba compiles; ``py_func`` of each is the interpreted
reference that ``tests/test_compiled_kernels.py`` holds the compiled one to, and the
independent checks of the scoring (``tests/test_untrusted_modes.py``,
``tests/test_rebased_bank.py``) run on the compiled ones.
"""

import math

import numba
import numpy as np

LOG_2PI = math.log(2.0 * math.pi)
#: the smallest normal double: a variance never falls below it
_TINY = float(np.finfo(np.float64).tiny)


@numba.njit(cache=True)
def _log_normal(x: float, var: float) -> float:
    """``log N(x; 0, var)``."""
    return -0.5 * (x * x / var + math.log(var) + LOG_2PI)


@numba.njit(cache=True)
def failure_terms(
    pairs: np.ndarray, innovation: np.ndarray, innovation_cov: np.ndarray, z: np.ndarray,
    previous_z: np.ndarray, offset_reading: np.ndarray, limits: np.ndarray,
    held_beyond_chance: np.ndarray,
) -> np.ndarray:  # fmt: skip
    """The densities of each failed pair, ``(k, 5)``.

    Parameters
    ----------
    pairs : ndarray of int, shape (k, 3)
        Mode, channel and reference slot (the mode that trusts the channel) of each pair.
    innovation, innovation_cov : ndarray, shapes (r, nz), (r, nz, nz)
        The update's innovations and covariances (IMU channels first).
    z : ndarray, shape (nz,)
        The measurement.
    previous_z : ndarray, shape (6,)
        The previous IMU reading (NaN where unknown: nothing held).
    offset_reading : ndarray, shape (k,)
        What each pair's learnt offset adds to its mode's prediction (0 without offsets).
    limits : ndarray, shape (8,)
        ``R`` of the six channels, then the observability threshold (sigmas) and the stuck
        reading's spread (noise sigmas).
    held_beyond_chance : ndarray, shape (6,)
        1.0 where the channel has repeated its reading exactly for longer than a healthy one
        does by chance (:class:`~immukf_sitl.estimation.held_readings.RepeatRuns`): the stuck
        part is seen then, however near the prediction the held value sits.

    Returns
    -------
    ndarray, shape (k, 5)
        Per pair: the UKF's factor of the channel ``N(nu; 0, S)`` (its offset or width
        included), the dead part ``N(z; 0, R)``, the stuck part (the reading equal to the
        previous one to ``stuck_sigmas``), and whether each of the two was seen (1.0 or 0.0). A
        part that cannot be seen (the mode's own prediction within the threshold of what the
        part reads, the reading not ruling it out, and for the stuck part no run of repeats
        beyond chance) scores as the reference mode scores the channel: it says nothing for or
        against the mode.
    """
    k = pairs.shape[0]
    n_sigma, stuck_sigmas = limits[6], limits[7]
    out = np.empty((k, 5))
    for f in range(k):
        j, i, ref = pairs[f, 0], pairs[f, 1], pairs[f, 2]
        r = limits[i]
        nu = innovation[j, i]
        reading = z[i]
        own = reading - nu - offset_reading[f]  # the mode's prediction without its offset
        log_any = _log_normal(nu, innovation_cov[j, i, i])
        s0 = innovation_cov[ref, i, i]
        log_reference = _log_normal(innovation[ref, i], s0)
        gate = n_sigma * math.sqrt(s0)
        # a NaN prediction is never observable: the comparisons are False
        dead_seen = abs(own) > gate or abs(reading) > n_sigma * math.sqrt(r)
        log_dead = _log_normal(reading, r) if dead_seen else log_reference
        held = previous_z[i]
        stuck_var = stuck_sigmas * stuck_sigmas * r
        stuck_seen = math.isfinite(held) and (
            abs(own - held) > gate
            or abs(reading - held) > n_sigma * math.sqrt(stuck_var)
            or held_beyond_chance[i] > 0.5
        )
        log_stuck = _log_normal(reading - held, stuck_var) if stuck_seen else log_reference
        out[f, 0] = log_any
        out[f, 1] = log_dead
        out[f, 2] = log_stuck
        out[f, 3] = 1.0 if dead_seen else 0.0
        out[f, 4] = 1.0 if stuck_seen else 0.0
    return out


@numba.njit(cache=True)
def _log_add_exp(a: float, b: float) -> float:
    """``log(exp(a) + exp(b))``."""
    top = max(a, b)
    if top == -math.inf:
        return -math.inf
    return top + math.log(math.exp(a - top) + math.exp(b - top))


@numba.njit(cache=True)
def _log_sum_exp(a: np.ndarray) -> float:
    """``log sum exp`` of a vector."""
    top = -math.inf
    for x in a:
        top = max(top, x)
    if top == -math.inf:
        return -math.inf
    total = 0.0
    for x in a:
        total += math.exp(x - top)
    return top + math.log(total)


@numba.njit(cache=True)
def failure_update(
    pairs: np.ndarray, terms: np.ndarray, innovation: np.ndarray, innovation_cov: np.ndarray,
    widths: np.ndarray, weights: np.ndarray, log_likelihood: np.ndarray, spreads: np.ndarray,
    noisy: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The modes' log-likelihoods and weights after scoring the failed pairs by the ways to fail.

    Each pair's factor is the predictive mixture of dead, stuck, offset, anything and noisy at
    the mode's weights; the weights become its posterior, floored. The offset part is itself a
    mixture: the healthy reading plus the offset, or now and then an outlier of it, which a
    width of ``V`` on that sample (the outlier gate) kept out of the update. A noisy part is the
    offset part at the noise of its factor, ``S + (k^2 - 1) R`` for ``S``.

    Parameters
    ----------
    pairs, terms : ndarray
        As :func:`failure_terms` takes and gives them.
    innovation, innovation_cov : ndarray
        As for :func:`failure_terms`.
    widths : ndarray, shape (r, 6)
        The variance each mode's update gave each channel (zeros: none).
    weights : ndarray, shape (r, 6, 4 + m)
        The modes' weights of dead, stuck, offset, anything and the ``m`` noise factors, per
        channel.
    log_likelihood : ndarray, shape (r,)
        ``log Lambda_j`` (eq. 25) as the filters computed them.
    spreads : ndarray, shape (8,)
        ``V = range^2 / 3`` of the six channels, then the weights' floor and the share of
        outliers among the samples of a channel read through its offset.
    noisy : ndarray, shape (6, m)
        ``(k^2 - 1) R`` of each channel at each noise factor ``k``.

    Returns
    -------
    (ndarray, ndarray)
        The log-likelihoods ``(r,)`` and the updated weights ``(r, 6, 4 + m)``.
    """
    floor, share = spreads[6], spreads[7]
    n_ways = weights.shape[2]
    out = log_likelihood.copy()
    updated = weights.copy()
    parts = np.empty(n_ways)
    told = np.empty(n_ways)
    log_w = np.empty(n_ways)
    for f in range(pairs.shape[0]):
        j, i = pairs[f, 0], pairs[f, 1]
        nu = innovation[j, i]
        s = innovation_cov[j, i, i]
        width = widths[j, i]
        log_factor = terms[f, 0]
        narrow = max(s - width, _TINY)
        log_anything = _log_normal(nu, narrow + spreads[i])
        # read through the offset but for an outlier now and then (a spike)
        log_offset = _log_add_exp(
            math.log1p(-share) + _log_normal(nu, narrow), math.log(share) + log_anything
        )
        parts[0], parts[1], parts[2], parts[3] = terms[f, 1], terms[f, 2], log_offset, log_anything
        # a part that cannot be seen says nothing of which way the channel failed
        told[0] = terms[f, 1] if terms[f, 3] > 0.5 else log_offset
        told[1] = terms[f, 2] if terms[f, 4] > 0.5 else log_offset
        told[2], told[3] = log_offset, log_anything
        for m in range(n_ways - 4):  # the offset way at a noisier sensor, outliers and all
            parts[4 + m] = _log_add_exp(
                math.log1p(-share) + _log_normal(nu, narrow + noisy[i, m]),
                math.log(share) + log_anything,
            )
            told[4 + m] = parts[4 + m]
        for s_ in range(n_ways):
            log_w[s_] = math.log(max(weights[j, i, s_], floor))
        out[j] += _log_sum_exp(log_w + parts) - log_factor
        joint = log_w + told
        norm = _log_sum_exp(joint)
        total = 0.0
        for s_ in range(n_ways):
            w = max(math.exp(joint[s_] - norm), floor)
            updated[j, i, s_] = w
            total += w
        for s_ in range(n_ways):
            updated[j, i, s_] /= total
    return out, updated


@numba.njit(cache=True)
def read_way(pairs: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """The way that leads each failed pair's weights (ties to the offset), ``(k,)``.

    The offset way is 2, the noise ways 4 on (:data:`~.fault_modes.FAILURE_WAYS`).
    """
    out = np.empty(pairs.shape[0], dtype=np.int64)
    for f in range(pairs.shape[0]):
        w = weights[pairs[f, 0], pairs[f, 1]]
        best = 2
        for s_ in range(w.shape[0]):
            if w[s_] > w[best]:
                best = s_
        out[f] = best
    return out


@numba.njit(cache=True)
def outlier_widths(
    innovation: np.ndarray, variance: np.ndarray, wide: np.ndarray, log_odds: float
) -> np.ndarray:
    """``V`` where a sample's outlier part beats its inlier part, 0 elsewhere, ``(k,)``.

    The offset way's parts: inlier ``N(nu; 0, S)``, outlier ``N(nu; 0, S + V)`` at prior odds
    ``exp(log_odds)``.
    """
    out = np.zeros(innovation.shape[0])
    for f in range(innovation.shape[0]):
        nu, s = innovation[f], variance[f]
        if log_odds + _log_normal(nu, s + wide[f]) > _log_normal(nu, s):
            out[f] = wide[f]
    return out
