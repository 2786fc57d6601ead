"""MAVLink 2 signing: key files, pymavlink's checks classified, and the signed chain over UDP.

Over real UDP: a signed chain detects the q fault; an unsigned (and a wrong-key) sender
interleaving forged HIGHRES_IMU as system 1 component 1 changes nothing in the estimate; signed
frames replayed from the flight are rejected.
"""

from __future__ import annotations

import json
import os
import socket
import stat
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from flights import with_fault_at

from immukf_sitl.cli import main as cli_main
from immukf_sitl.errors import UserError
from immukf_sitl.experiments.processes import free_udp_ports, spawn_cli
from immukf_sitl.mavlink import codec
from immukf_sitl.mavlink.flightlog import read_estimator_log
from immukf_sitl.mavlink.serve import READY, WARMING_UP
from immukf_sitl.mavlink.signing import LinkSigning, load_key, write_key
from immukf_sitl.mavlink.wire import (
    ESTIMATOR_COMPONENT_ID,
    SIM_COMPONENT_ID,
    SIM_LINK_ID,
    SIM_SYSTEM_ID,
    connect,
    mavlink,
    open_tlog_reader,
)
from immukf_sitl.samples import ImuSample

REPO = Path(__file__).resolve().parents[1]
Q_SCENARIO = REPO / "scenarios" / "q_gyro_zeroed.yaml"
KEY = bytes(range(32))
OTHER_KEY = bytes(range(1, 33))


def _imu(t_s: float, q: float = 0.0) -> ImuSample:
    return ImuSample(t_s, [0.5, 0.0, -9.8], [0.0, q, 0.0])


# -- key files --------------------------------------------------------------------------------


def test_write_key_makes_an_owner_only_file_that_loads_back(tmp_path: Path) -> None:
    path = tmp_path / "k.key"
    key = write_key(path)
    assert len(key) == 32 and load_key(path) == key
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    assert path.read_text().strip() == key.hex()


@pytest.mark.parametrize(
    ("content", "match"),
    [
        (None, r"k\.key: no such file"),
        ("ab" * 31, r"k\.key: expected 64 hex characters \(a 32-byte key\), got 62"),
        ("zz" * 32, r"k\.key: expected hex characters 0-9, a-f only"),
        (b"\xff\xfe" * 32, r"k\.key: expected 64 hex characters, got binary"),
    ],
)
def test_bad_key_files_are_one_line_user_errors(tmp_path: Path, content, match) -> None:
    path = tmp_path / "k.key"
    if isinstance(content, bytes):
        path.write_bytes(content)
    elif content is not None:
        path.write_text(content)
    with pytest.raises(UserError, match=match):
        load_key(path)


@pytest.mark.parametrize("command", ["serve", "sim", "proxy", "run"])
def test_every_command_reports_a_bad_key_in_one_line(tmp_path: Path, command, capsys) -> None:
    bad = tmp_path / "short.key"
    bad.write_text("abcd\n")
    argv = {
        "serve": ["serve", "--in", "udpin:127.0.0.1:0"],
        "sim": ["sim", str(Q_SCENARIO)],
        "proxy": ["proxy", str(Q_SCENARIO)],
        "run": ["run", str(Q_SCENARIO), "--out-dir", str(tmp_path / "out")],
    }[command]
    assert cli_main([*argv, "--signing-key", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == (
        f"immukf-sitl {command}: error: --signing-key {bad}: expected 64 hex characters "
        "(a 32-byte key), got 4"
    )
    assert "Traceback" not in "\n".join(err)


# -- pymavlink's checks, classified -------------------------------------------------------------


def _signed_sender(key: bytes, link_id: int = SIM_LINK_ID):
    """A pymavlink encoder (system 1, component 1) that signs with ``key``; never sends."""
    conn = connect("udpout:127.0.0.1:9", SIM_SYSTEM_ID, SIM_COMPONENT_ID, input_=False)
    signing = LinkSigning(key)
    signing.enable(conn, link_id)
    return conn, signing


def _parse(signing: LinkSigning, frame: bytes) -> list[str]:
    return [m.get_type() for m in signing.parser().parse_buffer(frame) or []]


def test_only_correctly_signed_new_frames_pass_and_each_rejection_has_its_cause() -> None:
    conn, _ = _signed_sender(KEY)
    forger, _ = _signed_sender(OTHER_KEY)
    receiver = LinkSigning(KEY)
    good = codec.highres_imu_message(_imu(1.0)).pack(conn.mav)
    unsigned = codec.highres_imu_message(_imu(1.01)).pack(mavlink.MAVLink(None, 1, 1))
    wrong_key = codec.highres_imu_message(_imu(1.02)).pack(forger.mav)
    later = codec.highres_imu_message(_imu(1.03)).pack(conn.mav)

    assert _parse(receiver, good) == ["HIGHRES_IMU"]
    assert _parse(receiver, unsigned) == ["BAD_DATA"]
    assert _parse(receiver, wrong_key) == ["BAD_DATA"]
    assert _parse(receiver, good) == ["BAD_DATA"]  # the same frame again: a replay
    assert _parse(receiver, later) == ["HIGHRES_IMU"]
    assert receiver.counters.as_dict() == {
        "unsigned_rejected": 1,
        "bad_signature": 1,
        "replayed": 1,
    }


def test_a_new_stream_more_than_a_minute_behind_our_clock_is_a_replay() -> None:
    conn, sender = _signed_sender(KEY)
    old = codec.highres_imu_message(_imu(1.0)).pack(conn.mav)  # stamped now
    receiver = LinkSigning(KEY)
    receiver.state.timestamp = sender.state.timestamp + 61 * 100_000  # we are 61 s later
    assert _parse(receiver, old) == ["BAD_DATA"]
    assert receiver.counters.replayed == 1 and receiver.counters.bad_signature == 0


def test_a_forged_frame_with_a_future_timestamp_cannot_lock_the_sender_out() -> None:
    conn, _ = _signed_sender(KEY)
    forger, forger_signing = _signed_sender(OTHER_KEY)
    receiver = LinkSigning(KEY)
    assert _parse(receiver, codec.highres_imu_message(_imu(1.0)).pack(conn.mav)) == ["HIGHRES_IMU"]
    forger_signing.state.timestamp += 10**12  # same stream (link 1, 1:1), far in the future
    forged = codec.highres_imu_message(_imu(1.01)).pack(forger.mav)
    assert _parse(receiver, forged) == ["BAD_DATA"]
    genuine = codec.highres_imu_message(_imu(1.02)).pack(conn.mav)
    assert _parse(receiver, genuine) == ["HIGHRES_IMU"]  # pymavlink alone would call it old
    assert receiver.counters.bad_signature == 1 and receiver.counters.replayed == 0


def test_a_faulted_frame_is_re_signed_in_its_senders_stream() -> None:
    conn, _ = _signed_sender(KEY)
    receiver = LinkSigning(KEY)
    (original,) = receiver.parser().parse_buffer(
        codec.highres_imu_message(_imu(2.0, q=0.3)).pack(conn.mav)
    )
    assert original.get_signed()
    frame = codec.repack_imu(original, _imu(2.0, q=0.0), KEY)
    (checked,) = LinkSigning(KEY).parser().parse_buffer(frame)
    assert checked.get_type() == "HIGHRES_IMU" and checked.ygyro == 0.0
    assert frame[-13:-6] == bytes(original.get_msgbuf()[-13:-6])  # link id and timestamp kept
    (unsigned,) = (
        LinkSigning(KEY).parser().parse_buffer(codec.repack_imu(original, _imu(2.0), None))
    )
    assert unsigned.get_type() == "BAD_DATA"


# -- the signed chain over UDP -------------------------------------------------------------------


@pytest.fixture(scope="module")
def signed_run(tmp_path_factory):
    """``run --sign`` of the q scenario, its fault at 14 s, to just past its detection (real UDP,
    lock-step)."""
    out = tmp_path_factory.mktemp("signed_run")
    scenario = with_fault_at(Q_SCENARIO.name, 14.0, out)
    argv = [str(scenario), "--sign", "--duration", "16", "--out-dir", str(out), "--json"]
    proc = subprocess.run(
        [sys.executable, "-m", "immukf_sitl.cli", "run", *argv],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=REPO,
    )
    assert proc.returncode == 0, proc.stderr
    return out, json.loads(proc.stdout)


@pytest.mark.slow
def test_a_signed_chain_detects_the_q_fault(signed_run) -> None:
    out, summary = signed_run
    assert [d["mode"] for d in summary["detections"]] == ["q"]
    assert summary["faults"][0]["detected_t_s"] < 15.5 and summary["false_alarms"] == 0
    signing = summary["stream"]["signing"]
    assert signing["serve"] == {
        "enabled": True,
        "unsigned_rejected": 0,
        "bad_signature": 0,
        "replayed": 0,
    }
    assert (
        signing["sim"]
        == signing["proxy"]
        == {
            "unsigned_rejected": 0,
            "bad_signature": 0,
            "replayed": 0,
        }
    )
    assert summary["stream"]["proxy"]["modified"] > 100  # faulted frames, re-signed
    assert summary["stream"]["estimator"]["steps"] == 1601
    assert summary["lag_us"]["n"] > 700 and summary["lag_us"]["max"] >= summary["lag_us"]["p99"]
    # what the estimator published is signed with the run's key and checks out
    key = load_key(out / "signing.key")
    checker = LinkSigning(key)
    reader = open_tlog_reader(str(out / "estimator.tlog"))
    frames = []
    while (msg := reader.recv_msg()) is not None:
        frames.append(bytes(msg.get_msgbuf()))
    parsed = [m for f in frames[:200] for m in checker.parser().parse_buffer(f) or []]
    assert len(parsed) == 200 and all(m.get_signed() for m in parsed)
    assert {m.get_srcComponent() for m in parsed} == {ESTIMATOR_COMPONENT_ID}


class _Forger:
    """Sends forged HIGHRES_IMU as system 1 component 1 to serve until stopped, and listens."""

    def __init__(self, port: int) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.port = port
        self.unsigned = 0
        self.wrong_key = 0
        self.replies = 0
        self._stop = threading.Event()
        self._signing = LinkSigning(OTHER_KEY)
        self._plain = mavlink.MAVLink(None, SIM_SYSTEM_ID, SIM_COMPONENT_ID)
        self._signed = mavlink.MAVLink(None, SIM_SYSTEM_ID, SIM_COMPONENT_ID)
        self._signing.watch(self._signed)
        self._signing.state.sign_outgoing = True
        self._signing.state.link_id = SIM_LINK_ID
        self._signing.state.timestamp = int((time.time() - 1420070400) * 1e5) + 10**9
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        rng = np.random.default_rng(7)
        k = 0
        while not self._stop.is_set():
            # a plausible sample just after a real one: if fused, the real next one is dropped
            t_s = 0.005 + 0.01 * (k % 1200)
            sample = ImuSample(t_s, rng.normal(0, 5, 3), rng.normal(0, 1, 3))
            encoder = self._plain if k % 2 == 0 else self._signed
            frame = codec.highres_imu_message(sample).pack(encoder)
            self.sock.sendto(frame, ("127.0.0.1", self.port))
            if k % 2 == 0:
                self.unsigned += 1
            else:
                self.wrong_key += 1
            k += 1
            try:
                while self.sock.recv(65536):
                    self.replies += 1
            except BlockingIOError:
                pass
            time.sleep(0.002)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)


@pytest.mark.slow
def test_forged_and_replayed_frames_change_nothing_in_the_estimate(signed_run, tmp_path) -> None:
    reference_dir, _ = signed_run
    key_path = reference_dir / "signing.key"
    p_proxy, p_est, p_gcs = free_udp_ports(3)
    est_tlog, proxy_tlog = tmp_path / "estimator.tlog", tmp_path / "proxy.tlog"
    sign = ["--signing-key", str(key_path)]
    serve = spawn_cli("serve", ["serve", "--in", f"udpin:127.0.0.1:{p_est}", "--out",
                                f"udpout:127.0.0.1:{p_gcs}", "--tlog", str(est_tlog), "--json",
                                "--stats-interval", "0", "--idle-exit", "2", "--sensors",
                                str(reference_dir / "sensors.yaml"), *sign])  # fmt: skip
    proxy = spawn_cli("proxy", ["proxy", str(Q_SCENARIO), "--in", f"udpin:127.0.0.1:{p_proxy}",
                                "--out", f"udpout:127.0.0.1:{p_est}", "--tlog", str(proxy_tlog),
                                "--json", *sign])  # fmt: skip
    forger = _Forger(p_est)
    children = [serve, proxy]
    try:
        serve.wait_ready(READY, 120, busy=WARMING_UP, busy_timeout_s=900.0)
        proxy.wait_ready("proxy:", 60)
        forger.start()
        sim = spawn_cli("sim", ["sim", str(Q_SCENARIO), "--out", f"udpout:127.0.0.1:{p_proxy}",
                                "--duration", "8", "--json", *sign])  # fmt: skip
        children.append(sim)
        sim.proc.wait(timeout=120)
        assert sim.proc.returncode == 0, sim.last_error()
        proxy_out = json.loads(proxy.stop().strip().splitlines()[-1])
        # the flight's own signed HIGHRES_IMU frames, sent again: replays
        reader = open_tlog_reader(str(proxy_tlog))
        imu_frames = []
        while (msg := reader.recv_msg()) is not None:
            if msg.get_type() == "HIGHRES_IMU":
                imu_frames.append(bytes(msg.get_msgbuf()))
        replays = imu_frames[100:120]
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            for frame in replays:
                sock.sendto(frame, ("127.0.0.1", p_est))
        # the forger ran on until now: its frames keep serve from its idle exit (2 s), which a
        # loaded machine could reach while the proxy stops and its tlog is read
        forger.stop()
        serve.proc.wait(timeout=30)
        serve_out = json.loads(serve.stop().strip().splitlines()[-1])
    finally:
        forger.stop()
        for child in children:
            if child.proc.poll() is None:
                child.proc.kill()
    assert forger.unsigned > 100 and forger.wrong_key > 100
    assert serve_out["signing"] == {
        "enabled": True,
        "unsigned_rejected": forger.unsigned,
        "bad_signature": forger.wrong_key,
        "replayed": len(replays),
    }
    assert forger.replies == 0  # no acknowledgement or output goes to an unsigned sender
    assert serve_out["counters"]["imu_samples"] == 801 == serve_out["counters"]["steps"]
    assert serve_out["counters"]["out_of_order"] == 0 and serve_out["bad_packets"] == 0
    assert proxy_out["signing"] == {"unsigned_rejected": 0, "bad_signature": 0, "replayed": 0}
    # the estimate is the reference run's, to the bit, over the common 8 s
    mine, reference = (
        read_estimator_log(est_tlog),
        read_estimator_log(reference_dir / "estimator.tlog"),
    )
    n = len(mine.attitude_t_s)
    assert n > 300
    np.testing.assert_array_equal(mine.attitude_t_s, reference.attitude_t_s[:n])
    np.testing.assert_array_equal(mine.euler_rad, reference.euler_rad[:n])


@pytest.mark.slow
def test_key_file_is_not_world_readable_after_run_sign(signed_run) -> None:
    out, _ = signed_run
    assert stat.S_IMODE(os.stat(out / "signing.key").st_mode) == 0o600
