"""A scenario file flown by the sim: mapping of its sections, and control doublets on top."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from immukf_sitl.scenario import ManoeuvreSpec, load_scenario
from sim.scenario_flight import flight_from_scenario

# flies JSBSim or the estimator chain
pytestmark = pytest.mark.slow

Y_SCENARIO = Path(__file__).resolve().parents[1] / "scenarios" / "y_accel_zeroed.yaml"


def test_every_section_reaches_the_sim(tmp_path):
    path = tmp_path / "s.yaml"
    path.write_text(
        """\
name: mapped
duration_s: 10
seed: 42
start: {lat_deg: 10.0, lon_deg: 20.0, alt_m: 300, airspeed_mps: 22, heading_deg: 90}
flight_plan:
  loop: false
  acceptance_radius_m: 20
  waypoints:
    - {north_m: 0, east_m: 400, alt_m: 310, airspeed_mps: 23}
sensors:
  imu: {accel_sigma_mps2: 0.05, gyro_sigma_radps: 0.001, gyro_bias_radps: [0.01, 0, 0]}
  gps: {rate_hz: 5, north_east_sigma_m: 1.0}
manoeuvres:
  - {t_s: 2, kind: aileron_doublet, amplitude_rad: 0.1, duration_s: 1}
""",
        encoding="utf-8",
    )
    flight = flight_from_scenario(load_scenario(path))
    ic = flight.driver.initial
    assert (ic.lat_deg, ic.lon_deg, ic.alt_m, ic.airspeed_mps) == (10.0, 20.0, 300.0, 22.0)
    assert ic.heading_rad == pytest.approx(math.pi / 2)
    assert flight.seed == 42
    assert flight.plan.loop is False and flight.plan.acceptance_radius_m == 20.0
    (wp,) = flight.plan.waypoints
    assert (wp.north_m, wp.east_m, wp.alt_m, wp.airspeed_mps) == (0.0, 400.0, 310.0, 23.0)
    assert flight.imu.spec.accel_sigma_mps2 == 0.05
    assert flight.imu.spec.gyro_bias_radps == (0.01, 0.0, 0.0)
    assert flight.gps.spec.rate_hz == 5.0 and flight.gps.spec.north_east_sigma_m == 1.0
    assert flight.manoeuvres[0].kind == "aileron_doublet"
    record = flight.start()
    assert record.truth.euler_rad[2] == pytest.approx(math.pi / 2, abs=1e-9)


def test_a_rudder_doublet_adds_to_the_autopilot_command():
    scenario = load_scenario(Y_SCENARIO)
    (doublet,) = scenario.manoeuvres
    plain = flight_from_scenario(dataclasses.replace(scenario, manoeuvres=()))
    with_doublet = flight_from_scenario(scenario)
    a, b = plain.start(), with_doublet.start()
    first = int(round(doublet.t_s / 0.01))
    steps = int(round((doublet.t_s + doublet.duration_s) / 0.01)) + 5
    rudder_a, rudder_b, times = [], [], []
    for _ in range(steps):
        a, b = plain.step(), with_doublet.step()
        rudder_a.append(a.controls[2])
        rudder_b.append(b.controls[2])
        times.append(b.time_s)
    difference = np.array(rudder_b) - np.array(rudder_a)
    # identical flights until the doublet starts, then exactly +amplitude on its first step
    # (the autopilot has not seen the aircraft respond yet)
    assert np.all(difference[: first - 1] == 0.0)
    assert times[first - 1] == pytest.approx(doublet.t_s)
    assert difference[first - 1] == pytest.approx(doublet.amplitude_rad, abs=1e-9)
    # the second half pushes the other way
    half = first - 1 + int(round(0.5 * doublet.duration_s / 0.01))
    assert difference[half] < 0.0
    assert not np.array_equal(a.truth.state_vector(), b.truth.state_vector())


def test_doublets_are_clipped_to_the_surface_limits():
    scenario = load_scenario(Y_SCENARIO)
    big = ManoeuvreSpec(t_s=1.0, kind="elevator_doublet", amplitude_rad=0.44, duration_s=2.0)
    flight = flight_from_scenario(dataclasses.replace(scenario, manoeuvres=(big,)))
    upper = flight.params.actuators.upper_limits
    lower = flight.params.actuators.lower_limits
    controls = np.array([0.2, 0.0, 0.0, 0.5])
    assert flight.apply_manoeuvres(controls, 1.5)[0] == pytest.approx(upper[0])
    low = flight.apply_manoeuvres(np.array([-0.2, 0.0, 0.0, 0.5]), 2.5)
    assert low[0] == pytest.approx(lower[0])
    assert np.array_equal(flight.apply_manoeuvres(controls, 0.5), controls)  # before it
    assert np.array_equal(flight.apply_manoeuvres(controls, 3.0), controls)  # after it
