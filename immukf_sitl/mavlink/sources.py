"""Which of an autopilot's IMU and GPS streams the estimator follows.

An autopilot sends one stream per IMU, and sometimes the same IMU in two messages: ArduPilot
RAW_IMU for its first IMU, SCALED_IMU2 and SCALED_IMU3 for the next two (and HIGHRES_IMU in
recent versions); PX4 HIGHRES_IMU; this project's sim HIGHRES_IMU. The estimator needs exactly
one, at a steady rate: :class:`StreamSelector` follows the first stream of the asked instance
(``--imu N``; by default any) that arrives, and the first GPS stream (GPS_RAW_INT, GPS2_RAW or
HIL_GPS, the raw receiver's message with its vertical velocity, as this sim sends a receiver
that reports it), and counts every stream it heard, for the reports.
"""

from __future__ import annotations

from collections import Counter

from immukf_sitl.mavlink.codec import IMU_MESSAGES, imu_instance
from immukf_sitl.mavlink.wire import MavMessage

GPS_MESSAGES = ("GPS_RAW_INT", "GPS2_RAW", "HIL_GPS")


def rate_hint(kind: str) -> str:
    """What raises an IMU message's rate on the autopilot that sends it."""
    if kind == "HIGHRES_IMU":
        return "PX4: MAV_n_MODE Onboard, or SET_MESSAGE_INTERVAL"
    return "ArduPilot: raise SRn_RAW_SENS, or SET_MESSAGE_INTERVAL"


def imu_label(kind: str, instance: int) -> str:
    """How reports name an IMU stream: ``RAW_IMU id 0``, ``SCALED_IMU2``."""
    return kind if kind.startswith("SCALED_IMU") else f"{kind} id {instance}"


class StreamSelector:
    """Follows one IMU stream and one GPS stream out of everything that arrives.

    Parameters
    ----------
    imu : int, optional
        The IMU instance to follow (0 first); None follows the first IMU stream heard.
    """

    def __init__(self, imu: int | None = None) -> None:
        self.imu = imu
        self.imu_stream: tuple[str, int] | None = None
        self.gps_stream: str | None = None
        self.imu_counts: Counter[tuple[str, int]] = Counter()

    def follows_imu(self, msg: MavMessage) -> bool:
        """Whether ``msg`` (one of the IMU messages) is from the followed IMU stream."""
        key = (msg.get_type(), imu_instance(msg))
        self.imu_counts[key] += 1
        if self.imu_stream is None and (self.imu is None or key[1] == self.imu):
            self.imu_stream = key
        return key == self.imu_stream

    def follows_gps(self, msg: MavMessage) -> bool:
        """Whether ``msg`` (one of :data:`GPS_MESSAGES`) is from the followed GPS stream."""
        if self.gps_stream is None:
            self.gps_stream = msg.get_type()
        return msg.get_type() == self.gps_stream

    @property
    def imu_source(self) -> str:
        """The followed IMU stream's label ("" before one arrived)."""
        return imu_label(*self.imu_stream) if self.imu_stream else ""

    def imu_sources(self) -> dict[str, int]:
        """Every IMU stream heard and its message count."""
        return {imu_label(*key): n for key, n in sorted(self.imu_counts.items())}

    def missing_imu(self) -> str | None:
        """Why no IMU stream is followed, in words (None when one is)."""
        if self.imu_stream is not None:
            return None
        if not self.imu_counts:
            return f"no IMU message ({', '.join(IMU_MESSAGES)})"
        heard = ", ".join(self.imu_sources())
        return f"no IMU instance {self.imu} (there is {heard})"
