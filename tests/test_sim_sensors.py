"""Sensor models: noise statistics against chi-square bounds, Gauss-Markov GPS, seeding."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pymap3d
import pytest
from scipy import stats

from immukf_sitl.models.sensors import GpsSpec, ImuSpec
from sim.driver import JsbsimDriver
from sim.sensors import GpsModel, ImuModel
from sim.truth import TruthState

# flies JSBSim or the estimator chain
pytestmark = pytest.mark.slow

SEED = 20240611


@pytest.fixture(scope="module")
def truth() -> TruthState:
    driver = JsbsimDriver()
    driver.trim()
    return driver.reset()


def chi2_bounds(n: int, sigma: float, p: float = 1e-4) -> tuple[float, float]:
    """Two-sided bounds of the sample standard deviation of n normal samples."""
    lo = stats.chi2.ppf(p / 2, n - 1)
    hi = stats.chi2.ppf(1 - p / 2, n - 1)
    return sigma * math.sqrt(lo / (n - 1)), sigma * math.sqrt(hi / (n - 1))


def test_imu_noise_has_the_specified_standard_deviation(truth):
    spec = ImuSpec()
    imu = ImuModel(spec, np.random.default_rng(SEED))
    n = 20000
    samples = np.array([imu.read(truth).as_array() for _ in range(n)])
    errors = samples - np.concatenate([truth.specific_force_body_mps2, truth.rates_body_radps])
    std = errors.std(axis=0, ddof=1)
    for channel in range(6):
        sigma = spec.accel_sigma_mps2 if channel < 3 else spec.gyro_sigma_radps
        lo, hi = chi2_bounds(n, sigma)
        assert lo < std[channel] < hi, (channel, std[channel], lo, hi)
        # zero mean: within 4 standard errors
        assert abs(errors[:, channel].mean()) < 4 * sigma / math.sqrt(n)
    # channels are independent
    corr = np.corrcoef(errors.T)
    assert np.max(np.abs(corr - np.eye(6))) < 4 / math.sqrt(n)


def test_imu_bias_and_noise_free(truth):
    bias = ImuSpec(
        accel_sigma_mps2=0.0,
        gyro_sigma_radps=0.0,
        accel_bias_mps2=(0.1, -0.2, 0.3),
        gyro_bias_radps=(0.01, 0.0, -0.02),
    )
    reading = ImuModel(bias, np.random.default_rng(SEED)).read(truth)
    assert np.allclose(reading.accel_mps2 - truth.specific_force_body_mps2, [0.1, -0.2, 0.3])
    assert np.allclose(reading.gyro_radps - truth.rates_body_radps, [0.01, 0.0, -0.02])
    assert reading.time_s == truth.time_s
    with pytest.raises(ValueError, match="accel_bias_mps2"):
        ImuSpec(accel_bias_mps2=(0.0, 0.0))
    with pytest.raises(ValueError, match="accel_sigma_mps2"):
        ImuSpec(accel_sigma_mps2=-1.0)


def test_gps_fixes_at_the_configured_rate(truth):
    gps = GpsModel(GpsSpec(rate_hz=2.0), np.random.default_rng(SEED))
    times = []
    for k in range(301):  # 0 .. 3 s at 100 Hz, accumulated like JSBSim's clock
        state = dataclasses.replace(truth, time_s=sum([0.01] * k))
        fix = gps.read(state)
        if fix is not None:
            times.append(round(fix.time_s, 6))
    assert times == [0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0]


def test_a_faster_gps_samples_the_same_error_process(truth):
    """The sigmas are a 1 Hz fix's: at 5 Hz each fix takes its share, so after 1 s the error's
    variance is the 1 Hz fix's sigma squared, and the stationary sigma is the 1 Hz one."""
    one, five = GpsSpec(), GpsSpec(rate_hz=5.0)
    assert np.array_equal(one.driving_sigmas_ned_m(), [0.21, 0.21, 0.40])  # 1 Hz: as given

    def stationary(spec: GpsSpec) -> np.ndarray:
        return spec.driving_sigmas_ned_m() / math.sqrt(
            -math.expm1(-2.0 * spec.k_gps_per_s * spec.period_s)
        )

    assert np.allclose(stationary(five), stationary(one), rtol=1e-12)
    after_1s = []
    for seed in range(3000):
        gps = GpsModel(five, np.random.default_rng(seed))
        for k in range(6):  # fixes at 0, 0.2, ..., 1.0 s; the first starts the error at zero
            gps.read(dataclasses.replace(truth, time_s=0.2 * k))
        after_1s.append(gps.position_error_ned_m)
    variance = np.var(after_1s, axis=0)
    # 3000 draws: the sample variance's relative sigma is sqrt(2 / 3000), 2.6 %; 4 sigmas
    assert np.allclose(variance, np.array([0.21, 0.21, 0.40]) ** 2, rtol=0.11), variance


def gauss_markov_run(truth: TruthState, n: int, seed: int):
    spec = GpsSpec()
    gps = GpsModel(spec, np.random.default_rng(seed))
    errors, fixes = [], []
    for k in range(n):
        fix = gps.read(dataclasses.replace(truth, time_s=float(k)))
        errors.append(gps.position_error_ned_m)
        fixes.append(fix)
    return spec, np.array(errors), fixes


def test_gps_position_error_is_first_order_gauss_markov(truth):
    n = 6000
    spec, errors, fixes = gauss_markov_run(truth, n, SEED)
    assert np.array_equal(errors[0], np.zeros(3))  # starts at zero, as in B&M
    decay = math.exp(-spec.k_gps_per_s * spec.period_s)
    eta = errors[1:] - decay * errors[:-1]
    for axis, sigma in enumerate(
        [spec.north_east_sigma_m, spec.north_east_sigma_m, spec.height_sigma_m]
    ):
        lo, hi = chi2_bounds(n - 1, sigma)
        std = eta[:, axis].std(ddof=1)
        assert lo < std < hi, (axis, std, lo, hi)
        # the driving noise is white: lag-1 autocorrelation within 4 standard errors
        e = eta[:, axis] - eta[:, axis].mean()
        lag1 = float(np.dot(e[1:], e[:-1]) / np.dot(e, e))
        assert abs(lag1) < 4 / math.sqrt(n)
        # while the error itself is strongly correlated, with the model's decay per fix
        x = errors[:, axis]
        fitted = float(np.dot(x[1:], x[:-1]) / np.dot(x[:-1], x[:-1]))
        assert fitted == pytest.approx(decay, abs=0.01)
    # the reported position carries exactly that error
    k = n - 1
    north, east, down = pymap3d.geodetic2ned(
        fixes[k].lat_deg,
        fixes[k].lon_deg,
        fixes[k].alt_m,
        truth.lat_deg,
        truth.lon_deg,
        truth.alt_m,
    )
    assert np.allclose([north, east, down], errors[k], atol=1e-6)


def test_gps_speed_and_course_noise(truth):
    n = 5000
    spec, _, fixes = gauss_markov_run(truth, n, SEED + 1)
    speed_err = np.array([f.ground_speed_mps for f in fixes]) - truth.ground_speed_mps
    course_err = np.array(
        [math.remainder(f.course_rad - truth.course_rad, 2 * math.pi) for f in fixes]
    )
    lo, hi = chi2_bounds(n, spec.ground_speed_sigma_mps)
    assert lo < speed_err.std(ddof=1) < hi
    lo, hi = chi2_bounds(n, spec.course_sigma_mps / truth.ground_speed_mps)
    assert lo < course_err.std(ddof=1) < hi
    assert all(-math.pi <= f.course_rad <= math.pi for f in fixes)


def test_same_seed_same_readings_other_seed_other_readings(truth):
    def readings(seed):
        imu = ImuModel(ImuSpec(), np.random.default_rng(seed))
        gps = GpsModel(GpsSpec(), np.random.default_rng(seed))
        out = []
        for k in range(300):
            state = dataclasses.replace(truth, time_s=k * 0.01)
            fix = gps.read(state)
            out.append(imu.read(state).as_array())
            if fix is not None:
                out.append(np.array([fix.lat_deg, fix.lon_deg, fix.alt_m, fix.course_rad]))
        return np.concatenate(out)

    assert np.array_equal(readings(7), readings(7))
    assert not np.array_equal(readings(7), readings(8))


def test_sensors_produce_the_project_sample_types(truth):
    from immukf_sitl.samples import GpsSample, ImuSample

    imu = ImuModel(ImuSpec(), np.random.default_rng(SEED)).read(truth)
    fix = GpsModel(GpsSpec(), np.random.default_rng(SEED)).read(truth)
    assert type(imu) is ImuSample and type(fix) is GpsSample
    assert fix.fix_type == 3
    with pytest.raises(ValueError):
        imu.accel_mps2[0] = 1.0  # read-only


def test_a_receiver_that_reports_its_vertical_velocity_draws_it_from_a_stream_of_its_own(truth):
    """vD is truth plus white noise of the sheet's sigma (chi-square bounds), and the rest of
    each fix is drawn exactly as by a receiver that does not report it."""
    spec = GpsSpec(reports_velocity_down=True, velocity_down_sigma_mps=0.15)
    with pytest.raises(ValueError, match="own rng"):
        GpsModel(spec, np.random.default_rng(SEED))
    reporting = GpsModel(
        spec, np.random.default_rng(SEED), velocity_down_rng=np.random.default_rng(SEED + 1)
    )
    silent = GpsModel(GpsSpec(), np.random.default_rng(SEED))
    n = 4000
    errors = []
    for k in range(n):
        state = dataclasses.replace(truth, time_s=float(k))
        fix, plain = reporting.read(state), silent.read(state)
        assert plain.velocity_down_mps is None
        assert dataclasses.replace(fix, velocity_down_mps=None) == plain
        errors.append(fix.velocity_down_mps - truth.velocity_ned_mps[2])
    lo, hi = chi2_bounds(n, 0.15)
    assert lo < np.std(errors, ddof=1) < hi
    assert abs(np.mean(errors)) < 4 * 0.15 / math.sqrt(n)
