"""The held controls' uncertainty and the averaged IMU's noise, against independent computations.

- :class:`ControlHold` measures a random walk's intensity from its samples: on a seeded walk of
  known intensity the estimate is unbiased (its mean over many increments within the chi-square
  spread of a mean of squared normals), and its variance grows as ``q * age``.
- :meth:`AircraftEstimator.control_sensitivity` (forward differences of the batched model)
  agrees with central differences of the aircraft model taken one control at a time, the gyros
  have no feedthrough, and ``B e`` predicts the step a small control error really makes.
- :func:`averaged_var_scale` is the variance of the mean of a faster stream's white samples:
  checked against the sample variance of seeded draws.
"""

from __future__ import annotations

import numpy as np
import pytest

from immukf_sitl.models.aero import AeroModel
from immukf_sitl.models.earth import NedOrigin
from immukf_sitl.models.params import load_aircraft_params
from immukf_sitl.models.sensors import IMU_PERIOD_S
from immukf_sitl.service.control_hold import ControlHold
from immukf_sitl.service.filters import build_aero_estimator
from immukf_sitl.service.stream_rate import averaged_var_scale


def test_hold_measures_a_random_walk_intensity_without_bias():
    rng = np.random.default_rng(7)
    q = np.array([0.04, 0.01, 0.0025, 0.09])  # rad^2/s (throttle: fraction^2/s)
    dt_s = 0.1
    hold = ControlHold(increments=1)
    u = np.zeros(4)
    estimates = []
    for k in range(4000):
        u = u + rng.normal(0.0, np.sqrt(q * dt_s))
        hold.add(k * dt_s, u.copy())
        if hold.intensity is not None:
            estimates.append(hold.intensity)
    mean = np.mean(estimates, axis=0)
    # du^2 / dt is q * chi2(1): mean q, variance 2 q^2; the mean of n is within 4 sigma
    n = len(estimates)
    assert np.all(np.abs(mean - q) < 4.0 * q * np.sqrt(2.0 / n))


def test_hold_variance_grows_with_age_and_is_nothing_before_two_samples():
    hold = ControlHold()
    assert hold.variance(1.0) is None
    hold.add(0.0, np.zeros(4))
    assert hold.variance(0.05) is None  # one sample: no increment yet
    hold.add(0.1, np.array([0.02, 0.0, 0.0, 0.1]))
    q = np.array([0.02**2, 0.0, 0.0, 0.1**2]) / 0.1
    np.testing.assert_allclose(hold.intensity, q)
    np.testing.assert_allclose(hold.variance(0.15), q * 0.05)
    assert hold.variance(0.1) is None  # the sample's own time: nothing held yet
    hold.add(0.2, np.array([0.02, 0.0, 0.0, 0.1]))  # still: the mean of the last two
    np.testing.assert_allclose(hold.intensity, q / 2)
    hold.reset()
    assert hold.intensity is None and hold.controls is None


@pytest.fixture(scope="module")
def cruise():
    model = AeroModel(load_aircraft_params(), NedOrigin(0.0, 0.0, 100.0))
    x, u = model.trim(25.0)
    return model, x, u


def test_sensitivity_matches_central_differences_of_the_model(cruise):
    model, x, u = cruise
    estimator = build_aero_estimator("ukf2", model)
    estimate = estimator.start(0.0, x, np.diag(np.full(12, 1e-4)), u)
    sens = estimator.control_sensitivity(estimate)
    mean = estimate.filter.mean
    h = 1e-5
    for i in range(4):
        e = np.zeros(4)
        e[i] = h
        b = (model.step(0.0, mean, u + e) - model.step(0.0, mean, u - e)) / (2 * h)
        d = (model.imu(0.0, mean, u + e) - model.imu(0.0, mean, u - e)) / (2 * h)
        # forward differences of step 1e-3 against central ones: second order, 1e-4 of the column
        np.testing.assert_allclose(sens.state[:, i], b, rtol=2e-3, atol=1e-4 * np.abs(b).max())
        np.testing.assert_allclose(sens.imu[:, i], d, rtol=2e-3, atol=1e-4 * np.abs(d).max())
    np.testing.assert_array_equal(sens.imu[3:], 0.0)  # a gyro reads the state, not the surfaces
    # a small control error moves the next state as B predicts (the model is smooth)
    err = np.array([0.01, -0.005, 0.008, 0.02])
    moved = model.step(0.0, mean, u + err) - model.step(0.0, mean, u)
    np.testing.assert_allclose(moved, sens.state @ err, rtol=0.05, atol=1e-6)
    var = err**2
    np.testing.assert_allclose(sens.state_cov(var), (sens.state * var) @ sens.state.T)
    np.testing.assert_allclose(sens.imu_var(var), np.diagonal(sens.imu @ np.diag(var) @ sens.imu.T))


@pytest.mark.parametrize("rate_hz", [200.0, 250.0, 300.0, 1000.0])
def test_averaged_var_scale_is_the_variance_of_the_mean_of_white_samples(rate_hz):
    rng = np.random.default_rng(11)
    sigma_100 = 1.0  # one sample at the filter's 100 Hz step
    sigma = sigma_100 * np.sqrt(rate_hz * IMU_PERIOD_S)  # the same noise density at rate_hz
    per_step = rate_hz * IMU_PERIOD_S
    for n in {int(np.floor(per_step)), int(np.ceil(per_step))}:
        means = rng.normal(0.0, sigma, size=(20000, n)).mean(axis=1)
        scale = averaged_var_scale(n, 1.0 / rate_hz, IMU_PERIOD_S)
        # the sample variance of 20000 normals is within 4 sigma of its value: sqrt(2/N)
        assert abs(means.var() / scale - 1.0) < 4.0 * np.sqrt(2.0 / 20000)
    assert averaged_var_scale(1, 0.004, IMU_PERIOD_S) == 1.0
    assert averaged_var_scale(3, None, IMU_PERIOD_S) == 1.0
