"""Ill-conditioned inputs give finite output and increment the right counters."""

import numpy as np
import pytest
from toy_systems import constant_velocity, range_bearing_model

from immukf_sitl.estimation import (
    ImmEstimator,
    Measurement,
    MeasurementModel,
    UnscentedKalmanFilter,
    sticky_transition,
)
from immukf_sitl.estimation.diagnostics import FilterDiagnostics
from immukf_sitl.estimation.linalg import robust_cholesky
from immukf_sitl.estimation.sigma_points import JulierSigmaPoints


def _finite(est):
    return np.all(np.isfinite(est.mean)) and np.all(np.isfinite(est.cov))


def test_nearly_singular_covariance_is_repaired_and_counted():
    sys = constant_velocity()
    ukf = UnscentedKalmanFilter(sys.process())
    v = np.array([1.0, 2.0, 0.5, -1.0])
    P = np.outer(v, v) * 1e4 - 1e-9 * np.eye(4)  # rank 1, slightly indefinite
    with pytest.raises(np.linalg.LinAlgError):
        np.linalg.cholesky(P)
    est = ukf.step(
        ukf.initial_estimate(0.0, np.array([1000.0, 500.0, 1.0, 1.0]), P),
        0.1,
        np.zeros(0),
        Measurement(np.array([1118.0, 0.46]), range_bearing_model()),
    )
    assert _finite(est)
    d = ukf.diagnostics
    assert d.cholesky_jitter + d.cholesky_eigen_floor >= 1
    assert np.all(np.linalg.eigvalsh(est.cov[0]) > -1e-6 * np.abs(est.cov[0]).max())


def test_eigen_floor_repairs_what_jitter_cannot():
    diag = FilterDiagnostics()
    P = np.diag([1.0, -5.0, 2.0])[None]  # clearly indefinite
    L = robust_cholesky(P, diag)
    assert diag.cholesky_eigen_floor == 1 and diag.cholesky_jitter == 0
    assert np.all(np.isfinite(L))
    repaired = L[0] @ L[0].T
    np.testing.assert_allclose(np.diag(repaired)[[0, 2]], [1.0, 2.0], rtol=1e-9)


def test_nan_covariance_entries_do_not_crash():
    diag = FilterDiagnostics()
    P = np.eye(3)[None].copy()
    P[0, 1, 1] = np.nan
    L = robust_cholesky(P, diag)
    assert np.all(np.isfinite(L)) and diag.cholesky_eigen_floor == 1


def test_nan_measurement_skips_the_update_and_is_counted():
    sys = constant_velocity()
    ukf = UnscentedKalmanFilter(sys.process())
    x0, P0 = np.array([1000.0, 500.0, 1.0, 1.0]), np.eye(4) * 10
    est = ukf.step(
        ukf.initial_estimate(0.0, x0, P0),
        0.1,
        np.zeros(0),
        Measurement(np.array([np.nan, 0.4]), range_bearing_model()),
    )
    assert ukf.diagnostics.skipped_nonfinite_measurement == 1
    assert not est.updated and _finite(est)
    np.testing.assert_allclose(est.mean[0], sys.F @ x0)


def test_million_sigma_innovation_stays_finite_and_is_counted():
    sys = constant_velocity()
    model = range_bearing_model()
    ukf = UnscentedKalmanFilter(sys.process())
    imm = ImmEstimator(ukf, sticky_transition(2, 0.99), probability_floor=1e-6)
    est = imm.initial_estimate(0.0, np.array([1000.0, 500.0, 1.0, 1.0]), np.eye(4))
    z = np.array([1118.0 + 1e6 * 5.0, 0.46])
    est = imm.step(est, 0.1, np.zeros(0), Measurement(z, model))
    assert np.all(np.isfinite(est.mean)) and np.all(np.isfinite(est.cov))
    assert np.all(np.isfinite(est.log_likelihoods)) and np.all(est.log_likelihoods < -1e9)
    np.testing.assert_allclose(est.mode_probabilities.sum(), 1.0)
    assert ukf.diagnostics.outlier_innovations == 2  # both modes saw it
    # and the next ordinary measurement still updates normally
    est = imm.step(est, 0.2, np.zeros(0), Measurement(np.array([1118.0, 0.46]), model))
    assert est.updated and np.all(np.isfinite(est.mean))


def test_every_covariance_is_symmetrised_each_step():
    sys = constant_velocity()
    ukf = UnscentedKalmanFilter(sys.process())
    P = np.eye(4) * 10
    P[0, 1] = 1e-3  # asymmetric on input
    est = ukf.step(ukf.initial_estimate(0.0, np.zeros(4) + 100, P), 0.1, np.zeros(0), None)
    assert np.array_equal(est.cov[0], est.cov[0].T)
    assert ukf.diagnostics.symmetrised == 2  # P(k|k) and P(k+1|k)
    # the input was symmetrised before use: the prediction is F ((P + P')/2) F' + G Q G'
    P_sym = 0.5 * (P + P.T)
    np.testing.assert_allclose(
        est.cov[0], sys.F @ P_sym @ sys.F.T + sys.G @ sys.Q @ sys.G.T, rtol=1e-12, atol=1e-13
    )


def test_a_non_finite_update_resets_the_filter_to_its_prior_and_is_counted():
    sys = constant_velocity()
    # an output model that overflows: P_zz and the gain become inf/NaN
    overflow = MeasurementModel(lambda t, x, u, w: x[:2] * 1e200 + (0.0 if w is None else w),
                                np.eye(2))  # fmt: skip
    ukf = UnscentedKalmanFilter(sys.process())
    x0, P0 = np.array([[1.0, 2.0, 0.5, -0.5], [3.0, 4.0, 0.1, 0.2]]), np.stack([np.eye(4)] * 2)
    est = ukf.step(ukf.initial_estimate(0.0, x0, P0), 0.1, np.zeros(0),
                   Measurement(np.array([1.0, 2.0]), overflow))  # fmt: skip
    assert ukf.diagnostics.nonfinite_state_reset == 2
    assert ukf.diagnostics.cholesky_eigen_floor == 2  # the non-finite P_zz were repaired first
    np.testing.assert_array_equal(est.mean, x0)
    np.testing.assert_array_equal(est.cov, P0)
    assert np.all(est.log_likelihood == -np.inf)


def test_an_update_that_leaves_a_negative_variance_resets_the_filter_and_is_counted():
    # an output that grows with the distance from the mean, under a negative central weight
    # (Julier, kappa = -2 over four states): the unscented P_zz has a negative eigenvalue, so
    # no update from it is a covariance; the filter keeps x(k|k), P(k|k) with likelihood zero
    sys = constant_velocity()
    m0 = np.array([1.0, 2.0, 0.0, 0.0])
    R = np.eye(2) * 1e-2

    def away(t, x, u, w):
        distance = np.sqrt(sum((x[i] - m0[i]) ** 2 for i in range(4)))
        return np.stack([x[0] + distance, x[1]]) + (0.0 if w is None else w)

    scheme = JulierSigmaPoints(kappa=-2.0)
    ukf = UnscentedKalmanFilter(sys.process(), scheme, noise_form="additive")
    P0 = np.eye(4)
    est = ukf.step(ukf.initial_estimate(0.0, m0[None], P0[None]), 0.1, np.zeros(0),
                   Measurement(m0[:2].copy(), MeasurementModel(away, R)))  # fmt: skip

    # the same unscented transform, by hand, about the filter's prediction
    pred_mean = sys.F @ m0
    pred_cov = sys.F @ P0 @ sys.F.T + sys.G @ sys.Q @ sys.G.T
    w = scheme.weights(4)
    columns = w.spread * np.linalg.cholesky(pred_cov)
    centre = pred_mean[:, None]
    points = np.column_stack([pred_mean, centre + columns, centre - columns])
    z = away(0.1, points, None, None)
    z_mean = z @ w.mean_weights
    P_zz = (z - z_mean[:, None]) * w.cov_weights @ (z - z_mean[:, None]).T + R
    assert np.linalg.eigvalsh(P_zz).min() < 0.0

    assert ukf.diagnostics.indefinite_state_reset == 1
    np.testing.assert_array_equal(est.mean[0], m0)
    np.testing.assert_array_equal(est.cov[0], P0)
    assert est.log_likelihood[0] == -np.inf
