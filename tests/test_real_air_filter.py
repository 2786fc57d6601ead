"""The filter model of a real aircraft, its noise, the gate, the latch, the alignment."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from immukf_sitl.estimation import FaultMode, ObservabilityGate, kernels, single_fault_modes
from immukf_sitl.estimation.ukf import _process_column_source
from immukf_sitl.models import aero_kernels
from immukf_sitl.models.aero import AeroModel
from immukf_sitl.models.airframe import AirframeUncertainty
from immukf_sitl.models.augmented import (
    FORCE,
    GPS_ERROR,
    GUST,
    GYRO_BIAS,
    MOMENT,
    N_AUGMENTED,
    N_RIGID,
    N_SLOW,
    WIND,
    AugmentedAeroModel,
    model_error_sigmas,
)
from immukf_sitl.models.earth import body_to_ned
from immukf_sitl.models.params import load_aircraft_params
from immukf_sitl.models.sensors import GpsSpec, ImuSpec, SensorSpec
from immukf_sitl.service.alignment import align, dead_accelerometer
from immukf_sitl.service.detection import DetectorConfig, FaultDetector
from immukf_sitl.service.filter_models import PaperModel, RealAirModel
from immukf_sitl.service.noise_model import milspec_scale_lengths_m, slow_state_noise

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def params():
    return load_aircraft_params()


@pytest.fixture(scope="module")
def trimmed(params):
    aero = AeroModel(params)
    x0, u0 = aero.trim(25.0)
    return aero, x0, u0


def _augmented(aero: AeroModel, decay: np.ndarray | None = None) -> AugmentedAeroModel:
    return AugmentedAeroModel(aero, np.zeros(N_SLOW) if decay is None else decay)


def test_zero_slow_states_fly_the_book_model(trimmed) -> None:
    aero, x0, u0 = trimmed
    model = _augmented(aero)
    x = np.concatenate([x0, np.zeros(N_SLOW)])
    x[9:12] = [0.05, -0.02, 0.03]
    np.testing.assert_array_equal(model.step(0.0, x, u0)[:N_RIGID], aero.step(0.0, x[:N_RIGID], u0))
    np.testing.assert_array_equal(model.imu(0.0, x, u0), aero.imu(0.0, x[:N_RIGID], u0))


def test_wind_acts_through_the_air_relative_velocity(trimmed) -> None:
    """In wind w, the forces are those of still air at v_a = v_g - R_bn w (B&M eq. 2.5)."""
    aero, x0, u0 = trimmed
    x0 = x0.copy()
    x0[6:9] = [0.2, 0.05, 1.0]  # banked, heading east-north-east
    wind = np.array([3.0, -4.0, 0.5])
    x = np.concatenate([x0, np.zeros(N_SLOW)])
    x[N_RIGID + WIND.start : N_RIGID + WIND.stop] = wind
    x[3:6] = x0[3:6] + body_to_ned(x0[6:9]).T @ wind  # ground velocity in body axes
    still = x0.copy()  # the same aircraft, air-relative velocity x0's, still air
    np.testing.assert_allclose(
        _augmented(aero).imu(0.0, x, u0), aero.imu(0.0, still, u0), rtol=1e-12, atol=1e-12
    )
    # the forces agree; the rigid body moves with the ground velocity
    moved = _augmented(aero).step(0.0, x, u0)
    np.testing.assert_allclose(moved[0:3] - x[0:3], 0.01 * body_to_ned(x0[6:9]) @ x[3:6], atol=2e-3)


def test_gyro_bias_and_gps_error_add_to_the_readings(trimmed) -> None:
    aero, x0, u0 = trimmed
    model = _augmented(aero)
    x = np.concatenate([x0, np.zeros(N_SLOW)])
    plain_imu, plain_gps = model.imu(0.0, x, u0), model.gps(0.0, x, u0)
    x[N_RIGID + GYRO_BIAS.start : N_RIGID + GYRO_BIAS.stop] = [0.01, -0.02, 0.03]
    x[N_RIGID + GPS_ERROR.start : N_RIGID + GPS_ERROR.stop] = [4.0, -3.0, 7.0]
    np.testing.assert_allclose(model.imu(0.0, x, u0) - plain_imu, [0, 0, 0, 0.01, -0.02, 0.03])
    np.testing.assert_allclose(
        model.gps(0.0, x, u0) - plain_gps, [4.0, -3.0, 7.0, 0, 0], atol=1e-12
    )


def test_slow_states_decay_exactly(trimmed) -> None:
    aero, x0, u0 = trimmed
    decay = np.linspace(0.0, 2.0, N_SLOW)
    model = _augmented(aero, decay)
    x = np.concatenate([x0, np.ones(N_SLOW)])
    x[N_RIGID + WIND.start : N_RIGID + WIND.stop] = 0.0  # keep the air still for this one
    out = model.step(0.0, x, u0)
    expected = x[N_RIGID:] * np.exp(-decay * aero.dt_s)
    np.testing.assert_allclose(out[N_RIGID:], expected, rtol=1e-15)


def test_gps_error_state_is_the_receivers_gauss_markov_model(params) -> None:
    """Stationary sigma sigma/sqrt(1 - exp(-2 k T)) (4.9 m), and the step noise keeps it."""
    gps = GpsSpec()
    noise = slow_state_noise(params, SensorSpec(), RealAirModel())
    stationary = gps.north_east_sigma_m / math.sqrt(1.0 - math.exp(-2.0 * gps.k_gps_per_s))
    assert noise.initial_sigma[GPS_ERROR][0] == pytest.approx(stationary)
    assert 4.8 < stationary < 5.0
    # the discretised process x+ = a x + w keeps its variance: a^2 s^2 + q = s^2
    a = math.exp(-gps.k_gps_per_s * 0.01)
    q = noise.step_variance(0.01)[GPS_ERROR][0]
    assert a * a * stationary**2 + q == pytest.approx(stationary**2, rel=1e-12)


def test_wind_noise_is_the_dryden_driving_noise(params) -> None:
    tuning = RealAirModel(design_turbulence="moderate", design_height_m=150.0)
    noise = slow_state_noise(params, SensorSpec(), tuning)
    length = milspec_scale_lengths_m(150.0)
    h_ft = 150.0 / 0.3048
    assert length[2] == pytest.approx(150.0)  # L_w = h
    assert length[0] == pytest.approx(h_ft / (0.177 + 0.000823 * h_ft) ** 1.2 * 0.3048)
    sigma_w = 0.1 * 30.0 * 0.514444  # MIL-F-8785C: sigma_w = 0.1 W20
    sigma_u = sigma_w / (0.177 + 0.000823 * h_ft) ** 0.4
    # MIL-HDBK-1797's first-order forms (Yeager eqs. 30-31): u at L_u / V, v at L_v / 2V
    psd_u = 2.0 * sigma_u**2 * 25.0 / length[0]
    psd_v = 2.0 * sigma_u**2 * 25.0 / (length[1] / 2.0)
    # horizontal: a random walk (any steady wind is learnt), each axis the mean of the two PSDs
    assert noise.stationary_sigma[WIND][0] ** 2 == pytest.approx(0.5 * (psd_u + psd_v))
    assert noise.stationary_sigma[WIND][1] == noise.stationary_sigma[WIND][0]
    assert noise.decay_per_s[WIND].tolist()[:2] == [0.0, 0.0]
    # vertical: the gust itself, zero mean over level ground (sigma_w, rate V / L_w)
    assert noise.stationary_sigma[WIND][2] == pytest.approx(sigma_w)
    assert noise.decay_per_s[WIND][2] == pytest.approx(25.0 / length[2])
    assert noise.initial_sigma[WIND][2] == pytest.approx(sigma_w)
    a = math.exp(-noise.decay_per_s[WIND][2] * 0.01)
    q = noise.step_variance(0.01)[WIND][2]
    assert a * a * sigma_w**2 + q == pytest.approx(sigma_w**2, rel=1e-12)


def test_no_bias_on_the_spec_sheet_means_inert_bias_states(params) -> None:
    noise = slow_state_noise(params, SensorSpec(), RealAirModel())
    assert np.all(noise.initial_sigma[GYRO_BIAS] == 0.0)
    assert np.all(noise.step_variance(0.01)[GYRO_BIAS] == 0.0)
    biased = SensorSpec(ImuSpec(gyro_bias_sigma_radps=0.0017, bias_instability=True))
    noise = slow_state_noise(params, biased, RealAirModel())
    assert noise.initial_sigma[GYRO_BIAS][0] == pytest.approx(math.hypot(0.0017, 5e-5))
    # a random walk: the turn-on bias does not decay; the wander's driving PSD 2 sigma^2 / tau
    assert noise.decay_per_s[GYRO_BIAS][0] == 0.0
    assert noise.step_variance(0.01)[GYRO_BIAS][0] == pytest.approx(2.0 * 5e-5**2 / 300.0 * 0.01)


def test_a_vertical_gusts_model_error_is_the_lift_slope_and_pitch_stiffness_error(params) -> None:
    """10 % of C_L_alpha and C_m_alpha over 0.06 rad of gust: ``0.1 C dalpha qbar S / m`` and
    ``0.1 |C_m_alpha| dalpha qbar S c / J_y`` (ISA sea level, the linear lift model)."""
    error = model_error_sigmas(
        params, AirframeUncertainty(0.1, 0.0, 0.0), 25.0, gust_attack_rad=0.06
    )
    qbar = 0.5 * 1.225 * 25.0**2
    geometry, aero, mass = params.geometry, params.aero, params.mass
    lift = 0.1 * aero.C_L_alpha * 0.06 * qbar * geometry.S_m2 / mass.mass_kg
    pitch = 0.1 * abs(aero.C_m_alpha) * 0.06 * qbar * geometry.S_m2 * geometry.c_m / mass.Jy_kgm2
    assert error.force_gust_mps2[2] == pytest.approx(lift, rel=0.03)  # drag and density: ~1 %
    assert error.moment_gust_radps2[1] == pytest.approx(pitch, rel=0.01)
    assert error.force_gust_mps2[2] > 30.0 * error.force_variation_mps2[2]  # calm: 0.01 m/s^2
    still = model_error_sigmas(params, AirframeUncertainty(0.1, 0.0, 0.0), 25.0)
    assert np.all(still.force_gust_mps2 == 0.0) and np.all(still.moment_gust_radps2 == 0.0)


def test_the_gust_part_of_the_corrections_is_the_turbulences(params) -> None:
    """The wind and gust states are all turbulence, the corrections partly; still design air:
    none of it."""
    noise = slow_state_noise(params, SensorSpec(), RealAirModel())
    share = noise.turbulence_share
    assert np.all(share[WIND] == 1.0) and np.all(share[GUST] == 1.0)
    assert 0.9 < share[FORCE][2] < 1.0 and 0.9 < share[MOMENT][1] < 1.0
    assert np.all(share[GYRO_BIAS] == 0.0) and np.all(share[GPS_ERROR] == 0.0)
    still = slow_state_noise(params, SensorSpec(), RealAirModel(design_turbulence="none"))
    assert np.all(still.turbulence_share[FORCE] == 0.0)


def test_model_error_grows_with_the_airframe_uncertainty(params) -> None:
    small = model_error_sigmas(params, AirframeUncertainty(0.05, 0.025, 0.05), 25.0)
    large = model_error_sigmas(params, AirframeUncertainty(0.10, 0.05, 0.10), 25.0)
    # one-at-a-time changes of an affine-in-parameter model: twice the sigma, twice the error
    np.testing.assert_allclose(large.force_mps2[2], 2.0 * small.force_mps2[2], rtol=0.02)
    assert np.all(large.force_variation_mps2 <= large.force_mps2 * 2.0 + 1e-12)
    exact = model_error_sigmas(params, AirframeUncertainty(), 25.0)
    assert np.all(exact.force_mps2 == 0.0) and np.all(exact.moment_radps2 == 0.0)


# --- the observability gate ---------------------------------------------------------------


def _gate_inputs(own_q: float, z_q: float, nu_q: float, s_q: float):
    modes = single_fault_modes()
    r = len(modes)
    noise_var = np.full(6, 0.00227**2)
    predicted = np.zeros((r, N_AUGMENTED))
    predicted[:, 10] = own_q

    def prediction(t_s, x, u):
        return np.vstack([np.zeros((4, x.shape[1])), x[10][None], np.zeros((1, x.shape[1]))])

    innovation = np.zeros((r, 6))
    innovation[0, 4] = nu_q
    cov = np.repeat(np.diag(noise_var)[None], r, axis=0)
    cov[0, 4, 4] = s_q
    z = np.zeros(6)
    z[4] = z_q
    gate = ObservabilityGate(modes, prediction, noise_var, 3.0)
    return gate, predicted, innovation, cov, z


def test_gate_silences_an_unobservable_channel() -> None:
    r_q = 0.00227**2
    gate, predicted, innovation, cov, z = _gate_inputs(0.0, 0.001, 0.0008, 1.2 * r_q)
    scored = gate(0.0, predicted, innovation, cov, z, np.zeros((2, 4)), np.zeros(7))
    q = FaultMode.from_name("q")
    j = single_fault_modes().index(q)
    zero_fit = -0.5 * (0.001**2 / r_q + math.log(2 * math.pi * r_q))
    healthy_fit = -0.5 * (0.0008**2 / (1.2 * r_q) + math.log(2 * math.pi * 1.2 * r_q))
    assert scored[j] == pytest.approx(healthy_fit - zero_fit)
    assert np.all(np.delete(scored, j) == 0.0)  # other modes' channels are observable? no: p, r
    # predicted at 0 too, but their channels' healthy innovation is 0 and z is 0: the same fit


def test_gate_leaves_an_observable_channel_alone() -> None:
    r_q = 0.00227**2
    gate, predicted, innovation, cov, z = _gate_inputs(0.05, 0.001, -0.049, 1.2 * r_q)
    scored = gate(0.0, predicted, innovation, cov, z, np.zeros((2, 4)), np.zeros(7))
    j = single_fault_modes().index(FaultMode.from_name("q"))
    assert scored[j] == 0.0


# --- declaration latch: a dead sensor stays declared, a recovered one clears ----------------


def _declared_q(cfg: DetectorConfig) -> tuple[FaultDetector, list]:
    modes = single_fault_modes()
    det = FaultDetector(modes, cfg, 0.0)
    q = modes.index(FaultMode.from_name("q"))
    probs = np.zeros(len(modes))
    probs[q] = 1.0
    events = []
    for k in range(50):
        events += det.update(k * 0.01, probs, np.zeros(6), ImuSpec().sigmas)
    assert det.declared == FaultMode.from_name("q")
    return det, events


def test_dead_sensor_is_not_cleared_through_a_straight_leg() -> None:
    """Probabilities back at fault-free for 10 s, q still reading zero plus noise: declared."""
    cfg = DetectorConfig(dwell_s=0.1, settle_s=0.0)
    det, _ = _declared_q(cfg)
    rng = np.random.default_rng(9)
    sigmas = ImuSpec().sigmas
    healthy = np.zeros(7)
    healthy[0] = 1.0
    for k in range(1000):
        imu = np.array([0.0, 0.0, -9.8, 0.0, 0.0, 0.0]) + sigmas * rng.standard_normal(6)
        assert det.update(0.5 + k * 0.01, healthy, imu, sigmas) == []
    assert det.declared == FaultMode.from_name("q")


def test_recovered_sensor_is_cleared_once_it_reads_beyond_its_noise() -> None:
    cfg = DetectorConfig(dwell_s=0.1, settle_s=0.0, clear_dwell_s=1.0)
    det, _ = _declared_q(cfg)
    sigmas = ImuSpec().sigmas
    healthy = np.zeros(7)
    healthy[0] = 1.0
    events = []
    for k in range(300):
        imu = np.array([0.0, 0.0, -9.8, 0.0, 0.05, 0.0])  # pulling up: q alive
        events += det.update(0.5 + k * 0.01, healthy, imu, sigmas)
    assert [e.kind for e in events] == ["cleared"]
    assert events[0].t_s == pytest.approx(1.5, abs=0.02)
    assert det.declared is None


# --- alignment with a dead sensor --------------------------------------------------------


def _specific_force(euler: np.ndarray) -> np.ndarray:
    return -body_to_ned(euler).T @ np.array([0.0, 0.0, 9.80665])


@pytest.mark.parametrize("failed", [(), ("z",)])
def test_alignment_with_a_zeroed_z_accelerometer_is_within_5_deg(failed) -> None:
    """Start-up (nothing declared) and re-alignment (z declared) on a dead z accelerometer."""
    rng = np.random.default_rng(4)
    for roll, pitch in [(0.0, 0.05), (0.35, 0.08), (-0.5, 0.02), (0.2, -0.05)]:
        euler = np.array([roll, pitch, 0.3])
        imu = np.concatenate([_specific_force(euler), [0.01, 0.02, 0.03]])
        imu[2] = 0.0
        imu[:3] += 0.0245 * rng.standard_normal(3)
        gps = np.array([0.0, 0.0, 0.0, 25.0, 0.3])
        nav = align(0.0, imu, gps, failed)
        assert np.degrees(np.abs(nav.euler_rad[:2] - euler[:2])).max() < 5.0, (roll, pitch)


def test_alignment_of_a_healthy_imu_is_unchanged() -> None:
    euler = np.array([0.4, 0.1, 0.0])
    imu = np.concatenate([_specific_force(euler), [0.0, 0.0, 0.0]])
    assert dead_accelerometer(imu[:3]) is None
    nav = align(0.0, imu, np.array([0.0, 0.0, 0.0, 25.0, 0.0]))
    np.testing.assert_allclose(nav.euler_rad[:2], euler[:2], atol=1e-12)


def test_body_to_ned_is_scipys_zyx_rotation() -> None:
    """The written-out R_nb against scipy's Rotation (an independent implementation)."""
    from scipy.spatial.transform import Rotation

    from immukf_sitl.models.earth import body_to_ned

    rng = np.random.default_rng(4)
    for _ in range(200):
        euler = rng.uniform([-np.pi, -1.5, -np.pi], [np.pi, 1.5, np.pi])
        expected = Rotation.from_euler("ZYX", euler[::-1]).as_matrix()
        np.testing.assert_allclose(body_to_ned(euler), expected, atol=1e-15)


@pytest.mark.slow
def test_perturbed_airframe_in_wind_flies_without_a_declaration() -> None:
    """The real-air filter on a drawn airframe, 6 m/s wind, light turbulence and a biased MEMS
    IMU (scenarios/fault_free_windy.yaml, 25 s): no fault declared, attitude held, and the
    position covariance not overconfident against the receiver's wandering error (NEES of
    every step within the 99.9 % chi-square bound of 3 d.o.f., 16.3; the paper's white 0.21 m
    GPS noise made it 20 times too confident)."""
    from immukf_sitl.experiments.inprocess import run_inprocess
    from immukf_sitl.models.earth import NedOrigin, geodetic_to_ned
    from immukf_sitl.scenario import load_scenario
    from immukf_sitl.service.pipeline import PipelineConfig

    scenario = load_scenario(REPO / "scenarios" / "fault_free_windy.yaml")
    config = PipelineConfig(
        variant="imm", sensors=scenario.sensors.spec_sheet(), filter_model=RealAirModel()
    )
    run = run_inprocess(scenario, config, duration_s=25.0)
    assert run.history.events() == []
    summary = run.summary().to_json()
    assert summary["est_error"]["att_max_deg"] < 15.0
    o = run.pipeline.origin
    origin = NedOrigin(o.lat_deg, o.lon_deg, o.alt_m)
    truth = {round(t.t_s, 3): t for t in run.truth}
    nees = []
    for out in run.history.outputs:
        t = truth[round(out.t_s, 3)]
        error = out.nav.position_ned_m - np.array(
            geodetic_to_ned(t.lat_deg, t.lon_deg, t.alt_m, origin)
        )
        nees.append(float(np.sum((error / out.nav.position_sigma_m) ** 2)))
    assert len(nees) > 2000
    assert max(nees) < 16.3


def test_the_dynamics_do_not_read_the_gps_errors(trimmed) -> None:
    """What lets a sigma point that moves only the gyro biases and GPS errors fly as its centre:
    the rigid body's derivative and RK4 step ignore ``e`` from ``N_DYNAMIC_EXTRA`` on, the IMU
    from ``N_OUTPUT_EXTRA`` on (bit for bit)."""
    aero, x0, u0 = trimmed
    rng = np.random.default_rng(21)
    n = 9
    x = np.ascontiguousarray(x0[:, None] + 0.1 * rng.standard_normal((12, n)))
    u = np.ascontiguousarray(np.repeat(u0[:, None], n, axis=1))
    v = rng.standard_normal((6, n))
    e = 0.1 * rng.standard_normal((aero_kernels.N_EXTRA, n))
    moved_e = e.copy()
    moved_e[aero_kernels.N_DYNAMIC_EXTRA :] = 50.0 * rng.standard_normal((6, n))
    gps_moved_e = e.copy()
    gps_moved_e[aero_kernels.N_OUTPUT_EXTRA :] = 50.0 * rng.standard_normal((3, n))
    k = aero._k
    steps, rates, imus = [], [], []
    for extra in (e, moved_e, gps_moved_e):
        out, xd, z = np.empty((12, n)), np.empty((12, n)), np.empty((6, n))
        aero_kernels.step_batch(x, u, v, extra, k, aero.dt_s, 1, out)
        aero_kernels.derivatives_batch(x, u, v, extra, k, xd)
        aero_kernels.imu_batch(x, u, extra, k, 1, z)
        steps.append(out)
        rates.append(xd)
        imus.append(z)
    np.testing.assert_array_equal(steps[0], steps[1])
    np.testing.assert_array_equal(rates[0], rates[1])
    np.testing.assert_array_equal(imus[0], imus[2])
    assert np.max(np.abs(imus[0][3:] - imus[1][3:])) > 1.0  # the gyros read their biases


def test_sigma_points_moving_only_the_gps_errors_fly_as_their_centre(trimmed) -> None:
    """The real-air filter's RK4 batch: the 2 x 6 points of each mode that move only the gyro
    biases and GPS errors reuse the centre's integration, and the step equals integrating every
    column."""
    aero, x0, u0 = trimmed
    model = _augmented(aero, np.full(N_SLOW, 0.01))
    rng = np.random.default_rng(22)
    modes, nv = 7, 6
    a = rng.standard_normal((modes, N_AUGMENTED, N_AUGMENTED))
    cov = 1e-3 * (a @ a.transpose(0, 2, 1)) + 1e-4 * np.eye(N_AUGMENTED)
    mean = np.concatenate([x0, 0.1 * rng.standard_normal(N_SLOW)]) + 0.01 * rng.standard_normal(
        (modes, N_AUGMENTED)
    )
    n_distinct = 1 + 2 * (N_AUGMENTED + nv)
    x = np.empty((N_AUGMENTED, modes, n_distinct))
    v = np.empty((nv, modes, n_distinct))
    kernels.augmented_process_points(
        mean, np.linalg.cholesky(cov), 0.3 * np.eye(nv), 6.0, x, v
    )  # eqs. (9)-(11)
    flat = [np.ascontiguousarray(a.reshape(a.shape[0], -1)) for a in (x[:N_RIGID], v)]
    e = np.ascontiguousarray(x[N_RIGID:].reshape(N_SLOW, -1))
    u = np.ascontiguousarray(np.repeat(u0[:, None], modes * n_distinct, axis=1))
    grouped, every = np.empty((12, modes * n_distinct)), np.empty((12, modes * n_distinct))
    args = (flat[0], u, flat[1], e, aero._k, aero.dt_s)
    assert aero_kernels.step_batch(*args, n_distinct, grouped) == modes * 2 * 6
    assert aero_kernels.step_batch(*args, 1, every) == 0
    np.testing.assert_array_equal(grouped, every)
    # and the model's step, which passes the sigma axis as the period, is that result
    np.testing.assert_array_equal(model.step(0.0, x, u0, v)[:N_RIGID].reshape(12, -1), every)
    # the output model: of the full set of points (eq. 15), those that repeat the centre's x
    # (here the 2 nw measurement-noise and the 2 nv process-noise points: these points are not
    # propagated) or move only the GPS errors take the centre's reading
    nw = 6
    source = _process_column_source(N_AUGMENTED + nv, N_AUGMENTED + nv + nw)
    full = np.ascontiguousarray(x[:, :, source])
    n_sigma = source.size
    z_grouped, z_every = np.empty((6, modes * n_sigma)), np.empty((6, modes * n_sigma))
    rigid = np.ascontiguousarray(full[:N_RIGID].reshape(12, -1))
    slow = np.ascontiguousarray(full[N_RIGID:].reshape(N_SLOW, -1))
    u_full = np.ascontiguousarray(np.repeat(u0[:, None], modes * n_sigma, axis=1))
    imu_args = (rigid, u_full, slow, aero._k)
    assert aero_kernels.imu_batch(*imu_args, n_sigma, z_grouped) == modes * 2 * (nw + nv + 3)
    assert aero_kernels.imu_batch(*imu_args, 1, z_every) == 0
    np.testing.assert_array_equal(z_grouped, z_every)
    np.testing.assert_array_equal(model.imu(0.0, full, u0).reshape(6, -1), z_every)


def test_a_zero_of_the_other_sign_is_a_different_input(trimmed) -> None:
    """Reuse needs bitwise-equal inputs: -0.0 and +0.0 compare equal but may not fly alike."""
    aero, x0, u0 = trimmed
    x = np.ascontiguousarray(np.repeat(x0[:, None], 2, axis=1))
    x[4] = 0.0
    x[4, 1] = -0.0
    u = np.ascontiguousarray(np.repeat(u0[:, None], 2, axis=1))
    out = np.empty((12, 2))
    args = (x, u, np.zeros((6, 2)), np.zeros((15, 2)), aero._k, aero.dt_s)
    z = np.empty((6, 2))
    assert aero_kernels.step_batch(*args, 2, out) == 0
    assert aero_kernels.imu_batch(x, u, args[3], aero._k, 2, z) == 0
    x[4, 1] = 0.0
    assert aero_kernels.step_batch(*args, 2, out) == 1
    assert aero_kernels.imu_batch(x, u, args[3], aero._k, 2, z) == 1


def test_start_up_probabilities_believe_the_imu_healthy(params) -> None:
    """The paper's chain starts at its stationary distribution, ``onset / recovery`` per fault
    mode against fault-free (its balance equations); the real-air chain is symmetric, whose
    stationary distribution (1/7 each) would believe a sensor dead at power-on 6 times in 7, so
    every fault mode starts at the onset probability instead."""
    from immukf_sitl.service.filters import build_aero_estimator

    aero = AeroModel(params)
    x0, u0 = aero.trim(25.0)
    paper = build_aero_estimator("imm", aero, filter_model=PaperModel())
    probs = paper.start(0.0, x0, np.eye(12) * 1e-4, u0).mode_probabilities
    np.testing.assert_allclose(probs[1:] / probs[0], 1e-4 / 0.25, rtol=1e-9)
    real = build_aero_estimator("imm", aero, filter_model=RealAirModel())
    mean, cov = real.augmented(x0, np.eye(12) * 1e-4)
    probs = real.start(0.0, mean, cov, u0).mode_probabilities
    np.testing.assert_allclose(probs[1:] / probs[0], 1e-7, rtol=1e-12)
    with pytest.raises(ValueError, match="initial_fault_probability"):
        RealAirModel(initial_fault_probability=0.5)
