"""The closed loop: Flight.step(navigation=) and the in-process run that flies on the estimate."""

from __future__ import annotations

import numpy as np
import pytest

from immukf_sitl.experiments.campaign import FailureCriterion
from immukf_sitl.experiments.inprocess import run_inprocess
from immukf_sitl.experiments.metrics import FailureMonitor, path_errors_m
from immukf_sitl.scenario import parse_scenario
from immukf_sitl.service.pipeline import PipelineConfig
from sim.autopilot import NavigationState
from sim.flight import Flight

# flies JSBSim or the estimator chain
pytestmark = pytest.mark.slow

PLAN = {
    "waypoints": [
        {"north_m": 110, "east_m": 0, "alt_m": 150},
        {"north_m": 260, "east_m": 180, "alt_m": 165},
    ]
}


def scenario(**changes: object):
    data = {"name": "cl", "duration_s": 8, "seed": 3, "flight_plan": PLAN}
    data.update(changes)
    return parse_scenario(data)


def test_flying_on_a_perfect_estimate_is_flying_on_truth() -> None:
    sc = scenario()
    flights = [Flight(sc.flight_plan, sc.seed) for _ in range(2)]
    records = [f.start() for f in flights]
    for _ in range(600):
        t = records[1].truth
        nav = NavigationState.from_navigation(
            t.time_s, t.position_ned_m, t.alt_m, t.velocity_ned_mps, t.euler_rad,
            t.rates_body_radps,
        )  # fmt: skip
        records = [flights[0].step(), flights[1].step(navigation=nav)]
    a, b = (r.truth for r in records)
    assert np.linalg.norm(a.position_ned_m - b.position_ned_m) < 0.5
    assert np.max(np.abs(a.euler_rad - b.euler_rad)) < np.radians(0.5)
    assert records[1].autopilot is not None and records[1].autopilot.leg_target_ne_m == (260, 180)


def test_a_bad_estimate_reaches_the_aircraft_only_in_closed_loop() -> None:
    # UKF-2 (fault-free model) with a dead q gyro from 4 s, in the first turn
    sc = scenario(faults=[{"t_s": 4.0, "channels": ["q"]}])
    config = PipelineConfig(variant="ukf2", sensors=sc.sensors.spec_sheet())
    criterion = FailureCriterion(stop=False)
    open_monitor = FailureMonitor(criterion, settle_s=3.0)
    closed_monitor = FailureMonitor(criterion, settle_s=3.0)
    opened = run_inprocess(sc, config, closed_loop=False, stop=open_monitor)
    closed = run_inprocess(sc, config, closed_loop=True, stop=closed_monitor)
    assert not opened.closed_loop and closed.closed_loop
    assert len(opened.records) == len(closed.records) == 801
    height = [abs(path_errors_m(r)[1]) for r in opened.records[1:]]
    assert max(height) < 10.0  # on truth the autopilot holds its altitude whatever the filter
    # the same sensors and seed: the two aircraft part only when the estimate goes bad
    apart = np.array(
        [
            np.degrees(np.max(np.abs(a.truth.euler_rad[:2] - b.truth.euler_rad[:2])))
            for a, b in zip(opened.records, closed.records, strict=True)
        ]
    )
    times = np.array([r.time_s for r in opened.records])
    assert apart[times < 4.0].max() < 2.0  # alignment transients only
    assert apart[times > 4.0].max() > 5.0
    # the estimate the autopilot flew on is the pipeline's, shifted to the flight's origin
    last = closed.estimates[-1]
    assert last is not None and last.time_s == pytest.approx(closed.records[-1].time_s)


def test_the_monitor_stops_a_flight_at_its_first_failure() -> None:
    sc = scenario(faults=[{"t_s": 4.0, "channels": ["q"]}])
    config = PipelineConfig(variant="ukf2", sensors=sc.sensors.spec_sheet())
    monitor = FailureMonitor(FailureCriterion(estimate_attitude_deg=5.0), settle_s=3.0)
    run = run_inprocess(sc, config, closed_loop=True, stop=monitor)
    assert monitor.reason == "diverged" and run.stop_reason == "diverged"
    assert run.records[-1].time_s == pytest.approx(monitor.t_s)
    assert len(run.records) < 801 and len(run.truth) == len(run.records)
