"""Autopilot logs and streams in: every IMU message, any format, the refusals in one line.

The recorded flight ``q_gyro_zeroed.tlog`` (the sim's twin, q gyro reading zero from 30 s) is
re-written the ways ArduPilot and PX4 send and log it: RAW_IMU/SCALED_IMU2 in mG and mrad/s,
telemetry rates, DataFlash and ULog. The answers are checked against the native replay of the
same flight (the same detection), against the formats' own readers, and against a real
third-party PX4 log (``tests/data/THIRD_PARTY.md``).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from flights import thinned

from immukf_sitl.errors import UserError
from immukf_sitl.experiments.replay import replay, summary_of
from immukf_sitl.logs.dataflash import write_dataflash
from immukf_sitl.logs.reader import check_replayable, imu_rate_hz, read_log
from immukf_sitl.logs.ulog import write_ulog
from immukf_sitl.mavlink import codec
from immukf_sitl.mavlink.flightlog import FlightLog, read_flight_log
from immukf_sitl.mavlink.tlog import TlogWriter
from immukf_sitl.mavlink.wire import mavlink
from immukf_sitl.options import FilterOptions
from immukf_sitl.samples import ActuatorSample, GpsSample, ImuSample

DATA = Path(__file__).parent / "data"
FLIGHT = DATA / "q_gyro_zeroed.tlog"
PX4_QUAD = DATA / "px4_multicopter_pyulog_sample.ulg"


@pytest.fixture(scope="module")
def flight() -> FlightLog:
    return read_flight_log(FLIGHT)


def _detections(log: FlightLog) -> list[tuple[str, float]]:
    pipeline = FilterOptions().pipeline()
    summary = summary_of(replay(log, pipeline), "x").to_json()
    return [(d["mode"], round(d["t_s"], 2)) for d in summary["detections"]]


def _write_ardupilot_tlog(
    path: Path, log: FlightLog, imu_hz: float, servo_hz: float, mav_type: int
) -> None:
    """The flight as an ArduPilot telemetry tlog: RAW_IMU and SCALED_IMU2 at ``imu_hz``,
    SERVO_OUTPUT_RAW at ``servo_hz``, GPS_RAW_INT, the vehicle's and a ground station's
    HEARTBEAT, the firmware STATUSTEXT and ArduPilot's own messages (AHRS2, HWSTATUS)."""
    vehicle = mavlink.MAVLink(None, 1, 1)
    gcs = mavlink.MAVLink(None, 255, 190)
    stream = thinned(log.stream, ImuSample, 1.0 / imu_hz)
    stream = thinned(stream, ActuatorSample, 1.0 / servo_hz)
    with TlogWriter(path) as tlog:

        def put(mav: mavlink.MAVLink, msg: mavlink.MAVLink_message, t_s: float) -> None:
            tlog.write(msg.pack(mav), t_s)

        put(vehicle, mavlink.MAVLink_statustext_message(6, b"ArduPlane V3.8.5 (2bf1c4d3)"), 0.0)
        last_beat = -1.0
        for sample in stream:
            t_s = sample.time_s
            if t_s - last_beat >= 1.0:
                last_beat = t_s
                beat = mavlink.MAVLink_heartbeat_message(mav_type, 3, 0, 0, 4, 3)
                put(vehicle, beat, t_s)
                put(gcs, mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3), t_s)
                put(vehicle, mavlink.MAVLink_hwstatus_message(5000, 0), t_s)
            if isinstance(sample, ImuSample):
                put(vehicle, codec.imu_message("RAW_IMU", sample), t_s)
                put(vehicle, codec.imu_message("SCALED_IMU2", sample), t_s)
                put(vehicle, mavlink.MAVLink_ahrs2_message(0, 0, 0, 0, 0, 0), t_s)
            elif isinstance(sample, GpsSample):
                put(vehicle, codec.gps_raw_int_message(sample), t_s)
            else:
                put(vehicle, codec.servo_output_raw_message(sample), t_s)


def _replay_cli(path: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "immukf_sitl.cli", "replay", str(path), *args],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip


def test_the_flight_replays_the_same_from_a_tlog_a_dataflash_bin_and_a_ulog(flight, tmp_path):
    native = _detections(flight)
    assert native and native[0][0] == "q" and 30.0 < native[0][1] < 31.0
    write_dataflash(tmp_path / "flight.bin", flight)
    write_ulog(tmp_path / "flight.ulg", flight)
    for name, kind in (("flight.bin", "dataflash"), ("flight.ulg", "ulog")):
        log = read_log(tmp_path / name)
        assert log.kind == kind and log.vehicle == "fixed-wing"
        assert [f.spec() for f in log.faults] == [f.spec() for f in flight.faults]
        assert _detections(log) == native, name


def test_a_telemetry_tlog_of_an_arduplane_reads_whole_and_is_refused_for_its_rate(flight, tmp_path):
    path = tmp_path / "mission_planner.tlog"
    _write_ardupilot_tlog(path, flight, imu_hz=3.6, servo_hz=3.3, mav_type=1)
    log = read_log(path)
    assert log.bad_records == 0  # every record is readable: AHRS2, HWSTATUS are ArduPilot's
    assert log.vehicle == "fixed-wing" and log.vehicle_evidence == "HEARTBEAT type FIXED_WING"
    assert set(log.imu_sources) == {"RAW_IMU id 0", "SCALED_IMU2"}
    assert log.imu_source == "RAW_IMU id 0"
    assert imu_rate_hz(log) == pytest.approx(1.0 / 0.28, rel=0.05)
    out = _replay_cli(path)
    assert out.returncode == 2 and "Traceback" not in out.stderr
    line = out.stderr.strip().splitlines()[-1]
    assert "RAW_IMU id 0 at 3.6 Hz: detection needs at least 20 Hz" in line
    assert "SRn_RAW_SENS" in line and "bad" not in line


def test_an_arduplane_companion_stream_at_50_hz_identifies_the_fault(flight, tmp_path):
    """RAW_IMU at 50 Hz in mG and mrad/s (ArduPilot's SRn_RAW_SENS 50), servo at 100 Hz: the
    same q fault, within 0.1 s of the native 100 Hz stream's detection."""
    path = tmp_path / "companion.tlog"
    _write_ardupilot_tlog(path, flight, imu_hz=50.0, servo_hz=100.0, mav_type=1)
    log = read_log(path)
    check_replayable(log, path, 20.0)
    found = _detections(log)
    native = _detections(flight)
    assert [m for m, _ in found] == ["q"]
    assert abs(found[0][1] - native[0][1]) <= 0.1
    second = read_log(path, imu=1)
    assert second.imu_source == "SCALED_IMU2"
    with pytest.raises(UserError, match=r"no IMU instance 2 \(there is RAW_IMU id 0, SCALED_IMU2"):
        read_log(path, imu=2)


def test_a_multicopter_is_refused_in_one_line_from_each_kind_of_log(flight, tmp_path):
    copter_tlog = tmp_path / "copter.tlog"
    _write_ardupilot_tlog(copter_tlog, flight, imu_hz=50.0, servo_hz=10.0, mav_type=2)
    copter_bin = tmp_path / "copter.bin"
    write_dataflash(copter_bin, flight, firmware="ArduCopter V4.5.7 (2a3dc4b7)")
    cases = {
        copter_tlog: "HEARTBEAT type QUADROTOR",
        copter_bin: 'firmware "ArduCopter V4.5.7',
        PX4_QUAD: "vehicle_status system_type 2",  # a real PX4 log (tests/data/THIRD_PARTY.md)
    }
    for path, evidence in cases.items():
        out = _replay_cli(path)
        assert out.returncode == 2 and "Traceback" not in out.stderr, path
        line = out.stderr.strip().splitlines()[-1]
        assert "this is a multicopter log" in line and evidence in line, line
        assert line.endswith("this tool models fixed-wing aircraft")


def test_a_log_without_servo_outputs_names_what_is_missing_in_its_format(flight, tmp_path):
    no_servo = FlightLog(
        stream=[s for s in flight.stream if not isinstance(s, ActuatorSample)],
        faults=flight.faults,
    )
    write_dataflash(tmp_path / "no_servo.bin", no_servo)
    write_ulog(tmp_path / "no_servo.ulg", no_servo)
    expected = {"no_servo.bin": "no RCOU record", "no_servo.ulg": "no actuator_outputs topic"}
    for name, words in expected.items():
        with pytest.raises(UserError, match=words):
            check_replayable(read_log(tmp_path / name), tmp_path / name, 20.0)
    out = _replay_cli(tmp_path / "no_servo.bin")
    assert out.returncode == 2 and "Traceback" not in out.stderr


def test_a_file_that_is_no_flight_log_is_said_so(tmp_path):
    junk = tmp_path / "notes.tlog"
    junk.write_bytes(np.random.default_rng(3).bytes(4096))
    out = _replay_cli(junk)
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert "not a flight log" in out.stderr


def test_an_airframe_heavier_than_the_default_warms_up_on_its_own_trim():
    """A 33 kg Aerosonde (3x the default) has no steady flight at 25 m/s within its control
    limits: the warm-up trims it where it has one, a true equilibrium, and never raises."""
    import dataclasses

    from immukf_sitl.models.aero import AeroModel
    from immukf_sitl.models.earth import NedOrigin
    from immukf_sitl.models.params import load_aircraft_params
    from immukf_sitl.service.pipeline import EstimatorPipeline, _warm_up_state

    params = load_aircraft_params()
    heavy = dataclasses.replace(params, mass=dataclasses.replace(params.mass, mass_kg=33.0))
    model = AeroModel(heavy, NedOrigin(0.0, 0.0, 100.0))
    with pytest.raises(RuntimeError):
        model.trim(25.0)
    x0, u0 = _warm_up_state(model)
    airspeed_mps = float(np.linalg.norm(x0[3:6]))
    assert airspeed_mps > 25.0  # heavier: trims faster
    derivatives = model.derivatives(0.0, x0, u0)
    assert np.max(np.abs(derivatives[3:6])) < 1e-5 and np.max(np.abs(derivatives[9:12])) < 1e-5
    EstimatorPipeline(heavy).warm_up()
