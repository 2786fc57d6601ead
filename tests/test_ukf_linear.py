"""On a linear-Gaussian system the UKF (both forms) is the Kalman filter."""

import numpy as np
import pytest
from toy_systems import constant_velocity, kalman_filter

from immukf_sitl.estimation import (
    JulierSigmaPoints,
    Measurement,
    SampleGate,
    ScaledSigmaPoints,
    UnscentedKalmanFilter,
)


def _relative_error(a, b):
    return np.max(np.abs(a - b)) / np.max(np.abs(b))


@pytest.mark.parametrize("noise_form", ["augmented", "additive"])
@pytest.mark.parametrize(
    "scheme",
    [JulierSigmaPoints(kappa=0.0), JulierSigmaPoints(kappa=1.0), ScaledSigmaPoints(0.5, 2.0, 0.0)],
    ids=["kappa0", "kappa1", "scaled"],
)
def test_ukf_equals_kalman_filter_over_100_steps(noise_form, scheme):
    sys = constant_velocity()
    rng = np.random.default_rng(1)
    zs = rng.normal(0.0, 3.0, size=(100, 2)) + np.linspace(0, 50, 100)[:, None]
    x0 = np.array([0.0, 0.0, 5.0, -2.0])
    P0 = np.diag([10.0, 10.0, 4.0, 4.0])
    P0[0, 2] = P0[2, 0] = 1.0
    reference = kalman_filter(sys, x0, P0, zs)

    ukf = UnscentedKalmanFilter(sys.process(), scheme, noise_form)
    model = sys.measurement()
    est = ukf.initial_estimate(0.0, x0, P0)
    for k, z in enumerate(zs):
        est = ukf.step(est, 0.1 * (k + 1), np.zeros(0), Measurement(z, model))
        assert est.t_s == 0.1 * (k + 1)
        x_ref, P_ref = reference[k]
        assert _relative_error(est.mean[0], x_ref) < 1e-9, k
        assert _relative_error(est.cov[0], P_ref) < 1e-9, k
    assert ukf.diagnostics.cholesky_jitter == 0
    assert ukf.diagnostics.steps == 100


def test_predict_only_step_propagates_mean_and_covariance():
    sys = constant_velocity()
    ukf = UnscentedKalmanFilter(sys.process())
    x0 = np.array([1.0, 2.0, 3.0, 4.0])
    P0 = np.diag([1.0, 2.0, 3.0, 4.0])
    est = ukf.step(ukf.initial_estimate(0.0, x0, P0), 0.1, np.zeros(0), None)
    np.testing.assert_allclose(est.mean[0], sys.F @ x0, rtol=1e-12)
    expected = sys.F @ P0 @ sys.F.T + sys.G @ sys.Q @ sys.G.T
    np.testing.assert_allclose(est.cov[0], expected, rtol=1e-12, atol=1e-14)
    assert not est.updated
    assert np.all(est.log_likelihood == 0.0)


def test_log_likelihood_is_the_gaussian_density_of_the_innovation():
    sys = constant_velocity()
    ukf = UnscentedKalmanFilter(sys.process())
    x0 = np.array([0.0, 0.0, 1.0, 1.0])
    P0 = np.eye(4)
    z = np.array([0.7, -0.4])
    model = sys.measurement()
    est = ukf.step(ukf.initial_estimate(0.0, x0, P0), 0.1, np.zeros(0), Measurement(z, model))
    Pp = sys.F @ P0 @ sys.F.T + sys.G @ sys.Q @ sys.G.T
    S = sys.H @ Pp @ sys.H.T + sys.R
    nu = z - sys.H @ sys.F @ x0
    expected = -0.5 * (nu @ np.linalg.solve(S, nu) + np.log(np.linalg.det(2 * np.pi * S)))
    assert est.log_likelihood[0] == pytest.approx(expected, rel=1e-12)
    assert est.nis[0] == pytest.approx(nu @ np.linalg.solve(S, nu), rel=1e-12)


@pytest.mark.parametrize("noise_form", ["augmented", "additive"])
def test_a_gate_sees_the_kalman_innovation_and_what_it_widens_is_not_read(noise_form):
    """A measurement's gate is handed the closed-form Kalman filter's innovation and the diagonal
    of its ``S``; a width it gives the second output leaves the update that of the first alone."""
    sys = constant_velocity()
    ukf = UnscentedKalmanFilter(sys.process(), noise_form=noise_form)
    x0 = np.array([0.0, 0.0, 1.0, 1.0])
    P0 = np.eye(4)
    z = np.array([0.7, -0.4])
    seen = {}

    def widths(innovation, variance):
        seen["innovation"], seen["variance"] = innovation.copy(), variance.copy()
        return np.array([0.0, 1e12])

    gate = SampleGate(np.array([0, 0]), np.array([0, 1]), widths)
    prior = ukf.initial_estimate(0.0, x0, P0)
    est = ukf.step(prior, 0.1, np.zeros(0), Measurement(z, sys.measurement(), gate=gate))
    Pp = sys.F @ P0 @ sys.F.T + sys.G @ sys.Q @ sys.G.T
    S = sys.H @ Pp @ sys.H.T + sys.R
    nu = z - sys.H @ sys.F @ x0
    np.testing.assert_allclose(seen["innovation"], nu, rtol=1e-9)
    np.testing.assert_allclose(seen["variance"], np.diag(S), rtol=1e-9)
    h = sys.H[:1]
    gain = Pp @ h.T / (h @ Pp @ h.T + sys.R[:1, :1])
    np.testing.assert_allclose(est.mean[0], sys.F @ x0 + gain[:, 0] * nu[0], rtol=1e-9, atol=1e-9)
    np.testing.assert_array_equal(est.gated, [[0.0, 1e12]])
