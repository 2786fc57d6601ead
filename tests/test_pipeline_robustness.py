"""The pipeline on damaged streams: restarts, GPS glitches, stale servos, corrupt samples,
duplicated and late servo outputs and fixes, the servo clock's 32-bit wrap; its geodesy."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from immukf_sitl.experiments.replay import ReplayResult, replay, summary_of
from immukf_sitl.mavlink.flightlog import FlightLog, read_flight_log
from immukf_sitl.models.earth import LocalGeodetic, NedOrigin, geodetic_to_ned, ned_to_geodetic
from immukf_sitl.models.params import load_aircraft_params
from immukf_sitl.models.sensors import GpsSpec, SensorSpec
from immukf_sitl.samples import ActuatorSample, GpsSample, ImuSample
from immukf_sitl.service.pipeline import ACTUATOR_TIME_WRAP_S, EstimatorPipeline, PipelineConfig

# flies JSBSim or the estimator chain
pytestmark = pytest.mark.slow

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


# -- duplicated, late and wrapped servo outputs and fixes --------------------------------------

SHORT_S = 25.0  # enough to align, settle and fly a while; keeps the three replays below short


@pytest.fixture(scope="module")
def short(fault_free) -> list:
    return [s for s in fault_free.stream if s.time_s <= SHORT_S]


@pytest.fixture(scope="module")
def short_clean(fault_free, short) -> ReplayResult:
    return _run(fault_free, short)[0]


def _final_state(result: ReplayResult) -> np.ndarray:
    last = result.history.outputs[-1]
    return np.concatenate([last.nav.position_ned_m, last.nav.euler_rad, last.mode_probabilities])


def test_duplicate_and_late_servo_outputs_and_fixes_are_counted_and_never_used(
    fault_free, short, short_clean
):
    stream, previous_servo, repeat = [], None, None
    n_servo = n_fix = 0
    for s in short:
        stream.append(s)
        if isinstance(s, GpsSample):
            repeat = s
            n_fix += 1
        elif isinstance(s, ImuSample) and repeat is not None:
            stream.append(repeat)  # the fix again after its step: fused twice if it were kept
            repeat = None
        elif isinstance(s, ActuatorSample):
            stream.append(s)  # duplicate
            if previous_servo is not None:
                stream.append(previous_servo)  # late: would act as the current controls
            previous_servo = s
            n_servo += 1
    result, _ = _run(fault_free, stream)
    c = result.pipeline.counters
    assert c.gps_out_of_order == n_fix
    assert c.actuator_out_of_order == 2 * n_servo - 1
    assert c.out_of_order == c.restarts == c.realignments == c.stale_actuator_steps == 0
    assert c.steps == short_clean.pipeline.counters.steps
    np.testing.assert_array_equal(_final_state(result), _final_state(short_clean))


def test_a_logs_vertical_velocity_is_fused_only_where_the_spec_sheet_says_so(
    fault_free, short, short_clean
):
    """Fixes that carry ``vD`` (here the truth's): the default spec sheet leaves it out (the
    estimate bit for bit that of the same fixes without it) and counts it; a receiver's spec
    sheet that reports it fuses it at every fix after the alignment's."""
    truth = {round(t.t_s, 3): t for t in fault_free.truth}
    stream = [
        dataclasses.replace(
            s, velocity_down_mps=float(truth[round(s.time_s, 3)].velocity_ned_mps[2])
        )
        if isinstance(s, GpsSample)
        else s
        for s in short
    ]
    n_fix = sum(isinstance(s, GpsSample) for s in stream)
    ignored, _ = _run(fault_free, stream)
    c = ignored.pipeline.counters
    assert c.gps_velocity_down == 0 and c.gps_velocity_down_unused >= n_fix - 2
    np.testing.assert_array_equal(_final_state(ignored), _final_state(short_clean))
    told = SensorSpec(gps=GpsSpec(reports_velocity_down=True))
    damaged = dataclasses.replace(fault_free, stream=stream)
    fused = replay(damaged, EstimatorPipeline(load_aircraft_params(), PipelineConfig(sensors=told)))
    c = fused.pipeline.counters
    assert c.gps_velocity_down >= n_fix - 2 and c.gps_velocity_down_unused == 0
    assert not np.array_equal(_final_state(fused), _final_state(short_clean))


def test_the_servo_clock_wrap_is_unwrapped(fault_free, short, short_clean):
    # the same flight 71.6 min later, crossing SERVO_OUTPUT_RAW's 32-bit wrap at 10 s
    offset_s = ACTUATOR_TIME_WRAP_S - 10.0
    stream, wrapped = [], 0
    for s in short:
        t_s = s.time_s + offset_s
        if isinstance(s, ActuatorSample) and t_s >= ACTUATOR_TIME_WRAP_S:
            t_s -= ACTUATOR_TIME_WRAP_S  # what decode_servo_output_raw gives after the wrap
            wrapped += 1
        stream.append(dataclasses.replace(s, time_s=t_s))
    result, _ = _run(fault_free, stream)
    c = result.pipeline.counters
    assert wrapped > 1000
    assert c.actuator_unwrapped == wrapped
    assert c.actuator_out_of_order == c.restarts == c.realignments == 0
    assert c.stale_actuator_steps == short_clean.pipeline.counters.stale_actuator_steps == 0
    assert c.steps == short_clean.pipeline.counters.steps
    np.testing.assert_allclose(_final_state(result), _final_state(short_clean), atol=1e-6)


def test_a_restarted_servo_sender_is_a_new_stream_not_a_wrap():
    pipeline = EstimatorPipeline(load_aircraft_params())
    pwm = (1500,) * 16
    late_s = ACTUATOR_TIME_WRAP_S + 500.0  # 80 min into a flight, past one wrap
    pipeline.on_imu(ImuSample(late_s - 0.01, [0.0, 0.0, -9.8], [0.0, 0.0, 0.0]))
    pipeline.on_actuators(ActuatorSample(late_s - ACTUATOR_TIME_WRAP_S, pwm))  # wrapped once
    pipeline.on_actuators(ActuatorSample(0.0, pwm))  # the sender restarted, not wrapped again
    pipeline.on_actuators(ActuatorSample(0.01, pwm))
    c = pipeline.counters
    assert c.actuator_unwrapped == 1 and c.actuator_out_of_order == 0


# -- geodesy of the published position ---------------------------------------------------------


@pytest.mark.parametrize(
    "origin",
    [
        NedOrigin(47.3977, 8.5456, 150.0),
        NedOrigin(0.0, -179.99, -400.0),
        NedOrigin(-33.87, 151.21, 2500.0),
        NedOrigin(84.0, 0.0, 0.0),
    ],
)
def test_local_geodetic_matches_pymap3d_to_a_millimetre_within_10_km(origin):
    rng = np.random.default_rng(3)
    n = 300
    ned = np.vstack(
        [rng.uniform(-10_000.0, 10_000.0, (2, n)), origin.alt_m - rng.uniform(-400.0, 10_000.0, n)]
    )
    frame = LocalGeodetic(origin)
    ours = np.array([frame.to_geodetic(*ned[:, i]) for i in range(n)]).T
    ref = ned_to_geodetic(ned, origin)
    metres_per_rad = 6.4e6
    north_err = np.radians(ours[0] - ref[0]) * metres_per_rad
    east_err = (
        np.radians((ours[1] - ref[1] + 180.0) % 360.0 - 180.0)
        * metres_per_rad
        * np.cos(np.radians(ref[0]))
    )
    assert np.abs(north_err).max() < 1e-3
    assert np.abs(east_err).max() < 1e-3
    assert np.abs(ours[2] - ref[2]).max() < 1e-3
    back = np.array([frame.to_ned(*ref[:, i]) for i in range(n)]).T
    np.testing.assert_allclose(back, geodetic_to_ned(ref[0], ref[1], ref[2], origin), atol=1e-3)
    np.testing.assert_allclose(back, ned, atol=1e-3)
