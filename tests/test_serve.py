"""``immukf-sitl serve`` over real UDP: acknowledgements, outputs, detection, robustness."""

import json
import math
import time

import numpy as np
import pytest

from immukf_sitl.errors import UserError
from immukf_sitl.experiments.run import free_udp_ports, spawn_cli
from immukf_sitl.mavlink import codec, serve
from immukf_sitl.mavlink.wire import connect, mavlink
from immukf_sitl.models.params import load_aircraft_params
from immukf_sitl.samples import ActuatorSample, GpsSample, ImuSample
from sim.flight import fly
from sim.flight_plans import default_flight_plan

# flies JSBSim or the estimator chain
pytestmark = pytest.mark.slow

FAULT_AT_S = 5.0
DURATION_S = 8.0


def _drain(conn, into):
    while True:
        msg = conn.recv_msg()
        if msg is None:
            return
        into.append(msg)


@pytest.fixture(scope="module")
def served():
    """Fly 8 s of JSBSim into a serve process lock-step, z accel zeroed at 5 s, plus junk."""
    p_in, p_gcs = free_udp_ports(2)
    gcs = connect(f"udpin:127.0.0.1:{p_gcs}", 255, 190)
    child = spawn_cli(
        "serve",
        ["serve", "--in", f"udpin:127.0.0.1:{p_in}", "--out", f"udpout:127.0.0.1:{p_gcs}",
         "--settle", "1.0", "--idle-exit", "1.5", "--json", "--stats-interval", "0"],
    )  # fmt: skip
    proc = child.proc
    sim = connect(f"udpout:127.0.0.1:{p_in}", 1, 1)
    params = load_aircraft_params()
    rng = np.random.default_rng(4)
    received, acks = [], []
    fix = None
    try:
        # bound, kernels compiled (patiently: a cold numba cache takes minutes under load)
        child.wait_ready(serve.READY, 120.0, busy=serve.WARMING_UP, busy_timeout_s=900.0)
        deadline = time.monotonic() + 120
        for rec in fly(default_flight_plan(), seed=11, duration_s=DURATION_S):
            t = rec.time_s
            if rec.gps is not None:
                g = rec.gps
                fix = GpsSample(t, g.lat_deg, g.lon_deg, g.alt_m, g.ground_speed_mps, g.course_rad)
                sim.mav.send(codec.gps_raw_int_message(fix))
            pwm = params.actuators.controls_to_pwm(rec.controls)
            servo = codec.servo_output_raw_message(
                ActuatorSample(t, tuple(pwm.get(c, 0) for c in range(1, 17))))  # fmt: skip
            sim.mav.send(servo)
            imu = rec.imu.as_array().copy()
            if t >= FAULT_AT_S:
                imu[2] = 0.0245 * rng.standard_normal()
            sim.mav.send(codec.highres_imu_message(ImuSample(t, imu[:3], imu[3:])))
            if rec.step == 200:  # junk: random bytes, a bad CRC, NaN fields, a duplicate
                sim.write(bytes(rng.integers(0, 256, 40, dtype=np.uint8)))
                frame = bytearray(codec.highres_imu_message(ImuSample(t, imu[:3], imu[3:]))
                                  .pack(mavlink.MAVLink(None, 1, 1)))  # fmt: skip
                frame[-3] ^= 0xFF
                sim.write(bytes(frame))
                sim.mav.send(codec.highres_imu_message(ImuSample(t, [math.nan, 0, 0], imu[3:])))
                sim.mav.send(codec.highres_imu_message(ImuSample(t, [1e30, 0, 0], imu[3:])))
                sim.mav.send(codec.highres_imu_message(ImuSample(t, imu[:3], imu[3:])))
                sim.mav.send(servo)  # a duplicate servo output and the last fix again
                sim.mav.send(codec.gps_raw_int_message(fix))
            # lock-step: stay within 10 steps of the last acknowledgement
            while time.monotonic() < deadline:
                _drain(sim, acks)
                _drain(gcs, received)
                done = [m.time_boot_ms for m in acks if m.get_type() == "SYSTEM_TIME"]
                if done and done[-1] >= int(round((t - 0.1) * 1000)):
                    break
                time.sleep(0.0005)
        time.sleep(0.5)
        _drain(gcs, received)
        _drain(sim, acks)
        out = child.stop(timeout_s=20)
        err = "\n".join(child.lines)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    return json.loads(out), received, acks, err


def test_every_imu_sample_is_acknowledged_with_its_time(served):
    _, _, acks, _ = served
    times = [m.time_boot_ms for m in acks if m.get_type() == "SYSTEM_TIME"]
    assert all(m.get_srcComponent() == 191 for m in acks)
    expected = int(round(DURATION_S * 100)) + 1
    assert len(set(times)) >= expected  # every step acknowledged (duplicates ack again)
    assert times[-1] == int(DURATION_S * 1000)


def test_z_accel_fault_is_detected_within_the_dwell(served):
    summary, received, _, _ = served
    detections = [e for e in summary["events"] if e["kind"] == "detected"]
    assert [e["mode"] for e in detections] == ["z"]
    assert FAULT_AT_S <= detections[0]["t_s"] <= FAULT_AT_S + 0.3
    texts = [m.text for m in received if m.get_type() == "STATUSTEXT"]
    assert any("z accel fault detected" in t for t in texts)
    fault_events = [m for m in received if m.get_type() == "NAMED_VALUE_INT"]
    assert fault_events and fault_events[0].name == "IMM_FAULT" and fault_events[0].value == 4


def test_published_messages_and_rates(served):
    _, received, _, _ = served
    kinds = {m.get_type() for m in received}
    assert {"HEARTBEAT", "ATTITUDE", "ATTITUDE_QUATERNION", "GLOBAL_POSITION_INT",
            "NAMED_VALUE_FLOAT"} <= kinds  # fmt: skip
    hb = [m for m in received if m.get_type() == "HEARTBEAT"][0]
    assert hb.type == mavlink.MAV_TYPE_ONBOARD_CONTROLLER and hb.get_srcComponent() == 191
    names = {m.name for m in received if m.get_type() == "NAMED_VALUE_FLOAT"}
    assert names == {"MP_NONE", "MP_AX", "MP_AY", "MP_AZ", "MP_P", "MP_Q", "MP_R"}
    att = [m for m in received if m.get_type() == "ATTITUDE"]
    span_s = (att[-1].time_boot_ms - att[0].time_boot_ms) / 1000
    assert len(att) / span_s == pytest.approx(50, rel=0.05)
    # the fused attitude is close to level flight and sane
    assert all(abs(m.roll) < 0.8 and abs(m.pitch) < 0.5 for m in att)
    # MAVLink 2 on the wire
    assert all(m.get_msgbuf()[0] == 0xFD for m in received)


def test_junk_is_counted_not_fatal(served):
    summary, _, _, err = served
    assert summary["bad_packets"] >= 1
    assert summary["decode_errors"] >= 2  # the NaN and the 1e30 HIGHRES_IMU
    assert summary["counters"]["out_of_order"] >= 1  # the duplicate
    assert summary["counters"]["actuator_out_of_order"] == 1
    assert summary["counters"]["gps_out_of_order"] == 1
    assert summary["received"].get("HIL_STATE_QUATERNION", 0) == 0
    assert summary["step_us"]["median"] > 0  # every fused sample was timed (speed: tools/)
    assert "Traceback" not in err


class _FakeProc:
    """A child that never exits and prints nothing more (its lines are set by the test)."""

    stderr: list = []

    def poll(self):
        return None


def _waiting_child(monkeypatch, ready_at_s: float | None):
    """A Child that printed serve's warming-up line; ``ready_at_s`` of a fake clock it is ready."""
    from immukf_sitl.experiments import processes

    clock = {"t": 0.0}
    child = processes.Child("serve", _FakeProc(), echo=False)
    child.lines.append(serve.WARMING_UP + ": imm (numba ...)")

    def sleep(dt):
        clock["t"] += 1.0
        if ready_at_s is not None and clock["t"] >= ready_at_s and len(child.lines) == 1:
            child.lines.append(serve.READY + ": imm on ...")

    monkeypatch.setattr(processes.time, "monotonic", lambda: clock["t"])
    monkeypatch.setattr(processes.time, "sleep", sleep)
    return child, clock


def test_a_serve_compiling_on_a_cold_cache_is_waited_for(monkeypatch, capsys):
    child, clock = _waiting_child(monkeypatch, ready_at_s=300.0)
    child.wait_ready(serve.READY, 120.0, busy=serve.WARMING_UP, busy_timeout_s=900.0)
    assert clock["t"] == 300.0
    assert "serve: still starting after 30 s" in capsys.readouterr().err


def test_a_serve_that_never_gets_ready_is_a_one_line_error(monkeypatch):
    child, clock = _waiting_child(monkeypatch, ready_at_s=None)
    with pytest.raises(UserError, match="did not report ready within 900 s.*warming up"):
        child.wait_ready(serve.READY, 120.0, busy=serve.WARMING_UP, busy_timeout_s=900.0)
    child, clock = _waiting_child(monkeypatch, ready_at_s=300.0)
    with pytest.raises(UserError, match="within 120 s"):  # without patience: the old failure
        child.wait_ready(serve.READY, 120.0)
