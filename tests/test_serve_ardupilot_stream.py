"""``serve`` on the streams ArduPilot sends a companion computer, over real UDP.

JSBSim flies the default plan; its IMU goes out as ArduPilot sends it (RAW_IMU for the first
IMU and SCALED_IMU2 for the second, in mG and mrad/s, at the ``SRn_RAW_SENS`` rate), with
SERVO_OUTPUT_RAW at 25 Hz and GPS_RAW_INT at the sim's 5 Hz. The z accelerometer of the first
IMU reads zero from 5 s.
"""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from immukf_sitl.experiments.run import free_udp_ports, spawn_cli
from immukf_sitl.mavlink import codec, serve
from immukf_sitl.mavlink.wire import connect
from immukf_sitl.models.params import load_aircraft_params
from immukf_sitl.samples import ActuatorSample, GpsSample, ImuSample
from sim.flight import fly
from sim.flight_plans import default_flight_plan

pytestmark = pytest.mark.slow

FAULT_AT_S = 5.0


def _drain(conn, into: list) -> None:
    while (msg := conn.recv_msg()) is not None:
        into.append(msg)


def _serve_ardupilot_stream(imu_hz: float, duration_s: float, args: list[str]) -> tuple:
    """Fly ``duration_s`` into a serve process lock-step; its summary and what the GCS heard."""
    p_in, p_gcs = free_udp_ports(2)
    gcs = connect(f"udpin:127.0.0.1:{p_gcs}", 255, 190)
    child = spawn_cli(
        "serve",
        ["serve", "--in", f"udpin:127.0.0.1:{p_in}", "--out", f"udpout:127.0.0.1:{p_gcs}",
         "--settle", "1.0", "--idle-exit", "1.5", "--json", "--stats-interval", "0", *args],
    )  # fmt: skip
    sim = connect(f"udpout:127.0.0.1:{p_in}", 1, 1)
    params = load_aircraft_params()
    rng = np.random.default_rng(5)
    received, acks = [], []
    imu_every = int(round(100.0 / imu_hz))
    try:
        child.wait_ready(serve.READY, 120.0, busy=serve.WARMING_UP, busy_timeout_s=900.0)
        deadline = time.monotonic() + 120
        for rec in fly(default_flight_plan(), seed=12, duration_s=duration_s):
            t = rec.time_s
            if rec.gps is not None:
                g = rec.gps
                fix = GpsSample(t, g.lat_deg, g.lon_deg, g.alt_m, g.ground_speed_mps, g.course_rad)
                sim.mav.send(codec.gps_raw_int_message(fix))
            if rec.step % 4 == 0:  # 25 Hz
                pwm = params.actuators.controls_to_pwm(rec.controls)
                channels = tuple(pwm.get(c, 0) for c in range(1, 17))
                sim.mav.send(codec.servo_output_raw_message(ActuatorSample(t, channels)))
            if rec.step % imu_every:
                continue
            imu = rec.imu.as_array().copy()
            healthy = ImuSample(t, imu[:3], imu[3:])
            if t >= FAULT_AT_S:
                imu[2] = 0.0245 * rng.standard_normal()
            # ArduPilot's RAW_SENSORS group: RAW_IMU first, then SCALED_IMU2
            sim.mav.send(codec.imu_message("RAW_IMU", ImuSample(t, imu[:3], imu[3:])))
            sim.mav.send(codec.imu_message("SCALED_IMU2", healthy))
            while time.monotonic() < deadline:  # lock-step: within 0.1 s of the last ack
                _drain(sim, acks)
                _drain(gcs, received)
                done = [m.time_boot_ms for m in acks if m.get_type() == "SYSTEM_TIME"]
                if done and done[-1] >= int(round((t - 0.1) * 1000)):
                    break
                time.sleep(0.0005)
        time.sleep(0.5)
        _drain(gcs, received)
        out = child.stop(timeout_s=20)
    finally:
        if child.proc.poll() is None:
            child.proc.kill()
    assert child.proc.returncode == 0, "\n".join(child.lines)
    return json.loads(out), received


def test_raw_imu_at_50_hz_is_followed_and_its_fault_identified():
    summary, received = _serve_ardupilot_stream(50.0, 8.0, [])
    assert summary["imu_source"] == "RAW_IMU id 0"
    assert set(summary["imu_sources"]) == {"RAW_IMU id 0", "SCALED_IMU2"}
    assert summary["imu_rate_hz"] == pytest.approx(50.0, rel=0.02)
    assert summary["servo_rate_hz"] == pytest.approx(25.0, rel=0.02)
    detections = [e for e in summary["events"] if e["kind"] == "detected"]
    assert [e["mode"] for e in detections] == ["z"]
    assert FAULT_AT_S <= detections[0]["t_s"] <= FAULT_AT_S + 1.0
    assert summary["counters"]["stale_actuator_steps"] == 0  # 40 ms servo: fresh at 3 intervals


def test_the_second_imu_is_followed_on_request_and_has_no_fault():
    summary, _ = _serve_ardupilot_stream(50.0, 8.0, ["--imu", "1"])
    assert summary["imu_source"] == "SCALED_IMU2"
    assert [e for e in summary["events"] if e["kind"] == "detected"] == []


def test_a_telemetry_rate_imu_is_said_once_as_statustext_and_estimated():
    summary, received = _serve_ardupilot_stream(5.0, 6.0, [])
    texts = [m.text for m in received if m.get_type() == "STATUSTEXT"]
    slow = [t for t in texts if "detection needs" in t]
    assert len(slow) == 1, texts
    assert slow[0].startswith("IMM: RAW_IMU id 0 at 5.0 Hz")
    assert summary["counters"]["slow_imu_steps"] > 0 and summary["aligned"]
    assert [e for e in summary["events"] if e["kind"] == "detected"] == []
