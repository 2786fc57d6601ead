"""Helpers of the tests over real UDP on loopback: free ports, datagram sinks, CLI subprocesses.

Every wait is bounded in time; subprocesses are killed by their context manager.
"""

from __future__ import annotations

import contextlib
import os
import select
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

from immukf_sitl.mavlink.wire import MavMessage, mavlink

REPO = Path(__file__).resolve().parents[1]


def free_udp_port() -> int:
    """A loopback UDP port that was free a moment ago (bind to 0, read it, release it)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def bound_socket(rcvbuf_bytes: int = 4 << 20) -> socket.socket:
    """A UDP socket on 127.0.0.1 with an OS-chosen port and a large receive buffer."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf_bytes)
    sock.bind(("127.0.0.1", 0))
    return sock


class DatagramSink:
    """Receives raw datagrams on its own socket in a thread, until stopped.

    Attributes
    ----------
    port : int
        Where to send.
    datagrams : list of bytes
        Everything received, in order.
    """

    def __init__(self) -> None:
        self.sock = bound_socket()
        self.port = int(self.sock.getsockname()[1])
        self.datagrams: list[bytes] = []
        self.peer: tuple[str, int] | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        self.sock.setblocking(False)
        while not self._stop.is_set():
            readable, _, _ = select.select([self.sock], [], [], 0.05)
            if not readable:
                continue
            while True:
                try:
                    data, peer = self.sock.recvfrom(65536)
                except BlockingIOError:
                    break
                self.datagrams.append(data)
                self.peer = peer

    def wait_for(self, count: int, timeout_s: float) -> bool:
        """Wait until ``count`` datagrams arrived (bounded); returns whether they did."""
        deadline = time.monotonic() + timeout_s
        while len(self.datagrams) < count and time.monotonic() < deadline:
            time.sleep(0.0005)
        return len(self.datagrams) >= count

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.sock.close()


def parse_frames(datagrams: Sequence[bytes]) -> list[MavMessage]:
    """Every MAVLink message in the datagrams (a fresh parser per datagram)."""
    out: list[MavMessage] = []
    for data in datagrams:
        parser = mavlink.MAVLink(None)
        parser.robust_parsing = True
        out.extend(parser.parse_buffer(data) or [])
    return out


def cli_command(args: Sequence[str]) -> list[str]:
    """``immukf-sitl ARGS`` through the current interpreter."""
    return [sys.executable, "-m", "immukf_sitl.cli", *args]


class CliProcess:
    """A running ``immukf-sitl`` subprocess with unbuffered pipes read in bounded waits."""

    def __init__(self, args: Sequence[str]) -> None:
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        self.proc = subprocess.Popen(
            cli_command(args),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            bufsize=0,
            cwd=REPO,
            env=env,
        )
        self._stderr = b""

    def read_line_starting(self, prefix: str, timeout_s: float) -> str:
        """The first stderr line starting with ``prefix`` (bounded wait)."""
        assert self.proc.stderr is not None
        fd = self.proc.stderr.fileno()
        deadline = time.monotonic() + timeout_s
        consumed = 0
        while time.monotonic() < deadline:
            lines = self._stderr[consumed:].split(b"\n")
            for line in lines[:-1]:
                consumed += len(line) + 1
                if line.decode().startswith(prefix):
                    return line.decode()
            readable, _, _ = select.select([fd], [], [], 0.1)
            if readable:
                chunk = os.read(fd, 65536)
                if not chunk:
                    break
                self._stderr += chunk
        raise AssertionError(
            f"no stderr line starting with {prefix!r} within {timeout_s} s: {self._stderr!r}"
        )

    def finish(self, timeout_s: float, signum: int | None = None) -> tuple[int, str, str]:
        """Optionally signal, then wait (bounded); ``(returncode, stdout, all of stderr)``."""
        if signum is not None:
            self.proc.send_signal(signum)
        out, err = self.proc.communicate(timeout=timeout_s)
        return self.proc.returncode, out.decode(), (self._stderr + err).decode()

    def kill(self) -> None:
        """Kill if still running and reap."""
        if self.proc.poll() is None:
            self.proc.kill()
        try:
            self.proc.communicate(timeout=10)
        except (ValueError, subprocess.TimeoutExpired):  # pipes already closed
            self.proc.wait(timeout=10)


@contextlib.contextmanager
def cli_process(args: Sequence[str]) -> Iterator[CliProcess]:
    """Start ``immukf-sitl ARGS``; always killed on exit of the block."""
    process = CliProcess(args)
    try:
        yield process
    finally:
        process.kill()
