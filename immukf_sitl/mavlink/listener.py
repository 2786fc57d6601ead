"""A minimal ground station on the estimator's output: mode probabilities and status texts.

``immukf-sitl run`` listens with it to show progress while the chain flies; it reads what a
ground station would (NAMED_VALUE_FLOAT ``MP_*``, STATUSTEXT) and nothing else.
"""

from __future__ import annotations

from immukf_sitl.mavlink.wire import connect

#: Source ids of the listener (MAVProxy uses 255:230; any GCS-like id will do).
LISTENER_SYSTEM_ID = 255
LISTENER_COMPONENT_ID = 190


class GroundStationListener:
    """Reads the estimator's published mode probabilities and texts from ``url`` (``udpin:``)."""

    def __init__(self, url: str) -> None:
        self.conn = connect(url, LISTENER_SYSTEM_ID, LISTENER_COMPONENT_ID)
        self.t_s = 0.0
        self.probabilities: dict[str, float] = {}
        self.texts: list[str] = []

    def poll(self) -> None:
        """Read everything waiting."""
        while True:
            msg = self.conn.recv_msg()
            if msg is None:
                return
            kind = msg.get_type()
            if kind == "NAMED_VALUE_FLOAT" and msg.name.startswith("MP_"):
                self.probabilities[msg.name] = msg.value
                self.t_s = msg.time_boot_ms / 1000.0
            elif kind == "STATUSTEXT":
                self.texts.append(msg.text)

    def line(self, duration_s: float) -> str:
        """Progress for people: the sim time heard and the two most probable modes."""
        top = sorted(self.probabilities.items(), key=lambda kv: -kv[1])[:2]
        probs = "  ".join(f"{n}={p:.2f}" for n, p in top)
        return f"run: t={self.t_s:5.1f}/{duration_s:.0f} s  {probs}"

    def close(self) -> None:
        """Release the socket."""
        self.conn.close()
