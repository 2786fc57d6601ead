"""Real UDP plumbing for the end-to-end tests: free ports and bounded waits."""

from __future__ import annotations

import socket
import subprocess
import time


def free_udp_ports(n: int) -> list[int]:
    """``n`` distinct loopback UDP ports that were free a moment ago."""
    socks, ports = [], []
    for _ in range(n):
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", 0))
        socks.append(s)
        ports.append(s.getsockname()[1])
    for s in socks:
        s.close()
    return ports


def stop(proc: subprocess.Popen, timeout_s: float = 10.0) -> tuple[str, str]:
    """SIGINT a child, then kill it if it lingers; returns its stdout and stderr."""
    if proc.poll() is None:
        proc.send_signal(2)
    try:
        out, err = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
    return out, err


def wait_for(predicate, timeout_s: float, interval_s: float = 0.01) -> bool:
    """Poll ``predicate`` until true or the time is up."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(interval_s)
    return predicate()
