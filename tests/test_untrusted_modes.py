"""Untrusted-channel fault modes: the likelihood against an independent Gaussian computation,
and the evidence threshold the module docstring derives."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import multivariate_normal, norm
from toy_systems import identity_output, oscillator_bank

from immukf_sitl.estimation import (
    DeadOrAnyEvidence,
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


def _bank_innovations(rng, modes, width):
    """Innovations and covariances of a 7-mode bank as the UKF makes them (widths included)."""
    r = len(modes)
    nu = rng.normal(0.0, 0.01, (r, 6))
    cov = np.empty((r, 6, 6))
    for j in range(r):
        a = rng.normal(0.0, 0.005, (6, 6))
        cov[j] = a @ a.T + np.diag(ImuSpec().sigmas ** 2) + np.diag(width[j])
        nu[j] += rng.normal(0.0, 1.0, 6) * np.sqrt(width[j])
    return nu, cov


def test_dead_or_any_swaps_the_wide_factor_for_the_mixture():
    """Against a direct computation, channel by channel: observable channels mix N(z; 0, R)
    and the wide density; unobservable ones mix the fault-free mode's marginal instead."""
    modes = single_fault_modes()
    imu = ImuSpec()
    width = fault_mode_noise_var(modes, "untrusted", imu.ranges)
    evidence = DeadOrAnyEvidence(modes, imu.sigmas**2, width, dead_weight=0.5, n_sigma=3.0)
    rng = np.random.default_rng(8)
    nu, cov = _bank_innovations(rng, modes, width)
    z = rng.normal(0.0, 0.3, 6)
    z[1] = 1e-4  # y near zero: a mode's prediction of it may sit within 3 sigma of zero
    base = rng.normal(-50.0, 5.0, len(modes))
    got = evidence(0.0, None, nu, cov, z, None, base)
    assert got[0] == base[0]  # the fault-free mode is untouched
    for j in range(1, len(modes)):
        i = j - 1
        s_wide = cov[j, i, i]
        own = z[i] - nu[j, i]
        wide = norm.logpdf(nu[j, i], 0.0, math.sqrt(s_wide))
        if abs(own) > 3.0 * math.sqrt(cov[0, i, i]):
            dead = math.log(0.5) + norm.logpdf(z[i], 0.0, imu.sigmas[i])
        else:
            dead = norm.logpdf(nu[0, i], 0.0, math.sqrt(cov[0, i, i]))
        mixture = np.logaddexp(dead, math.log(0.5) + wide)
        assert got[j] == pytest.approx(base[j] - wide + mixture, rel=1e-12, abs=1e-9)


def test_a_dead_channel_scores_as_sharply_as_a_zero_mode():
    """A q gyro reading zero plus noise where the mode predicts 0.1 rad/s: the untrusted mode's
    channel term is the zero mode's less ln 2."""
    modes = single_fault_modes()
    imu = ImuSpec()
    width = fault_mode_noise_var(modes, "untrusted", imu.ranges)
    evidence = DeadOrAnyEvidence(modes, imu.sigmas**2, width)
    z = np.array([0.0, 0.0, -9.8, 0.0, 0.0002, 0.0])
    nu = np.zeros((7, 6))
    cov = np.tile(np.diag(imu.sigmas**2 * 4.0), (7, 1, 1)) + width[:, :, None] * np.eye(6)
    nu[5, 4] = z[4] - 0.1  # the q mode predicts 0.1 rad/s
    nu[0, 4] = 0.0  # the fault-free mode has followed the dead gyro
    got = evidence(0.0, None, nu, cov, z, None, np.zeros(7))
    zero_mode = norm.logpdf(z[4], 0.0, imu.sigmas[4])
    wide = norm.logpdf(nu[5, 4], 0.0, math.sqrt(cov[5, 4, 4]))
    mixture = np.logaddexp(zero_mode + math.log(0.5), wide + math.log(0.5))
    assert got[5] == pytest.approx(mixture - wide, abs=1e-9)
    assert mixture == pytest.approx(zero_mode + math.log(0.5), abs=1e-3)  # the zero part rules
