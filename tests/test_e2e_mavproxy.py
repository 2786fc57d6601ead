"""End to end over real UDP: ``immukf-sitl run`` (sim -> proxy -> serve, lock-step on loopback)
with a real, headless MAVProxy as the ground station.

The q gyro is zeroed at 14 s, in the climbing right turn (``scenarios/q_gyro_zeroed.yaml`` with its
fault moved from 30 s, cut to 20 s: the same checks in a shorter flight). The run's JSON must
report q identified within 1.0 s of the fault becoming observable and no false alarm; MAVProxy's
own tlog must hold, from the estimator (system 1, component 191), the seven mode probabilities,
ATTITUDE and the detection STATUSTEXT. MAVProxy is started before the run, left to record its
backlog, stopped with SIGINT (a SIGTERM once left a 0-byte tlog) and killed if it lingers; every
wait is bounded.

The ``busy`` case flies the same beside one CPU burner per core (less the other test workers,
which keep a core busy each), paced to the wall clock, as a ground station on a loaded machine
would hear it in flight: a STATUSTEXT lost there is a detection the operator never sees.
(Lock-step runs about twice faster than the air: beside the burners it once outran MAVProxy,
which had recorded 31 of a 36 s flight when it was stopped.) MAVProxy needs about a quarter of a
core for this stream (9.4 s of CPU for a 36 s flight, measured idle); starved below that, it falls
behind and its socket's receive buffer (about a second of this stream) overflows, so the kernel
drops the newest datagrams and the flight's last seconds never reach it. The busy case accepts a
lost tail only where the kernel counted those drops on MAVProxy's socket, and still requires the
declaration and a second of the faulted mode after it.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import pytest
from flights import with_fault_at
from udp_tools import REPO, free_udp_port

from immukf_sitl.mavlink.wire import (
    ESTIMATOR_COMPONENT_ID,
    ESTIMATOR_SYSTEM_ID,
    open_tlog_reader,
)

# flies JSBSim or the estimator chain
pytestmark = pytest.mark.slow

SCENARIO = "q_gyro_zeroed.yaml"
DURATION_S = 20.0
FAULT_T_S = 14.0
MP_NAMES = {"MP_NONE", "MP_AX", "MP_AY", "MP_AZ", "MP_P", "MP_Q", "MP_R"}
#: 26 s here idle, 55 s paced beside two CPU burners (the estimator catching up); bounded so that a
#: hung chain fails instead of blocking CI, with room for a cold numba cache (the first run
#: compiles every kernel)
RUN_TIMEOUT_S = 150.0
MAVPROXY_READY_S = 20.0
STOP_TIMEOUT_S = 10.0
#: MAVProxy may still be working through its socket's backlog when the run ends: it is stopped
#: once it has recorded the estimator's last probability, or has recorded nothing new from the
#: estimator for DRAIN_QUIET_S (what it lost it will not record), or after DRAIN_TIMEOUT_S
DRAIN_QUIET_S = 5.0
DRAIN_TIMEOUT_S = 60.0
#: seconds between looks at MAVProxy's tlog (each parses the whole file, ~0.5 s of CPU idle, taken
#: from a MAVProxy that may be starved already)
DRAIN_POLL_S = 1.0


def _mavproxy_command() -> list[str] | None:
    """``mavproxy.py`` beside this interpreter (the venv's bin/), else the one on PATH."""
    beside = Path(sys.executable).parent / "mavproxy.py"
    if beside.is_file():
        return [sys.executable, str(beside)]
    found = shutil.which("mavproxy.py")
    return [found] if found else None


def _stop(proc: subprocess.Popen, timeout_s: float = STOP_TIMEOUT_S) -> bool:
    """SIGINT the child's process group, then SIGKILL it if it lingers; True if SIGINT did."""
    graceful = True
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            graceful = False
    _kill(proc)
    return graceful


def _last_probability_t_s(msgs: list) -> float | None:
    """Time (s) of the estimator's last ``MP_Q`` among ``msgs``, or None."""
    times = [
        m.time_boot_ms / 1000.0
        for m in msgs
        if m.get_type() == "NAMED_VALUE_FLOAT"
        and m.name == "MP_Q"
        and (m.get_srcSystem(), m.get_srcComponent())
        == (ESTIMATOR_SYSTEM_ID, ESTIMATOR_COMPONENT_ID)
    ]
    return max(times, default=None)


def _wait_until_recorded(tlog: Path, last_sent_t_s: float) -> float:
    """Block until ``tlog`` holds the estimator's ``MP_Q`` of ``last_sent_t_s``, or its estimator
    messages stop growing for DRAIN_QUIET_S, or DRAIN_TIMEOUT_S; the seconds waited. The file is
    parsed again only when it has grown (MAVProxy's own heartbeats grow it too)."""
    started = last_change = time.monotonic()
    count, size = -1, -1
    while time.monotonic() - started < DRAIN_TIMEOUT_S:
        now_size = tlog.stat().st_size if tlog.exists() else 0
        if now_size != size and now_size > 0:
            size = now_size
            msgs = _read_gcs_tlog(tlog)
            recorded_t_s = _last_probability_t_s(msgs)
            if recorded_t_s is not None and recorded_t_s >= last_sent_t_s:
                break
            ours = sum(
                (m.get_srcSystem(), m.get_srcComponent())
                == (ESTIMATOR_SYSTEM_ID, ESTIMATOR_COMPONENT_ID)
                for m in msgs
            )
            if ours != count:
                count, last_change = ours, time.monotonic()
        if time.monotonic() - last_change >= DRAIN_QUIET_S:
            break
        time.sleep(DRAIN_POLL_S)
    return time.monotonic() - started


def _udp_drops(port: int) -> int | None:
    """Datagrams the kernel dropped on the loopback UDP socket bound to ``port`` (its receive
    buffer full), from Linux's /proc/net/udp; None where that is not readable."""
    table = Path("/proc/net/udp")
    if not table.is_file():
        return None
    local = f"0100007F:{port:04X}"
    for line in table.read_text().splitlines()[1:]:
        fields = line.split()
        if len(fields) > 12 and fields[1] == local:
            return int(fields[-1])
    return None


def _kill(proc: subprocess.Popen) -> None:
    """SIGKILL the child's own process group (its session: it and its children only)."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    try:
        proc.wait(timeout=STOP_TIMEOUT_S)
    except subprocess.TimeoutExpired:  # pragma: no cover - a zombie that will not be reaped
        pass


def _read_gcs_tlog(path: Path) -> list:
    """Every message MAVProxy recorded, in order."""
    log = open_tlog_reader(str(path))
    msgs = []
    try:
        while (msg := log.recv_match()) is not None:
            if msg.get_type() != "BAD_DATA":
                msgs.append(msg)
    finally:
        log.close()
    return msgs


def _busy_burners() -> int:
    """One burner per core, less the other pytest-xdist workers, which keep a core busy each.

    Two burners beside the other worker on two cores missed the fault in both clean-clone CI
    runs of the first parallel suite (it passed in three warm runs here): the chain's three
    processes then share two cores with three CPU-bound ones.
    """
    others = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")) - 1
    return max(1, (os.cpu_count() or 2) - others)


@pytest.fixture(params=["idle", "busy"])
def cpu_burners(request: pytest.FixtureRequest):
    """Processes spinning on the CPU for the test's duration: none, or the machine loaded."""
    count = _busy_burners() if request.param == "busy" else 0
    burners = [
        subprocess.Popen(
            [sys.executable, "-c", "while True: pass"],
            stdin=subprocess.DEVNULL,
            start_new_session=True,
        )
        for _ in range(count)
    ]
    yield len(burners)
    for proc in burners:
        _kill(proc)


def test_run_with_mavproxy_ground_station(tmp_path: Path, cpu_burners: int) -> None:
    mavproxy_cmd = _mavproxy_command()
    if mavproxy_cmd is None:
        pytest.skip(
            f"mavproxy.py not found beside {sys.executable} or on PATH "
            "(install the dev extras: pip install -e '.[dev]')"
        )
    gcs_dir = tmp_path / "gcs"
    gcs_dir.mkdir()
    run_dir = tmp_path / "run"
    gcs_tlog = gcs_dir / "gcs.tlog"
    gcs_out = gcs_dir / "mavproxy.out"
    port = free_udp_port()
    env = dict(os.environ, PYTHONUNBUFFERED="1")

    mavproxy = run = None
    started = time.monotonic()
    try:
        with open(gcs_out, "wb") as out:
            mavproxy = subprocess.Popen(
                [
                    *mavproxy_cmd,
                    f"--master=udpin:127.0.0.1:{port}",
                    "--daemon",
                    "--non-interactive",
                    f"--state-basedir={gcs_dir}",
                    f"--logfile={gcs_tlog}",
                    "--default-modules=log",
                    "--cmd=set flushlogs True",
                ],
                cwd=gcs_dir,
                stdin=subprocess.DEVNULL,
                stdout=out,
                stderr=subprocess.STDOUT,
                env=env,
                start_new_session=True,
            )
        # Ready when it listens: it prints this after binding the master port.
        deadline = time.monotonic() + MAVPROXY_READY_S
        while b"Waiting for heartbeat" not in gcs_out.read_bytes():
            assert mavproxy.poll() is None, f"MAVProxy exited: {gcs_out.read_text()[-2000:]}"
            assert time.monotonic() < deadline, f"MAVProxy not ready: {gcs_out.read_text()}"
            time.sleep(0.1)
        ready_s = time.monotonic() - started

        run = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "immukf_sitl.cli",
                "run",
                str(with_fault_at(SCENARIO, FAULT_T_S, tmp_path)),
                "--duration",
                f"{DURATION_S:g}",
                "--gcs",
                f"udpout:127.0.0.1:{port}",
                "--json",
                "--out-dir",
                str(run_dir),
                *(["--realtime"] if cpu_burners else []),
            ],  # fmt: skip
            cwd=REPO,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=env,
            start_new_session=True,  # its sim, proxy and serve share its process group
        )
        try:
            stdout, stderr = run.communicate(timeout=RUN_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            _kill(run)
            pytest.fail(f"immukf-sitl run did not finish within {RUN_TIMEOUT_S:g} s")
        run_s = time.monotonic() - started - ready_s
        assert run.returncode == 0, f"run failed ({run.returncode}): {stderr[-3000:]}"
        assert mavproxy.poll() is None, f"MAVProxy died: {gcs_out.read_text()[-2000:]}"
        last_sent_t_s = _last_probability_t_s(_read_gcs_tlog(run_dir / "estimator.tlog"))
        assert last_sent_t_s is not None, "the estimator's own tlog holds no MP_Q"
        drain_s = _wait_until_recorded(gcs_tlog, last_sent_t_s)
        dropped = _udp_drops(port)  # before MAVProxy closes its socket
        stopped_by_sigint = _stop(mavproxy)
    finally:
        for proc in (run, mavproxy):
            if proc is not None:
                _kill(proc)
    print(
        f"e2e ({cpu_burners} CPU burners): MAVProxy ready {ready_s:.1f} s, run {run_s:.1f} s, "
        f"drained {drain_s:.1f} s, kernel dropped {dropped} datagrams on its socket, "
        f"MAVProxy {'stopped by SIGINT' if stopped_by_sigint else 'killed'}"
    )

    # The run's own verdict.
    summary = json.loads(stdout.strip().splitlines()[-1])
    assert summary["received_truth_messages"] == 0
    assert summary["false_alarms"] == 0, summary["false_alarm_detections"]
    assert all(d["t_s"] >= FAULT_T_S for d in summary["detections"]), summary["detections"]
    (fault,) = summary["faults"]
    assert fault["channels"] == ["q"]
    assert fault["observable_t_s"] is not None and fault["observable_t_s"] >= FAULT_T_S
    assert fault["mode"] == "q" and fault["detected_t_s"] is not None, fault
    assert 0.0 <= fault["detected_t_s"] - fault["observable_t_s"] <= 1.0, fault
    q_detections = [d for d in summary["detections"] if d["mode"] == "q"]
    assert q_detections and q_detections[0]["t_s"] <= fault["observable_t_s"] + 1.0

    # What the ground station recorded.
    assert gcs_tlog.is_file() and gcs_tlog.stat().st_size > 0, gcs_out.read_text()[-2000:]
    msgs = _read_gcs_tlog(gcs_tlog)
    by_source = Counter((m.get_srcSystem(), m.get_srcComponent(), m.get_type()) for m in msgs)
    print("e2e: MAVProxy recorded", dict(sorted(by_source.items())))
    # The truth stays in the recorder: nothing of it reaches the ground station either.
    assert not any(kind == "HIL_STATE_QUATERNION" for _, _, kind in by_source), by_source
    ours = [
        m
        for m in msgs
        if (m.get_srcSystem(), m.get_srcComponent())
        == (ESTIMATOR_SYSTEM_ID, ESTIMATOR_COMPONENT_ID)
    ]
    kinds = Counter(m.get_type() for m in ours)
    assert kinds["ATTITUDE"] > 0, kinds
    assert kinds["HEARTBEAT"] > 0, kinds

    probs = [m for m in ours if m.get_type() == "NAMED_VALUE_FLOAT" and m.name in MP_NAMES]
    assert {m.name for m in probs} == MP_NAMES
    mp_q = [(m.time_boot_ms / 1000.0, m.value) for m in probs if m.name == "MP_Q"]
    before = [p for t, p in mp_q if t < FAULT_T_S]
    last_t = max(t for t, _ in mp_q)
    last_second = [p for t, p in mp_q if t >= last_t - 1.0]
    assert before and max(before) < 0.5, max(before, default=None)
    assert last_second and min(last_second) > 0.9, min(last_second, default=None)
    if cpu_burners and dropped:
        # the kernel dropped the tail at a starved MAVProxy's full socket (module docstring):
        # it must still have heard the declaration and a second of the faulted mode after it
        print(f"e2e: MAVProxy heard {last_t:.1f} of the {last_sent_t_s:.1f} s sent")
        assert last_t >= fault["detected_t_s"] + 1.0, (last_t, fault)
    else:
        assert last_t >= last_sent_t_s, (last_t, last_sent_t_s, dropped)

    texts = [m.text for m in ours if m.get_type() == "STATUSTEXT"]
    assert any(t.startswith("IMM: q gyro fault detected, p=") for t in texts), texts
    # and MAVProxy showed it to its user as a vehicle message
    assert "AP: IMM: q gyro fault detected, p=" in gcs_out.read_text(), gcs_out.read_text()
