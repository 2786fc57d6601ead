"""Supervision of the chain's child processes: start, wait until ready, watch, stop.

``run`` starts ``serve``, ``proxy`` and ``sim`` as ``immukf-sitl`` sub-commands with this
interpreter, on loopback UDP ports that were free a moment before.
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass, field

from immukf_sitl.errors import UserError


@dataclass
class Child:
    """A subprocess whose stderr is collected (and echoed when asked) by a thread."""

    name: str
    proc: subprocess.Popen
    echo: bool
    lines: deque = field(default_factory=lambda: deque(maxlen=200))

    def __post_init__(self) -> None:
        self._thread = threading.Thread(target=self._pump, daemon=True)
        self._thread.start()

    def _pump(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            line = line.rstrip()
            self.lines.append(line)
            if self.echo:
                print(f"  [{self.name}] {line}", file=sys.stderr, flush=True)

    def _printed(self, prefix: str) -> bool:
        return any(line.startswith(prefix) for line in list(self.lines))

    def wait_ready(
        self,
        prefix: str,
        timeout_s: float,
        *,
        busy: str | None = None,
        busy_timeout_s: float = 0.0,
        notice_every_s: float = 30.0,
    ) -> None:
        """Block until the child prints a line starting with ``prefix`` (its ports are bound).

        A child that announces a long start-up step with a line starting with ``busy`` (serve:
        compiling its numba kernels, minutes on a cold cache under load) is given
        ``busy_timeout_s`` from that line on instead of ``timeout_s``, and a note goes to stderr
        every ``notice_every_s`` while it works. A child that exits first is a one-line error.
        """
        started = time.monotonic()
        deadline = started + timeout_s
        busy_since: float | None = None
        next_notice = math.inf
        while True:
            now = time.monotonic()
            if self._printed(prefix):
                return
            if self.proc.poll() is not None:
                raise UserError(f"{self.name} failed to start: {self.last_error()}")
            if busy is not None and busy_since is None and self._printed(busy):
                busy_since = now
                deadline = max(deadline, now + busy_timeout_s)
                next_notice = now + notice_every_s
            if now >= deadline:
                break
            if now >= next_notice:
                print(
                    f"{self.name}: still starting after {now - started:.0f} s "
                    f"({self.last_error()})",
                    file=sys.stderr,
                    flush=True,
                )
                next_notice = now + notice_every_s
            time.sleep(0.02)
        waited = time.monotonic() - started
        if busy_since is not None:
            raise UserError(
                f"{self.name} did not report ready within {waited:.0f} s; its last line: "
                f"{self.last_error()}"
            )
        raise UserError(f"{self.name} did not report ready within {waited:.0f} s")

    def stop(self, timeout_s: float = 15.0) -> str:
        """SIGINT, wait, kill if needed; returns stdout."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
        try:
            out, _ = self.proc.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            out, _ = self.proc.communicate()
        self._thread.join(timeout=2.0)
        return out or ""

    def last_error(self) -> str:
        """The child's last stderr line (its one-line error, if it failed)."""
        return self.lines[-1] if self.lines else "(no output)"


def free_udp_ports(n: int) -> list[int]:
    """``n`` distinct loopback UDP ports that were free a moment ago."""
    import socket

    socks = []
    for _ in range(n):
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", 0))
        socks.append(s)
    ports = [s.getsockname()[1] for s in socks]
    for s in socks:
        s.close()
    return ports


def spawn_cli(name: str, argv: list[str], echo: bool = False) -> Child:
    """Start ``immukf-sitl ARGV`` with this interpreter; stderr collected by a thread."""
    cmd = [sys.executable, "-m", "immukf_sitl.cli", *argv]
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(
        cmd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        stdin=subprocess.DEVNULL,
        text=True,
        env=env,
    )
    return Child(name, proc, echo)
