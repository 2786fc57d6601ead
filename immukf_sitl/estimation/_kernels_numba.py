"""Compiled kernels of the UKF and IMM step (numba): the numpy reference's maths in a few calls.

The numpy code (``ukf.py``, ``sigma_points.py``, ``linalg.py``, ``imm.py``) is the reference.
At the IMM's sizes (7 modes, 12 states, 49 sigma points) each of its ~150 numpy calls per step
costs more in dispatch than in arithmetic; these loops compute the same quantities for the
whole bank per phase of the step. They differ from the reference by rounding only (the order
of floating-point sums, and covariances symmetric by construction where the reference
symmetrises a product): ``tests/test_compiled_kernels.py`` compares each with its numpy
counterpart, ``tests/test_imm_regression.py`` whole runs.

Layouts are the numpy path's: sigma points ``(n, B, S)`` (component axis first, as every model
function takes them), means ``(B, n)``, covariances ``(B, n, n)``, residuals ``(B, n, S)``.
Outputs go into arrays the caller allocates: boxing arrays returned by a numba function costs
more than the work here. Angle rows are given as a boolean mask.

Cholesky factors carry a guard: a pivot below ``PIVOT_GUARD_REL`` times its diagonal entry
(or a non-finite one) makes the kernel report failure, and the caller repairs the stack with
:func:`immukf_sitl.estimation.linalg.robust_cholesky`, which runs LAPACK first. So every repair
is decided, and counted, by the same code as on the numpy path; the guard only keeps a
rounding difference between this factorisation and LAPACK's from deciding a borderline case
(healthy filter covariances have pivot ratios above 0.05).
"""

import math

import numba
import numpy as np

#: Smallest accepted ``pivot / diagonal`` ratio; below it LAPACK decides (see module docstring).
PIVOT_GUARD_REL = 1e-10
_TWO_PI = 2.0 * math.pi


@numba.njit(cache=True, inline="always", error_model="numpy")
def _wrap(a):
    """[-pi, pi), as ``angles.wrap_angle`` (Python's float modulo, like numpy's)."""
    return (a + math.pi) % _TWO_PI - math.pi


@numba.njit(cache=True, error_model="numpy")
def _cholesky_into(a, out):
    """Lower Cholesky factor of the symmetric ``a`` (n, n) into ``out``; False if unsure."""
    n = a.shape[0]
    for j in range(n):
        pivot = a[j, j]
        for k in range(j):
            pivot -= out[j, k] * out[j, k]
        if not pivot > PIVOT_GUARD_REL * a[j, j]:  # also catches NaN and non-positive
            return False
        d = math.sqrt(pivot)
        out[j, j] = d
        for i in range(j):
            out[i, j] = 0.0
        for i in range(j + 1, n):
            t = a[i, j]
            for k in range(j):
                t -= out[i, k] * out[j, k]
            out[i, j] = t / d
    return True


@numba.njit(cache=True, error_model="numpy")
def factor(cov, sym, chol):
    """``sym = (P + P') / 2`` and its lower Cholesky factor, for a stack ``(B, n, n)``.

    Returns False when any factor failed the pivot guard (``chol`` is then incomplete).
    """
    batch, n, _ = cov.shape
    ok = True
    for b in range(batch):
        for i in range(n):
            for j in range(n):
                sym[b, i, j] = 0.5 * (cov[b, i, j] + cov[b, j, i])
        if not _cholesky_into(sym[b], chol[b]):
            ok = False
    return ok


@numba.njit(cache=True, error_model="numpy")
def state_points(mean, sqrt_cov, spread, out):
    """Sigma points of eq. (11) into ``out`` (n, B, 2n + 1), as ``sigma_points``."""
    batch, n = mean.shape
    for b in range(batch):
        for i in range(n):
            m = mean[b, i]
            out[i, b, 0] = m
            for c in range(n):
                off = spread * sqrt_cov[b, i, c]
                out[i, b, 1 + c] = m + off
                out[i, b, 1 + n + c] = m - off


@numba.njit(cache=True, error_model="numpy")
def augmented_process_points(mean, chol, noise_sqrt, spread, x_out, v_out):
    """The ``(x, v)`` parts of the augmented sigma points (eqs. 9-11) whose ``(x, v)`` differ.

    Columns: the centre, ``+`` the ``nx + nv`` state and process-noise directions, ``-`` the
    same: ``x_out`` (nx, B, nd), ``v_out`` (nv, B, nd) with ``nd = 1 + 2 (nx + nv)``. The
    points that perturb only the measurement noise share the centre's ``(x, v)``.
    """
    batch, nx = mean.shape
    nv = noise_sqrt.shape[0]
    nxv = nx + nv
    for b in range(batch):
        for i in range(nx):
            m = mean[b, i]
            x_out[i, b, 0] = m
            for c in range(nx):
                off = spread * chol[b, i, c]
                x_out[i, b, 1 + c] = m + off
                x_out[i, b, 1 + nxv + c] = m - off
            for c in range(nv):
                x_out[i, b, 1 + nx + c] = m
                x_out[i, b, 1 + nxv + nx + c] = m
        for i in range(nv):
            v_out[i, b, 0] = 0.0
            for c in range(nx):
                v_out[i, b, 1 + c] = 0.0
                v_out[i, b, 1 + nxv + c] = 0.0
            for c in range(nv):
                off = spread * noise_sqrt[i, c]
                v_out[i, b, 1 + nx + c] = 0.0 + off
                v_out[i, b, 1 + nxv + nx + c] = 0.0 - off


@numba.njit(cache=True, error_model="numpy")
def _gather_moments(points, b, src, wm, angle, cols, mean, sines, cosines):
    """Columns ``points[:, b, src[s]]`` into ``cols`` (S, n) and their weighted means.

    Sums run over ``s`` in order for every row at once (independent chains, so they pipeline);
    angle rows get the circular mean, with one sine and cosine per distinct column (``sines``,
    ``cosines``: scratch of the distinct count).
    """
    n = points.shape[0]
    nd = points.shape[2]
    n_sigma = src.size
    for i in range(n):
        mean[i] = 0.0
    for s in range(n_sigma):
        d = src[s]
        w = wm[s]
        for i in range(n):
            value = points[i, b, d]
            cols[s, i] = value
            mean[i] += value * w
    for i in range(n):
        if angle[i]:
            for d in range(nd):
                sines[d] = math.sin(points[i, b, d])
                cosines[d] = math.cos(points[i, b, d])
            sin_sum = 0.0
            cos_sum = 0.0
            for s in range(n_sigma):
                sin_sum += sines[src[s]] * wm[s]
                cos_sum += cosines[src[s]] * wm[s]
            mean[i] = math.atan2(sin_sum, cos_sum)


@numba.njit(cache=True, error_model="numpy")
def _centre_columns(cols, mean, angle):
    """``cols[s] -= mean`` in place, angle rows wrapped: the residuals, (S, n)."""
    n_sigma, n = cols.shape
    for s in range(n_sigma):
        for i in range(n):
            cols[s, i] -= mean[i]
    _wrap_columns(cols, angle)


@numba.njit(cache=True, error_model="numpy")
def _wrap_columns(cols, angle):
    """Wrap the angle columns of ``cols`` (S, n) in place.

    The angle test sits outside the loop over samples: inside it, LLVM if-converts the branch
    and evaluates the modulo (a libm call) for every element.
    """
    n_sigma, n = cols.shape
    for i in range(n):
        if angle[i]:
            for s in range(n_sigma):
                cols[s, i] = _wrap(cols[s, i])


@numba.njit(cache=True, error_model="numpy")
def predict_moments(moved, src, wm, wc, angle, add_cov, x_points, mean, cov, res):
    """Eqs. (14), (16)-(18): the transformed sigma points and their weighted moments.

    ``moved`` (nx, B, nd) holds ``f`` of the distinct columns; column ``s`` of the full set is
    ``moved[:, :, src[s]]`` (``src`` is the identity when every column is distinct). Writes the
    full points ``x_points`` (nx, B, S), ``mean`` (B, nx), ``cov`` (B, nx, nx) plus
    ``add_cov`` (symmetric by construction) and the wrapped residuals ``res`` (B, nx, S).
    """
    nx, batch, nd = moved.shape
    n_sigma = src.size
    rt = np.empty((n_sigma, nx))
    acc = np.empty((nx, nx))
    m = np.empty(nx)
    sines = np.empty(nd)
    cosines = np.empty(nd)
    for b in range(batch):
        _gather_moments(moved, b, src, wm, angle, rt, m, sines, cosines)
        for i in range(nx):
            mean[b, i] = m[i]
            for s in range(n_sigma):
                x_points[i, b, s] = rt[s, i]
        _centre_columns(rt, m, angle)
        for i in range(nx):
            for s in range(n_sigma):
                res[b, i, s] = rt[s, i]
        _weighted_outer(rt, wc, acc)
        for i in range(nx):
            for j in range(i + 1):
                value = acc[i, j] + add_cov[i, j]
                cov[b, i, j] = value
                cov[b, j, i] = value


@numba.njit(cache=True, inline="always", error_model="numpy")
def _fill(a, value):
    """``a[:, :] = value`` as a loop (array expressions cost compile time)."""
    for i in range(a.shape[0]):
        for j in range(a.shape[1]):
            a[i, j] = value


@numba.njit(cache=True, error_model="numpy")
def _weighted_outer(rt, weights, acc):
    """``acc = sum_s (r_s w_s) r_s'`` for rows ``rt[s]`` (full square; callers read i >= j)."""
    n_sigma, n = rt.shape
    _fill(acc, 0.0)
    for s in range(n_sigma):
        w = weights[s]
        for i in range(n):
            a = rt[s, i] * w
            for j in range(n):
                acc[i, j] += a * rt[s, j]


@numba.njit(cache=True, error_model="numpy")
def centred(points, mean, angle, res):
    """``res[b, :, s] = points[:, b, s] - mean[b]`` (B, n, S), angle rows wrapped."""
    n, batch, n_sigma = points.shape
    for b in range(batch):
        for i in range(n):
            m = mean[b, i]
            for s in range(n_sigma):
                res[b, i, s] = points[i, b, s] - m
            if angle[i]:
                for s in range(n_sigma):
                    res[b, i, s] = _wrap(res[b, i, s])


@numba.njit(cache=True, error_model="numpy")
def update(
    pred_mean,
    pred_cov,
    x_res,
    z_points,
    wm,
    wc,
    z_angle,
    x_angle,
    z,
    add_r,
    z_cov,
    innovation,
    new_mean,
    new_cov,
    nis,
    log_det,
):
    """Eqs. (19)-(24): output moments, innovation and the Kalman update of every mode.

    ``z_cov`` gets ``P_zz + add_r`` (eq. 20; ``add_r`` is ``R`` in the additive form, zeros in
    the augmented one). The gain is never formed: with ``L L' = P_zz``, ``W = L^-1 P_zx``,
    ``x = x^- + W' L^-1 z~`` (eq. 22) and ``P = P^- - W' W`` (eq. 23 with the Kalman sign).
    Returns False when a factor of ``P_zz`` failed the pivot guard (outputs then incomplete).
    """
    nz, batch, n_sigma = z_points.shape
    nx = pred_mean.shape[1]
    src = np.arange(n_sigma)
    zr = np.empty((n_sigma, nz))
    xw = np.empty((n_sigma, nx))
    sines = np.empty(n_sigma)
    cosines = np.empty(n_sigma)
    zm = np.empty(nz)
    acc = np.empty((nz, nz))
    cross_t = np.empty((nz, nx))
    chol = np.empty((nz, nz))
    white = np.empty((nz, nx))
    white_innov = np.empty(nz)
    outer = np.empty((nx, nx))
    ok = True
    for b in range(batch):
        _gather_moments(z_points, b, src, wm, z_angle, zr, zm, sines, cosines)
        for i in range(nz):
            innovation[b, i] = z[i] - zm[i]  # eq. (21)
        _wrap_columns(innovation[b : b + 1], z_angle)
        _centre_columns(zr, zm, z_angle)
        _weighted_outer(zr, wc, acc)  # eq. (20)
        for i in range(nz):
            for j in range(i + 1):
                value = acc[i, j] + add_r[i, j]
                z_cov[b, i, j] = value
                z_cov[b, j, i] = value
        # eq. (19), transposed: P_zx[c, a] = sum_s z~_s[c] (x~_s[a] w_s)
        for s in range(n_sigma):
            w = wc[s]
            for a in range(nx):
                xw[s, a] = x_res[b, a, s] * w
        _fill(cross_t, 0.0)
        for s in range(n_sigma):
            for c in range(nz):
                zc = zr[s, c]
                for a in range(nx):
                    cross_t[c, a] += xw[s, a] * zc
        if not _cholesky_into(z_cov[b], chol):
            ok = False
            continue
        # forward substitution: white = L^-1 P_zx, white_innov = L^-1 z~
        for i in range(nz):
            d = chol[i, i]
            t = innovation[b, i]
            for k in range(i):
                t -= chol[i, k] * white_innov[k]
            white_innov[i] = t / d
            for a in range(nx):
                white[i, a] = cross_t[i, a]
            for k in range(i):
                lik = chol[i, k]
                for a in range(nx):
                    white[i, a] -= lik * white[k, a]
            for a in range(nx):
                white[i, a] /= d
        total = 0.0
        half_log_det = 0.0
        for i in range(nz):
            total += white_innov[i] * white_innov[i]
            half_log_det += math.log(chol[i, i])
        nis[b] = total
        log_det[b] = 2.0 * half_log_det
        for a in range(nx):  # eq. (22)
            gain_innov = 0.0
            for i in range(nz):
                gain_innov += white[i, a] * white_innov[i]
            new_mean[b, a] = pred_mean[b, a] + gain_innov
        _wrap_columns(new_mean[b : b + 1], x_angle)
        _fill(outer, 0.0)  # eq. (23): P - W'W, symmetric by construction
        for i in range(nz):
            for a in range(nx):
                wa = white[i, a]
                for c in range(nx):
                    outer[a, c] += wa * white[i, c]
        for a in range(nx):
            for c in range(a + 1):
                value = pred_cov[b, a, c] - outer[a, c]
                new_cov[b, a, c] = value
                new_cov[b, c, a] = value
    return ok


@numba.njit(cache=True, error_model="numpy")
def imm_mix(log_transition, log_mu, means, covs, angle, log_c, mixed_mean, mixed_cov):
    """Eqs. (6)-(8) in log space for every mode ``j``: ``log c_j``, ``x^0j``, ``P^0j``."""
    r, nx = means.shape
    mixing = np.empty((r, r))
    spread = np.empty((r, nx))
    row = np.empty(nx)
    for j in range(r):
        peak = -math.inf
        for i in range(r):
            value = log_transition[i, j] + log_mu[i]
            mixing[i, j] = value
            if value > peak:
                peak = value
        if not math.isfinite(peak):
            peak = 0.0
        total = 0.0
        for i in range(r):
            total += math.exp(mixing[i, j] - peak)
        log_c[j] = math.log(total) + peak  # eq. (6): c_j
        for i in range(r):
            mixing[i, j] = math.exp(mixing[i, j] - log_c[j])  # mu_{i|j}
    sines = np.zeros((r, nx))
    cosines = np.zeros((r, nx))
    for a in range(nx):
        if angle[a]:
            for i in range(r):
                sines[i, a] = math.sin(means[i, a])
                cosines[i, a] = math.cos(means[i, a])
    for j in range(r):
        for a in range(nx):  # eq. (7), circular for angles
            if angle[a]:
                s_sum = 0.0
                c_sum = 0.0
                for i in range(r):
                    s_sum += mixing[i, j] * sines[i, a]
                    c_sum += mixing[i, j] * cosines[i, a]
                mixed_mean[j, a] = math.atan2(s_sum, c_sum)
            else:
                total = 0.0
                for i in range(r):
                    total += mixing[i, j] * means[i, a]
                mixed_mean[j, a] = total
        for i in range(r):
            for a in range(nx):
                spread[i, a] = means[i, a] - mixed_mean[j, a]
        _wrap_columns(spread, angle)
        for a in range(nx):  # eq. (8)
            for c in range(nx):
                row[c] = 0.0
            for i in range(r):
                w = mixing[i, j]
                wa = spread[i, a] * w
                for c in range(nx):
                    row[c] += w * covs[i, a, c] + wa * spread[i, c]
            for c in range(nx):
                mixed_cov[j, a, c] = row[c]


@numba.njit(cache=True, error_model="numpy")
def _nan_max(values):
    """``np.max`` of a 1-D array: NaN if any element is NaN."""
    peak = -math.inf
    for v in values:
        if math.isnan(v):
            return math.nan
        if v > peak:
            peak = v
    return peak


@numba.njit(cache=True, error_model="numpy")
def imm_posterior(log_lik, log_c, floor, log_mu, probs):
    """Eq. (26) in log space, then the probability floor (``imm.floor_probabilities``).

    ``mu_j`` is proportional to ``Lambda_j c_j``; the common factor ``max_j Lambda_j`` is divided
    out first; when no likelihood is finite the predicted odds ``c_j`` are kept.
    """
    r = log_lik.size
    best = _nan_max(log_lik)
    for j in range(r):
        log_mu[j] = log_c[j] if not math.isfinite(best) else (log_lik[j] - best) + log_c[j]
    peak = _nan_max(log_mu)
    if not math.isfinite(peak):
        peak = 0.0
    total = 0.0
    for j in range(r):
        total += math.exp(log_mu[j] - peak)
    log_norm = math.log(total) + peak
    for j in range(r):
        log_mu[j] -= log_norm
        probs[j] = math.exp(log_mu[j])
    lowest = math.inf
    for j in range(r):
        if math.isnan(probs[j]):  # as np.min
            return
        lowest = min(lowest, probs[j])
    if not (floor > 0.0 and lowest < floor):
        return
    fixed = np.empty(r, dtype=np.bool_)
    scaled = np.empty(r)
    for j in range(r):
        fixed[j] = probs[j] < floor
    for _ in range(r):
        n_fixed = 0
        free_sum = 0.0
        for j in range(r):
            if fixed[j]:
                n_fixed += 1
            else:
                free_sum += probs[j]
        factor = (1.0 - floor * n_fixed) / free_sum
        changed = False
        for j in range(r):
            scaled[j] = probs[j] * factor
            if not fixed[j] and scaled[j] < floor:
                fixed[j] = True
                changed = True
        if not changed:
            break
    for j in range(r):
        probs[j] = floor if fixed[j] else scaled[j]
        log_mu[j] = math.log(probs[j])


@numba.njit(cache=True, error_model="numpy")
def imm_combine(means, covs, probs, angle, mean, cov):
    """Eqs. (27)-(28): the probability-weighted mean (circular for angles) and covariance."""
    r, nx = means.shape
    spread = np.empty((r, nx))
    for a in range(nx):
        if angle[a]:
            s_sum = 0.0
            c_sum = 0.0
            for j in range(r):
                s_sum += math.sin(means[j, a]) * probs[j]
                c_sum += math.cos(means[j, a]) * probs[j]
            mean[a] = math.atan2(s_sum, c_sum)
        else:
            total = 0.0
            for j in range(r):
                total += means[j, a] * probs[j]
            mean[a] = total
    for j in range(r):
        for a in range(nx):
            spread[j, a] = means[j, a] - mean[a]
    _wrap_columns(spread, angle)
    for a in range(nx):
        for c in range(a + 1):
            total = 0.0
            for j in range(r):
                total += probs[j] * (covs[j, a, c] + spread[j, a] * spread[j, c])
            cov[a, c] = total
            cov[c, a] = total
