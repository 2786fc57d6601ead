"""The filter's kernels: compiled equals interpreted, and both equal independent numpy maths.

:mod:`immukf_sitl.estimation.kernels` is the only implementation of the filter's arithmetic. Each
kernel is checked twice here: against the same source run by the interpreter
(``load_kernels(compiled=False)``, numba disabled; the two must agree to rounding), and against the
textbook formula written with numpy arrays in this file (LAPACK Cholesky, explicit gains and
inverses). Whole filters then run compiled and interpreted side by side, safeguards included.
"""

import math

import numba
import numpy as np
import pytest
from scipy.stats import norm
from toy_systems import (
    constant_velocity,
    identity_output,
    oscillator_bank,
    range_bearing_model,
    simulate_target,
)

from immukf_sitl.estimation import (
    ImmEstimator,
    JulierSigmaPoints,
    Measurement,
    MeasurementModel,
    ScaledSigmaPoints,
    UnscentedKalmanFilter,
    fault_mode_output,
    single_fault_modes,
    sticky_transition,
)
from immukf_sitl.estimation import kernels as compiled_kernels
from immukf_sitl.estimation.angles import wrap_angle
from immukf_sitl.estimation.failure_kernels import (
    failure_terms,
    failure_update,
    outlier_widths,
    read_way,
)
from immukf_sitl.estimation.fault_modes import FaultMode, bank_modes, failed_channels
from immukf_sitl.estimation.ukf import _process_column_source, load_kernels

#: Compiled against interpreted: the same operations in the same order, so rounding only.
SAME = 1e-13
#: Kernels against the numpy formulas here (other summation orders, LAPACK).
RTOL = 1e-12
LOG_2PI = np.log(2.0 * np.pi)


@pytest.fixture(scope="module", params=[True, False], ids=["compiled", "uncompiled"])
def kern(request):
    """Each kernel test runs on the compiled module and on its interpreted copy."""
    return load_kernels(request.param)


def random_covariances(rng, batch, n, scale=1.0):
    a = rng.standard_normal((batch, n, n)) * scale
    return a @ a.transpose(0, 2, 1) + 0.1 * np.eye(n)


def angle_mask(n, angle_idx):
    mask = np.zeros(n, dtype=bool)
    mask[list(angle_idx)] = True
    return mask


# -- the numpy formulas the kernels must reproduce ---------------------------------------------


def np_sigma_points(mean, sqrt_cov, spread):
    """Eq. (11) with numpy: columns [x, x + c L, x - c L], layout (n, B, 2n + 1)."""
    centre = mean[:, :, None]
    offsets = spread * sqrt_cov
    return np.concatenate([centre, centre + offsets, centre - offsets], axis=2).transpose(1, 0, 2)


def np_moments(points, weights, angle_idx=()):
    """Eqs. (16)-(18) with numpy: weighted mean (circular for angles), residuals, covariance."""
    mean = points @ weights.mean_weights
    for i in angle_idx:
        mean[i] = np.arctan2(
            np.sin(points[i]) @ weights.mean_weights, np.cos(points[i]) @ weights.mean_weights
        )
    res = points - mean[:, :, None]
    for i in angle_idx:
        res[i] = wrap_angle(res[i])
    res = res.transpose(1, 0, 2)
    cov = np.einsum("bis,s,bjs->bij", res, weights.cov_weights, res)
    return mean.T, cov, res


def np_kalman_update(pred_mean, pred_cov, x_res, z_points, weights, z, add_r, z_angle, x_angle):
    """Eqs. (19)-(25) with an explicit gain and inverse."""
    z_mean, z_cov, z_res = np_moments(z_points, weights, z_angle)
    z_cov = z_cov + add_r
    cross = np.einsum("bis,s,bjs->bij", x_res, weights.cov_weights, z_res)  # P_xz
    innovation = z[None] - z_mean
    for i in z_angle:
        innovation[:, i] = wrap_angle(innovation[:, i])
    gain = cross @ np.linalg.inv(z_cov)
    new_mean = pred_mean + np.einsum("bij,bj->bi", gain, innovation)
    for i in x_angle:
        new_mean[:, i] = wrap_angle(new_mean[:, i])
    new_cov = pred_cov - gain @ z_cov @ gain.transpose(0, 2, 1)
    nis = np.einsum("bi,bij,bj->b", innovation, np.linalg.inv(z_cov), innovation)
    log_lik = -0.5 * (nis + np.log(np.linalg.det(2 * np.pi * z_cov)))
    return dict(
        z_cov=z_cov, cross=cross.transpose(0, 2, 1), innovation=innovation, new_mean=new_mean,
        new_cov=new_cov, nis=nis, log_lik=log_lik,
    )  # fmt: skip


def assert_close(actual, expected, rtol=RTOL):
    """Elementwise, relative to the array's largest entry (covariances mix scales)."""
    expected = np.asarray(expected)
    np.testing.assert_allclose(actual, expected, rtol=0.0, atol=rtol * np.max(np.abs(expected)))


# -- the two forms of the kernels ---------------------------------------------------------------


def test_interpreted_kernels_are_the_same_source_without_numba():
    interpreted = load_kernels(False)
    assert isinstance(compiled_kernels.update, numba.core.registry.CPUDispatcher)
    assert not isinstance(interpreted.update, numba.core.registry.CPUDispatcher)
    assert interpreted.update.__code__.co_code == compiled_kernels.update.py_func.__code__.co_code
    # helpers too: every kernel calls plain Python functions when interpreted
    assert not isinstance(interpreted._gain_update, numba.core.registry.CPUDispatcher)
    assert load_kernels() is load_kernels(True) is compiled_kernels


@pytest.mark.parametrize("compiled", ["python", None])
def test_a_compiled_flag_that_is_not_a_bool_is_rejected(compiled):
    with pytest.raises(ValueError, match="compiled: expected True or False"):
        UnscentedKalmanFilter(constant_velocity().process(), compiled=compiled)


def test_wrap_angle_is_the_kernel_formula_on_arrays():
    angles = np.array([-7.0, -np.pi, -1.0, 0.0, np.pi - 1e-12, np.pi, 4.0, 10.0])
    wrapped = wrap_angle(angles)
    assert np.all((wrapped >= -np.pi) & (wrapped < np.pi))
    np.testing.assert_allclose(np.cos(wrapped), np.cos(angles), atol=1e-12)
    assert [compiled_kernels.wrap(a) for a in angles] == list(wrapped)


# -- kernel by kernel, against numpy ------------------------------------------------------------


def test_factor_is_symmetrise_then_cholesky(kern):
    rng = np.random.default_rng(1)
    cov = random_covariances(rng, 7, 12)
    cov[:, 0, 1] += 1e-9  # asymmetric input
    sym, chol = np.empty_like(cov), np.empty_like(cov)
    assert kern.factor(cov, sym, chol)
    assert np.array_equal(sym, 0.5 * (cov + cov.transpose(0, 2, 1)))
    np.testing.assert_allclose(chol, np.linalg.cholesky(sym), rtol=RTOL, atol=1e-14)
    assert np.all(np.triu(chol, 1) == 0.0)


@pytest.mark.parametrize("defect", ["indefinite", "nan", "singular"])
def test_factor_hands_doubtful_matrices_to_the_repair(kern, defect):
    cov = random_covariances(np.random.default_rng(2), 3, 5)
    if defect == "indefinite":
        cov[1] = np.diag([1.0, -5.0, 2.0, 1.0, 1.0])
    elif defect == "nan":
        cov[1, 2, 3] = cov[1, 3, 2] = np.nan
    else:
        v = np.arange(1.0, 6.0)
        cov[1] = np.outer(v, v)  # rank one: a pivot of rounding size
    assert not kern.factor(cov, np.empty_like(cov), np.empty_like(cov))


def test_state_points_are_eq_11(kern):
    rng = np.random.default_rng(3)
    mean = rng.standard_normal((7, 12))
    chol = np.linalg.cholesky(random_covariances(rng, 7, 12))
    out = np.empty((12, 7, 25))
    kern.state_points(mean, chol, 3.5, out)
    assert np.array_equal(out, np_sigma_points(mean, chol, 3.5))


def test_augmented_points_are_the_sigma_points_of_the_stacked_state(kern):
    rng = np.random.default_rng(4)
    nx, nv, nw, batch = 12, 6, 5, 7
    mean = rng.standard_normal((batch, nx))
    chol = np.linalg.cholesky(random_covariances(rng, batch, nx))
    sqrt_v = np.linalg.cholesky(random_covariances(rng, 1, nv)[0])
    sqrt_w = np.linalg.cholesky(random_covariances(rng, 1, nw)[0])
    n_aug = nx + nv + nw
    spread = np.sqrt(n_aug)
    # eqs. (9)-(10): zero noise means, block-diagonal square root
    mean_aug = np.zeros((batch, n_aug))
    mean_aug[:, :nx] = mean
    sqrt_aug = np.zeros((batch, n_aug, n_aug))
    sqrt_aug[:, :nx, :nx] = chol
    sqrt_aug[:, nx : nx + nv, nx : nx + nv] = sqrt_v
    sqrt_aug[:, nx + nv :, nx + nv :] = sqrt_w
    full = np_sigma_points(mean_aug, sqrt_aug, spread)
    distinct = np.r_[0, 1 : 1 + nx + nv, 1 + n_aug : 1 + n_aug + nx + nv]
    x_out = np.empty((nx, batch, distinct.size))
    v_out = np.empty((nv, batch, distinct.size))
    kern.augmented_process_points(mean, chol, sqrt_v, spread, x_out, v_out)
    assert np.array_equal(x_out, full[:nx][:, :, distinct])
    assert np.array_equal(v_out, full[nx : nx + nv][:, :, distinct])
    # the columns left out repeat the centre's (x, v)
    others = np.setdiff1d(np.arange(2 * n_aug + 1), distinct)
    assert np.array_equal(full[: nx + nv][:, :, others], np.repeat(full[: nx + nv, :, :1], 10, 2))
    w_out = np.empty((nw, batch, 2 * n_aug + 1))
    kern.measurement_noise_points(sqrt_w, spread, nx + nv, w_out)
    assert np.array_equal(w_out, full[nx + nv :])


@pytest.mark.parametrize("duplicated", [False, True])
def test_predict_moments_are_eqs_16_to_18(kern, duplicated):
    rng = np.random.default_rng(5)
    nx, batch, n_aug = 4, 3, 6
    weights = ScaledSigmaPoints(alpha=0.8, beta=2.0, kappa=1.0).weights(n_aug)
    n_sigma = 2 * n_aug + 1
    if duplicated:  # columns 5, 6, 11, 12 repeat the centre, as the w-only points do
        source = np.array([0, 1, 2, 3, 4, 0, 0, 5, 6, 7, 8, 0, 0])
    else:
        source = np.arange(n_sigma)
    moved = rng.standard_normal((nx, batch, source.max() + 1))
    moved[1] = np.pi - 0.05 + 0.1 * rng.random((batch, source.max() + 1))  # straddles +-pi
    moved[1] = wrap_angle(moved[1])
    added = np.diag([0.1, 0.2, 0.3, 0.4])
    x_points = np.empty((nx, batch, n_sigma))
    mean = np.empty((batch, nx))
    cov = np.empty((batch, nx, nx))
    res = np.empty((batch, nx, n_sigma))
    kern.predict_moments(
        moved,
        source,
        kern.MomentWeights(weights.mean_weights, weights.cov_weights),
        angle_mask(nx, (1,)),
        added,
        kern.Moments(x_points, mean, cov, res),
    )
    assert np.array_equal(x_points, moved[:, :, source])
    ref_mean, ref_cov, ref_res = np_moments(x_points, weights, (1,))
    np.testing.assert_allclose(mean, ref_mean, rtol=RTOL, atol=1e-15)
    np.testing.assert_allclose(res, ref_res, rtol=RTOL, atol=1e-15)
    np.testing.assert_allclose(cov, ref_cov + added, rtol=RTOL, atol=1e-15)
    assert np.array_equal(cov, cov.transpose(0, 2, 1))


def test_predict_moments_over_distinct_columns_equal_the_sums_over_all(kern):
    """The augmented form's repeated centre columns summed once, weights pooled: eqs. (16)-(18)
    over every column (identity source, each copy its own column) give the same moments."""
    rng = np.random.default_rng(8)
    nx, nv, nw, batch = 7, 3, 4, 2
    n_aug = nx + nv + nw
    source = _process_column_source(nx + nv, n_aug)
    weights = ScaledSigmaPoints(alpha=0.9, beta=2.0, kappa=0.5).weights(n_aug)  # Wc0 != Wm0
    moved = rng.standard_normal((nx, batch, source.max() + 1))
    moved[2] = wrap_angle(np.pi - 0.05 + 0.1 * rng.random((batch, source.max() + 1)))
    added = np.diag(np.linspace(0.1, 0.7, nx))
    angles = angle_mask(nx, (2,))

    def moments(points, src):
        outs = (np.empty((nx, batch, src.size)), np.empty((batch, nx)),
                np.empty((batch, nx, nx)), np.empty((batch, nx, src.size)))  # fmt: skip
        kern.predict_moments(
            points,
            src,
            kern.MomentWeights(weights.mean_weights, weights.cov_weights),
            angles,
            added,
            kern.Moments(*outs),
        )
        return outs

    pooled = moments(moved, source)
    full = moments(np.ascontiguousarray(moved[:, :, source]), np.arange(source.size))
    assert np.array_equal(pooled[0], full[0])
    for got, expected in zip(pooled[1:], full[1:], strict=True):
        np.testing.assert_allclose(got, expected, rtol=RTOL, atol=1e-14)
    assert np.array_equal(pooled[2], pooled[2].transpose(0, 2, 1))


def _update_case(rng, batch=5, nx=6, nz=4):
    """Transformed points of a mildly nonlinear map, a measurement near +-pi on channel 1."""
    weights = JulierSigmaPoints(1.0).weights(nx)
    pred_mean = rng.standard_normal((batch, nx))
    pred_mean[:, 2] = np.pi - 0.02
    pred_cov = random_covariances(rng, batch, nx, 0.3)
    points = np_sigma_points(pred_mean, np.linalg.cholesky(pred_cov), weights.spread)
    _, _, x_res = np_moments(points, weights, (2,))
    z_points = np.stack([points[0] + 0.1 * points[1] ** 2, wrap_angle(points[2] + 0.01),
                         np.sin(points[3]), points[4] * points[5]])  # fmt: skip
    z = np.array([0.3, -np.pi + 0.01, 0.2, -0.1])
    # each filter adds its own: R, and on one channel a fault mode's width
    add_r = np.repeat(np.diag([0.05, 0.01, 0.02, 0.03])[None], batch, axis=0)
    add_r[np.arange(batch), np.arange(batch) % nz, np.arange(batch) % nz] += 100.0
    return weights, pred_mean, pred_cov, x_res, np.ascontiguousarray(z_points), z, add_r


def _run_update(kern, weights, pred_mean, pred_cov, x_res, z_points, z, add_r, angles):
    nz, batch, _ = z_points.shape
    nx = pred_mean.shape[1]
    out = dict(
        z_cov=np.empty((batch, nz, nz)), cross=np.empty((batch, nz, nx)),
        innovation=np.empty((batch, nz)), z_chol=np.empty((batch, nz, nz)),
        new_mean=np.empty((batch, nx)), new_cov=np.empty((batch, nx, nx)), nis=np.empty(batch),
        log_lik=np.empty(batch),
    )  # fmt: skip
    status = kern.update(
        kern.Prediction(pred_mean, pred_cov, x_res),
        z_points,
        kern.MomentWeights(weights.mean_weights, weights.cov_weights),
        kern.Observed(z, add_r, angle_mask(nz, angles[0])),
        angle_mask(nx, angles[1]),
        kern.Updated(*out.values()),  # the dict's order is the record's
    )
    return status, out


def test_update_is_the_kalman_update_with_an_explicit_gain(kern):
    case = _update_case(np.random.default_rng(10))
    angles = ((1,), (2,))
    status, out = _run_update(kern, *case, angles)
    assert status == 0  # factored, and every result finite
    weights, pred_mean, pred_cov, x_res, z_points, z, add_r = case
    ref = np_kalman_update(pred_mean, pred_cov, x_res, z_points, weights, z, add_r, *angles)
    for name, expected in ref.items():
        assert_close(out[name], expected, 1e-10)
    np.testing.assert_allclose(out["z_chol"], np.linalg.cholesky(ref["z_cov"]), atol=1e-12)
    assert np.array_equal(out["new_cov"], out["new_cov"].transpose(0, 2, 1))
    # and from LAPACK's factors, gain_update (the path after a repair) gives the same update
    again = {name: np.empty_like(out[name]) for name in ("new_mean", "new_cov", "nis", "log_lik")}
    n_nonfinite = kern.gain_update(
        kern.Prediction(pred_mean, pred_cov, x_res),
        angle_mask(pred_mean.shape[1], (2,)),
        kern.Updated(
            out["z_cov"], out["cross"], out["innovation"], np.linalg.cholesky(out["z_cov"]),
            *again.values(),
        ),
    )  # fmt: skip
    assert n_nonfinite == 0
    for name, values in again.items():
        assert_close(values, out[name], 1e-12)


def test_update_counts_the_filters_whose_update_is_not_finite(kern):
    weights, pred_mean, pred_cov, x_res, z_points, z, add_r = _update_case(
        np.random.default_rng(14)
    )
    pred_mean[1, 0] = np.nan
    pred_cov[3, 4, 4] = np.inf
    status, out = _run_update(
        kern, weights, pred_mean, pred_cov, x_res, z_points, z, add_r, ((), ())
    )
    assert status == 2
    finite = np.isfinite(out["new_mean"]).all(axis=1) & np.isfinite(out["new_cov"]).all(axis=(1, 2))
    assert list(finite) == [True, False, True, False, True]


def test_update_reports_an_innovation_covariance_it_cannot_factor(kern):
    weights, pred_mean, pred_cov, x_res, z_points, z, add_r = _update_case(
        np.random.default_rng(11)
    )
    z_points[3] = 0.0  # an output that ignores the state...
    add_r[:, 3, 3] = 0.0  # ...and has no noise: P_zz singular
    status, out = _run_update(
        kern, weights, pred_mean, pred_cov, x_res, z_points, z, add_r, ((), ())
    )
    assert status == -1
    assert np.all(out["z_cov"][:, 3, :] == 0.0)


def _mixing_case(rng, r=7, nx=6):
    means = rng.standard_normal((r, nx))
    means[:, 2] = wrap_angle(np.pi + 0.2 * rng.standard_normal(r))  # an angle across +-pi
    covs = random_covariances(rng, r, nx)
    log_mu = np.log(rng.dirichlet(np.ones(r)))
    log_mu[3] = -np.inf  # a mode ruled out
    with np.errstate(divide="ignore"):
        log_t = np.log(sticky_transition(r, 0.9))
    return means, covs, log_mu, log_t


def test_imm_mix_and_combine_are_eqs_6_to_8_and_27_to_28(kern):
    rng = np.random.default_rng(6)
    means, covs, log_mu, log_t = _mixing_case(rng)
    r, nx = means.shape
    angle = angle_mask(nx, (2,))
    log_c, mixed_mean, mixed_cov = np.empty(r), np.empty((r, nx)), np.empty((r, nx, nx))
    kern.imm_mix(log_t, log_mu, means, covs, angle, log_c, mixed_mean, mixed_cov)
    mu, T = np.exp(log_mu), np.exp(log_t)
    c = T.T @ mu  # eq. (6)
    np.testing.assert_allclose(log_c, np.log(c), rtol=RTOL)
    for j in range(r):
        w = T[:, j] * mu / c[j]  # mu_{i|j}
        x0 = w @ means  # eq. (7); circular for the angle
        x0[2] = np.arctan2(w @ np.sin(means[:, 2]), w @ np.cos(means[:, 2]))
        d = means - x0
        d[:, 2] = wrap_angle(d[:, 2])
        P0 = np.einsum("i,iab->ab", w, covs) + (d.T * w) @ d  # eq. (8)
        np.testing.assert_allclose(mixed_mean[j], x0, rtol=RTOL, atol=1e-15)
        np.testing.assert_allclose(mixed_cov[j], P0, rtol=RTOL, atol=1e-15)

    probs = rng.dirichlet(np.ones(r))
    mean, cov = np.empty(nx), np.empty((nx, nx))
    kern.imm_combine(means, covs, probs, angle, mean, cov)
    x = probs @ means  # eq. (27)
    x[2] = np.arctan2(probs @ np.sin(means[:, 2]), probs @ np.cos(means[:, 2]))
    d = means - x
    d[:, 2] = wrap_angle(d[:, 2])
    np.testing.assert_allclose(mean, x, rtol=RTOL, atol=1e-15)
    np.testing.assert_allclose(cov, np.einsum("j,jab->ab", probs, covs) + (d.T * probs) @ d,
                               rtol=RTOL, atol=1e-15)  # fmt: skip
    assert np.array_equal(cov, cov.T)


@pytest.mark.parametrize(
    "log_lik",
    [
        [-3.0, -1e6, -2e6, -5.0, -1e7, -4.0, -9e5],  # floor over several rounds
        [-3.0, -np.inf, -2.0, -5.0, -np.inf, -4.0, -1.0],  # modes that rejected the data
        [-np.inf] * 7,  # every mode rejected it: the predicted odds stay
        [1e12, 1e12 - 3.0, 0.0, 1.0, 2.0, 3.0, 4.0],  # huge log-likelihoods keep precision
    ],
)
@pytest.mark.parametrize("floor", [0.0, 1e-6, 0.01])
def test_mode_probabilities_are_eq_26_with_the_floor(kern, log_lik, floor):
    log_lik = np.array(log_lik)
    c = np.random.default_rng(9).dirichlet(np.ones(7))
    log_mu, probs = np.empty(7), np.empty(7)
    kern.imm_posterior(log_lik, np.log(c), floor, log_mu, probs)
    # eq. (26): mu_j proportional to Lambda_j c_j (c_j when no likelihood is finite)
    log_unfloored = np.log(c) + (log_lik - np.max(log_lik) if np.isfinite(log_lik).any() else 0.0)
    log_unfloored -= np.logaddexp.reduce(log_unfloored)
    unfloored = np.exp(log_unfloored)
    np.testing.assert_allclose(np.exp(log_mu), probs, rtol=1e-15)
    np.testing.assert_allclose(probs.sum(), 1.0, rtol=1e-14)
    raised = probs == floor
    if floor == 0.0 or unfloored.min() >= floor:
        assert not raised.any() or floor == 0.0
        np.testing.assert_allclose(log_mu, log_unfloored, rtol=1e-12)
    else:
        # the floor: every probability at least the floor, those below it raised to it, the
        # others scaled by one common factor (their ratios kept)
        assert probs.min() >= floor * (1 - 1e-12) and raised[unfloored < floor].all()
        ratio = probs[~raised] / unfloored[~raised]
        np.testing.assert_allclose(ratio, ratio[0], rtol=1e-12)
        assert ratio[0] < 1.0


# -- compiled against interpreted, on the same inputs -------------------------------------------


def _both(name, *args):
    """Run kernel ``name`` compiled and interpreted on copies of ``args``; both argument lists."""
    runs = []
    for kern in (compiled_kernels, load_kernels(False)):
        copies = [_copy(a) for a in args]
        result = getattr(kern, name)(*copies)
        runs.append((result, _flat(copies)))
    return runs


def _copy(value):
    """A copy of an array, or of a record of arrays (field by field)."""
    if isinstance(value, np.ndarray):
        return value.copy()
    if isinstance(value, tuple):
        return type(value)(*(_copy(v) for v in value))
    return value


def _flat(values):
    """The arrays of ``values``, records opened, in order."""
    out = []
    for v in values:
        out.extend(_flat(v) if isinstance(v, tuple) else [v])
    return out


def _assert_same_runs(runs):
    (result_c, args_c), (result_p, args_p) = runs
    assert result_c == result_p
    for a, b in zip(args_c, args_p, strict=True):
        if isinstance(a, np.ndarray) and a.dtype == float:
            scale = np.max(np.abs(b[np.isfinite(b)]), initial=1.0)
            np.testing.assert_allclose(a, b, rtol=SAME, atol=SAME * scale)


def test_compiled_and_interpreted_update_agree():
    weights, pred_mean, pred_cov, x_res, z_points, z, add_r = _update_case(
        np.random.default_rng(12)
    )
    nz, batch, _ = z_points.shape
    nx = pred_mean.shape[1]
    outs = [np.empty(s) for s in [(batch, nz, nz), (batch, nz, nx), (batch, nz), (batch, nz, nz),
                                  (batch, nx), (batch, nx, nx), (batch,), (batch,)]]  # fmt: skip
    _assert_same_runs(
        _both(
            "update",
            compiled_kernels.Prediction(pred_mean, pred_cov, x_res),
            z_points,
            compiled_kernels.MomentWeights(weights.mean_weights, weights.cov_weights),
            compiled_kernels.Observed(z, add_r, angle_mask(nz, (1,))),
            angle_mask(nx, (2,)),
            compiled_kernels.Updated(*outs),
        )
    )


def test_compiled_and_interpreted_imm_kernels_agree():
    rng = np.random.default_rng(13)
    means, covs, log_mu, log_t = _mixing_case(rng)
    r, nx = means.shape
    angle = angle_mask(nx, (2,))
    _assert_same_runs(_both(
        "imm_mix", log_t, log_mu, means, covs, angle, np.empty(r), np.empty((r, nx)),
        np.empty((r, nx, nx)),
    ))  # fmt: skip
    log_lik = np.array([-3.0, -1e6, -2e6, -5.0, -1e7, -4.0, -9e5])
    _assert_same_runs(_both("imm_posterior", log_lik, log_mu, 1e-4, np.empty(r), np.empty(r)))
    probs = rng.dirichlet(np.ones(r))
    _assert_same_runs(_both("imm_combine", means, covs, probs, angle, np.empty(nx),
                            np.empty((nx, nx))))  # fmt: skip


# -- whole filters: compiled and interpreted side by side ---------------------------------------


def _assert_same_estimate(fast, ref, rtol=1e-10):
    assert fast.t_s == ref.t_s
    for name in ("mean", "cov", "predicted_mean", "predicted_cov", "log_likelihood", "nis"):
        assert_close(getattr(fast, name), getattr(ref, name), rtol)
    if ref.innovation is None:
        assert fast.innovation is None and fast.innovation_cov is None
    else:
        assert_close(fast.innovation, ref.innovation, rtol)
        assert_close(fast.innovation_cov, ref.innovation_cov, rtol)
    assert fast.updated == ref.updated


@pytest.mark.parametrize("noise_form", ["augmented", "additive"])
@pytest.mark.parametrize("scheme", [JulierSigmaPoints(), ScaledSigmaPoints(0.5, 2.0, 1.0)])
def test_ukf_compiled_and_interpreted_agree_on_range_bearing_tracking(noise_form, scheme):
    sys = constant_velocity()
    model = range_bearing_model()
    rng = np.random.default_rng(7)
    _, zs = simulate_target(rng, sys, np.array([-1500.0, 30.0, 8.0, -1.0]), 60)  # bearing ~ pi
    filters = [
        UnscentedKalmanFilter(sys.process(), scheme, noise_form, compiled=b) for b in (True, False)
    ]
    assert [f.compiled for f in filters] == [True, False]
    x0, P0 = np.array([-1490.0, 20.0, 7.0, 0.0]), np.diag([400.0, 400.0, 4.0, 4.0])
    ests = [f.initial_estimate(0.0, x0, P0) for f in filters]
    for k, z in enumerate(zs):
        measurement = None if k % 7 == 3 else Measurement(z, model)  # some predict-only steps
        ests = [f.step(e, 0.1 * (k + 1), np.zeros(0), measurement) for f, e in zip(
            filters, ests, strict=True)]  # fmt: skip
        _assert_same_estimate(*ests)
    assert filters[0].diagnostics == filters[1].diagnostics


@pytest.mark.parametrize("noise_form", ["augmented", "additive"])
def test_imm_compiled_and_interpreted_agree_on_a_fault_bank(noise_form):
    process, A = oscillator_bank()
    modes = list(single_fault_modes())
    output = MeasurementModel(
        fault_mode_output(identity_output, modes, "zero"), np.eye(6) * 0.05**2, name="imu"
    )
    rng = np.random.default_rng(8)
    imms = [
        ImmEstimator(
            UnscentedKalmanFilter(process, noise_form=noise_form, compiled=b),
            sticky_transition(7, 0.99),
            1e-4,
        )
        for b in (True, False)
    ]
    ests = [imm.initial_estimate(0.0, np.zeros(6), np.eye(6)) for imm in imms]
    x = np.array([1.0, 0.3, -0.8, 0.2, 1.0, 0.6])
    for k in range(60):
        x = A @ x + 0.01 * rng.standard_normal(6)
        mask = modes[4].healthy_mask if k >= 30 else np.ones(6)
        z = x * mask + 0.05 * rng.standard_normal(6)
        ests = [imm.step(e, 0.1 * (k + 1), np.zeros(0), Measurement(z, output)) for imm, e in zip(
            imms, ests, strict=True)]  # fmt: skip
        fast, ref = ests
        for name in ("mean", "cov", "mode_probabilities", "mode_means", "mode_covs", "nis"):
            assert_close(getattr(fast, name), getattr(ref, name), 1e-9)
        assert_close(fast.log_likelihoods, ref.log_likelihoods, 1e-9)
    assert ests[0].most_likely_mode == 4
    assert imms[0].diagnostics == imms[1].diagnostics


def test_repairs_are_counted_alike_compiled_and_interpreted():
    sys = constant_velocity()
    v = np.array([1.0, 2.0, 0.5, -1.0])
    bad_covs = [
        np.outer(v, v) * 1e4 - 1e-9 * np.eye(4),  # rank 1, slightly indefinite: jitter
        np.diag([1.0, -5.0, 2.0, 1.0]),  # eigen floor
    ]
    nan_cov = np.eye(4) * 10
    nan_cov[1, 1] = np.nan
    bad_covs.append(nan_cov)
    z_huge = Measurement(np.array([1118.0 + 5e6, 0.46]), range_bearing_model())
    z_nan = Measurement(np.array([np.nan, 0.46]), range_bearing_model())
    for noise_form in ("augmented", "additive"):
        filters = [
            UnscentedKalmanFilter(sys.process(), noise_form=noise_form, compiled=b)
            for b in (True, False)
        ]
        for P in bad_covs:
            for z in (Measurement(np.array([1118.0, 0.46]), range_bearing_model()), z_huge, z_nan):
                ests = [
                    f.step(f.initial_estimate(0.0, np.array([1000.0, 500.0, 1.0, 1.0]), P), 0.1,
                           np.zeros(0), z)
                    for f in filters
                ]  # fmt: skip
                _assert_same_estimate(*ests, rtol=1e-8)
        fast, ref = (f.diagnostics for f in filters)
        assert fast == ref
        assert fast.cholesky_jitter and fast.cholesky_eigen_floor and fast.outlier_innovations
        assert fast.skipped_nonfinite_measurement


@pytest.mark.parametrize("noise_form", ["augmented", "additive"])
def test_an_innovation_covariance_the_kernels_cannot_factor_is_repaired_and_counted(noise_form):
    sys = constant_velocity()
    # the first channel ignores the state and has no noise: P_zz is singular
    blind = MeasurementModel(
        lambda t, x, u, w: np.stack([0.0 * x[0], x[1]]) + (0.0 if w is None else w),
        np.diag([0.0, 4.0]),
    )
    filters = [
        UnscentedKalmanFilter(sys.process(), noise_form=noise_form, compiled=b)
        for b in (True, False)
    ]
    x0, P0 = np.array([10.0, 5.0, 1.0, 1.0]), np.eye(4)
    ests = [
        f.step(f.initial_estimate(0.0, x0, P0), 0.1, np.zeros(0),
               Measurement(np.array([0.0, 5.5]), blind))
        for f in filters
    ]  # fmt: skip
    _assert_same_estimate(*ests)
    assert filters[0].diagnostics == filters[1].diagnostics
    assert filters[0].diagnostics.cholesky_jitter == 1
    # the blind channel carries no information: the update is the east-position update alone
    Pp = ests[0].predicted_cov[0]
    gain = Pp[:, 1] / (Pp[1, 1] + 4.0)
    expected = ests[0].predicted_mean[0] + gain * (5.5 - ests[0].predicted_mean[0, 1])
    np.testing.assert_allclose(ests[0].mean[0], expected, rtol=1e-6)


# -- the untrusted modes' scoring (estimation/failure_kernels.py) ------------------------------


def _scoring_inputs(seed: int):
    """A re-based bank's failed pairs with random innovations, offsets, readings and weights."""
    rng = np.random.default_rng(seed)
    modes = bank_modes(FaultMode.from_name("p"))
    failed, channels = failed_channels(modes)
    reference = rng.integers(0, len(modes), failed.size)
    pairs = np.column_stack([failed, channels, reference]).astype(np.int64)
    r = len(modes)
    innovation = rng.normal(0.0, 0.05, (r, 9))
    a = rng.normal(0.0, 0.05, (r, 9, 9))
    cov = a @ np.transpose(a, (0, 2, 1)) + 1e-4 * np.eye(9)
    z = rng.normal(0.0, 0.3, 9)
    z[channels[:2]] = 1e-5  # readings near zero: some dead parts are not seen
    previous = z[:6] + rng.normal(0.0, 1e-4, 6)
    previous[0] = np.nan  # nothing held on one channel
    offset_reading = rng.normal(0.0, 0.1, failed.size)
    limits = np.concatenate([rng.uniform(1e-5, 1e-3, 6), [3.0, 0.1]])
    weights = rng.dirichlet(np.ones(8), (r, 6))  # dead, stuck, offset, anything, 4 noisy
    widths = rng.uniform(0.0, 1e-4, (r, 6))
    spreads = np.concatenate([rng.uniform(1.0, 10.0, 6), [1e-6, 0.01]])
    noisy = np.outer(limits[:6], np.array([2.0, 4.0, 8.0, 16.0]) ** 2 - 1.0)
    return (
        pairs,
        innovation,
        cov,
        z,
        previous,
        offset_reading,
        limits,
        weights,
        widths,
        (
            spreads,
            noisy,
        ),
    )


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_failure_scoring_compiled_equals_interpreted(seed):
    pairs, nu, cov, z, previous, offset, limits, weights, widths, spreads = _scoring_inputs(seed)
    held = (np.random.default_rng(seed + 10).uniform(size=6) < 0.5).astype(float)
    terms = failure_terms(pairs, nu, cov, z, previous, offset, limits, held)
    reference = failure_terms.py_func(pairs, nu, cov, z, previous, offset, limits, held)
    np.testing.assert_allclose(terms, reference, rtol=SAME, atol=0.0)
    assert 0 < terms[:, 3].sum() < len(pairs)  # seen and unseen dead parts both exercised
    base = np.random.default_rng(seed).normal(-40.0, 5.0, len(weights))
    got = failure_update(pairs, terms, nu, cov, widths, weights, base, *spreads)
    want = failure_update.py_func(pairs, terms, nu, cov, widths, weights, base, *spreads)
    for a, b in zip(got, want, strict=True):
        np.testing.assert_allclose(a, b, rtol=SAME, atol=1e-15)
    np.testing.assert_allclose(got[1].sum(axis=2), 1.0, rtol=1e-12)  # weights stay a simplex


@pytest.mark.parametrize("seed", [1, 2])
def test_outlier_gate_kernels_compiled_equal_interpreted_and_numpy(seed):
    """The gate's kernels against their interpreted selves and a numpy computation: which
    way leads each pair's weights, the pairs' innovation moments (eqs. 17, 20, 21), the widths."""
    pairs, _, _, z, _, _, _, weights, _, (spreads, _) = _scoring_inputs(seed)
    way = read_way(pairs, weights)
    np.testing.assert_array_equal(way, read_way.py_func(pairs, weights))
    ways = weights[pairs[:, 0], pairs[:, 1]]
    np.testing.assert_array_equal(way, np.argmax(ways, axis=1))  # no ties in random weights
    rng = np.random.default_rng(seed)
    r, nz, n_points = len(weights), z.size, 13
    z_points = rng.normal(0.0, 1.0, (nz, r, n_points))
    wm = rng.dirichlet(np.ones(n_points))
    wc = rng.uniform(0.0, 0.2, n_points)
    added_r = np.tile(np.diag(rng.uniform(0.1, 1.0, nz)), (r, 1, 1))
    filters, outputs = pairs[:, 0].copy(), pairs[:, 1].copy()
    got = np.empty((2, len(pairs)))
    want = np.empty((2, len(pairs)))
    compiled_kernels.pair_moments(z_points, filters, outputs, wm, wc, added_r, z, got[0], got[1])
    compiled_kernels.pair_moments.py_func(z_points, filters, outputs, wm, wc, added_r, z, *want)
    np.testing.assert_allclose(got, want, rtol=SAME, atol=0.0)
    points = z_points[outputs, filters]
    predicted = points @ wm
    np.testing.assert_allclose(got[0], z[outputs] - predicted, rtol=1e-12)
    spread = ((points - predicted[:, None]) ** 2) @ wc + added_r[filters, outputs, outputs]
    np.testing.assert_allclose(got[1], spread, rtol=1e-12)
    wide = spreads[outputs] * 1e-3
    widths = outlier_widths(got[0], got[1], wide, math.log(0.01 / 0.99))
    np.testing.assert_array_equal(
        widths, outlier_widths.py_func(got[0], got[1], wide, math.log(0.01 / 0.99))
    )
    inlier = norm.logpdf(got[0], 0.0, np.sqrt(got[1]))
    outlier = math.log(0.01 / 0.99) + norm.logpdf(got[0], 0.0, np.sqrt(got[1] + wide))
    np.testing.assert_array_equal(widths, np.where(outlier > inlier, wide, 0.0))
