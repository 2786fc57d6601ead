"""Fault observability: the band rule, every fault kind, and the shipped scenarios in flight."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from immukf_sitl.experiments.observability import (
    MIN_NOISE_FACTOR,
    SUSTAINED_S,
    channel_band_sigma,
    channel_sigma,
    fault_deviation,
    fault_observable_time_s,
    first_observable_time_s,
)
from immukf_sitl.models.sensors import ImuSpec
from immukf_sitl.scenario import FaultSpec, load_scenario
from sim.scenario_flight import flight_from_scenario

# flies JSBSim or the estimator chain
pytestmark = pytest.mark.slow

SCENARIO_DIR = Path(__file__).resolve().parents[1] / "scenarios"
#: The shipped flights must make each fault observable this soon after it starts (s).
MAX_OBSERVABILITY_DELAY_S = 1.0


def test_first_time_beyond_the_band():
    t = np.arange(0.0, 5.0, 0.5)
    values = np.array([9.0, 0.0, 0.1, -0.4, 0.6, -0.7, 0.0, 0.0, 0.0, 0.0])
    assert first_observable_time_s(t, values, 0.0, sigma=0.1) == 0.0
    assert first_observable_time_s(t, values, 0.5, sigma=0.1) == 2.0  # strictly beyond 5 sigma
    assert first_observable_time_s(t, values, 0.5, sigma=0.1, n_sigma=3.0) == 1.5
    assert first_observable_time_s(t, values, 3.0, sigma=0.1) is None
    with pytest.raises(ValueError, match="equal 1-D shapes"):
        first_observable_time_s(t, values[:3], 0.0, sigma=0.1)


def test_a_crossing_counts_once_it_has_lasted_the_hold():
    """Beyond the band for the hold: observable at the stretch's start, not before."""
    t = np.arange(0.0, 1.0, 0.01)
    values = np.zeros(t.size)
    values[10] = 1.0  # one sample at 0.10 s
    values[30:40] = 1.0  # ten samples from 0.30 s: they hold 0.1 s
    values[60:72] = -1.0  # twelve from 0.60 s
    assert first_observable_time_s(t, values, 0.0, sigma=0.1) == pytest.approx(0.10)
    assert first_observable_time_s(t, values, 0.0, sigma=0.1, hold_s=0.1) == pytest.approx(0.30)
    assert first_observable_time_s(t, values, 0.0, sigma=0.1, hold_s=0.11) == pytest.approx(0.60)
    assert first_observable_time_s(t, values, 0.0, sigma=0.1, hold_s=0.2) is None
    tail = np.where(t >= 0.85, 1.0, 0.0)  # beyond it when the data ends, at 0.99 s
    assert first_observable_time_s(t, tail, 0.0, sigma=0.1, hold_s=0.1) == pytest.approx(0.85)
    assert first_observable_time_s(t, tail, 0.0, sigma=0.1, hold_s=0.2) is None
    with pytest.raises(ValueError, match="hold_s"):
        first_observable_time_s(t, values, 0.0, sigma=0.1, hold_s=-1.0)


def test_a_gain_is_observable_once_sustained_and_a_spike_on_its_sample():
    """A gust's one-sample jolt times a gain is not a fault to see; a spike lasts one sample."""
    t = np.arange(0.0, 3.0, 0.01)
    imu = np.zeros((t.size, 6))
    imu[:, 2] = -9.81
    imu[150, 1] = 2.0  # a one-sample lateral jolt at 1.5 s
    imu[(t >= 2.0) & (t < 2.5), 1] = 2.0  # a half-second sideslip from 2 s
    spec = ImuSpec()
    gain = FaultSpec(t_s=1.0, channels=("y",), kind="scale", value=0.5)
    assert fault_observable_time_s(gain, t, imu, spec, hold_s=0.0) == pytest.approx(1.5)
    assert fault_observable_time_s(gain, t, imu, spec) == pytest.approx(2.0)
    assert SUSTAINED_S < 0.5
    spikes = FaultSpec(t_s=1.0, channels=("y",), kind="spikes", value=5.0, rate_hz=2.0)
    first = fault_observable_time_s(spikes, t, imu, spec)
    assert first is not None and first < 1.0 + 3.0 / 2.0  # the first spikes, not a stretch


def test_channel_sigmas():
    imu = ImuSpec(accel_sigma_mps2=0.1, gyro_sigma_radps=0.01)
    assert [channel_sigma(c, imu) for c in "xyzpqr"] == [0.1] * 3 + [0.01] * 3
    with pytest.raises(ValueError, match="channel 'w'"):
        channel_sigma("w", imu)


def test_the_band_holds_what_a_healthy_sensor_of_the_spec_sheet_reads():
    """Noise and turn-on bias in quadrature: a bias inside the spec sheet is not a fault."""
    imu = ImuSpec(accel_sigma_mps2=0.03, gyro_sigma_radps=0.003, accel_bias_sigma_mps2=0.04,
                  gyro_bias_sigma_radps=0.004)  # fmt: skip
    assert channel_band_sigma("x", imu) == pytest.approx(0.05)
    assert channel_band_sigma("q", imu) == pytest.approx(0.005)
    assert channel_band_sigma("q", ImuSpec(gyro_sigma_radps=0.003)) == pytest.approx(0.003)
    t = np.arange(0.0, 2.0, 0.01)
    small = FaultSpec(0.5, ("q",), "bias", 0.024)  # 4.8 band sigmas: never observable
    large = FaultSpec(0.5, ("q",), "bias", 0.026)
    truth = np.zeros((t.size, 6))
    assert fault_observable_time_s(small, t, truth, imu) is None
    assert fault_observable_time_s(large, t, truth, imu) == pytest.approx(0.5)


def test_deviation_of_each_kind():
    t = np.arange(0.0, 4.0, 1.0)
    truth = np.array([1.0, 2.0, 3.0, 4.0])
    zero = FaultSpec(t_s=1.0, channels=("q",), kind="zero")
    stuck = FaultSpec(t_s=1.0, channels=("q",), kind="stuck")
    bias = FaultSpec(t_s=1.0, channels=("q",), kind="bias", value=0.5, end_t_s=3.0)
    drift = FaultSpec(t_s=1.0, channels=("q",), kind="drift", value=0.25)
    assert np.array_equal(fault_deviation(zero, t, truth), [0.0, -2.0, -3.0, -4.0])
    assert np.array_equal(fault_deviation(stuck, t, truth), [0.0, 0.0, -1.0, -2.0])
    assert np.array_equal(fault_deviation(bias, t, truth), [0.0, 0.5, 0.5, 0.0])
    assert np.array_equal(fault_deviation(drift, t, truth), [0.0, 0.0, 0.25, 0.5])
    scale = FaultSpec(t_s=1.0, channels=("q",), kind="scale", value=0.5)
    assert np.array_equal(fault_deviation(scale, t, truth), [0.0, -1.0, -1.5, -2.0])


def test_noise_is_observable_from_onset_only_above_the_smallest_detectable_factor():
    """A factor k puts ``2 (1 - Phi(5 / k))`` of the samples beyond 5 sigma: one a second at
    100 Hz for k = 1.94, which MIN_NOISE_FACTOR rounds to 2."""
    assert 2.0 * stats.norm.sf(5.0 / 1.94) * 100.0 == pytest.approx(1.0, rel=0.02)
    t = np.arange(0.0, 3.0, 0.01)
    imu = np.zeros((t.size, 6))
    loud = FaultSpec(t_s=1.0, channels=("p",), kind="noise", value=MIN_NOISE_FACTOR * 1.5)
    quiet = FaultSpec(t_s=1.0, channels=("p",), kind="noise", value=MIN_NOISE_FACTOR)
    assert fault_observable_time_s(loud, t, imu, ImuSpec()) == pytest.approx(1.0)
    assert fault_observable_time_s(quiet, t, imu, ImuSpec()) is None


def test_a_fault_on_several_channels_is_observable_when_any_is():
    t = np.arange(0.0, 3.0, 0.01)
    imu = np.zeros((t.size, 6))
    imu[:, 2] = -9.8  # f_z: always away from zero
    imu[t >= 2.0, 4] = 0.1  # q: from 2 s
    noise = ImuSpec()
    q_only = FaultSpec(t_s=1.0, channels=("q",))
    assert fault_observable_time_s(q_only, t, imu, noise) == pytest.approx(2.0)
    assert fault_observable_time_s(FaultSpec(t_s=1.0, channels=("z", "q")), t, imu, noise) == 1.0
    assert fault_observable_time_s(FaultSpec(t_s=1.0, channels=("y",)), t, imu, noise) is None
    ended = FaultSpec(t_s=1.0, channels=("q",), end_t_s=1.5)
    assert fault_observable_time_s(ended, t, imu, noise) is None
    with pytest.raises(ValueError, match=r"shape \(N, 6\)"):
        fault_observable_time_s(q_only, t, imu[:, :3], noise)


def fly_truth(path: Path, until_s: float) -> tuple[np.ndarray, np.ndarray]:
    scenario = load_scenario(path)
    flight = flight_from_scenario(scenario)
    records = [flight.start()]
    records += [flight.step() for _ in range(int(round(until_s / flight.driver.dt_s)))]
    times = np.array([r.time_s for r in records])
    imu = np.array(
        [
            np.concatenate([r.truth.specific_force_body_mps2, r.truth.rates_body_radps])
            for r in records
        ]
    )
    return times, imu


@pytest.mark.parametrize(
    "name",
    [
        "x_accel_zeroed",
        "y_accel_zeroed",
        "z_accel_zeroed",
        "p_gyro_zeroed",
        "q_gyro_zeroed",
        "r_gyro_zeroed",
    ],
)
def test_each_shipped_fault_becomes_observable_soon_after_it_starts(name):
    path = SCENARIO_DIR / f"{name}.yaml"
    scenario = load_scenario(path)
    (fault,) = scenario.faults
    times, imu = fly_truth(path, fault.t_s + 5.0)
    t_obs = fault_observable_time_s(fault, times, imu, scenario.sensors.imu)
    assert t_obs is not None
    delay = t_obs - fault.t_s
    print(f"{name}: observable {delay:.2f} s after the fault")
    assert 0.0 <= delay <= MAX_OBSERVABILITY_DELAY_S
    # Gyro and y faults are invisible in the straight, level, coordinated flight just before
    # the manoeuvre: the scenario really exercises the observability rule.
    if fault.channels[0] in ("y", "p", "q", "r"):
        assert delay > 0.1
