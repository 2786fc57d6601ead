"""The compiled UKF/IMM kernels agree with the numpy reference, and count the same safeguards."""

import importlib.util

import numpy as np
import pytest
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
    fault_masked_output,
    sigma_points,
    single_fault_modes,
    sticky_transition,
    unscented_transform,
)
from immukf_sitl.estimation.angles import wrap_angle
from immukf_sitl.estimation.imm import logsumexp
from immukf_sitl.estimation.linalg import block_diagonal, symmetrise

pytestmark = pytest.mark.skipif(
    importlib.util.find_spec("numba") is None, reason="numba not installed"
)
RTOL = 1e-12


@pytest.fixture(scope="module")
def kernels():
    from immukf_sitl.estimation import _kernels_numba

    return _kernels_numba


def random_covariances(rng, batch, n, scale=1.0):
    a = rng.standard_normal((batch, n, n)) * scale
    return a @ a.transpose(0, 2, 1) + 0.1 * np.eye(n)


def angle_mask(n, angle_idx):
    mask = np.zeros(n, dtype=bool)
    mask[list(angle_idx)] = True
    return mask


def test_factor_is_symmetrise_then_cholesky(kernels):
    rng = np.random.default_rng(1)
    cov = random_covariances(rng, 7, 12)
    cov[:, 0, 1] += 1e-9  # asymmetric input
    sym, chol = np.empty_like(cov), np.empty_like(cov)
    assert kernels.factor(cov, sym, chol)
    assert np.array_equal(sym, symmetrise(cov))
    np.testing.assert_allclose(chol, np.linalg.cholesky(sym), rtol=RTOL, atol=1e-14)
    assert np.all(np.triu(chol, 1) == 0.0)


@pytest.mark.parametrize("defect", ["indefinite", "nan", "singular"])
def test_factor_hands_doubtful_matrices_to_the_repair(kernels, defect):
    cov = random_covariances(np.random.default_rng(2), 3, 5)
    if defect == "indefinite":
        cov[1] = np.diag([1.0, -5.0, 2.0, 1.0, 1.0])
    elif defect == "nan":
        cov[1, 2, 3] = cov[1, 3, 2] = np.nan
    else:
        v = np.arange(1.0, 6.0)
        cov[1] = np.outer(v, v)  # rank one: a pivot of rounding size
    assert not kernels.factor(cov, np.empty_like(cov), np.empty_like(cov))


def test_sigma_points_are_the_numpy_points(kernels):
    rng = np.random.default_rng(3)
    mean = rng.standard_normal((7, 12))
    chol = np.linalg.cholesky(random_covariances(rng, 7, 12))
    out = np.empty((12, 7, 25))
    kernels.state_points(mean, chol, 3.5, out)
    assert np.array_equal(out, sigma_points(mean, chol, 3.5))


def test_augmented_process_points_are_the_distinct_numpy_points(kernels):
    rng = np.random.default_rng(4)
    nx, nv, nw, batch = 12, 6, 5, 7
    mean = rng.standard_normal((batch, nx))
    chol = np.linalg.cholesky(random_covariances(rng, batch, nx))
    sqrt_v = np.linalg.cholesky(random_covariances(rng, 1, nv)[0])
    sqrt_w = np.linalg.cholesky(random_covariances(rng, 1, nw)[0])
    n_aug = nx + nv + nw
    spread = np.sqrt(n_aug)
    mean_aug = np.zeros((batch, n_aug))
    mean_aug[:, :nx] = mean
    full = sigma_points(mean_aug, block_diagonal([chol, sqrt_v, sqrt_w], batch), spread)
    distinct = np.r_[0, 1 : 1 + nx + nv, 1 + n_aug : 1 + n_aug + nx + nv]
    x_out = np.empty((nx, batch, distinct.size))
    v_out = np.empty((nv, batch, distinct.size))
    kernels.augmented_process_points(mean, chol, sqrt_v, spread, x_out, v_out)
    assert np.array_equal(x_out, full[:nx][:, :, distinct])
    assert np.array_equal(v_out, full[nx : nx + nv][:, :, distinct])


@pytest.mark.parametrize("duplicated", [False, True])
def test_predict_moments_is_the_unscented_transform(kernels, duplicated):
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
    angle = angle_mask(nx, (1,))
    x_points = np.empty((nx, batch, n_sigma))
    mean = np.empty((batch, nx))
    cov = np.empty((batch, nx, nx))
    res = np.empty((batch, nx, n_sigma))
    kernels.predict_moments(
        moved, source, weights.mean_weights, weights.cov_weights, angle, added, x_points,
        mean, cov, res,
    )  # fmt: skip
    assert np.array_equal(x_points, moved[:, :, source])
    ref_mean, ref_cov, ref_res = unscented_transform(x_points, weights, (1,))
    np.testing.assert_allclose(mean, ref_mean, rtol=RTOL, atol=1e-15)
    np.testing.assert_allclose(res, ref_res, rtol=RTOL, atol=1e-15)
    np.testing.assert_allclose(cov, symmetrise(ref_cov + added), rtol=RTOL, atol=1e-15)
    assert np.array_equal(cov, cov.transpose(0, 2, 1))


def test_mixing_and_combination_are_the_numpy_ones(kernels):
    rng = np.random.default_rng(6)
    process, _ = oscillator_bank()
    imm = ImmEstimator(UnscentedKalmanFilter(process, backend="numpy"), sticky_transition(7, 0.9))
    imm.angle_idx = (2,)  # exercise the circular means
    means = rng.standard_normal((7, 6))
    means[:, 2] = wrap_angle(np.pi + 0.2 * rng.standard_normal(7))
    covs = random_covariances(rng, 7, 6)
    log_mu = np.log(rng.dirichlet(np.ones(7)))
    log_mu[3] = -np.inf  # a mode ruled out
    log_joint = imm.log_transition + log_mu[:, None]
    ref_log_c = logsumexp(log_joint, axis=0)
    ref_mean, ref_cov = imm._mix(means, covs, np.exp(log_joint - ref_log_c[None, :]))
    log_c, mixed_mean, mixed_cov = np.empty(7), np.empty((7, 6)), np.empty((7, 6, 6))
    kernels.imm_mix(
        imm.log_transition, log_mu, means, covs, angle_mask(6, (2,)), log_c, mixed_mean, mixed_cov
    )
    np.testing.assert_allclose(log_c, ref_log_c, rtol=RTOL)
    np.testing.assert_allclose(mixed_mean, ref_mean, rtol=RTOL, atol=1e-15)
    np.testing.assert_allclose(mixed_cov, ref_cov, rtol=RTOL, atol=1e-15)

    probs = np.exp(log_mu)
    ref_mean, ref_cov = imm._combine(means, covs, probs)
    mean, cov = np.empty(6), np.empty((6, 6))
    kernels.imm_combine(means, covs, probs, angle_mask(6, (2,)), mean, cov)
    np.testing.assert_allclose(mean, ref_mean, rtol=RTOL, atol=1e-15)
    np.testing.assert_allclose(cov, ref_cov, rtol=RTOL, atol=1e-15)


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
def test_mode_probabilities_are_the_numpy_ones(kernels, log_lik, floor):
    process, _ = oscillator_bank()
    imm = ImmEstimator(
        UnscentedKalmanFilter(process, backend="numpy"), sticky_transition(7, 0.9), floor
    )
    log_lik = np.array(log_lik)
    log_c = np.log(np.random.default_rng(9).dirichlet(np.ones(7)))
    ref_log_mu, ref_probs = imm._posterior(log_lik, log_c)
    log_mu, probs = np.empty(7), np.empty(7)
    kernels.imm_posterior(log_lik, log_c, floor, log_mu, probs)
    np.testing.assert_allclose(probs, ref_probs, rtol=RTOL, atol=1e-300)
    np.testing.assert_allclose(log_mu, ref_log_mu, rtol=RTOL)
    assert probs.min() >= floor * (1 - 1e-12)


# -- whole filters: numpy and compiled backends side by side ----------------------------------


def assert_close(actual, expected, rtol):
    """Elementwise, relative to the array's largest entry (covariances mix scales)."""
    np.testing.assert_allclose(actual, expected, rtol=0.0, atol=rtol * np.max(np.abs(expected)))


def _assert_same_estimate(fast, ref, rtol=1e-10):
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
def test_ukf_backends_agree_on_range_bearing_tracking(noise_form, scheme):
    sys = constant_velocity()
    model = range_bearing_model()
    rng = np.random.default_rng(7)
    _, zs = simulate_target(rng, sys, np.array([-1500.0, 30.0, 8.0, -1.0]), 60)  # bearing ~ pi
    filters = [
        UnscentedKalmanFilter(sys.process(), scheme, noise_form, backend=b)
        for b in ("numba", "numpy")
    ]
    assert [f.backend for f in filters] == ["numba", "numpy"]
    states = [(np.array([[-1490.0, 20.0, 7.0, 0.0]]), np.diag([400.0, 400.0, 4.0, 4.0])[None])] * 2
    for k, z in enumerate(zs):
        measurement = None if k % 7 == 3 else Measurement(z, model)  # some predict-only steps
        ests = [f.step(0.1 * k, x, P, np.zeros(0), measurement) for f, (x, P) in zip(
            filters, states, strict=True)]  # fmt: skip
        _assert_same_estimate(*ests)
        states = [(e.mean, e.cov) for e in ests]
    assert filters[0].diagnostics == filters[1].diagnostics


@pytest.mark.parametrize("noise_form", ["augmented", "additive"])
def test_imm_backends_agree_on_a_fault_bank(noise_form):
    process, A = oscillator_bank()
    modes = list(single_fault_modes())
    output = MeasurementModel(
        fault_masked_output(identity_output, modes), np.eye(6) * 0.05**2, name="imu"
    )
    rng = np.random.default_rng(8)
    imms = [
        ImmEstimator(
            UnscentedKalmanFilter(process, noise_form=noise_form, backend=b),
            sticky_transition(7, 0.99),
            1e-4,
        )
        for b in ("numba", "numpy")
    ]
    ests = [imm.initial_estimate(0.0, np.zeros(6), np.eye(6)) for imm in imms]
    x = np.array([1.0, 0.3, -0.8, 0.2, 1.0, 0.6])
    for k in range(80):
        x = A @ x + 0.01 * rng.standard_normal(6)
        mask = modes[4].healthy_mask if k >= 40 else np.ones(6)
        z = x * mask + 0.05 * rng.standard_normal(6)
        ests = [imm.step(e, 0.1 * k, np.zeros(0), Measurement(z, output)) for imm, e in zip(
            imms, ests, strict=True)]  # fmt: skip
        fast, ref = ests
        for name in ("mean", "cov", "mode_probabilities", "mode_means", "mode_covs", "nis"):
            assert_close(getattr(fast, name), getattr(ref, name), 1e-9)
        assert_close(fast.log_likelihoods, ref.log_likelihoods, 1e-9)
    assert ests[0].most_likely_mode == 4
    assert imms[0].diagnostics == imms[1].diagnostics


def test_repairs_are_counted_alike_on_both_backends():
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
            UnscentedKalmanFilter(sys.process(), noise_form=noise_form, backend=b)
            for b in ("numba", "numpy")
        ]
        for P in bad_covs:
            for z in (Measurement(np.array([1118.0, 0.46]), range_bearing_model()), z_huge, z_nan):
                ests = [
                    f.step(0.0, np.array([[1000.0, 500.0, 1.0, 1.0]]), P[None], np.zeros(0), z)
                    for f in filters
                ]
                _assert_same_estimate(*ests, rtol=1e-8)
        fast, ref = (f.diagnostics for f in filters)
        assert fast == ref
        assert fast.cholesky_jitter and fast.cholesky_eigen_floor and fast.outlier_innovations
        assert fast.skipped_nonfinite_measurement


@pytest.mark.parametrize("noise_form", ["augmented", "additive"])
def test_an_innovation_covariance_the_kernels_cannot_factor_goes_to_the_numpy_update(noise_form):
    sys = constant_velocity()
    # the first channel ignores the state and has no noise: P_zz is singular
    blind = MeasurementModel(
        lambda t, x, u, w: np.stack([0.0 * x[0], x[1]]) + (0.0 if w is None else w),
        np.diag([0.0, 4.0]),
    )
    filters = [
        UnscentedKalmanFilter(sys.process(), noise_form=noise_form, backend=b)
        for b in ("numba", "numpy")
    ]
    ests = [
        f.step(0.0, np.array([[10.0, 5.0, 1.0, 1.0]]), np.eye(4)[None], np.zeros(0),
               Measurement(np.array([0.0, 5.5]), blind))
        for f in filters
    ]  # fmt: skip
    _assert_same_estimate(*ests)
    assert filters[0].diagnostics == filters[1].diagnostics
    assert filters[0].diagnostics.cholesky_jitter == 1


def test_unknown_backend_is_rejected():
    with pytest.raises(ValueError, match="backend must be"):
        UnscentedKalmanFilter(constant_velocity().process(), backend="cuda")
