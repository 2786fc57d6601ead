"""The additive-noise UKF against filterpy's UnscentedKalmanFilter, same sigma points."""

import numpy as np
import pytest
from filterpy.kalman import MerweScaledSigmaPoints
from filterpy.kalman import UnscentedKalmanFilter as FilterpyUkf
from toy_systems import DT_S, constant_velocity, range_bearing, range_bearing_model, simulate_target

from immukf_sitl.estimation import Measurement, ScaledSigmaPoints, UnscentedKalmanFilter


@pytest.mark.parametrize("alpha,beta,kappa", [(1.0, 2.0, 0.0), (0.5, 2.0, 1.0)])
def test_additive_ukf_matches_filterpy_on_range_bearing(alpha, beta, kappa):
    sys = constant_velocity()
    rng = np.random.default_rng(7)
    xs, zs = simulate_target(rng, sys, np.array([800.0, -300.0, 5.0, 20.0]), 120)

    points = MerweScaledSigmaPoints(4, alpha=alpha, beta=beta, kappa=kappa)
    ref = FilterpyUkf(
        dim_x=4,
        dim_z=2,
        dt=DT_S,
        hx=lambda x: range_bearing(x),
        fx=lambda x, dt: sys.F @ x,
        points=points,
    )
    x0 = np.array([790.0, -290.0, 4.0, 18.0])
    P0 = np.diag([100.0, 100.0, 9.0, 9.0])
    ref.x, ref.P = x0.copy(), P0.copy()
    ref.Q = sys.G @ sys.Q @ sys.G.T
    ref.R = range_bearing_model().noise_cov.copy()

    ukf = UnscentedKalmanFilter(
        sys.process(), ScaledSigmaPoints(alpha, beta, kappa), noise_form="additive"
    )
    # the bearing stays far from +-pi here; both filters use plain (not circular) means, as
    # filterpy's default unscented_transform does
    model = range_bearing_model(angles=False)
    est = ukf.initial_estimate(0.0, x0, P0)
    for k, z in enumerate(zs):
        ref.predict()
        ref.update(z)
        est = ukf.step(est, (k + 1) * DT_S, np.zeros(0), Measurement(z, model))
        x, P = est.mean, est.cov
        np.testing.assert_allclose(x[0], ref.x, rtol=1e-8, atol=1e-8 * np.abs(ref.x).max())
        np.testing.assert_allclose(P[0], ref.P, rtol=1e-8, atol=1e-8 * np.abs(ref.P).max())
    # and the filter tracks: final position error well inside 3 sigma
    err = xs[-1][:2] - x[0, :2]
    assert err @ np.linalg.solve(P[0, :2, :2], err) < 13.8  # chi2(2) 0.999
