"""What serve's lag is measured from and with: kernel receive stamps, histograms, quaternions."""

from __future__ import annotations

import socket
import sys
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from immukf_sitl.cli import main as cli_main
from immukf_sitl.mavlink import wire
from immukf_sitl.mavlink.codec import euler_to_quaternion
from immukf_sitl.mavlink.wire import DatagramReader, connect
from immukf_sitl.service.timing import DurationHistogram, SimTimeWindows, lag_statistics


def _kernel_attaches_stamps() -> bool:
    """Whether this kernel attaches SO_TIMESTAMPNS to a datagram (a sandbox may accept the
    option and attach none), asked with a raw socket and ample room for ancillary data."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as rx:
        rx.bind(("127.0.0.1", 0))
        rx.setsockopt(socket.SOL_SOCKET, wire._SO_TIMESTAMPNS, 1)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            tx.sendto(b"x", rx.getsockname())
        rx.settimeout(1.0)
        _, ancillary, _, _ = rx.recvmsg(16, 1024)
    return any(kind == wire._SO_TIMESTAMPNS for _, kind, _ in ancillary)


def _wait_for_arrival_stamps(reader: DatagramReader, sender: socket.socket) -> None:
    """Wait until the kernel stamps datagrams as they arrive rather than as they are read.

    Linux switches arrival stamping on lazily (a deferred static key) when the first socket of
    the machine asks for it; until then a stamped socket's datagram is stamped at its read. The
    wait sends probes until one is stamped at least 10 ms before its read, for at most 2 s.
    """
    deadline_s = time.monotonic() + 2.0
    while time.monotonic() < deadline_s:
        sender.sendto(b"probe", reader.sock.getsockname())
        time.sleep(0.02)
        read_ns = time.time_ns()
        datagram = reader.read()
        if datagram is not None and read_ns - datagram[1] >= 10_000_000:
            return
    pytest.fail("no datagram was stamped at its arrival within 2 s")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="SO_TIMESTAMPNS is Linux's")
def test_the_arrival_stamp_includes_the_time_a_datagram_waited_in_the_socket() -> None:
    if not _kernel_attaches_stamps():
        pytest.skip("this kernel accepts SO_TIMESTAMPNS and attaches no stamp (a sandbox)")
    conn = connect("udpin:127.0.0.1:0", 1, 191)
    reader = DatagramReader(conn)
    assert reader.kernel_stamps
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender:
        _wait_for_arrival_stamps(reader, sender)
        sender.sendto(b"\xfdabc", conn.port.getsockname())
        sent_ns = time.time_ns()
        time.sleep(0.05)  # the datagram waits in the queue
        read_ns = time.time_ns()
        data, arrival_ns, peer = reader.read()
        assert data == b"\xfdabc" and peer[1] == sender.getsockname()[1]
    assert read_ns - arrival_ns >= 50_000_000  # the wait is counted: not a read-time stamp
    assert arrival_ns <= read_ns and arrival_ns >= sent_ns - 1_000_000_000
    assert reader.read() is None
    conn.close()


def test_a_datagram_without_a_kernel_stamp_is_stamped_at_the_read_and_says_so() -> None:
    conn = connect("udpin:127.0.0.1:0", 1, 191)
    reader = DatagramReader(conn)
    if reader.kernel_stamps:  # the option is withdrawn, as a sandbox that ignores it would
        conn.port.setsockopt(socket.SOL_SOCKET, wire._SO_TIMESTAMPNS, 0)
    reader.kernel_stamps = True  # as if the option had been accepted
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender:
        sender.sendto(b"\xfdabc", conn.port.getsockname())
        time.sleep(0.05)
        read_ns = time.time_ns()
        _, arrival_ns, _ = reader.read()
    assert arrival_ns >= read_ns and not reader.kernel_stamps
    if sys.platform.startswith("linux"):  # from then on every datagram is stamped at its read
        conn.port.setsockopt(socket.SOL_SOCKET, wire._SO_TIMESTAMPNS, 1)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender:
            sender.sendto(b"\xfdabd", conn.port.getsockname())
            time.sleep(0.05)
            read_ns = time.time_ns()
            _, arrival_ns, _ = reader.read()
        assert arrival_ns >= read_ns
    conn.close()


def test_histogram_quantiles_match_numpy_to_the_bin() -> None:
    rng = np.random.default_rng(3)
    values = rng.gamma(2.0, 300.0, 20_000)
    hist = DurationHistogram()
    for v in values:
        hist.add(v)
    summary = hist.summary()
    assert summary["n"] == 20_000 and summary["max"] == pytest.approx(values.max(), abs=0.1)
    assert abs(summary["p99"] - np.percentile(values, 99)) <= 1.0
    assert abs(summary["median"] - np.median(values)) <= 1.0
    hist.clear()
    assert hist.summary()["n"] == 0 and hist.counts.sum() == 0


def test_windows_split_by_sim_time_and_restart_at_a_clock_jump() -> None:
    windows = SimTimeWindows(10.0)
    for k in range(2500):  # 25 s at 100 Hz, lag every other sample
        windows.add(k * 0.01, 200.0 + k % 7, 900.0 if k % 2 == 0 else None)
    windows.add(1.0, 300.0, None)  # the sender's clock went back: a new window
    report = windows.report()
    assert [w["t_start_s"] for w in report] == [0.0, 10.0, 20.0, 0.0]
    assert [w["step_us"]["n"] for w in report] == [1000, 1000, 500, 1]
    assert report[0]["lag_us"]["n"] == 500 and report[-1].get("partial")
    assert lag_statistics([])["n"] == 0 and lag_statistics([1.0, 3.0])["max"] == 3.0


def test_closed_form_quaternion_is_scipys() -> None:
    rng = np.random.default_rng(5)
    for euler in rng.uniform([-np.pi, -1.5, -np.pi], [np.pi, 1.5, np.pi], (500, 3)):
        x, y, z, w = Rotation.from_euler("ZYX", euler[::-1]).as_quat()
        np.testing.assert_allclose(euler_to_quaternion(euler), [w, x, y, z], atol=1e-15)


def test_a_realtime_priority_out_of_range_is_one_line(capsys) -> None:
    assert cli_main(["serve", "--realtime-priority", "120"]) == 2
    assert capsys.readouterr().err.strip() == (
        "immukf-sitl serve: error: --realtime-priority: expected 1..99, got 120"
    )
