"""Untrusted-channel fault modes: the likelihood against an independent Gaussian computation,
and the evidence threshold the module docstring derives."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import multivariate_normal, norm
from toy_systems import identity_output, oscillator_bank

from immukf_sitl.estimation import (
    Measurement,
    MeasurementModel,
    UnscentedKalmanFilter,
    fault_mode_noise_var,
    fault_mode_output,
    single_fault_modes,
)
from immukf_sitl.models.sensors import ImuSpec

SENSOR_SIGMA = 0.05
RANGES = np.array([20.0] * 3 + [5.0] * 3)


@pytest.mark.parametrize("form", ["augmented", "additive"])
def test_each_mode_scores_the_reading_with_its_failed_channels_widened(form):
    """A linear Gaussian bank (where the UKF is exact): mode j's log-likelihood is
    ``log N(z; A x, A P A' + Q + R + diag(V_j))`` and its update leaves the failed channel's
    reading out to within ``S / V``."""
    modes = single_fault_modes()
    process, A = oscillator_bank()
    r = np.eye(6) * SENSOR_SIGMA**2
    width = fault_mode_noise_var(modes, "untrusted", RANGES)
    model = MeasurementModel(
        fault_mode_output(identity_output, modes, "untrusted"), r, name="imu", mode_noise_var=width
    )
    ukf = UnscentedKalmanFilter(process, noise_form=form)
    rng = np.random.default_rng(4)
    x0 = rng.standard_normal(6)
    p0 = np.diag(rng.uniform(0.01, 0.1, 6))
    batch = len(modes)
    start = ukf.initial_estimate(0.0, np.tile(x0, (batch, 1)), np.tile(p0, (batch, 1, 1)))
    z = A @ x0 + rng.normal(0.0, 0.3, 6)
    z[4] += 2.0  # the q reading is far off
    out = ukf.step(start, 0.1, np.zeros(0), Measurement(z, model))
    pred_cov = A @ p0 @ A.T + process.noise_cov
    for j in range(batch):
        s = pred_cov + r + np.diag(width[j])
        expected = multivariate_normal(A @ x0, s).logpdf(z)
        assert out.log_likelihood[j] == pytest.approx(expected, rel=1e-9, abs=1e-9)
    q_mode = 5
    assert np.argmax(out.log_likelihood) == q_mode
    # the q mode's update is the update without the q channel
    keep = [0, 1, 2, 3, 5]
    s5 = pred_cov[np.ix_(keep, keep)] + r[np.ix_(keep, keep)]
    gain = pred_cov[:, keep] @ np.linalg.inv(s5)
    without_q = A @ x0 + gain @ (z[keep] - (A @ x0)[keep])
    s_q = pred_cov[4, 4] + r[4, 4]
    bound = abs(z[4] - (A @ x0)[4]) * s_q / width[q_mode, 4]  # what the wide channel still moves
    assert np.max(np.abs(out.mean[q_mode] - without_q)) <= bound
    assert np.max(np.abs(out.mean[0] - without_q)) > 50 * bound  # the fault-free mode is moved


def test_the_width_is_the_variance_of_a_reading_spread_over_the_range():
    modes = single_fault_modes()
    width = fault_mode_noise_var(modes, "untrusted", RANGES, n_extra=5)
    assert width.shape == (7, 11)
    assert not width[0].any()  # fault-free: nothing added
    for j in range(1, len(modes)):
        i = modes[j].bits.bit_length() - 1  # the failed channel
        assert width[j, i] == pytest.approx(RANGES[i] ** 2 / 3.0)
        assert np.count_nonzero(width[j]) == 1
    assert fault_mode_noise_var(modes, "zero", RANGES) is None
    # uniform over +-range has variance range^2 / 3
    assert np.var(np.random.default_rng(1).uniform(-5.0, 5.0, 200_000)) == pytest.approx(
        25.0 / 3.0, rel=0.01
    )


@pytest.mark.parametrize(("i", "expected_sigmas"), [(0, 4.0), (4, 4.3)])
def test_the_untrusted_mode_wins_beyond_the_derived_number_of_sigmas(i, expected_sigmas):
    """Per step the untrusted mode out-scores the healthy one when the innovation exceeds
    ``sqrt(ln((S + V) / S))`` sigmas (S = R here): 4.0 for the accelerometer, 4.3 for the
    gyro, as the module docstring says."""
    imu = ImuSpec()
    s = imu.sigmas[i] ** 2
    v = imu.ranges[i] ** 2 / 3.0

    def gain(k: float) -> float:
        nu = k * math.sqrt(s)
        return norm.logpdf(nu, 0.0, math.sqrt(s + v)) - norm.logpdf(nu, 0.0, math.sqrt(s))

    crossing = next(k / 100 for k in range(100, 1000) if gain(k / 100) > 0.0)
    assert crossing == pytest.approx(expected_sigmas, abs=0.1)
