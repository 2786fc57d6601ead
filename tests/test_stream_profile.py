"""The sim speaking as ArduPilot and PX4: messages, rates, units, noise and parameters.

Each check has an independent reference: the mean of the truth-step samples for the IMU
messages (within the wire's quantisation), a chi-square bound for the per-sample noise at
250 Hz, ArduPlane's layouts for the parameters the sim answers.
"""

from __future__ import annotations

import dataclasses
import math
from collections import Counter

import numpy as np
import pytest
from udp_tools import REPO

from immukf_sitl.cli import build_parser, main
from immukf_sitl.mavlink import codec
from immukf_sitl.mavlink.servo_params import ServoParamRequest
from immukf_sitl.mavlink.stream_requests import StreamRequest
from immukf_sitl.mavlink.wire import mavlink
from immukf_sitl.models.servo_map import ServoMap
from immukf_sitl.samples import GpsSample
from immukf_sitl.scenario import ScenarioError, load_scenario
from immukf_sitl.stream_profile import StreamProfile
from sim.emitter import profile_argv, profile_from_args
from sim.profile_stream import AUTOPILOTS, ParamServer
from sim.scenario_flight import flight_from_scenario, profile_stream

SCENARIO = load_scenario(REPO / "scenarios" / "fault_free.yaml")


def _fly(profile: StreamProfile, seconds: float):
    flight = flight_from_scenario(SCENARIO, profile=profile)
    stream, params = profile_stream(flight, profile)
    records = [flight.start()]
    messages = list(stream.messages(records[0]))
    for _ in range(int(round(seconds / flight.driver.dt_s))):
        records.append(flight.step())
        messages += stream.messages(records[-1])
    return flight, records, messages, params


def test_ardupilot_rates_units_and_means() -> None:
    profile = StreamProfile("ardupilot")
    _, records, messages, params = _fly(profile, 2.0)
    counts = Counter(m.get_type() for m in messages)
    # 2 s + the first record: 101 IMU messages at 50 Hz, 21 servo at 10 Hz, 11 fixes at 5 Hz
    assert counts["RAW_IMU"] == counts["SCALED_IMU2"] == 101
    assert counts["SERVO_OUTPUT_RAW"] == 21
    assert counts["GPS_RAW_INT"] == 11
    assert counts["HIGHRES_IMU"] == 0
    beat = next(m for m in messages if m.get_type() == "HEARTBEAT")
    assert beat.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
    assert beat.type == mavlink.MAV_TYPE_FIXED_WING
    raw = [m for m in messages if m.get_type() == "RAW_IMU"]
    # message k (k >= 1) is the mean of truth steps 2k-1 and 2k, stamped at step 2k
    for k in (1, 37, 100):
        pair = records[2 * k - 1 : 2 * k + 1]
        sample = codec.decode_imu(raw[k])
        assert sample.time_s == pytest.approx(pair[-1].time_s, abs=1e-6)
        mean_accel = np.mean([r.imu.accel_mps2 for r in pair], axis=0)
        mean_gyro = np.mean([r.imu.gyro_radps for r in pair], axis=0)
        np.testing.assert_allclose(sample.accel_mps2, mean_accel, atol=0.5 * 9.80665e-3 + 1e-9)
        np.testing.assert_allclose(sample.gyro_radps, mean_gyro, atol=0.5e-3 + 1e-9)
    assert params is not None


def test_px4_truth_at_250_hz_with_the_same_noise_density() -> None:
    profile = StreamProfile("px4")
    flight, records, messages, _ = _fly(profile, 2.0)
    assert flight.driver.dt_s == pytest.approx(0.004)
    imu = [m for m in messages if m.get_type() == "HIGHRES_IMU"]
    assert len(imu) == len(records) == 501
    beat = next(m for m in messages if m.get_type() == "HEARTBEAT")
    assert beat.autopilot == mavlink.MAV_AUTOPILOT_PX4
    assert Counter(m.get_type() for m in messages)["SERVO_OUTPUT_RAW"] == 21
    residual = np.array([r.imu.gyro_radps - r.truth.rates_body_radps for r in records])
    residual -= residual.mean(axis=0)  # the constant bias
    n = residual.size
    sigma = SCENARIO.sensors.imu.gyro_sigma_radps * math.sqrt(2.5)
    # chi-square with n - 3 degrees of freedom: +-4.5 sigma of its normal approximation
    ratio = float(np.sum(residual**2)) / (sigma**2 * (n - 3))
    assert abs(ratio - 1.0) < 4.5 * math.sqrt(2.0 / (n - 3))


def test_native_profile_is_the_old_stream() -> None:
    profile = StreamProfile()
    _, records, messages, params = _fly(profile, 0.5)
    counts = Counter(m.get_type() for m in messages)
    assert counts["HIGHRES_IMU"] == counts["SERVO_OUTPUT_RAW"] == len(records) == 51
    assert params is None
    imu = [m for m in messages if m.get_type() == "HIGHRES_IMU"]
    sample = codec.decode_imu(imu[20])
    np.testing.assert_allclose(sample.gyro_radps, records[20].imu.gyro_radps, rtol=1e-6)


@pytest.mark.parametrize("layout", ["conventional", "elevon", "vtail"])
def test_the_vehicle_answers_the_map_serve_asks_for(layout: str) -> None:
    server = ParamServer(ServoMap.layout(layout))
    request = ServoParamRequest()
    beat = codec.heartbeat_message(mavlink.MAV_TYPE_FIXED_WING, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA)
    beat._header = mavlink.MAVLink_header(beat.id, srcSystem=1, srcComponent=1)
    request.on_heartbeat(beat)
    asked = request.requests(0.0)
    assert len(asked) == 81 and request.requests(0.5) == []  # one round per second
    for message in asked:
        for answer in server.answer(message):
            request.on_param_value(answer)
    assert request.done and not request.missing
    got = request.servo_map()
    assert got is not None
    assert [(o.channel, o.function) for o in got.outputs] == [
        (o.channel, o.function) for o in ServoMap.layout(layout).outputs
    ]
    listed = server.answer(mavlink.MAVLink_param_request_list_message(1, 1))
    assert len(listed) == 81 and listed[0].param_count == 81


def test_a_px4_vehicle_is_not_asked() -> None:
    request = ServoParamRequest()
    beat = codec.heartbeat_message(mavlink.MAV_TYPE_FIXED_WING, mavlink.MAV_AUTOPILOT_PX4)
    request.on_heartbeat(beat)
    assert request.requests(0.0) == [] and request.target is None


def test_profile_errors_are_one_line(tmp_path) -> None:
    text = (REPO / "scenarios" / "fault_free.yaml").read_text()
    for profile, message in (
        ("profile: apm\n", "expected one of native, ardupilot, px4"),
        ("profile: {name: px4, imu_hz: 5}\n", "imu_hz: expected 20 to 1000 Hz"),
        ("profile: {name: px4, servo_layout: vtail}\n", "only the ardupilot profile"),
    ):
        path = tmp_path / "s.yaml"
        path.write_text(text + profile)
        with pytest.raises(ScenarioError, match=message) as info:
            load_scenario(path)
        assert "\n" not in str(info.value)


@pytest.mark.parametrize("profile", ["ardupilot", "px4"])
def test_request_streams_raises_the_rates(profile: str) -> None:
    """serve's requests, answered by the sim's autopilot: the rates move to what was asked."""
    slow = StreamProfile(profile, imu_hz=20.0, servo_hz=5.0)
    flight = flight_from_scenario(SCENARIO, profile=slow)
    stream, _ = profile_stream(flight, slow)
    request = StreamRequest()
    autopilot = AUTOPILOTS[profile]
    beat = codec.heartbeat_message(mavlink.MAV_TYPE_FIXED_WING, autopilot)
    beat._header = mavlink.MAVLink_header(beat.id, srcSystem=1, srcComponent=1)
    request.on_heartbeat(beat)
    for message in request.requests(0.0):
        for ack in stream.on_request(message):
            request.on_command_ack(ack)
    imu = "RAW_IMU" if profile == "ardupilot" else "HIGHRES_IMU"
    assert request.accepted == {imu, "SERVO_OUTPUT_RAW"}  # GPS: the receiver's own rate
    fallback = request.requests(1.5)
    assert [m.req_stream_id for m in fallback] == [mavlink.MAV_DATA_STREAM_EXTENDED_STATUS]
    records = [flight.start()] + [
        flight.step() for _ in range(int(round(2.0 / flight.driver.dt_s)))
    ]
    counts = Counter(m.get_type() for r in records for m in stream.messages(r))
    assert counts[imu] == 101 and counts["SERVO_OUTPUT_RAW"] == 51  # 50 Hz and 25 Hz over 2 s
    line = request.report({imu: 50.0, "SERVO_OUTPUT_RAW": 25.0, "GPS_RAW_INT": None})
    assert f"{imu} asked 50 Hz (SET_MESSAGE_INTERVAL), got 50.0 Hz" in line
    assert "GPS_RAW_INT asked 5 Hz (REQUEST_DATA_STREAM), got nothing" in line


def test_request_data_stream_is_honoured() -> None:
    slow = StreamProfile("ardupilot", imu_hz=20.0, servo_hz=5.0)
    flight = flight_from_scenario(SCENARIO, profile=slow)
    stream, _ = profile_stream(flight, slow)
    for group, rate in (
        (mavlink.MAV_DATA_STREAM_RAW_SENSORS, 50),
        (mavlink.MAV_DATA_STREAM_RC_CHANNELS, 25),
    ):
        assert (
            stream.on_request(mavlink.MAVLink_request_data_stream_message(1, 1, group, rate, 1))
            == []
        )
    records = [flight.start()] + [flight.step() for _ in range(200)]
    counts = Counter(m.get_type() for r in records for m in stream.messages(r))
    assert counts["RAW_IMU"] == 101 and counts["SERVO_OUTPUT_RAW"] == 51


@pytest.mark.parametrize(
    "profile",
    [
        StreamProfile(),
        StreamProfile("ardupilot", imu_hz=25.0, servo_layout="elevon"),
        StreamProfile("px4", imu_hz=250.0, servo_hz=5.0, gps_hz=10.0),
    ],
)
def test_run_hands_the_sim_the_profile_it_was_given(profile: StreamProfile) -> None:
    """``run --profile``: the sim's command line parses back to the same profile."""
    parser = build_parser(["sim"])
    args = parser.parse_args(["sim", "scenarios/fault_free.yaml", *profile_argv(profile)])
    assert profile_from_args(args, SCENARIO.profile) == profile


def test_run_refuses_a_profile_without_the_faulted_imu(tmp_path, capsys) -> None:
    text = (REPO / "scenarios" / "q_gyro_zeroed.yaml").read_text()
    path = tmp_path / "second_imu.yaml"
    path.write_text(text.replace("kind: zero}", "kind: zero, imu: 1}") + "profile: ardupilot\n")
    assert main(["run", str(path), "--profile", "px4", "--out-dir", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "faults[0].imu: 1, but the px4 profile sends imu 0 as" in err


@pytest.mark.parametrize(("name", "message"), [("native", "HIL_GPS"), ("ardupilot", "GPS_RAW_INT")])
def test_a_vertical_velocity_goes_on_the_wire_where_the_profile_sends_it(name, message) -> None:
    """The native sim sends a receiver's vD in HIL_GPS (packed and parsed as MAVLink 2 bytes,
    within its cm/s); ArduPilot's GPS_RAW_INT has no field for it, as on the real link."""
    gps = dataclasses.replace(SCENARIO.sensors.gps, reports_velocity_down=True, rate_hz=5.0)
    scenario = dataclasses.replace(SCENARIO, sensors=dataclasses.replace(SCENARIO.sensors, gps=gps))
    profile = StreamProfile(name)
    flight = flight_from_scenario(scenario, profile=profile)
    stream, _ = profile_stream(flight, profile)
    sender, parser = mavlink.MAVLink(None, 1, 1), mavlink.MAVLink(None, 255, 190)
    fixes = []
    for k in range(int(round(1.0 / flight.driver.dt_s)) + 1):
        record = flight.start() if k == 0 else flight.step()
        for msg in stream.messages(record):
            if msg.get_type() in ("GPS_RAW_INT", "HIL_GPS"):
                fixes.append((record.gps, parser.parse_buffer(msg.pack(sender))[0]))
    assert len(fixes) == 6 and {m.get_type() for _, m in fixes} == {message}
    for sent, msg in fixes:
        got = codec.decode_gps(msg)
        assert sent.velocity_down_mps is not None
        if message == "HIL_GPS":
            assert got.velocity_down_mps == pytest.approx(sent.velocity_down_mps, abs=0.005)
        else:
            assert got.velocity_down_mps is None
        assert got.ground_speed_mps == pytest.approx(sent.ground_speed_mps, abs=0.005)
        assert abs(math.remainder(got.course_rad - sent.course_rad, 2 * math.pi)) < 1e-4
        assert (got.lat_deg, got.lon_deg) == pytest.approx((sent.lat_deg, sent.lon_deg), abs=1e-7)


def test_a_gps_message_without_a_3d_fix_is_named_in_its_error() -> None:
    fix = GpsSample(1.0, 47.0, 8.0, 400.0, 20.0, 0.5, 2, -0.5)
    with pytest.raises(codec.DecodeError, match="HIL_GPS fix_type 2 is not a 3D fix"):
        codec.decode_gps(codec.gps_message(fix))
    with pytest.raises(ValueError, match="vertical velocity"):
        codec.hil_gps_message(dataclasses.replace(fix, velocity_down_mps=None))
