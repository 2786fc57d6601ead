"""Supervision of the chain's child processes: start, wait until ready, watch, stop.

``run`` starts ``serve``, ``proxy`` and ``sim`` as ``immukf-sitl`` sub-commands with this
interpreter, on loopback UDP ports that were free a moment before.
"""

from __future__ import annotations

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

    def wait_ready(self, prefix: str, timeout_s: float) -> None:
        """Block until the child prints a line starting with ``prefix`` (its ports are bound)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if any(line.startswith(prefix) for line in list(self.lines)):
                return
            if self.proc.poll() is not None:
                raise UserError(f"{self.name} failed to start: {self.last_error()}")
            time.sleep(0.02)
        raise UserError(f"{self.name} did not report ready within {timeout_s:.0f} s")

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
