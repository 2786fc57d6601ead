"""The sim's MAVLink stream over real UDP: rates, order, MAVLink 2, truth only in the tlog,
and the lock-step protocol with an acknowledging estimator stand-in."""

from __future__ import annotations

import json
import math
import select
import signal
import threading
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from udp_tools import DatagramSink, cli_process, parse_frames

from immukf_sitl.mavlink.codec import euler_to_quaternion
from immukf_sitl.mavlink.wire import (
    ESTIMATOR_COMPONENT_ID,
    MavConnection,
    connect,
    mavlink,
    open_tlog_reader,
)
from immukf_sitl.scenario import load_scenario
from immukf_sitl.stream_profile import StreamProfile
from sim.emitter import TRUTH_COMPONENT_ID, AckTimeout, LockStep, SimEmitter
from sim.profile_stream import ProfileStream
from sim.scenario_flight import flight_from_scenario

# flies JSBSim or the estimator chain
pytestmark = pytest.mark.slow

SCENARIO = Path(__file__).resolve().parents[1] / "scenarios" / "q_gyro_zeroed.yaml"
SIM_S = 3.0
STEPS = int(round(SIM_S / 0.01)) + 1  # step 0 .. 300


class Acknowledger:
    """An estimator stand-in: acknowledges each HIGHRES_IMU with SYSTEM_TIME, in a thread.

    Parameters
    ----------
    component : int
        Source component of the acknowledgements.
    ack_until_s : float
        Stop acknowledging after this sim time (keeps listening).
    """

    def __init__(self, component: int = ESTIMATOR_COMPONENT_ID, ack_until_s: float = math.inf):
        self.conn: MavConnection = connect("udpin:127.0.0.1:0", 1, component)
        self.port = int(self.conn.port.getsockname()[1])
        self.ack_until_s = ack_until_s
        self.imu_times_usec: list[int] = []
        self.types: Counter[str] = Counter()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            select.select([self.conn.fd], [], [], 0.05)
            while True:
                message = self.conn.recv_msg()
                if message is None:
                    break
                self.types[message.get_type()] += 1
                if message.get_type() == "HIGHRES_IMU":
                    self.imu_times_usec.append(message.time_usec)
                    if message.time_usec * 1e-6 <= self.ack_until_s:
                        self.conn.mav.system_time_send(0, message.time_usec // 1000)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.conn.close()


@pytest.fixture(scope="module")
def free_run(tmp_path_factory):
    """``immukf-sitl sim --free-run`` for 3 s of sim time into a listener, with a tlog."""
    tlog = tmp_path_factory.mktemp("sim") / "sim.tlog"
    sink = DatagramSink()
    try:
        args = ["sim", str(SCENARIO), "--free-run", "--duration", str(SIM_S), "--json"]
        args += ["--out", f"udpout:127.0.0.1:{sink.port}", "--tlog", str(tlog)]
        with cli_process(args) as sim:
            code, out, err = sim.finish(timeout_s=60)
        assert code == 0, err
        sink.wait_for(sum(json.loads(out)["sent"].values()), timeout_s=5.0)
        datagrams = list(sink.datagrams)
    finally:
        sink.close()
    return datagrams, tlog, json.loads(out), err


def test_free_run_rates_of_sim_time(free_run):
    datagrams, _, summary, err = free_run
    messages = parse_frames(datagrams)
    counts = Counter(m.get_type() for m in messages)
    # 3 s of sim time, steps 0..300: 100 Hz IMU and actuators, 1 Hz GPS and HEARTBEAT
    assert counts == {
        "HIGHRES_IMU": STEPS,
        "SERVO_OUTPUT_RAW": STEPS,
        "GPS_RAW_INT": 4,
        "HEARTBEAT": 4,
    }
    assert summary["sent"] == dict(counts) and summary["steps"] == STEPS
    assert summary["mode"] == "free-run" and summary["sim_time_s"] == pytest.approx(SIM_S)
    assert "sim: free-run: 301 steps" in err
    imu_times = [m.time_usec for m in messages if m.get_type() == "HIGHRES_IMU"]
    assert imu_times == [10_000 * k for k in range(STEPS)]
    gps_times = [m.time_usec for m in messages if m.get_type() == "GPS_RAW_INT"]
    assert gps_times == [0, 1_000_000, 2_000_000, 3_000_000]


def test_free_run_frames_are_mavlink2_in_step_order(free_run):
    datagrams, _, _, _ = free_run
    assert all(d[0] == 0xFD for d in datagrams)
    messages = parse_frames(datagrams)
    assert len(messages) == len(datagrams)  # one frame per datagram
    assert {(m.get_srcSystem(), m.get_srcComponent()) for m in messages} == {(1, 1)}
    assert [m.get_seq() for m in messages] == [k % 256 for k in range(len(messages))]
    order = [m.get_type() for m in messages[:8]]
    assert order == [
        "HEARTBEAT",
        "GPS_RAW_INT",
        "SERVO_OUTPUT_RAW",
        "HIGHRES_IMU",
        "SERVO_OUTPUT_RAW",
        "HIGHRES_IMU",
        "SERVO_OUTPUT_RAW",
        "HIGHRES_IMU",
    ]
    heartbeat = messages[0]
    assert heartbeat.type == mavlink.MAV_TYPE_FIXED_WING
    assert heartbeat.autopilot == mavlink.MAV_AUTOPILOT_INVALID
    imu = [m for m in messages if m.get_type() == "HIGHRES_IMU"]
    assert {m.fields_updated for m in imu} == {0x3F}


def test_truth_is_only_in_the_tlog(free_run):
    datagrams, tlog, summary, _ = free_run
    wire_types = {m.get_type() for m in parse_frames(datagrams)}
    assert "HIL_STATE_QUATERNION" not in wire_types
    reader = open_tlog_reader(str(tlog))
    logged = []
    while (message := reader.recv_match()) is not None:
        logged.append(message)
    assert logged[0].get_type() == "STATUSTEXT" and logged[0].text == "SCENARIO q-gyro-zeroed"
    truth = [m for m in logged if m.get_type() == "HIL_STATE_QUATERNION"]
    sent = [m for m in logged if m.get_srcComponent() == 1]
    wind = [m for m in logged if m.get_type() == "WIND_COV"]
    assert "WIND_COV" not in wire_types
    assert len(truth) == len(wind) == STEPS
    assert summary["tlog_records"] == len(logged) == len(sent) + 2 * STEPS + 1
    # every frame sent is in the log, byte for byte, in order
    assert [bytes(m.get_msgbuf()) for m in sent] == datagrams
    # one truth per step, with the step's time, after the step's frames
    assert [m.time_usec for m in truth] == [10_000 * k for k in range(STEPS)]
    position = {id(m): i for i, m in enumerate(logged)}
    imu = [m for m in sent if m.get_type() == "HIGHRES_IMU"]
    assert all(position[id(t)] == position[id(i)] + 1 for t, i in zip(truth, imu, strict=True))
    # truth frames have their own component and an unbroken sequence
    assert {(m.get_srcSystem(), m.get_srcComponent()) for m in truth} == {(1, TRUTH_COMPONENT_ID)}
    truth_stream = [m for m in logged if m.get_srcComponent() == TRUTH_COMPONENT_ID]
    assert [m.get_seq() for m in truth_stream] == [k % 256 for k in range(2 * STEPS + 1)]
    # each truth record is followed by the wind of the same step
    assert all(
        position[id(w)] == position[id(t)] + 1 and w.time_usec == t.time_usec
        for t, w in zip(truth, wind, strict=True)
    )
    # records are stamped with sim time: the step's time for the step's frames and truth
    step_time = 0.0
    for message in logged[1:]:
        if message.get_type() == "HIGHRES_IMU":
            step_time = message.time_usec * 1e-6
        if message.get_type() in ("HIGHRES_IMU", "HIL_STATE_QUATERNION", "WIND_COV"):
            assert message._timestamp == pytest.approx(step_time, abs=1e-6)
        else:
            assert step_time - 1e-6 <= message._timestamp <= step_time + 0.0100001


def test_the_stream_is_the_in_process_flight(free_run):
    """Same seed, same flight: the wire carries exactly the Flight's records."""
    datagrams, tlog, _, _ = free_run
    flight = flight_from_scenario(load_scenario(SCENARIO))
    records = [flight.start()] + [flight.step() for _ in range(STEPS - 1)]
    imu = [m for m in parse_frames(datagrams) if m.get_type() == "HIGHRES_IMU"]
    sent = np.array([[m.xacc, m.yacc, m.zacc, m.xgyro, m.ygyro, m.zgyro] for m in imu])
    expected = np.array([r.imu.as_array() for r in records], dtype=np.float32)
    assert np.array_equal(sent.astype(np.float32), expected)
    reader = open_tlog_reader(str(tlog))
    truth = []
    while (message := reader.recv_match(type="HIL_STATE_QUATERNION")) is not None:
        truth.append(message)
    for record, message in zip(records[::37], truth[::37], strict=True):
        t = record.truth
        q = euler_to_quaternion(np.asarray(t.euler_rad))
        assert np.allclose(message.attitude_quaternion, q, atol=1e-6)
        assert np.allclose(
            [message.rollspeed, message.pitchspeed, message.yawspeed], t.rates_body_radps
        )
        force = np.array([message.xacc, message.yacc, message.zacc]) * 9.80665e-3
        assert np.allclose(force, t.specific_force_body_mps2, atol=0.006)  # 1 mG resolution
        assert message.lat == round(t.lat_deg * 1e7) and message.alt == round(t.alt_m * 1e3)
        assert np.allclose([message.vx, message.vy, message.vz], t.velocity_ned_mps * 100, atol=0.6)
        assert message.true_airspeed == round(t.airspeed_mps * 100)


def test_step_encoder_servo_pwm_maps_back_to_the_controls():
    flight = flight_from_scenario(load_scenario(SCENARIO))
    record = flight.start()
    for _ in range(50):
        record = flight.step()
    encoder = ProfileStream(StreamProfile(), flight.params.actuators)
    sample = encoder.actuator_sample(record)
    assert len(sample.pwm_us) == 16
    back = flight.params.actuators.pwm_to_controls(sample.pwm_us)
    assert np.allclose(back[:3], record.controls[:3], atol=0.002)  # 1 us of PWM
    assert back[3] == pytest.approx(record.controls[3], abs=0.002)


def test_lockstep_window_bookkeeping():
    lock = LockStep(window_steps=10)
    assert all(lock.may_send(k) for k in range(10)) and not lock.may_send(10)
    lock.acknowledge(0)
    assert lock.may_send(10) and not lock.may_send(11)
    lock.acknowledge(2999)  # an estimator that truncates 3.0 s to 2999 ms
    assert lock.acked_step == 300 and lock.may_send(310) and not lock.may_send(311)
    lock.acknowledge(100)  # late duplicates never move it back
    assert lock.acked_step == 300
    with pytest.raises(ValueError, match="window_steps"):
        LockStep(window_steps=0)


def test_lockstep_delivers_every_step_in_order_to_an_acknowledger():
    acker = Acknowledger()
    try:
        args = ["sim", str(SCENARIO), "--duration", str(SIM_S), "--json"]
        args += ["--out", f"udpout:127.0.0.1:{acker.port}"]
        with cli_process(args) as sim:
            code, out, err = sim.finish(timeout_s=60)
        assert code == 0, err
        summary = json.loads(out)
    finally:
        acker.close()
    assert acker.imu_times_usec == [10_000 * k for k in range(STEPS)]  # none lost, in order
    assert "HIL_STATE_QUATERNION" not in acker.types
    assert summary["mode"] == "lockstep" and summary["acked_time_s"] == pytest.approx(SIM_S)
    assert summary["received"] == {"SYSTEM_TIME": STEPS}
    print(f"lock-step with a trivial acknowledger: {summary['steps_per_s']:.0f} steps/s")


@pytest.mark.parametrize(
    ("component", "ack_until_s", "expected_steps", "heard"),
    [
        (ESTIMATOR_COMPONENT_ID, 0.5, 61, r"last acknowledged sim time 0\.50 s"),
        (1, math.inf, 10, "none received"),  # acknowledgements from the wrong component
    ],
    ids=["estimator-stalls", "wrong-component"],
)
def test_lockstep_waits_for_acknowledgements_then_gives_up(
    component, ack_until_s, expected_steps, heard
):
    acker = Acknowledger(component=component, ack_until_s=ack_until_s)
    connection = connect(f"udpout:127.0.0.1:{acker.port}", 1, 1, input_=False)
    flight = flight_from_scenario(load_scenario(SCENARIO))
    emitter = SimEmitter(
        flight, connection, steps=300, ack_timeout_s=0.5, window_steps=10, progress_period_s=0
    )
    started = time.monotonic()
    try:
        with pytest.raises(AckTimeout, match=rf"for 0\.5 s at sim time .*{heard}.*--free-run"):
            emitter.run()
        elapsed = time.monotonic() - started
        time.sleep(0.1)  # let the last datagrams arrive
    finally:
        acker.close()
        connection.close()
    # exactly W steps beyond the last acknowledged one went out, then the sim waited
    assert len(acker.imu_times_usec) == expected_steps
    assert elapsed < 5.0


def test_a_signal_stops_the_run_after_the_current_step():
    class StopAfterFiveSteps(SimEmitter):
        def _send(self, record):
            super()._send(record)
            if record.step == 4:
                self.stop_signal = signal.SIGINT

    sink = DatagramSink()
    connection = connect(f"udpout:127.0.0.1:{sink.port}", 1, 1, input_=False)
    flight = flight_from_scenario(load_scenario(SCENARIO))
    try:
        emitter = StopAfterFiveSteps(
            flight, connection, steps=300, mode="free-run", progress_period_s=0
        )
        summary = emitter.run()
    finally:
        connection.close()
        sink.close()
    assert summary.stopped_by == "SIGINT" and summary.steps == 5
    assert summary.sim_time_s == pytest.approx(0.04)
    assert summary.sent == {
        "HEARTBEAT": 1,
        "GPS_RAW_INT": 1,
        "SERVO_OUTPUT_RAW": 5,
        "HIGHRES_IMU": 5,
    }
