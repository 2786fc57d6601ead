"""The pipeline on damaged streams: restarts, GPS glitches, stale servos, corrupt samples."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from immukf_sitl.experiments.replay import ReplayResult, replay, summary_of
from immukf_sitl.mavlink.flightlog import FlightLog, read_flight_log
from immukf_sitl.models.params import load_aircraft_params
from immukf_sitl.samples import ActuatorSample, GpsSample, ImuSample
from immukf_sitl.service.pipeline import EstimatorPipeline

DATA = Path(__file__).parent / "data"


@pytest.fixture(scope="module")
def fault_free() -> FlightLog:
    return read_flight_log(DATA / "fault_free.tlog")


def _run(log: FlightLog, stream) -> tuple[ReplayResult, dict]:
    damaged = dataclasses.replace(log, stream=list(stream))
    result = replay(damaged, EstimatorPipeline(load_aircraft_params()))
    return result, summary_of(result, "damaged").to_json()


def _final_attitude_error_deg(result: ReplayResult, log: FlightLog) -> float:
    last = result.history.outputs[-1]
    truth = min(log.truth, key=lambda s: abs(s.t_s - last.t_s))
    err = (last.nav.euler_rad - truth.euler_rad + np.pi) % (2 * np.pi) - np.pi
    return float(np.degrees(np.abs(err)).max())


def test_a_restarted_sender_starts_a_new_flight(fault_free):
    half = [s for s in fault_free.stream if s.time_s < 20.0]
    result, _ = _run(fault_free, half + half)  # the sim restarted at 20 s
    counters = result.pipeline.counters
    assert counters.restarts == 1 and counters.out_of_order == 0
    assert counters.steps > 1.9 * 1900  # both flights estimated, not the second dropped


def test_a_gps_glitch_is_rejected_and_raises_no_alarm(fault_free):
    stream = []
    for s in fault_free.stream:
        if isinstance(s, GpsSample) and s.time_s == pytest.approx(20.0):
            s = dataclasses.replace(s, lat_deg=s.lat_deg + 0.045)  # 5 km north
        stream.append(s)
    result, summary = _run(fault_free, stream)
    assert result.pipeline.counters.rejected_gps == 1
    assert summary["detections"] == [] and summary["false_alarms"] == 0
    assert _final_attitude_error_deg(result, fault_free) < 1.0


def test_stale_servo_outputs_hold_decisions(fault_free):
    stream = [
        s for s in fault_free.stream if not (isinstance(s, ActuatorSample) and s.time_s > 20.0)
    ]
    result, summary = _run(fault_free, stream)
    assert result.pipeline.counters.stale_actuator_steps > 1900  # 20 s without servo outputs
    assert summary["detections"] == []


def test_a_corrupt_sample_does_not_leave_the_estimate_ruined(fault_free):
    stream = []
    for s in fault_free.stream:
        if isinstance(s, ImuSample) and s.time_s == pytest.approx(20.0):
            s = ImuSample(s.time_s, [1e6, 0.0, -9.8], s.gyro_radps)
        stream.append(s)
    result, summary = _run(fault_free, stream)
    assert all(np.all(np.isfinite(o.nav.euler_rad)) for o in result.history.outputs)
    assert _final_attitude_error_deg(result, fault_free) < 2.0
    assert summary["false_alarms"] <= 1  # the spike itself may be declared an x fault
