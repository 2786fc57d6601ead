"""The filter's arithmetic, written once: loop kernels of the UKF (eqs. 9-25) and IMM (6-8, 26-28).

Every kernel is a plain Python function in the subset numba compiles, decorated with
``numba.njit``. The filter calls the compiled functions; the same source run by the interpreter
(:func:`immukf_sitl.estimation.ukf.load_kernels` with ``compiled=False``, which loads this module
with ``numba.config.DISABLE_JIT``) is the uncompiled reference that
``tests/test_compiled_kernels.py`` compares them with, kernel by kernel and filter by filter.
The independent checks of the maths (closed-form unscented transforms, the linear Kalman
filter, filterpy, NEES/NIS, the textbook IMM formulas) run on the compiled kernels.

At the IMM's sizes (7 modes, 12 states, 49 sigma points) an array-expression formulation costs
more in dispatch than in arithmetic; these loops compute each phase of the step for the whole
bank in one call. The model functions ``f`` and ``g`` are called by the filter between kernels.

Layouts: sigma points ``(n, B, S)`` (component axis first, as every model function takes them),
means ``(B, n)``, covariances ``(B, n, n)``, residuals ``(B, n, S)``. Outputs go into arrays
the caller allocates (boxing arrays returned by a compiled function costs more than the work
here). Angle components are given as a boolean mask: circular means, wrapped residuals. A
kernel's related arrays travel as one record of a fixed shape (:class:`MomentWeights`,
:class:`Moments`, :class:`Prediction`, :class:`Observed`, :class:`Updated`; named tuples, which
numba compiles to plain fields), so that no kernel takes more than eight arguments and a caller
names what it passes. The kernels read the records by position (the field order is the
record's), so a caller on the hot path may pass plain tuples: numba types a plain tuple of
arrays faster than a named one at every call.

Cholesky factors carry a guard: a pivot below ``PIVOT_GUARD_REL`` times its diagonal entry (or
a non-finite one) makes the kernel report failure, and the caller factors the stack with
:func:`immukf_sitl.estimation.linalg.robust_cholesky` (LAPACK, then the counted repairs). So
every repair is decided, and counted, by one piece of code; the guard only keeps a rounding
difference between this factorisation and LAPACK's from deciding a borderline case (healthy
filter covariances have pivot ratios above 0.05).

Every kernel behaves the same compiled and interpreted: ``error_model="numpy"`` (division by
zero gives inf/NaN) is never relied on, and logarithms of zero go through :func:`_log`.
"""

import math
from typing import NamedTuple

import numba
import numpy as np

#: Smallest accepted ``pivot / diagonal`` ratio; below it LAPACK decides (see module docstring).
PIVOT_GUARD_REL = 1e-10
TWO_PI = 2.0 * math.pi
LOG_2PI = math.log(2.0 * math.pi)


class MomentWeights(NamedTuple):
    """Mean and covariance weights of the sigma points, shape (S,) each (eq. 12)."""

    wm: np.ndarray
    wc: np.ndarray


class Moments(NamedTuple):
    """What :func:`predict_moments` writes.

    The full points ``(n, B, S)``, the means ``(B, n)``, the covariances ``(B, n, n)`` and the
    residuals ``(B, n, S)``.
    """

    points: np.ndarray
    mean: np.ndarray
    cov: np.ndarray
    res: np.ndarray


class Prediction(NamedTuple):
    """The prediction the update starts from.

    ``x(k+1|k)`` ``(B, nx)``, ``P(k+1|k)`` ``(B, nx, nx)`` and the state residuals ``X_s - x^``
    ``(B, nx, S)`` of the points the outputs come from.
    """

    mean: np.ndarray
    cov: np.ndarray
    res: np.ndarray


class Observed(NamedTuple):
    """What was measured and how to read it.

    The measurement ``z`` ``(nz,)``, what each filter adds to its ``P_zz`` ``(B, nz, nz)``
    (``R`` in the additive form, a fault mode's width on its failed channels in either form)
    and the output's angle mask ``(nz,)``.
    """

    z: np.ndarray
    add_r: np.ndarray
    angle: np.ndarray


class Updated(NamedTuple):
    """What the update writes.

    ``P_zz`` ``(B, nz, nz)``, ``P_zx`` ``(B, nz, nx)``, ``z~`` ``(B, nz)``, the factors of
    ``P_zz`` ``(B, nz, nz)``, ``x(k+1|k+1)`` ``(B, nx)``, ``P(k+1|k+1)`` ``(B, nx, nx)``, NIS
    ``(B,)`` and ``log Lambda`` ``(B,)``.
    """

    z_cov: np.ndarray
    cross: np.ndarray
    innovation: np.ndarray
    z_chol: np.ndarray
    mean: np.ndarray
    cov: np.ndarray
    nis: np.ndarray
    log_lik: np.ndarray


class _UpdateScratch(NamedTuple):
    """Per-filter scratch of the update, reused across the bank."""

    src: np.ndarray
    cols: np.ndarray
    z_mean: np.ndarray
    xw: np.ndarray
    trig: tuple
    acc: np.ndarray
    white: np.ndarray
    white_innov: np.ndarray
    outer: np.ndarray


@numba.njit(cache=True, inline="always", error_model="numpy")
def wrap(angle: float) -> float:
    """Wrap to [-pi, pi): ``(a + pi) mod 2 pi - pi`` (Python's float modulo, as numpy's).

    Also the array form: :func:`immukf_sitl.estimation.angles.wrap_angle` runs this function
    uncompiled on numpy arrays.
    """
    return (angle + math.pi) % TWO_PI - math.pi


@numba.njit(cache=True, inline="always", error_model="numpy")
def _log(x):
    """``log x``, with ``log 0 = -inf`` also when interpreted (``math.log`` raises there)."""
    if x > 0.0:
        return math.log(x)
    return -math.inf if x == 0.0 else math.nan


@numba.njit(cache=True, inline="always", error_model="numpy")
def _fill(a, value):
    """``a[:, :] = value`` as a loop (array expressions cost compile time)."""
    for i in range(a.shape[0]):
        for j in range(a.shape[1]):
            a[i, j] = value


# -- square roots and sigma points (eqs. 9-11) -------------------------------------------------


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
def factor(cov: np.ndarray, sym: np.ndarray, chol: np.ndarray) -> bool:
    """``sym = (P + P') / 2`` and its lower Cholesky factor ``L L' = sym``, for a stack.

    Parameters
    ----------
    cov : ndarray, shape (B, n, n)
        ``P``, symmetric up to rounding.
    sym, chol : ndarray, shape (B, n, n)
        Outputs: the symmetrised ``P`` and ``L`` (zeros above the diagonal).

    Returns
    -------
    bool
        False when any factor failed the pivot guard (``chol`` is then incomplete).
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
def state_points(mean: np.ndarray, sqrt_cov: np.ndarray, spread: float, out: np.ndarray) -> None:
    """Eq. (11): the sigma points ``[x, x + c L[:, 0..n-1], x - c L[:, 0..n-1]]``.

    Parameters
    ----------
    mean : ndarray, shape (B, n)
    sqrt_cov : ndarray, shape (B, n, n)
        Any ``L`` with ``L L' = P``.
    spread : float
        The ``c`` of the sigma-point scheme.
    out : ndarray, shape (n, B, 2n + 1)
        Output.
    """
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
def _noise_rows(noise_sqrt, spread, first, half, b, out):
    """Noise rows of augmented sigma points (eqs. 9-11: zero mean, ``+- c`` times ``sqrt(Q)``).

    Row ``i`` of ``out[:, b, :]`` is zero but for ``+ c L[i, k]`` at column ``1 + first + k``
    and ``- c L[i, k]`` at column ``1 + half + first + k``.
    """
    n_rows, n_dirs = noise_sqrt.shape
    for i in range(n_rows):
        for s in range(out.shape[2]):
            out[i, b, s] = 0.0
        for k in range(n_dirs):
            off = spread * noise_sqrt[i, k]
            out[i, b, 1 + first + k] = 0.0 + off
            out[i, b, 1 + half + first + k] = 0.0 - off


@numba.njit(cache=True, error_model="numpy")
def augmented_process_points(
    mean: np.ndarray,
    chol: np.ndarray,
    noise_sqrt: np.ndarray,
    spread: float,
    x_out: np.ndarray,
    v_out: np.ndarray,
) -> None:
    """The ``(x, v)`` parts of the augmented sigma points (eqs. 9-11) whose ``(x, v)`` differ.

    The augmented mean is ``[x, 0, 0]`` (eq. 9), its square root ``diag(L, sqrt Q, sqrt R)``
    (eq. 10). Columns written: the centre, ``+`` the ``nx + nv`` state and process-noise
    directions, ``-`` the same. The points that perturb only the measurement noise share the
    centre's ``(x, v)``.

    Parameters
    ----------
    mean : ndarray, shape (B, nx)
    chol : ndarray, shape (B, nx, nx)
        ``L`` with ``L L' = P``.
    noise_sqrt : ndarray, shape (nv, nv)
        ``sqrt Q``.
    spread : float
        The ``c`` of the sigma-point scheme at the augmented dimension.
    x_out, v_out : ndarray, shapes (nx, B, nd), (nv, B, nd), ``nd = 1 + 2 (nx + nv)``
        Outputs.
    """
    batch, nx = mean.shape
    nxv = nx + noise_sqrt.shape[0]
    for b in range(batch):
        for i in range(nx):
            m = mean[b, i]
            x_out[i, b, 0] = m
            for c in range(nx):
                off = spread * chol[b, i, c]
                x_out[i, b, 1 + c] = m + off
                x_out[i, b, 1 + nxv + c] = m - off
            for c in range(nx, nxv):
                x_out[i, b, 1 + c] = m
                x_out[i, b, 1 + nxv + c] = m
        _noise_rows(noise_sqrt, spread, nx, nxv, b, v_out)


@numba.njit(cache=True, error_model="numpy")
def measurement_noise_points(
    noise_sqrt: np.ndarray, spread: float, n_xv: int, out: np.ndarray
) -> None:
    """The ``w`` rows of the augmented sigma points (eqs. 9-11).

    Only the ``2 nw`` columns after the ``(x, v)`` directions of each sign are non-zero.

    Parameters
    ----------
    noise_sqrt : ndarray, shape (nw, nw)
        ``sqrt R``.
    spread : float
        The ``c`` of the sigma-point scheme at the augmented dimension ``n_a = n_xv + nw``.
    n_xv : int
        ``nx + nv``.
    out : ndarray, shape (nw, B, 2 n_a + 1)
        Output.
    """
    n_aug = n_xv + noise_sqrt.shape[1]
    for b in range(out.shape[1]):
        _noise_rows(noise_sqrt, spread, n_xv, n_aug, b, out)


# -- the unscented transform (eqs. 12, 16-18, 20) ----------------------------------------------


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
                cols[s, i] = wrap(cols[s, i])


@numba.njit(cache=True, error_model="numpy")
def _gather_moments(points, b, src, wm, angle, cols, mean, trig):
    """Columns ``points[:, b, src[s]]`` into ``cols`` (S, n) and their weighted mean (eq. 16).

    Sums run over ``s`` in order for every row at once (independent chains, so they pipeline);
    angle rows get the circular mean ``atan2(sum w sin, sum w cos)``, with one sine and cosine
    per distinct column (``trig``: the scratch ``(sines, cosines)`` of the distinct count).
    """
    sines, cosines = trig
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
def _weighted_outer(rt, weights, acc):
    """``acc = sum_s (r_s w_s) r_s'`` for rows ``rt[s]``: the lower triangle ``i >= j`` only.

    The sum is symmetric, so callers read ``i >= j`` and mirror it (half the work of the
    square); the upper triangle of ``acc`` stays zero.
    """
    n_sigma, n = rt.shape
    _fill(acc, 0.0)
    s = 0
    while s + 4 <= n_sigma:  # four samples per pass: a quarter of the loads and stores of acc
        w0, w1, w2, w3 = weights[s], weights[s + 1], weights[s + 2], weights[s + 3]
        for i in range(n):
            a0, a1, a2, a3 = rt[s, i] * w0, rt[s + 1, i] * w1, rt[s + 2, i] * w2, rt[s + 3, i] * w3
            for j in range(i + 1):
                acc[i, j] += (a0 * rt[s, j] + a1 * rt[s + 1, j]) + (
                    a2 * rt[s + 2, j] + a3 * rt[s + 3, j]
                )
        s += 4
    for t in range(s, n_sigma):
        w = weights[t]
        for i in range(n):
            a = rt[t, i] * w
            for j in range(i + 1):
                acc[i, j] += a * rt[t, j]


@numba.njit(cache=True, error_model="numpy")
def predict_moments(
    moved: np.ndarray,
    src: np.ndarray,
    weights: MomentWeights,
    angle: np.ndarray,
    add_cov: np.ndarray,
    out: Moments,
) -> None:
    """Eqs. (16)-(18): the transformed sigma points and their weighted moments.

    ``x^ = sum_s Wm_s X_s`` (eq. 16, circular for angles), ``r_s = X_s - x^`` (eq. 17, angles
    wrapped), ``P = sum_s Wc_s r_s r_s' + add_cov`` (eq. 18, symmetric by construction).

    The sums run over the distinct columns ``d`` of ``moved`` only, each weighted by the sum of
    the weights of the columns that repeat it (``sum_{s: src[s] = d} W_s``): the same sums
    regrouped, so equal up to rounding, without the ``2 nw`` copies of the centre the augmented
    form carries (a third of its columns at the real-air model's sizes).

    Parameters
    ----------
    moved : ndarray, shape (nx, B, nd)
        ``f`` of the distinct sigma points (eq. 14).
    src : ndarray of int64, shape (S,)
        Column ``s`` of the full set is ``moved[:, :, src[s]]`` (the identity when every column
        is distinct).
    weights : MomentWeights
        Mean and covariance weights, shape (S,) each.
    angle : ndarray of bool, shape (nx,)
        Angle rows.
    add_cov : ndarray, shape (nx, nx)
        Added to the covariance (``Q`` in the additive form; the slow states' driving noise,
        or zeros, in the augmented one).
    out : Moments
        Outputs: the full points, ``x^``, ``P``, the residuals.
    """
    wm, wc = weights
    x_points, mean, cov, res = out
    nx, batch, nd = moved.shape
    n_sigma = src.size
    wm_d = np.zeros(nd)  # the weights of the distinct columns
    wc_d = np.zeros(nd)
    for s in range(n_sigma):
        wm_d[src[s]] += wm[s]
        wc_d[src[s]] += wc[s]
    distinct = np.arange(nd)
    rd = np.empty((nd, nx))
    acc = np.empty((nx, nx))
    m = np.empty(nx)
    trig = (np.empty(nd), np.empty(nd))
    for b in range(batch):
        _gather_moments(moved, b, distinct, wm_d, angle, rd, m, trig)  # eq. (16)
        _centre_columns(rd, m, angle)  # eq. (17)
        for i in range(nx):
            mean[b, i] = m[i]
            for s in range(n_sigma):
                d = src[s]
                x_points[i, b, s] = moved[i, b, d]
                res[b, i, s] = rd[d, i]
        _weighted_outer(rd, wc_d, acc)  # eq. (18)
        for i in range(nx):
            for j in range(i + 1):
                value = acc[i, j] + add_cov[i, j]
                cov[b, i, j] = value
                cov[b, j, i] = value


@numba.njit(cache=True, error_model="numpy")
def centred(points: np.ndarray, mean: np.ndarray, angle: np.ndarray, res: np.ndarray) -> None:
    """Residuals of eq. (17) about a given mean: ``res[b, :, s] = points[:, b, s] - mean[b]``.

    Parameters
    ----------
    points : ndarray, shape (n, B, S)
    mean : ndarray, shape (B, n)
    angle : ndarray of bool, shape (n,)
        Rows wrapped to [-pi, pi).
    res : ndarray, shape (B, n, S)
        Output.
    """
    n, batch, n_sigma = points.shape
    for b in range(batch):
        for i in range(n):
            m = mean[b, i]
            for s in range(n_sigma):
                res[b, i, s] = points[i, b, s] - m
            if angle[i]:
                for s in range(n_sigma):
                    res[b, i, s] = wrap(res[b, i, s])


# -- the measurement update (eqs. 19-25) -------------------------------------------------------


@numba.njit(cache=True, error_model="numpy")
def _output_moments(b, z_points, weights, observed, x_res, scratch, out):
    """Eqs. (17), (19)-(21) for filter ``b``: ``P_zz + add_r``, ``P_zx`` and the innovation."""
    wm, wc = weights
    z, add_r, z_angle = observed
    src, zr, zm, xw, acc = scratch.src, scratch.cols, scratch.z_mean, scratch.xw, scratch.acc
    z_cov, cross, innovation = out[0], out[1], out[2]  # Updated's first three
    nz, _, n_sigma = z_points.shape
    nx = x_res.shape[1]
    _gather_moments(z_points, b, src, wm, z_angle, zr, zm, scratch.trig)  # eq. (17)
    for i in range(nz):
        innovation[b, i] = z[i] - zm[i]  # eq. (21)
    _wrap_columns(innovation[b : b + 1], z_angle)
    _centre_columns(zr, zm, z_angle)
    _weighted_outer(zr, wc, acc)  # eq. (20)
    for i in range(nz):
        for j in range(i + 1):
            value = acc[i, j] + add_r[b, i, j]
            z_cov[b, i, j] = value
            z_cov[b, j, i] = value
    # eq. (19), transposed: P_zx[c, a] = sum_s z~_s[c] (x~_s[a] w_s)
    for s in range(n_sigma):
        w = wc[s]
        for a in range(nx):
            xw[s, a] = x_res[b, a, s] * w
    for c in range(nz):
        for a in range(nx):
            cross[b, c, a] = 0.0
    s = 0
    while s + 4 <= n_sigma:  # four samples per pass, as in _weighted_outer
        for c in range(nz):
            z0, z1, z2, z3 = zr[s, c], zr[s + 1, c], zr[s + 2, c], zr[s + 3, c]
            for a in range(nx):
                cross[b, c, a] += (xw[s, a] * z0 + xw[s + 1, a] * z1) + (
                    xw[s + 2, a] * z2 + xw[s + 3, a] * z3
                )
        s += 4
    for t in range(s, n_sigma):
        for c in range(nz):
            zc = zr[t, c]
            for a in range(nx):
                cross[b, c, a] += xw[t, a] * zc


@numba.njit(cache=True, error_model="numpy")
def _gain_update(b, pred, x_angle, scratch, out):
    """Eqs. (22)-(25) for filter ``b`` from the lower factor ``L`` of ``P_zz``.

    The gain is never formed: with ``W = L^-1 P_zx`` and ``e = L^-1 z~``, ``K = W' L^-1``
    (eq. 24), so ``x = x^- + W' e`` (eq. 22) and ``P = P^- - W' W`` (eq. 23 with the Kalman
    sign; the paper prints ``+ K P_zz K'``). ``NIS = e' e``; eq. (25) in log space,
    ``log Lambda = -(NIS + log det P_zz + nz log 2 pi) / 2`` (its printed exponent lacks the
    minus sign). Returns whether the new mean and covariance are finite.
    """
    pred_mean, pred_cov, _ = pred
    white, white_innov, outer = scratch.white, scratch.white_innov, scratch.outer
    _, cross, innovation, z_chol, new_mean, new_cov, nis, log_lik = out
    nz = innovation.shape[1]
    nx = pred_mean.shape[1]
    chol = z_chol[b]
    # forward substitution: white = L^-1 P_zx, white_innov = L^-1 z~
    for i in range(nz):
        d = chol[i, i]
        t = innovation[b, i]
        for k in range(i):
            t -= chol[i, k] * white_innov[k]
        white_innov[i] = t / d
        for a in range(nx):
            white[i, a] = cross[b, i, a]
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
    log_lik[b] = -0.5 * (total + 2.0 * half_log_det + nz * LOG_2PI)  # eq. (25)
    for a in range(nx):  # eq. (22)
        gain_innov = 0.0
        for i in range(nz):
            gain_innov += white[i, a] * white_innov[i]
        new_mean[b, a] = pred_mean[b, a] + gain_innov
    _wrap_columns(new_mean[b : b + 1], x_angle)
    _fill(outer, 0.0)  # eq. (23): P - W'W, symmetric by construction: its lower triangle
    for i in range(nz):
        for a in range(nx):
            wa = white[i, a]
            for c in range(a + 1):
                outer[a, c] += wa * white[i, c]
    finite = True
    for a in range(nx):
        finite = finite and math.isfinite(new_mean[b, a])
        for c in range(a + 1):
            value = pred_cov[b, a, c] - outer[a, c]
            new_cov[b, a, c] = value
            new_cov[b, c, a] = value
            finite = finite and math.isfinite(value)
    return finite


@numba.njit(cache=True, error_model="numpy")
def _update_scratch(nz, nx, n_sigma):
    """Scratch of :func:`_output_moments` and :func:`_gain_update` for one bank."""
    return _UpdateScratch(
        np.arange(n_sigma), np.empty((n_sigma, nz)), np.empty(nz), np.empty((n_sigma, nx)),
        (np.empty(n_sigma), np.empty(n_sigma)), np.empty((nz, nz)), np.empty((nz, nx)),
        np.empty(nz), np.empty((nx, nx)),
    )  # fmt: skip


@numba.njit(cache=True, error_model="numpy")
def update(
    pred: Prediction,
    z_points: np.ndarray,
    weights: MomentWeights,
    observed: Observed,
    x_angle: np.ndarray,
    out: Updated,
) -> int:
    """Eqs. (17), (19)-(25): output moments, innovation and the Kalman update of every filter.

    ``z^ = sum_s Wm_s Z_s`` (eq. 17), ``P_zz = sum_s Wc_s (Z_s - z^)(Z_s - z^)' + add_r``
    (eq. 20), ``P_xz = sum_s Wc_s (X_s - x^)(Z_s - z^)'`` (eq. 19), ``z~ = z - z^`` (eq. 21),
    then :func:`gain_update` (eqs. 22-25).

    Parameters
    ----------
    pred : Prediction
        ``x(k+1|k)``, ``P(k+1|k)`` and the state residuals of the points ``z_points`` came from.
    z_points : ndarray, shape (nz, B, S)
        ``g`` of the sigma points (eq. 15).
    weights : MomentWeights
        Mean and covariance weights.
    observed : Observed
        The measurement, what each filter adds to ``P_zz`` and the output's angle mask.
    x_angle : ndarray of bool, shape (nx,)
        Angle components of the state.
    out : Updated
        Outputs: ``P_zz``, ``P_zx`` (transposed ``P_xz``), ``z~``, the factors of ``P_zz``, and
        those of :func:`gain_update`.

    Returns
    -------
    int
        The number of filters whose new mean or covariance is not finite; -1 when a factor of
        ``P_zz`` failed the pivot guard: the caller then factors ``out.z_cov`` itself and calls
        :func:`gain_update` (the outputs after ``z_chol`` are incomplete).
    """
    pred_mean, _, x_res = pred
    z_cov, _, _, z_chol, _, _, _, _ = out
    nz, batch, n_sigma = z_points.shape
    scratch = _update_scratch(nz, pred_mean.shape[1], n_sigma)
    n_nonfinite = 0
    factored = True
    for b in range(batch):
        _output_moments(b, z_points, weights, observed, x_res, scratch, out)
        if not _cholesky_into(z_cov[b], z_chol[b]):
            factored = False
        elif not _gain_update(b, pred, x_angle, scratch, out):
            n_nonfinite += 1
    return n_nonfinite if factored else -1


@numba.njit(cache=True, error_model="numpy")
def gain_update(pred: Prediction, x_angle: np.ndarray, out: Updated) -> int:
    """Eqs. (22)-(25) of every filter from given factors ``L`` of ``P_zz`` (``out.z_chol``).

    With ``W = L^-1 P_zx`` and ``e = L^-1 z~`` (the gain ``K = P_xz P_zz^-1`` of eq. 24 is never
    formed): ``x = x^- + W' e`` (eq. 22), ``P = P^- - W' W`` (eq. 23 with the Kalman sign; the
    paper prints ``+ K P_zz K'``), ``NIS = e' e`` and eq. (25) in log space,
    ``log Lambda = -(NIS + log det P_zz + nz log 2 pi) / 2`` (its printed exponent lacks the
    minus sign). ``out`` holds ``P_zx``, ``z~`` and the factors as :func:`update` writes them,
    and takes ``x(k+1|k+1)``, ``P(k+1|k+1)``, NIS and ``log Lambda``; ``x_angle`` marks the
    state's angles (wrapped after the update).

    Returns
    -------
    int
        The number of filters whose new mean or covariance is not finite.
    """
    pred_mean = pred[0]
    nz, nx = out[1].shape[1], pred_mean.shape[1]  # from P_zx and x(k+1|k)
    scratch = _update_scratch(nz, nx, 0)
    n_nonfinite = 0
    for b in range(pred_mean.shape[0]):
        if not _gain_update(b, pred, x_angle, scratch, out):
            n_nonfinite += 1
    return n_nonfinite


@numba.njit(cache=True, error_model="numpy")
def pair_moments(
    z_points: np.ndarray, filters: np.ndarray, outputs: np.ndarray, mean_weights: np.ndarray,
    cov_weights: np.ndarray, added_r: np.ndarray, z: np.ndarray, innovation: np.ndarray,
    variance: np.ndarray,
) -> None:  # fmt: skip
    """The innovation (eq. 21) and its variance (eq. 20's diagonal) of some (filter, output) pairs.

    ``z_points`` ``(nz, B, S)`` as :func:`update` takes them; ``filters``, ``outputs`` ``(k,)``;
    ``added_r`` ``(B, nz, nz)``; writes ``innovation`` and ``variance`` ``(k,)``. Angle outputs
    are not wrapped.
    """
    for f in range(filters.shape[0]):
        b, i = filters[f], outputs[f]
        predicted = 0.0
        for s in range(z_points.shape[2]):
            predicted += mean_weights[s] * z_points[i, b, s]  # eq. (17)
        spread = 0.0
        for s in range(z_points.shape[2]):
            d = z_points[i, b, s] - predicted
            spread += cov_weights[s] * d * d
        innovation[f] = z[i] - predicted
        variance[f] = spread + added_r[b, i, i]


@numba.njit(cache=True, error_model="numpy")
def keep_consider(
    consider: np.ndarray, pred_mean: np.ndarray, pred_cov: np.ndarray, new_mean: np.ndarray,
    new_cov: np.ndarray,
) -> None:  # fmt: skip
    """Eqs. (22)-(23) with the consider rows of the gain zeroed (Schmidt): ``x_c``, ``P_cc`` kept.

    Parameters
    ----------
    consider : ndarray of int64, shape (nc,)
        Indices of the consider states.
    pred_mean, pred_cov : ndarray, shapes (B, nx), (B, nx, nx)
        ``x(k+1|k)``, ``P(k+1|k)``.
    new_mean, new_cov : ndarray, shapes (B, nx), (B, nx, nx)
        ``x(k+1|k+1)``, ``P(k+1|k+1)`` of the full update; their consider entries are reset to
        the prediction's in place.
    """
    n_c = consider.size
    for b in range(new_mean.shape[0]):
        for a in range(n_c):
            i = consider[a]
            new_mean[b, i] = pred_mean[b, i]
            for c in range(n_c):
                j = consider[c]
                new_cov[b, i, j] = pred_cov[b, i, j]


# -- the IMM (eqs. 6-8, 26-28) -----------------------------------------------------------------


@numba.njit(cache=True, error_model="numpy")
def imm_mix(
    log_transition: np.ndarray, log_mu: np.ndarray, means: np.ndarray, covs: np.ndarray,
    angle: np.ndarray, log_c: np.ndarray, mixed_mean: np.ndarray, mixed_cov: np.ndarray,
) -> None:  # fmt: skip
    """Eqs. (6)-(8) in log space for every mode ``j``: ``log c_j``, ``x^0j``, ``P^0j``.

    ``c_j = sum_i p_ij mu_i`` (eq. 6) and ``mu_{i|j} = p_ij mu_i / c_j``;
    ``x^0j = sum_i mu_{i|j} x^i`` (eq. 7, circular for angles);
    ``P^0j = sum_i mu_{i|j} [P^i + (x^i - x^0j)(x^i - x^0j)']`` (eq. 8).

    Parameters
    ----------
    log_transition : ndarray, shape (r, r)
        ``log p_ij`` (eq. 3; ``-inf`` for impossible transitions).
    log_mu : ndarray, shape (r,)
        ``log mu_i(k)``.
    means, covs : ndarray, shapes (r, nx), (r, nx, nx)
        ``x^i(k|k)``, ``P^i(k|k)``.
    angle : ndarray of bool, shape (nx,)
        Angle components.
    log_c, mixed_mean, mixed_cov : ndarray, shapes (r,), (r, nx), (r, nx, nx)
        Outputs: ``log c_j``, ``x^0j``, ``P^0j``.
    """
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
        log_c[j] = _log(total) + peak  # eq. (6): c_j
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
def floor_probabilities(probs: np.ndarray, floor: float, log_probs: np.ndarray) -> None:
    """Raise every probability to at least ``floor``, taking the mass from the others pro rata.

    Probabilities below the floor are set to it; the rest are scaled to share what is left,
    repeated until none falls below (at most ``r`` rounds); the result sums to one. Nothing
    changes when the floor is 0, no probability is below it, or one is NaN.

    Parameters
    ----------
    probs : ndarray, shape (r,)
        Probabilities summing to one; floored in place.
    floor : float
        The floor, below ``1 / r``.
    log_probs : ndarray, shape (r,)
        Gets the logarithms of the floored probabilities (left alone when nothing changes).
    """
    r = probs.size
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
        scale = (1.0 - floor * n_fixed) / free_sum
        changed = False
        for j in range(r):
            scaled[j] = probs[j] * scale
            if not fixed[j] and scaled[j] < floor:
                fixed[j] = True
                changed = True
        if not changed:
            break
    for j in range(r):
        probs[j] = floor if fixed[j] else scaled[j]
        log_probs[j] = math.log(probs[j])


@numba.njit(cache=True, error_model="numpy")
def imm_posterior(
    log_lik: np.ndarray, log_c: np.ndarray, floor: float, log_mu: np.ndarray, probs: np.ndarray
) -> None:
    """Eq. (26) in log space, then :func:`floor_probabilities`.

    ``mu_j = Lambda_j c_j / sum_i Lambda_i c_i``; the common factor ``max_j Lambda_j`` is divided
    out first so that huge log-likelihoods keep their precision; when no likelihood is finite
    (every mode rejected the data) the predicted odds ``c_j`` are kept.

    Parameters
    ----------
    log_lik, log_c : ndarray, shape (r,)
        ``log Lambda_j(k+1)`` (eq. 25) and ``log c_j`` (eq. 6).
    floor : float
        Probability floor (0: none).
    log_mu, probs : ndarray, shape (r,)
        Outputs: ``log mu_j(k+1)`` and ``mu_j(k+1)``.
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
    log_norm = _log(total) + peak
    for j in range(r):
        log_mu[j] -= log_norm
        probs[j] = math.exp(log_mu[j])
    floor_probabilities(probs, floor, log_mu)


@numba.njit(cache=True, error_model="numpy")
def imm_combine(
    means: np.ndarray, covs: np.ndarray, probs: np.ndarray, angle: np.ndarray, mean: np.ndarray,
    cov: np.ndarray,
) -> None:  # fmt: skip
    """Eqs. (27)-(28): the probability-weighted mean (circular for angles) and covariance.

    ``x = sum_j mu_j x^j`` (eq. 27). Eq. (28) as printed sums over ``j`` but uses ``x^i`` and
    ``x^0j``; the standard IMM combination, used here, is
    ``P = sum_j mu_j [P^j + (x^j - x)(x^j - x)']`` (symmetric by construction).

    Parameters
    ----------
    means, covs, probs : ndarray, shapes (r, nx), (r, nx, nx), (r,)
        ``x^j(k+1|k+1)``, ``P^j(k+1|k+1)``, ``mu_j(k+1)``.
    angle : ndarray of bool, shape (nx,)
        Angle components.
    mean, cov : ndarray, shapes (nx,), (nx, nx)
        Outputs: ``x(k+1|k+1)``, ``P(k+1|k+1)``.
    """
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
