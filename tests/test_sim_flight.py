"""The flight loop: JSBSim flies the default plan under the autopilot on truth; determinism."""

from __future__ import annotations

import time

import numpy as np
import pytest

from sim.flight import Flight, fly
from sim.flight_plans import default_flight_plan

# flies JSBSim or the estimator chain
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def flight_120s():
    plan = default_flight_plan()
    start = time.perf_counter()
    records = list(fly(plan, seed=3, duration_s=120.0))
    wall = time.perf_counter() - start
    print(f"120 s flight: {wall:.2f} s wall, {len(records) / wall:.0f} steps/s")
    return plan, records


def test_default_plan_manoeuvres_within_its_envelope(flight_120s):
    _, records = flight_120s
    phi = np.array([r.truth.euler_rad[0] for r in records])
    alt = np.array([r.truth.alt_m for r in records])
    assert phi.max() > np.radians(20) and phi.min() < -np.radians(20)  # turns both ways
    assert alt.max() > 175.0 and alt.min() < 135.0  # a climb and a descent
    assert 100.0 < alt.min() and alt.max() < 200.0


def test_altitude_and_airspeed_hold(flight_120s):
    _, records = flight_120s
    flown = [r for r in records if r.autopilot is not None and r.time_s > 2.0]
    alt_err = np.array([r.truth.alt_m - r.autopilot.altitude_ref_m for r in flown])
    va_err = np.array([r.truth.airspeed_mps - r.autopilot.airspeed_cmd_mps for r in flown])
    # after capture of each commanded altitude, the aircraft stays within 10 m of it
    captured, worst_captured = False, 0.0
    target = None
    for r in flown:
        if r.autopilot.altitude_target_m != target:
            target, captured = r.autopilot.altitude_target_m, False
        error = abs(r.truth.alt_m - target)
        captured = captured or error < 2.0
        if captured:
            worst_captured = max(worst_captured, error)
    print(
        f"max |alt - reference| {np.abs(alt_err).max():.2f} m, after capture "
        f"{worst_captured:.2f} m; max |airspeed error| {np.abs(va_err).max():.2f} m/s"
    )
    assert np.abs(alt_err).max() < 10.0
    assert worst_captured < 10.0
    assert np.abs(va_err).max() < 2.0


def test_every_waypoint_passed_within_30_m(flight_120s):
    plan, records = flight_120s
    later = [r for r in records if r.time_s > 5.0]
    position = np.array([r.truth.position_ned_m[:2] for r in later])
    misses = []
    for wp in plan.waypoints:
        misses.append(
            float(np.min(np.hypot(position[:, 0] - wp.north_m, position[:, 1] - wp.east_m)))
        )
    print("closest approach to each waypoint (m):", np.round(misses, 2))
    assert max(misses) < 30.0
    assert records[-1].autopilot.waypoints_reached >= len(plan.waypoints)


def test_records_fit_together(flight_120s):
    _, records = flight_120s
    assert [r.step for r in records[:3]] == [0, 1, 2]
    assert records[0].autopilot is None
    assert np.allclose(records[-1].time_s, 120.0)
    gps_steps = [r.step for r in records if r.gps is not None]
    assert gps_steps[:3] == [0, 100, 200] and len(gps_steps) == 121
    for r in records[::997]:
        assert np.array_equal(r.controls, r.truth.controls)
        assert r.imu.time_s == r.time_s
        assert r.controls.shape == (4,)


def test_same_seed_same_flight_other_seed_other_noise():
    def run(seed):
        return [
            np.concatenate([r.truth.state_vector(), r.controls, r.imu.as_array()])
            for r in fly(default_flight_plan(), seed=seed, duration_s=10.0)
        ]

    a, b, c = run(11), run(11), run(12)
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    differs = [not np.array_equal(x[16:], y[16:]) for x, y in zip(a, c, strict=True)]
    assert all(differs)  # the IMU noise differs at every step
    truth_same = [np.array_equal(x[:16], y[:16]) for x, y in zip(a, c, strict=True)]
    assert all(truth_same)  # flying on truth, the noise does not change the flight


def test_flight_must_start_before_stepping():
    flight = Flight(default_flight_plan(), seed=1)
    with pytest.raises(RuntimeError, match="start"):
        flight.step()
