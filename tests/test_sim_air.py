"""Real air and a real airframe in the simulator: wind, turbulence, airframe draws, IMU biases.

JSBSim's own atmosphere does the air (no hand-written turbulence); the scenario schema drives
it; the truth in the sim's tlog carries the wind the aircraft felt; the filter is told only the
sensors' spec sheet.
"""

from __future__ import annotations

import argparse
import math
import tempfile
from pathlib import Path

import numpy as np
import pytest
import yaml
from udp_tools import DatagramSink, cli_process

from immukf_sitl.mavlink.flightlog import read_flight_log
from immukf_sitl.models.airframe import (
    AirframeSpec,
    AirframeUncertainty,
    airframe_factors,
    scaled_params,
)
from immukf_sitl.models.params import load_aircraft_params
from immukf_sitl.models.sensors import ImuSpec
from immukf_sitl.models.wind import TURBULENCE_LEVELS, WindSpec, milspec_low_altitude_sigmas
from immukf_sitl.options import FilterOptions
from immukf_sitl.scenario import ScenarioError, load_scenario, parse_scenario, sensors_to_yaml
from sim.driver import InitialConditions, JsbsimDriver
from sim.flight import fly
from sim.flight_plans import default_flight_plan
from sim.scenario_flight import flight_from_scenario
from sim.sensors import ImuModel
from sim.truth import TruthState

# flies JSBSim or the estimator chain
pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[1]
BASE = yaml.safe_load((REPO / "scenarios" / "fault_free.yaml").read_text())


def _scenario(tmp_path: Path, **blocks: object) -> Path:
    data = dict(BASE, **blocks)
    path = tmp_path / "air.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


# -- schema --------------------------------------------------------------------------------


def test_the_schema_reads_airframe_wind_and_bias_keys(tmp_path):
    path = _scenario(
        tmp_path,
        airframe={"scale": {"mass_kg": 1.05, "C_m_alpha": 1.1},
                  "uncertainty": {"aero": 0.1, "mass": 0.05, "inertia": 0.1}},
        wind={"speed_mps": 6, "from_deg": 270, "down_mps": 0, "turbulence": "moderate"},
        sensors={"imu": {"accel_bias_mps2": [0.05, -0.03, 0.08],
                         "gyro_bias_radps": [0.004, -0.002, 0.003], "bias_instability": True,
                         "gyro_bias_sigma_radps": 0.002}},
    )  # fmt: skip
    s = load_scenario(path)
    assert s.airframe.scale == {"mass_kg": 1.05, "C_m_alpha": 1.1}
    assert s.airframe.uncertainty == AirframeUncertainty(0.1, 0.05, 0.1)
    assert s.wind == WindSpec(6.0, 270.0, 0.0, "moderate")
    assert s.sensors.imu.bias_instability and s.sensors.imu.gyro_bias_sigma_radps == 0.002
    assert s.sensors.imu.gyro_bias_radps == (0.004, -0.002, 0.003)


@pytest.mark.parametrize(
    ("blocks", "message"),
    [
        ({"airframe": {"scale": {"C_m_alfa": 1.1}}}, r"airframe\.scale\.C_m_alfa: unknown param"),
        ({"airframe": {"scale": {"mass_kg": -1}}}, r"airframe\.scale\.mass_kg: expected"),
        ({"airframe": {"uncertainty": {"aero": 0.9}}}, r"airframe\.uncertainty\.aero"),
        ({"wind": {"turbulence": "storm"}}, r"wind\.turbulence: expected one of none, light"),
        ({"wind": {"speed_mps": 50}}, r"wind\.speed_mps: expected a number"),
        ({"wind": {"gusts": 1}}, r"wind\.gusts: unknown field"),
        ({"sensors": {"imu": {"bias_instability": "yes"}}}, r"bias_instability: expected true"),
    ],
)
def test_bad_air_fields_are_one_line_errors(tmp_path, blocks, message):
    with pytest.raises(ScenarioError, match=message) as exc:
        load_scenario(_scenario(tmp_path, **blocks))
    assert "\n" not in str(exc.value)


# -- airframe ------------------------------------------------------------------------------


def test_an_airframe_draw_is_reproducible_and_scales_what_it_names():
    book = load_aircraft_params()
    spec = AirframeSpec({"mass_kg": 1.05}, AirframeUncertainty(aero=0.1, inertia=0.1))
    a, b, other = (airframe_factors(book, spec, s) for s in (7, 7, 8))
    assert a == b and a != other
    assert a["mass_kg"] == pytest.approx(1.05)  # mass only scaled: its sigma is 0
    aero = [v for k, v in a.items() if k.startswith("C_")]
    assert len(aero) > 20 and 0.03 < float(np.std(aero)) < 0.2  # about 10 % each
    assert {"Jx_kgm2", "Jy_kgm2", "Jz_kgm2", "Jxz_kgm2"} <= set(a)
    flown = scaled_params(book, a)
    assert flown.mass.mass_kg == pytest.approx(11.0 * 1.05)
    assert flown.aero.C_m_alpha == pytest.approx(book.aero.C_m_alpha * a["C_m_alpha"])
    assert flown.geometry == book.geometry  # nothing else moved
    assert airframe_factors(book, AirframeSpec(), 7) == {}


def test_jsbsim_flies_the_scaled_airframe(tmp_path):
    scenario = load_scenario(_scenario(tmp_path, airframe={"scale": {"mass_kg": 1.2}}))
    flight = flight_from_scenario(scenario, out_dir=tmp_path)
    assert flight.driver.mass_kg == pytest.approx(11.0 * 1.2, rel=1e-6)
    assert (tmp_path / "jsbsim" / "aircraft" / "aerosonde" / "aerosonde.xml").is_file()
    assert flight.airframe_factors == {"mass_kg": pytest.approx(1.2)}


def test_a_scaled_airframe_in_scratch_space_leaves_nothing_behind(tmp_path, monkeypatch):
    """Without ``out_dir`` the aircraft goes to a temporary directory that is gone once JSBSim
    has loaded it (a campaign once left one per run in /tmp), and the flight still flies it."""
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    scenario = load_scenario(_scenario(tmp_path, airframe={"scale": {"mass_kg": 1.2}}))
    flight = flight_from_scenario(scenario)
    assert list(scratch.iterdir()) == []
    assert flight.driver.mass_kg == pytest.approx(11.0 * 1.2, rel=1e-6)
    flight.start()
    flight.step()
    assert flight.driver.mass_kg == pytest.approx(11.0 * 1.2, rel=1e-6)


# -- the air -------------------------------------------------------------------------------


def test_steady_wind_is_read_back_from_the_sims_tlog(tmp_path):
    wind = {"speed_mps": 8.0, "from_deg": 200.0, "down_mps": 0.5, "turbulence": "none"}
    scenario = _scenario(tmp_path, wind=wind)
    tlog = tmp_path / "sim.tlog"
    sink = DatagramSink()
    args = ["sim", str(scenario), "--out", f"udpout:127.0.0.1:{sink.port}", "--free-run",
            "--duration", "5", "--tlog", str(tlog), "--json"]  # fmt: skip
    try:
        with cli_process(args) as sim:
            code, _, err = sim.finish(timeout_s=120)
    finally:
        sink.close()
    assert code == 0, err
    truth = read_flight_log(tlog).truth
    assert len(truth) == 501
    winds = np.array([s.wind_ned_mps for s in truth])  # time 0 included
    to = math.radians(200.0 + 180.0)
    expected = np.array([8.0 * math.cos(to), 8.0 * math.sin(to), 0.5])
    assert np.abs(winds - expected).max() < 0.1


def test_a_start_in_wind_is_the_still_air_trim_moved_with_the_air():
    """A steady wind changes nothing the aircraft feels at time 0 and after (trim controls
    held): same airspeed, specific force and rates as the still-air start. The first IMU
    sample once read a 13 deg sideslip and the first step kicked the roll rate to -14 deg/s:
    the state at time 0 was computed before the wind was set."""
    states = {}
    for name, wind in (("calm", WindSpec()), ("windy", WindSpec(10.0, 270.0, 0.0, "none"))):
        driver = JsbsimDriver(InitialConditions(airspeed_mps=25.0), wind=wind)
        trim = driver.trim()
        first = driver.reset()
        states[name] = [first] + [driver.step(trim.controls) for _ in range(5)]
    # what remains is a hundredth of the glitch (the rotating earth's Coriolis on a ground
    # speed 10 m/s different, the integrator's start): mm/s, cm/s^2
    for calm, windy in zip(states["calm"], states["windy"], strict=True):
        assert windy.airspeed_mps == pytest.approx(calm.airspeed_mps, abs=0.01)
        np.testing.assert_allclose(
            windy.specific_force_body_mps2, calm.specific_force_body_mps2, atol=0.05
        )
        np.testing.assert_allclose(windy.rates_body_radps, calm.rates_body_radps, atol=0.005)
    np.testing.assert_allclose(states["windy"][0].wind_ned_mps, [0.0, 10.0, 0.0], atol=1e-9)


@pytest.mark.parametrize("level", ["light", "moderate"])
def test_turbulence_rms_is_in_the_milspec_band(level):
    steady = WindSpec(6.0, 270.0, 0.0, level)
    records = list(fly(default_flight_plan(), seed=5, duration_s=120.0, wind=steady))
    wind = np.array([r.truth.wind_ned_mps for r in records[100:]])
    gust = wind - steady.steady_ned_mps()
    height = float(np.mean([r.truth.alt_m for r in records]))
    sigma_u, _, sigma_w = milspec_low_altitude_sigmas(TURBULENCE_LEVELS[level].w20_mps, height)
    horizontal = math.sqrt(float(np.mean(np.sum(gust[:, :2] ** 2, axis=1))) / 2.0)
    vertical = float(np.sqrt(np.mean(gust[:, 2] ** 2)))
    print(f"{level}: horizontal {horizontal:.2f} (sigma_u {sigma_u:.2f}), vertical "
          f"{vertical:.2f} (sigma_w {sigma_w:.2f}) m/s")  # fmt: skip
    # 120 s at 25 m/s spans about 20 correlation lengths: the sample RMS is within ~35 %
    assert 0.6 * sigma_u < horizontal < 1.5 * sigma_u
    assert 0.6 * sigma_w < vertical < 1.5 * sigma_w
    # the turbulence also reaches the rates JSBSim damps with (p, q, r-turb)
    assert np.std([r.truth.rates_body_radps[0] for r in records]) > 0.01


def test_the_autopilot_keeps_flying_the_plan_in_moderate_turbulence_and_10_mps_wind():
    plan = default_flight_plan()
    records = list(fly(plan, seed=3, duration_s=120.0, wind=WindSpec(10.0, 270.0, 0.0, "moderate")))
    flown = [r for r in records if r.autopilot is not None and r.time_s > 5.0]
    alt_err = np.array([r.truth.alt_m - r.autopilot.altitude_ref_m for r in flown])
    va_err = np.array([r.truth.airspeed_mps - r.autopilot.airspeed_cmd_mps for r in flown])
    assert np.abs(alt_err).max() < 10.0
    assert np.abs(va_err).max() < 4.0
    # every leg flown to its end was captured: |cross-track| < 15 m before the switch (a turn
    # at 35 m/s over the ground overshoots by the turn radius first, as physics wants)
    legs: dict[int, list[float]] = {}
    for r in flown:
        legs.setdefault(r.autopilot.waypoint_index, []).append(abs(r.autopilot.cross_track_m))
    completed = list(legs)[:-1]
    assert len(completed) >= 4
    for index in completed:
        assert min(legs[index][-500:]) < 15.0, index
    position = np.array([r.truth.position_ned_m[:2] for r in flown])
    for wp in plan.waypoints[: len(completed)]:
        assert np.hypot(position[:, 0] - wp.north_m, position[:, 1] - wp.east_m).min() < 30.0


# -- sensors -------------------------------------------------------------------------------


def _truth_at_rest() -> TruthState:
    zeros = np.zeros(3)
    return TruthState(0.0, 47.0, 8.0, 150.0, zeros, zeros, zeros, zeros, zeros, 25.0, 0.0,
                      0.0, np.array([0.0, 0.0, -9.8]), np.zeros(4))  # fmt: skip


def test_turn_on_bias_is_drawn_from_the_spec_sheet_and_the_wander_is_gauss_markov():
    spec = ImuSpec(accel_sigma_mps2=0.0, gyro_sigma_radps=0.0, gyro_bias_sigma_radps=0.01)
    biases = np.array(
        [
            ImuModel(spec, np.random.default_rng(0), np.random.default_rng(s)).bias
            for s in range(400)
        ]
    )
    assert np.std(biases[:, 3:]) == pytest.approx(0.01, rel=0.1)
    assert np.all(biases[:, :3] == 0.0)
    wander = ImuSpec(accel_sigma_mps2=0.0, gyro_sigma_radps=0.0, bias_instability=True,
                     gyro_bias_instability_radps=1e-3, bias_time_constant_s=2.0)  # fmt: skip
    model = ImuModel(wander, np.random.default_rng(0), np.random.default_rng(1))
    truth = _truth_at_rest()
    series = np.array([model.read(truth).gyro_radps[0] for _ in range(20_000)])
    assert np.std(series) == pytest.approx(1e-3, rel=0.25)  # stationary sigma
    lag = int(2.0 / 0.01)
    corr = np.corrcoef(series[:-lag], series[lag:])[0, 1]
    assert corr == pytest.approx(math.exp(-1.0), abs=0.12)  # e^-1 at one time constant


def test_the_sensors_file_reaches_the_filters_R(tmp_path):
    imu = {"gyro_sigma_radps": 0.01, "gyro_bias_radps": [0.1, 0, 0]}
    noisy = parse_scenario(dict(BASE, sensors={"imu": imu}))
    path = tmp_path / "sensors.yaml"
    path.write_text(sensors_to_yaml(noisy.sensors))
    ns = argparse.ArgumentParser()
    FilterOptions.add_arguments(ns)
    default = FilterOptions.from_args(ns.parse_args([]))
    told = FilterOptions.from_args(ns.parse_args(["--sensors", str(path)]))
    assert told.sensors.imu.gyro_bias_radps == (0.0, 0.0, 0.0)  # never the true bias

    def imu_r(options: FilterOptions) -> np.ndarray:
        pipeline = options.pipeline()
        from immukf_sitl.models.earth import NedOrigin
        from immukf_sitl.service.filters import build_estimator

        cfg = pipeline.config
        estimator = build_estimator(cfg.variant, pipeline.params, NedOrigin(47.0, 8.0, 150.0),
                                    sensors=cfg.sensors)  # fmt: skip
        return estimator.imu_model.noise_cov

    assert np.diag(imu_r(default))[3] == pytest.approx(0.00227**2)
    assert np.diag(imu_r(told))[3] == pytest.approx(0.01**2)
    assert np.diag(imu_r(told))[0] == pytest.approx(0.0245**2)


def test_every_drawn_airframe_is_a_body_that_can_exist():
    book = load_aircraft_params()
    spec = AirframeSpec({}, AirframeUncertainty(aero=0.1, mass=0.05, inertia=0.1))
    jz = []
    for seed in range(300):
        factors = airframe_factors(book, spec, seed)
        flown = scaled_params(book, factors)  # raises on a non-physical inertia
        jz.append(flown.mass.Jz_kgm2 / book.mass.Jz_kgm2)
    assert 0.05 < float(np.std(jz)) < 0.12  # about the 10 % asked for
