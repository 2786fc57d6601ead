"""The fault proxy: the pure FaultInjector (every kind, statistics of the zero fault), the
re-packed HIGHRES_IMU, robustness to garbage, its tlog, and the UDP shell over real sockets
(alone, and in the lock-step chain sim -> proxy -> estimator stand-in)."""

from __future__ import annotations

import json
import math
import signal
import socket
import time
from pathlib import Path

import numpy as np
import pytest
from scipy import stats
from test_sim_emitter import Acknowledger
from udp_tools import DatagramSink, bound_socket, cli_process, free_udp_port, parse_frames

from immukf_sitl.errors import UserError
from immukf_sitl.experiments.observability import fault_deviation
from immukf_sitl.mavlink import codec
from immukf_sitl.mavlink.codec import repack_imu
from immukf_sitl.mavlink.tlog import TlogWriter
from immukf_sitl.mavlink.wire import ESTIMATOR_COMPONENT_ID, mavlink, open_tlog_reader
from immukf_sitl.models.sensors import ImuSpec
from immukf_sitl.samples import ImuSample
from immukf_sitl.scenario import FaultSpec, check_fault_imus, load_scenario
from sim.fault_proxy import FaultInjector, FaultProxy, fault_rng
from sim.scenario_flight import flight_from_scenario

REPO = Path(__file__).resolve().parents[1]
NOISE = ImuSpec()
BASE = np.array([0.5, 0.02, -9.8, 0.1, 0.2, -0.3])


def sample(t_s: float, values: np.ndarray = BASE) -> ImuSample:
    return ImuSample(t_s, values[:3], values[3:])


def injector(*faults: FaultSpec, seed: int = 5) -> FaultInjector:
    return FaultInjector(faults, NOISE, fault_rng(seed))


def chi2_bounds(n: int, sigma: float, p: float = 1e-4) -> tuple[float, float]:
    """Two-sided bounds of the sample standard deviation of n normal samples."""
    lo = stats.chi2.ppf(p / 2, n - 1)
    hi = stats.chi2.ppf(1 - p / 2, n - 1)
    return sigma * math.sqrt(lo / (n - 1)), sigma * math.sqrt(hi / (n - 1))


# -- FaultInjector -------------------------------------------------------------------------------


def test_zero_is_the_sensors_white_noise_and_leaves_other_channels_alone():
    inj = injector(FaultSpec(t_s=1.0, channels=("x", "q"), kind="zero"))
    before = sample(0.99)
    assert inj.apply(before) is before  # untouched before t_s
    n = 20000
    out = np.array([inj.apply(sample(1.0 + 0.01 * k)).as_array() for k in range(n)])
    for channel, sigma in ((0, NOISE.accel_sigma_mps2), (4, NOISE.gyro_sigma_radps)):
        lo, hi = chi2_bounds(n, sigma)
        assert lo < out[:, channel].std(ddof=1) < hi
        assert abs(out[:, channel].mean()) < 4 * sigma / math.sqrt(n)
    untouched = [1, 2, 3, 5]
    assert np.array_equal(out[:, untouched], np.tile(BASE[untouched], (n, 1)))


def test_stuck_holds_the_value_at_onset():
    inj = injector(FaultSpec(t_s=1.0, channels=("p",), kind="stuck"))
    ramp = [BASE + 0.1 * k for k in range(5)]
    out = [inj.apply(sample(0.98 + 0.01 * k, v)).as_array() for k, v in enumerate(ramp)]
    assert out[0][3] == ramp[0][3] and out[1][3] == ramp[1][3]  # before 1.0
    assert [o[3] for o in out[2:]] == [ramp[2][3]] * 3  # held from the first faulty sample
    assert [o[4] for o in out] == [v[4] for v in ramp]  # q follows the truth


def test_bias_adds_and_drift_ramps():
    inj = injector(
        FaultSpec(t_s=2.0, channels=("z",), kind="bias", value=0.3),
        FaultSpec(t_s=2.0, channels=("r",), kind="drift", value=0.01),
    )
    out = inj.apply(sample(4.0)).as_array()
    assert out[2] == pytest.approx(BASE[2] + 0.3)
    assert out[5] == pytest.approx(BASE[5] + 0.01 * 2.0)
    assert np.array_equal(out[[0, 1, 3, 4]], BASE[[0, 1, 3, 4]])


def test_scale_multiplies_the_reading():
    inj = injector(FaultSpec(t_s=1.0, channels=("x", "p"), kind="scale", value=-0.5))
    out = inj.apply(sample(1.0)).as_array()
    assert out[[0, 3]] == pytest.approx(-0.5 * BASE[[0, 3]])
    assert np.array_equal(out[[1, 2, 4, 5]], BASE[[1, 2, 4, 5]])


def test_noise_makes_the_readings_spread_value_times_the_sensors():
    """The healthy reading already holds one sigma of noise: the proxy adds the rest in
    quadrature, so a noisy healthy stream through it has ``value * sigma``."""
    factor, n = 4.0, 20000
    inj = injector(FaultSpec(t_s=0.0, channels=("r",), kind="noise", value=factor))
    rng = np.random.default_rng(11)
    sigma = NOISE.gyro_sigma_radps
    healthy = BASE[5] + sigma * rng.standard_normal(n)
    out = np.array(
        [inj.apply(sample(0.01 * k, np.r_[BASE[:5], healthy[k]])).gyro_radps[2] for k in range(n)]
    )
    lo, hi = chi2_bounds(n, factor * sigma)
    assert lo < out.std(ddof=1) < hi
    assert abs(out.mean() - BASE[5]) < 4 * factor * sigma / math.sqrt(n)


def test_spikes_come_at_their_rate_with_both_signs_and_the_truth_tools_see_the_same_ones():
    fault = FaultSpec(t_s=2.0, channels=("q",), kind="spikes", value=0.4, rate_hz=3.0)
    inj = injector(fault)
    times = 0.01 * np.arange(60001)  # 600 s at 100 Hz
    out = np.array([inj.apply(sample(t)).gyro_radps[1] for t in times]) - BASE[4]
    hits = out[np.abs(out) > 1e-12]
    count = hits.size
    expected = 3.0 * (times[-1] - 2.0)
    assert stats.poisson.ppf(1e-4, expected) < count < stats.poisson.ppf(1 - 1e-4, expected)
    assert set(np.round(np.abs(hits), 9)) <= {0.4, 0.8}  # two in one 10 ms sample: rare
    assert stats.binomtest(int(np.sum(hits > 0)), count).pvalue > 1e-4
    assert not np.any(out[times < 2.0])
    truth = np.tile(BASE[4], times.size)
    assert np.allclose(fault_deviation(fault, times, truth), out, atol=1e-12)


def test_the_sensor_recovers_at_end_t_s():
    inj = injector(FaultSpec(t_s=1.0, channels=("y",), kind="zero", end_t_s=2.0))
    assert inj.apply(sample(1.5)).as_array()[1] != BASE[1]
    recovered = sample(2.0)
    assert inj.apply(recovered) is recovered
    assert inj.active(1.5) and not inj.active(2.0)


def test_faults_apply_in_file_order():
    bias_then_zero = injector(
        FaultSpec(t_s=0.0, channels=("q",), kind="bias", value=1.0),
        FaultSpec(t_s=0.0, channels=("q",), kind="zero"),
    )
    zero_then_bias = injector(
        FaultSpec(t_s=0.0, channels=("q",), kind="zero"),
        FaultSpec(t_s=0.0, channels=("q",), kind="bias", value=1.0),
    )
    assert abs(bias_then_zero.apply(sample(1.0)).gyro_radps[1]) < 0.02
    assert abs(zero_then_bias.apply(sample(1.0)).gyro_radps[1] - 1.0) < 0.02


def test_same_seed_same_faults_and_a_stream_of_its_own():
    fault = FaultSpec(t_s=0.0, channels=("p", "q", "r"), kind="zero")
    a, b = injector(fault, seed=9), injector(fault, seed=9)
    out_a = [a.apply(sample(0.01 * k)).as_array() for k in range(50)]
    out_b = [b.apply(sample(0.01 * k)).as_array() for k in range(50)]
    assert np.array_equal(out_a, out_b)
    # independent of the sim's IMU and GPS streams (children 0 and 1 of the same seed)
    draws = fault_rng(9).standard_normal(6)
    for child in np.random.SeedSequence(9).spawn(2):
        assert not np.allclose(draws, np.random.default_rng(child).standard_normal(6))
    scenario = load_scenario(REPO / "scenarios" / "q_gyro_zeroed.yaml")
    assert FaultInjector.from_scenario(scenario).faults == scenario.faults


# -- the re-packed message and the datagram transform --------------------------------------------


def imu_frame(t_s: float, seq: int = 77, fields: int = 0x3F, mavlink1: bool = False) -> bytes:
    message = codec.highres_imu_message(sample(t_s))
    message.fields_updated = fields
    encoder = mavlink.MAVLink(None, 1, 1)
    encoder.seq = seq
    return bytes(message.pack(encoder, force_mavlink1=mavlink1))


def parse_one(frame: bytes):
    parser = mavlink.MAVLink(None)
    (message,) = parser.parse_buffer(frame)
    return message


@pytest.mark.parametrize("mavlink1", [False, True], ids=["mavlink2", "mavlink1"])
def test_repacked_imu_keeps_everything_but_the_faulted_channels(mavlink1):
    original = parse_one(imu_frame(1.5, seq=201, fields=0x1FFF, mavlink1=mavlink1))
    faulted = sample(1.5, BASE * np.array([1, 1, 1, 1, 0, 1]))
    frame = repack_imu(original, faulted)
    assert frame[0] == (0xFE if mavlink1 else 0xFD)
    message = parse_one(frame)
    assert message.get_seq() == 201
    assert (message.get_srcSystem(), message.get_srcComponent()) == (1, 1)
    assert message.fields_updated == 0x1FFF  # never cleared: that would hand over the answer
    assert message.time_usec == original.time_usec and message.ygyro == 0.0
    for name in ("xacc", "yacc", "zacc", "xgyro", "zgyro", "id"):
        assert getattr(message, name) == getattr(original, name)


def test_transform_never_crashes_and_counts_bad_datagrams():
    proxy = FaultProxy(injector(FaultSpec(t_s=1.0, channels=("q",))), None, None)
    garbage = b"\xfd\x05garbage that is not MAVLink"
    assert proxy.transform(garbage) == garbage
    truncated = imu_frame(2.0)[:20]
    assert proxy.transform(truncated) == truncated
    nan_imu = codec.highres_imu_message(sample(2.0))
    nan_imu.xacc = float("nan")
    nan_frame = bytes(nan_imu.pack(mavlink.MAVLink(None, 1, 1)))
    assert proxy.transform(nan_frame) == nan_frame  # unusable: forwarded, the estimator counts it
    assert proxy.transform(b"") == b""
    assert proxy.stats.bad == 3 and proxy.stats.modified == 0
    heartbeat = bytes(
        mavlink.MAVLink_heartbeat_message(1, 8, 0, 0, 4, 3).pack(mavlink.MAVLink(None, 1, 1))
    )
    early, late = imu_frame(0.5, seq=3), imu_frame(1.5, seq=4)
    assert proxy.transform(heartbeat + early) == heartbeat + early
    out = proxy.transform(heartbeat + late + heartbeat)
    assert (
        out.startswith(heartbeat)
        and out.endswith(heartbeat)
        and out != heartbeat + late + heartbeat
    )
    messages = parse_frames([out])
    assert [m.get_type() for m in messages] == ["HEARTBEAT", "HIGHRES_IMU", "HEARTBEAT"]
    assert messages[1].get_seq() == 4 and abs(messages[1].ygyro) < 5 * NOISE.gyro_sigma_radps
    assert proxy.stats.modified == 1 and proxy.stats.bad == 3


def test_tlog_records_the_forwarded_stream_and_annotates_faults(tmp_path):
    path = tmp_path / "proxy.tlog"
    fault = FaultSpec(t_s=1.0, channels=("q", "r"), kind="zero", end_t_s=1.02)
    with TlogWriter(path) as tlog:
        proxy = FaultProxy(injector(fault), None, None, tlog=tlog, scenario_name="demo")
        forwarded = [
            proxy.transform(imu_frame(t, seq=k)) for k, t in enumerate([0.99, 1.0, 1.01, 1.02])
        ]
    reader = open_tlog_reader(str(path))
    logged = []
    while (message := reader.recv_match()) is not None:
        logged.append(message)
    texts = [(m._timestamp, m.text) for m in logged if m.get_type() == "STATUSTEXT"]
    assert texts == [
        (0.0, "SCENARIO demo"),
        (pytest.approx(1.0), "FAULT zero q+r t=1.000"),
        (pytest.approx(1.02), "FAULT END zero q+r t=1.020"),
    ]
    imu = [m for m in logged if m.get_type() == "HIGHRES_IMU"]
    assert [bytes(m.get_msgbuf()) for m in imu] == forwarded
    assert [m._timestamp for m in imu] == pytest.approx([0.99, 1.0, 1.01, 1.02])
    assert {m.get_srcComponent() for m in logged if m.get_type() == "STATUSTEXT"} == {195}


# -- over UDP --------------------------------------------------------------------------------------


def scenario_file(tmp_path: Path, fault_t_s: float) -> Path:
    text = (REPO / "scenarios" / "q_gyro_zeroed.yaml").read_text(encoding="utf-8")
    text = text.replace("{t_s: 30, channels: [q]", f"{{t_s: {fault_t_s}, channels: [q]")
    path = tmp_path / "q_early.yaml"
    path.write_text(text, encoding="utf-8")
    assert load_scenario(path).faults[0].t_s == fault_t_s
    return path


def recv_all(sock: socket.socket, count: int, timeout_s: float) -> list[bytes]:
    sock.settimeout(0.05)
    out: list[bytes] = []
    deadline = time.monotonic() + timeout_s
    while len(out) < count and time.monotonic() < deadline:
        try:
            out.append(sock.recv(65536))
        except TimeoutError:
            continue
    return out


@pytest.mark.slow
def test_proxy_over_udp_faults_only_imu_after_t_s_and_forwards_replies(tmp_path):
    scenario = scenario_file(tmp_path, 1.0)
    estimator = DatagramSink()
    sim_side = bound_socket()
    port = free_udp_port()
    sim_mav = mavlink.MAVLink(None, 1, 1)
    sent: list[bytes] = []
    try:
        args = ["proxy", str(scenario), "--in", f"udpin:127.0.0.1:{port}"]
        args += ["--out", f"udpout:127.0.0.1:{estimator.port}", "--json"]
        with cli_process(args) as proxy:
            proxy.read_line_starting("proxy:", timeout_s=30)
            for k in range(201):  # 0 .. 2 s, paced step by step: nothing can overflow
                t = 0.01 * k
                step = []
                if k % 100 == 0:
                    hb = mavlink.MAVLink_heartbeat_message(1, 8, 0, 0, 4, 3)
                    step.append(bytes(hb.pack(sim_mav)))
                    sim_mav.seq += 1
                servo = codec.servo_output_raw_message(codec.ActuatorSample(t, (1500,) * 4))
                step.append(bytes(servo.pack(sim_mav)))
                sim_mav.seq += 1
                step.append(bytes(codec.highres_imu_message(sample(t)).pack(sim_mav)))
                sim_mav.seq = (sim_mav.seq + 1) % 256
                if k == 150:
                    step.append(b"\x00\x01 not a MAVLink frame")
                for datagram in step:
                    sim_side.sendto(datagram, ("127.0.0.1", port))
                sent += step
                assert estimator.wait_for(len(sent), timeout_s=5.0)
            # replies of the estimator go back to the sim, byte for byte
            est_mav = mavlink.MAVLink(None, 1, ESTIMATOR_COMPONENT_ID)
            replies = []
            for k in range(5):
                reply = bytes(mavlink.MAVLink_system_time_message(0, 10 * k).pack(est_mav))
                est_mav.seq += 1
                estimator.sock.sendto(reply, estimator.peer)
                replies.append(reply)
            assert recv_all(sim_side, 5, timeout_s=5.0) == replies
            code, out, err = proxy.finish(timeout_s=15, signum=signal.SIGTERM)
        received = list(estimator.datagrams)
    finally:
        estimator.close()
        sim_side.close()
    assert code == 0, err
    assert len(received) == len(sent)
    modified = 0
    for before, after in zip(sent, received, strict=True):
        messages = parse_frames([before])
        if not (messages[0].get_type() == "HIGHRES_IMU" and messages[0].time_usec >= 1_000_000):
            assert after == before  # everything else, and the IMU before t_s: byte-identical
            continue
        modified += 1
        original, faulted = messages[0], parse_frames([after])[0]
        assert abs(faulted.ygyro) < 5 * NOISE.gyro_sigma_radps
        assert faulted.fields_updated == 0x3F and faulted.get_seq() == original.get_seq()
        for name in ("time_usec", "xacc", "yacc", "zacc", "xgyro", "zgyro"):
            assert getattr(faulted, name) == getattr(original, name)
    assert modified == 101  # 1.00 .. 2.00 s
    counts = json.loads(out)
    assert counts == {
        "forwarded": len(sent) + 5,
        "to_estimator": len(sent),
        "to_sim": 5,
        "modified": 101,
        "bad": 1,
    }
    assert "stopped by SIGTERM" in err and "modified 101 IMU messages" in err


@pytest.mark.slow
def test_lockstep_chain_through_the_proxy(tmp_path):
    """sim (lock-step) -> proxy -> estimator stand-in: acknowledgements flow back through the
    proxy, every step arrives in order, q is zeroed from t_s and nothing else changes."""
    scenario = scenario_file(tmp_path, 1.0)
    acker = Acknowledger()
    proxy_port = free_udp_port()
    try:
        proxy_args = ["proxy", str(scenario), "--in", f"udpin:127.0.0.1:{proxy_port}"]
        proxy_args += ["--out", f"udpout:127.0.0.1:{acker.port}", "--json"]
        sim_args = ["sim", str(scenario), "--duration", "3", "--json"]
        sim_args += ["--out", f"udpout:127.0.0.1:{proxy_port}"]
        with cli_process(proxy_args) as proxy:
            proxy.read_line_starting("proxy:", timeout_s=30)
            with cli_process(sim_args) as sim:
                sim_code, sim_out, sim_err = sim.finish(timeout_s=60)
            proxy_code, proxy_out, proxy_err = proxy.finish(timeout_s=15, signum=signal.SIGINT)
    finally:
        acker.close()
    assert sim_code == 0, sim_err
    assert proxy_code == 0, proxy_err
    summary, counts = json.loads(sim_out), json.loads(proxy_out)
    assert summary["acked_time_s"] == pytest.approx(3.0)
    assert acker.imu_times_usec == [10_000 * k for k in range(301)]
    assert "HIL_STATE_QUATERNION" not in acker.types
    assert counts["modified"] == 201 and counts["bad"] == 0  # steps 100 .. 300
    assert counts["to_sim"] == 301  # every acknowledgement went back through the proxy
    print(f"lock-step through the proxy: {summary['steps_per_s']:.0f} steps/s")


@pytest.mark.slow
def test_chain_imu_matches_the_flight_except_the_faulted_channel(tmp_path):
    """The q values the estimator stand-in received in the chain are noise after t_s; the
    other channels are the in-process flight's (checked on a captured stream)."""
    scenario_path = scenario_file(tmp_path, 1.0)
    scenario = load_scenario(scenario_path)
    flight = flight_from_scenario(scenario)
    records = [flight.start()] + [flight.step() for _ in range(200)]
    inj = FaultInjector.from_scenario(scenario)
    proxy = FaultProxy(inj, None, None)
    mav = mavlink.MAVLink(None, 1, 1)
    received = []
    for record in records:
        frame = bytes(codec.highres_imu_message(record.imu).pack(mav))
        mav.seq = (mav.seq + 1) % 256
        received.append(parse_frames([proxy.transform(frame)])[0])
    q = np.array([m.ygyro for m in received])
    true_q = np.array([r.imu.gyro_radps[1] for r in records], dtype=np.float32)
    assert np.array_equal(q[:100].astype(np.float32), true_q[:100])
    assert np.all(np.abs(q[100:]) < 5 * NOISE.gyro_sigma_radps)
    others = np.array([[m.xacc, m.yacc, m.zacc, m.xgyro, m.zgyro] for m in received])
    expected = np.array([r.imu.as_array()[[0, 1, 2, 3, 5]] for r in records], dtype=np.float32)
    assert np.array_equal(others.astype(np.float32), expected)


def test_transform_rewrites_every_faulted_frame_of_a_long_stream():
    """2000 frames through one proxy: each comes out rewritten (its cost is a benchmark's
    business, not a unit test's: a loaded CI machine made a timed assertion flaky)."""
    inj = injector(FaultSpec(t_s=0.0, channels=("q",)))
    proxy = FaultProxy(inj, None, None)
    frames = [imu_frame(0.01 * k, seq=k % 256) for k in range(2000)]
    out = [proxy.transform(frame) for frame in frames]
    assert proxy.stats.modified == len(frames)
    assert all(o != f for o, f in zip(out, frames, strict=True))


def test_a_fault_takes_one_imu_and_its_sibling_stays_healthy(tmp_path):
    """ArduPilot's two IMUs interleaved: a stuck fault of IMU 1 leaves RAW_IMU (IMU 0) alone."""
    fault = FaultSpec(t_s=1.0, channels=("q",), kind="stuck", imu=1)
    path = tmp_path / "proxy.tlog"
    with TlogWriter(path) as tlog:
        proxy = FaultProxy(injector(fault), None, None, tlog=tlog)
        encoder = mavlink.MAVLink(None, 1, 1)
        out = []
        for k in range(4):
            t_s, first, second = 0.99 + 0.01 * k, BASE + 0.01 * k, BASE - 0.02 * k
            for kind, values, instance in (("RAW_IMU", first, 0), ("SCALED_IMU2", second, 1)):
                message = codec.imu_message(kind, sample(t_s, values), instance)
                out.append(proxy.transform(bytes(message.pack(encoder))))
    decoded = [codec.decode_imu(m) for m in parse_frames(out)]
    raw, scaled = decoded[0::2], decoded[1::2]
    quantum = codec.MRAD_RADPS
    healthy_q = [BASE[4] + 0.01 * k for k in range(4)]
    assert [s.gyro_radps[1] for s in raw] == pytest.approx(healthy_q, abs=quantum)
    held = [s.gyro_radps[1] for s in scaled]
    assert held[1:] == [held[1]] * 3  # IMU 1's own value at onset, not IMU 0's
    assert held[1] == pytest.approx(BASE[4] - 0.02, abs=quantum)
    assert proxy.stats.modified == 3  # IMU 1's three samples from the onset
    reader = open_tlog_reader(str(path))
    texts = []
    while (message := reader.recv_match(type="STATUSTEXT")) is not None:
        texts.append(message.text)
    assert "FAULT stuck q t=1.000 i=1" in texts


def test_a_fault_on_an_imu_the_profile_does_not_send_is_a_one_line_error(tmp_path):
    text = (REPO / "scenarios" / "q_gyro_zeroed.yaml").read_text()
    path = tmp_path / "two.yaml"
    path.write_text(text.replace("kind: zero}", "kind: zero, imu: 1}"))
    with pytest.raises(UserError, match=r"faults\[0\]\.imu: 1, but the native profile sends "):
        check_fault_imus(load_scenario(path))
    path.write_text(text.replace("kind: zero}", "kind: zero, imu: 1}") + "profile: ardupilot\n")
    check_fault_imus(load_scenario(path))
    assert load_scenario(path).faults[0].imu == 1
