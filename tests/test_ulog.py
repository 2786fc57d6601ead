"""PX4 ULog: the writer's files read back by read_ulog and by pyulog itself, and bad files."""

from __future__ import annotations

import math
import struct
from pathlib import Path

import numpy as np
import pytest
from pyulog import ULog

from immukf_sitl.errors import UserError
from immukf_sitl.logs.ulog import MAGIC, ULogWriter, is_ulog, read_ulog, write_ulog
from immukf_sitl.mavlink.flightlog import FaultRecord, FlightLog, read_flight_log
from immukf_sitl.samples import ActuatorSample, GpsSample, ImuSample

DATA = Path(__file__).parent / "data"


def _of(log: FlightLog, kind: type) -> list:
    return [s for s in log.stream if isinstance(s, kind)]


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> tuple[FlightLog, Path, int]:
    log = read_flight_log(DATA / "q_gyro_zeroed.tlog")
    path = tmp_path_factory.mktemp("ulog") / "q_gyro_zeroed.ulg"
    size = write_ulog(path, log)
    return log, path, size


def _small_log() -> FlightLog:
    stream: list = []
    for k in range(30):
        t_s = 100.0 + 0.01 * k
        stream.append(ImuSample(t_s, [0.1, -0.2, -9.8 + 0.001 * k], [0.01 * k, 0.02, -0.03]))
        if k % 10 == 0:
            stream.append(GpsSample(t_s, 47.3977, 8.5456, 150.0, 25.0, 3.1, 3))
            stream.append(ActuatorSample(t_s, (1500, 1400, 1600, 1000) + (0,) * 12))
    fault = FaultRecord("bias", ("x", "z"), 100.1, 0.2, end_t_s=100.2)
    return FlightLog(stream=stream, faults=[fault], scenario="small")


def test_round_trip_of_the_recorded_flight(recorded: tuple[FlightLog, Path, int]) -> None:
    log, path, size = recorded
    assert path.stat().st_size == size
    back = read_ulog(path)
    assert back.kind == "ulog" and back.bad_records == 0
    assert back.vehicle == "fixed-wing" and back.vehicle_evidence == "vehicle_status system_type 1"
    assert back.imu_source == "sensor_combined"
    assert back.imu_sources == {"sensor_combined": len(_of(log, ImuSample))}
    assert back.faults == log.faults and back.scenario == log.scenario == "q-gyro-zeroed"
    # IMU: float32 fields, so equal to the float32 of the original (times to the microsecond)
    imu, imu_back = _of(log, ImuSample), _of(back, ImuSample)
    assert len(imu_back) == len(imu) == 4001
    a = np.array([s.as_array() for s in imu])
    b = np.array([s.as_array() for s in imu_back])
    np.testing.assert_array_equal(b, a.astype(np.float32).astype(float))
    assert max(abs(x.time_s - y.time_s) for x, y in zip(imu, imu_back, strict=True)) <= 0.5e-6
    # GPS: lat/lon int32 degE7 (half a unit: 0.5e-7 deg), alt int32 mm (0.5 mm), float32 speed
    # and course (relative 1e-7; the course compared modulo 2 pi)
    gps, gps_back = _of(log, GpsSample), _of(back, GpsSample)
    assert len(gps_back) == len(gps) == 41
    for x, y in zip(gps, gps_back, strict=True):
        assert abs(y.time_s - x.time_s) <= 0.5e-6 and y.fix_type == x.fix_type
        assert abs(y.lat_deg - x.lat_deg) <= 0.5e-7 + 1e-12
        assert abs(y.lon_deg - x.lon_deg) <= 0.5e-7 + 1e-12
        assert abs(y.alt_m - x.alt_m) <= 0.5e-3 + 1e-9
        assert y.ground_speed_mps == pytest.approx(x.ground_speed_mps, rel=1e-7)
        assert abs(math.remainder(y.course_rad - x.course_rad, 2 * math.pi)) <= 1e-6
        assert -math.pi <= y.course_rad < math.pi
    # PWM: exact
    pwm, pwm_back = _of(log, ActuatorSample), _of(back, ActuatorSample)
    assert [s.pwm_us for s in pwm_back] == [s.pwm_us for s in pwm]
    assert [s.time_s for s in pwm_back] == pytest.approx([s.time_s for s in pwm], abs=0.5e-6)
    times = [s.time_s for s in back.stream]
    assert times == sorted(times)


def test_pyulog_reads_the_written_file_as_px4_would_write_it(
    recorded: tuple[FlightLog, Path, int],
) -> None:
    log, path, _ = recorded
    raw = path.read_bytes()
    # header: magic, version 1, start time (us) = the first record's; then the flag bits
    magic, version, start_us = struct.unpack_from("<7sBQ", raw, 0)
    assert (magic, version) == (b"ULog\x01\x12\x35", 1)
    assert start_us == round(min(s.time_s for s in log.stream) * 1e6)
    size, kind = struct.unpack_from("<HB", raw, 16)
    assert (chr(kind), size) == ("B", 40)
    assert raw[19 : 19 + 40] == bytes(40)  # no compat/incompat flags, no appended data
    ulog = ULog(str(path))
    assert not ulog.file_corruption and ulog.start_timestamp == start_us
    assert ulog.msg_info_dict == {"sys_name": "PX4", "ver_sw": "immukf-sitl writer"}
    names = {d.name: d for d in ulog.data_list}
    assert set(names) == {
        "sensor_combined",
        "actuator_outputs",
        "vehicle_gps_position",
        "vehicle_status",
    }
    assert all(d.multi_id == 0 for d in ulog.data_list)
    fields = {n: [f.field_name for f in d.field_data] for n, d in names.items()}
    assert fields["sensor_combined"][:8] == [
        "timestamp",
        "gyro_rad[0]",
        "gyro_rad[1]",
        "gyro_rad[2]",
        "gyro_integral_dt",
        "accelerometer_timestamp_relative",
        "accelerometer_m_s2[0]",
        "accelerometer_m_s2[1]",
    ]
    assert {"lat", "lon", "alt", "vel_m_s", "cog_rad", "fix_type"} <= set(
        fields["vehicle_gps_position"]
    )
    assert fields["actuator_outputs"] == ["timestamp", "noutputs"] + [
        f"output[{i}]" for i in range(16)
    ]
    # PX4's trailing padding: actuator_outputs is 76 bytes, padded to 80
    assert ulog.message_formats["actuator_outputs"].fields[-1] == ("uint8_t", 4, "_padding0")
    sc = names["sensor_combined"].data
    first = _of(log, ImuSample)[0]
    assert sc["gyro_rad[1]"][0] == np.float32(first.gyro_radps[1])
    assert sc["accelerometer_m_s2[2]"][0] == np.float32(first.accel_mps2[2])
    assert sc["gyro_integral_dt"][1] == 10_000  # 100 Hz
    gps = names["vehicle_gps_position"].data
    first_fix = _of(log, GpsSample)[0]
    assert gps["lat"][0] == round(first_fix.lat_deg * 1e7)
    assert gps["alt"][0] == round(first_fix.alt_m * 1e3)
    act = names["actuator_outputs"].data
    assert act["noutputs"][0] == 4 and act["output[0]"][0] == _of(log, ActuatorSample)[0].pwm_us[0]
    status = names["vehicle_status"].data
    assert set(status["system_type"]) == {1} and set(status["vehicle_type"]) == {2}
    texts = [(m.timestamp, m.message, m.log_level_str()) for m in ulog.logged_messages]
    assert texts == [
        (start_us, "SCENARIO q-gyro-zeroed", "INFO"),
        (30_000_000, "FAULT zero q t=30.000", "INFO"),
    ]
    stamps = [d.data["timestamp"] for d in ulog.data_list]
    assert all(np.all(np.diff(t.astype(np.int64)) >= 0) for t in stamps)


def test_quadrotor_system_type_reads_as_multicopter(tmp_path: Path) -> None:
    path = tmp_path / "quad.ulg"
    write_ulog(path, _small_log(), system_type=2)
    back = read_ulog(path)
    assert back.vehicle == "multicopter"
    assert back.vehicle_evidence == "vehicle_status system_type 2"
    status = ULog(str(path)).get_dataset("vehicle_status").data
    assert set(status["vehicle_type"]) == {1}  # PX4's VEHICLE_TYPE_ROTARY_WING


def test_small_log_round_trip_carries_faults_with_ends(tmp_path: Path) -> None:
    log = _small_log()
    path = tmp_path / "small.ulg"
    write_ulog(path, log)
    back = read_ulog(path)
    assert back.faults == log.faults and back.scenario == "small"
    assert [s.pwm_us for s in _of(back, ActuatorSample)] == [
        s.pwm_us for s in _of(log, ActuatorSample)
    ]
    assert all(-math.pi <= g.course_rad < math.pi for g in _of(back, GpsSample))


def test_params_round_trip_as_int32_and_float(tmp_path: Path) -> None:
    path = tmp_path / "params.ulg"
    log = _small_log()
    log.params = {"FW_AIRSPD_TRIM": 15.0}
    params = {"MAV_TYPE": 1, "SYS_AUTOSTART": 4001, "FW_AIRSPD_TRIM": 17.5, "EKF2_GYR_NOISE": 0.015}
    write_ulog(path, log, params=params)
    initial = ULog(str(path)).initial_parameters
    assert initial["MAV_TYPE"] == 1 and isinstance(initial["MAV_TYPE"], int)
    assert initial["FW_AIRSPD_TRIM"] == 17.5 and isinstance(initial["FW_AIRSPD_TRIM"], float)
    back = read_ulog(path).params
    assert set(back) == set(params) and back["SYS_AUTOSTART"] == 4001
    assert back["EKF2_GYR_NOISE"] == pytest.approx(0.015, rel=1e-7)  # stored as float32


def _hand_built(path: Path, status: dict | None = None, params: dict | None = None) -> None:
    """A log of the topics the writer does not write: vehicle_imu, sensor_gps (doubles)."""
    w = ULogWriter()
    for name, value in (params or {}).items():
        w.param(name, value)
    w.topic("vehicle_imu", ("uint64_t timestamp", "uint64_t timestamp_sample",
                            "uint32_t accel_device_id", "uint32_t gyro_device_id",
                            "float[3] delta_angle", "float[3] delta_velocity",
                            "uint16_t delta_angle_dt", "uint16_t delta_velocity_dt"))  # fmt: skip
    w.topic("sensor_gps", ("uint64_t timestamp", "double latitude_deg", "double longitude_deg",
                           "double altitude_msl_m", "float vel_m_s", "float cog_rad",
                           "uint8_t fix_type"))  # fmt: skip
    w.topic("actuator_outputs", ("uint64_t timestamp", "float[16] output", "uint8_t noutputs"))
    if status is not None:
        w.topic("vehicle_status", tuple(f"uint8_t {k}" for k in status) + ("uint64_t timestamp",))
        w.data("vehicle_status", 1_000_000, **status)
    for k in range(5):
        t_us = 1_000_000 + 4_000 * k
        w.data("vehicle_imu", t_us + 500, timestamp_sample=t_us, delta_angle_dt=4000,
               delta_velocity_dt=4000, delta_angle=[0.0004, 0, -0.0008],
               delta_velocity=[0, 0.02, -0.0392])  # fmt: skip
    w.data("sensor_gps", 1_000_000, latitude_deg=47.39770001, longitude_deg=8.5456,
           altitude_msl_m=488.25, vel_m_s=20.0, cog_rad=3.5, fix_type=3)  # fmt: skip
    w.data("sensor_gps", 1_200_000, latitude_deg=47.4, fix_type=2)  # no 3D fix: dropped
    w.data("actuator_outputs", 1_000_000, output=[1500.4] * 6 + [1100.0] * 10, noutputs=6)
    w.text(1_010_000, "SCENARIO hand-built")
    w.text(1_012_000, "FAULT zero q t=1.012")
    w.write(path)


def test_vehicle_imu_sensor_gps_and_actuator_outputs_fields(tmp_path: Path) -> None:
    path = tmp_path / "hand.ulg"
    _hand_built(path)
    log = read_ulog(path, imu=0)
    assert log.imu_source == "vehicle_imu[0]" and log.imu_sources == {"vehicle_imu[0]": 5}
    assert read_ulog(path).imu_source == "vehicle_imu[0]"  # no sensor_combined: the first IMU
    imu = _of(log, ImuSample)
    assert imu[0].time_s == pytest.approx(1.0)  # timestamp_sample, not the publication time
    np.testing.assert_allclose(imu[0].gyro_radps, [0.1, 0.0, -0.2], rtol=1e-6)  # rad / 4 ms
    np.testing.assert_allclose(imu[0].accel_mps2, [0.0, 5.0, -9.8], rtol=1e-6)
    (gps,) = _of(log, GpsSample)
    assert (gps.lat_deg, gps.alt_m, gps.fix_type) == (47.39770001, 488.25, 3)
    assert gps.course_rad == pytest.approx(3.5 - 2 * math.pi, abs=1e-6)
    (act,) = _of(log, ActuatorSample)
    assert act.pwm_us == (1500,) * 6 + (0,) * 10  # past noutputs: 0
    assert log.scenario == "hand-built" and log.faults[0].t_s == pytest.approx(1.012)
    assert log.vehicle is None and log.vehicle_evidence == ""


@pytest.mark.parametrize(
    ("status", "params", "vehicle", "evidence"),
    [
        ({"vehicle_type": 2}, None, "fixed-wing", "vehicle_status vehicle_type 2"),
        ({"vehicle_type": 1}, None, "multicopter", "vehicle_status vehicle_type 1"),
        ({"vehicle_type": 1, "is_vtol": 1}, None, "fixed-wing", "vehicle_status is_vtol"),
        (
            {"system_type": 0, "vehicle_type": 2},
            None,
            "fixed-wing",
            "vehicle_status vehicle_type 2",
        ),
        (None, {"MAV_TYPE": 13}, "multicopter", "parameter MAV_TYPE 13"),
    ],
)
def test_vehicle_falls_back_to_vehicle_type_then_mav_type(
    tmp_path: Path, status: dict | None, params: dict | None, vehicle: str, evidence: str
) -> None:
    path = tmp_path / "vehicle.ulg"
    _hand_built(path, status, params)
    log = read_ulog(path)
    assert (log.vehicle, log.vehicle_evidence) == (vehicle, evidence)


def test_absent_imu_instance_is_a_user_error_naming_what_is_there(
    recorded: tuple[FlightLog, Path, int], tmp_path: Path
) -> None:
    _, path, _ = recorded
    with pytest.raises(UserError, match=r"no vehicle_imu\[3\].*sensor_combined \(4001 samples\)"):
        read_ulog(path, imu=3)
    hand = tmp_path / "hand.ulg"
    _hand_built(hand)
    with pytest.raises(
        UserError, match=r"no vehicle_imu\[1\] in this log; it has vehicle_imu\[0\] \(5 "
    ):
        read_ulog(hand, imu=1)


def test_missing_and_foreign_files_are_user_errors(
    recorded: tuple[FlightLog, Path, int], tmp_path: Path
) -> None:
    with pytest.raises(UserError, match="no such log"):
        read_ulog(tmp_path / "absent.ulg")
    with pytest.raises(UserError, match="not a PX4 ULog"):
        read_ulog(DATA / "q_gyro_zeroed.tlog")
    empty = tmp_path / "empty.ulg"
    empty.write_bytes(b"")
    with pytest.raises(UserError, match="not a PX4 ULog"):
        read_ulog(empty)
    assert is_ulog(recorded[1].read_bytes()[:16]) and is_ulog(MAGIC)
    assert not is_ulog(b"ULog") and not is_ulog((DATA / "q_gyro_zeroed.tlog").read_bytes()[:16])


def test_truncated_file_gives_whole_records_or_one_line_error(
    recorded: tuple[FlightLog, Path, int], tmp_path: Path
) -> None:
    _, path, size = recorded
    full = read_ulog(path)
    raw = path.read_bytes()
    outcomes = []
    for cut in (10, 16, 100, 600, size // 3, size // 2 + 7, size - 5):
        cut_path = tmp_path / f"cut_{cut}.ulg"
        cut_path.write_bytes(raw[:cut])
        try:
            log = read_ulog(cut_path)
        except UserError as exc:
            assert "\n" not in str(exc) and str(cut_path) in str(exc)
            outcomes.append("error")
            continue
        for kind in (ImuSample, GpsSample, ActuatorSample):
            part, whole = _of(log, kind), _of(full, kind)
            assert len(part) <= len(whole)
            assert [s.time_s for s in part] == [s.time_s for s in whole[: len(part)]]
        imu = _of(log, ImuSample)
        whole_imu = _of(full, ImuSample)[: len(imu)]
        assert all(
            np.array_equal(a.as_array(), b.as_array()) for a, b in zip(imu, whole_imu, strict=True)
        )
        outcomes.append(len(log.stream))
    assert outcomes[0] == "error"  # the 16-byte header itself is cut
    # the last cut loses the last record only (a vehicle_status here, so the stream is whole)
    assert outcomes[-1] == len(full.stream)
    records = sum(len(d.data["timestamp"]) for d in ULog(str(path)).data_list)
    cut_records = sum(len(d.data["timestamp"]) for d in ULog(str(cut_path)).data_list)
    assert cut_records == records - 1
    assert 0 < outcomes[-3] < outcomes[-2] < outcomes[-1]


def test_a_fix_carries_vel_d_where_vel_ned_valid_says_so(tmp_path: Path) -> None:
    """vel_d_m_s (NED down) is read where vel_ned_valid is set, as pyulog reads the file;
    vel_n/vel_e are the ground speed along the course."""
    stream: list = []
    for k, vd in enumerate([-1.5, None, 2.25]):
        t_s = 10.0 + k
        stream.append(ImuSample(t_s, [0.0, 0.0, -9.8], [0.0, 0.0, 0.0]))
        stream.append(GpsSample(t_s, 47.3977, 8.5456, 150.0, 20.0, math.pi / 6, 3, vd))
    path = tmp_path / "vd.ulg"
    write_ulog(path, FlightLog(stream=stream))
    gps = next(d for d in ULog(str(path)).data_list if d.name == "vehicle_gps_position").data
    assert list(gps["vel_ned_valid"]) == [1, 0, 1]
    np.testing.assert_allclose(gps["vel_d_m_s"], [-1.5, 0.0, 2.25])
    np.testing.assert_allclose(gps["vel_n_m_s"], 20.0 * math.cos(math.pi / 6), rtol=1e-6)
    np.testing.assert_allclose(gps["vel_e_m_s"], 10.0, rtol=1e-6)
    back = _of(read_ulog(path), GpsSample)
    assert [s.velocity_down_mps for s in back] == [-1.5, None, 2.25]
