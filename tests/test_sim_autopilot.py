"""Autopilot building blocks: PID anti-windup, navigation interface, plan and waypoint logic."""

from __future__ import annotations

import math

import numpy as np
import pytest

from immukf_sitl.models.params import load_aircraft_params
from immukf_sitl.scenario import FlightPlan, Waypoint
from sim.autopilot import (
    Autopilot,
    NavigationState,
    PidController,
    wrap_angle_rad,
)
from sim.driver import JsbsimDriver


def test_pid_output_is_limited_and_integrator_does_not_wind_up():
    pid = PidController(kp=1.0, ki=1.0, kd=0.0, lower=-1.0, upper=1.0)
    for _ in range(1000):  # large error for 10 s: saturated
        out = pid.update(5.0, 0.01)
    assert out == 1.0
    assert pid.integral < 1.0  # conditional integration stopped it
    # the error reverses: the output leaves saturation at once
    assert pid.update(-0.5, 0.01) < 0.5
    pid.reset()
    assert pid.integral == 0.0


def test_pid_derivative_acts_on_the_measured_rate():
    pid = PidController(kp=0.0, ki=0.0, kd=2.0, lower=-10.0, upper=10.0)
    assert pid.update(0.0, 0.01, rate=1.5) == pytest.approx(-3.0)


def test_wrap_angle():
    assert wrap_angle_rad(3 * math.pi / 2) == pytest.approx(-math.pi / 2)
    assert wrap_angle_rad(-3 * math.pi / 2) == pytest.approx(math.pi / 2)


@pytest.mark.slow
def test_navigation_from_a_state_vector_matches_the_truth():
    driver = JsbsimDriver()
    trim = driver.trim()
    driver.reset()
    for _ in range(300):
        truth = driver.step(trim.controls + np.array([0.0, 0.05, 0.02, 0.0]))
    from_truth = NavigationState.from_truth(truth)
    from_state = NavigationState.from_state_vector(
        truth.time_s, truth.state_vector(), origin_alt_m=driver.origin[2]
    )
    assert np.allclose(from_state.velocity_ned_mps, from_truth.velocity_ned_mps, atol=1e-6)
    assert from_state.alt_m == pytest.approx(from_truth.alt_m, abs=0.05)
    assert from_state.airspeed_mps == pytest.approx(from_truth.airspeed_mps, abs=1e-9)
    assert from_state.beta_rad == pytest.approx(from_truth.beta_rad, abs=1e-9)
    with pytest.raises(ValueError, match="shape"):
        NavigationState.from_state_vector(0.0, np.zeros(9), 0.0)


def test_plan_validation():
    with pytest.raises(ValueError, match="at least one"):
        FlightPlan(waypoints=())
    with pytest.raises(ValueError, match="acceptance_radius_m"):
        FlightPlan(waypoints=(Waypoint(0.0, 0.0, 100.0),), acceptance_radius_m=0.0)
    with pytest.raises(ValueError, match="airspeed_mps"):
        Waypoint(0.0, 0.0, 100.0, airspeed_mps=80.0)
    with pytest.raises(ValueError, match="finite"):
        Waypoint(math.nan, 0.0, 100.0)


def nav_at(north: float, east: float, course: float = 0.0, alt: float = 100.0) -> NavigationState:
    velocity = 25.0 * np.array([math.cos(course), math.sin(course), 0.0])
    return NavigationState(
        time_s=0.0,
        position_ned_m=np.array([north, east, -alt]),
        alt_m=alt,
        velocity_ned_mps=velocity,
        euler_rad=np.array([0.0, 0.05, course]),
        rates_body_radps=np.zeros(3),
        airspeed_mps=25.0,
        beta_rad=0.0,
    )


def make_autopilot(plan: FlightPlan) -> Autopilot:
    params = load_aircraft_params()
    driver = JsbsimDriver(params=params)
    trim = driver.trim()
    act = params.actuators
    return Autopilot(plan, trim, 0.01, act.lower_limits, act.upper_limits)


def test_waypoints_switch_within_radius_or_past_the_perpendicular_and_loop():
    plan = FlightPlan(
        waypoints=(Waypoint(500.0, 0.0, 100.0), Waypoint(500.0, 500.0, 100.0)),
        acceptance_radius_m=15.0,
        loop=True,
    )
    ap = make_autopilot(plan)
    ap.update(nav_at(0.0, 0.0))
    assert ap.waypoint_index == 0
    ap.update(nav_at(490.0, 5.0))  # within 15 m
    assert ap.waypoint_index == 1 and ap.status.waypoints_reached == 1
    ap.update(nav_at(480.0, 520.0, course=math.pi / 2))  # beyond the perpendicular at 40 m
    assert ap.waypoint_index == 0 and ap.status.waypoints_reached == 2


def test_last_waypoint_holds_the_line_without_loop():
    plan = FlightPlan(waypoints=(Waypoint(300.0, 0.0, 100.0),), loop=False)
    ap = make_autopilot(plan)
    ap.update(nav_at(0.0, 0.0))
    ap.update(nav_at(400.0, 20.0))
    assert ap.status.waypoints_reached == 1
    assert ap.waypoint_index == 0
    # right of the line (east > 0): the course command turns left, back to the line
    assert ap.status.cross_track_m == pytest.approx(20.0)
    assert ap.status.course_cmd_rad < 0.0


def test_commands_are_limited_and_slew_limited():
    plan = FlightPlan(waypoints=(Waypoint(0.0, -1000.0, 300.0),))
    ap = make_autopilot(plan)
    params = load_aircraft_params()
    previous = ap.trim.controls.copy()
    for _ in range(200):
        controls = ap.update(nav_at(0.0, 0.0))  # far off course and 200 m low
        assert np.all(controls >= params.actuators.lower_limits - 1e-12)
        assert np.all(controls <= params.actuators.upper_limits + 1e-12)
        assert np.all(
            np.abs(controls[:3] - previous[:3]) <= ap.gains.surface_rate_radps * 0.01 + 1e-12
        )
        previous = controls
    assert abs(ap.status.roll_cmd_rad) == pytest.approx(ap.gains.roll_limit_rad)
    assert ap.status.roll_cmd_rad < 0.0  # target to the west: turn left
    # climbing, towards a reference that rises at the climb-rate limit
    assert ap.status.altitude_ref_m == pytest.approx(100.0 + 200 * 0.01 * ap.gains.climb_rate_mps)
    assert ap.trim.theta_rad < ap.status.pitch_cmd_rad
    assert ap.status.pitch_cmd_rad <= ap.trim.theta_rad + ap.gains.pitch_limit_rad
