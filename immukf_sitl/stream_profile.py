"""What the simulator sends, and how fast: the project's own stream, ArduPilot's or PX4's.

A :class:`StreamProfile` is the sim speaking as one autopilot speaks on a companion-computer
link (``sim --profile``, a scenario's ``profile:``):

==========  ======================  ========  =========  =======  ==========================
profile     IMU message             IMU (Hz)  servo (Hz) GPS (Hz) HEARTBEAT autopilot
==========  ======================  ========  =========  =======  ==========================
native      HIGHRES_IMU             100       100        sensors  MAV_AUTOPILOT_INVALID
ardupilot   RAW_IMU + SCALED_IMU2   50        10         5        MAV_AUTOPILOT_ARDUPILOTMEGA
px4         HIGHRES_IMU             250       10         5        MAV_AUTOPILOT_PX4
==========  ======================  ========  =========  =======  ==========================

ArduPilot's rates are what ``SRn_RAW_SENS`` = 50 and ``SRn_RC_CHAN`` = 10 give on a
companion link; PX4's are its onboard mode's SERVO_OUTPUT_RAW (10 Hz) with HIGHRES_IMU raised
to 250 Hz. ``native`` keeps the scenario's GPS rate (``sensors.gps.rate_hz``). Rates are
settable per scenario or on the command line, IMU 20 Hz to 1 kHz.

An IMU slower than the truth's 100 Hz step sends the mean of the samples since its last
message (its white noise drops as ``sqrt(rate / 100)``); a faster one runs the truth at its
own rate, each sample's noise raised by ``sqrt(rate / 100)`` (the same noise density). The
ArduPilot profile's servo outputs follow ``servo_layout`` (ArduPlane's conventional AETR,
elevons or a V-tail) and it answers PARAM_REQUEST_READ/LIST with the matching ``SERVOn_*``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["PROFILES", "SERVO_LAYOUTS", "StreamProfile", "TRUTH_RATE_HZ"]

#: the truth simulator's step rate at and below which the IMU is a mean of its samples
TRUTH_RATE_HZ = 100.0
#: name -> (IMU messages, IMU Hz, servo Hz, GPS Hz or None for the scenario's)
PROFILES: dict[str, tuple[tuple[str, ...], float, float, float | None]] = {
    "native": (("HIGHRES_IMU",), 100.0, 100.0, None),
    "ardupilot": (("RAW_IMU", "SCALED_IMU2"), 50.0, 10.0, 5.0),
    "px4": (("HIGHRES_IMU",), 250.0, 10.0, 5.0),
}
SERVO_LAYOUTS = ("conventional", "elevon", "vtail")


@dataclass(frozen=True)
class StreamProfile:
    """One autopilot's stream: its IMU messages and the rates of IMU, servo and GPS.

    ``None`` rates take the profile's defaults (:data:`PROFILES`); ``gps_hz`` None on
    ``native`` is the scenario's GPS rate. Raises ``ValueError`` on a bad field.
    """

    name: str = "native"
    imu_hz: float | None = None
    servo_hz: float | None = None
    gps_hz: float | None = None
    servo_layout: str = "conventional"

    def __post_init__(self) -> None:
        if self.name not in PROFILES:
            raise ValueError(f"profile {self.name!r}: expected one of {', '.join(PROFILES)}")
        for field_name, lo, hi in (
            ("imu_hz", 20.0, 1000.0),
            ("servo_hz", 1.0, 1000.0),
            ("gps_hz", 0.2, 20.0),
        ):
            value = getattr(self, field_name)
            if value is not None and not (math.isfinite(value) and lo <= value <= hi):
                raise ValueError(f"{field_name}: expected {lo:g} to {hi:g} Hz, got {value}")
        if self.servo_layout not in SERVO_LAYOUTS:
            raise ValueError(
                f"servo_layout {self.servo_layout!r}: expected one of {', '.join(SERVO_LAYOUTS)}"
            )
        if self.servo_layout != "conventional" and self.name != "ardupilot":
            raise ValueError(
                f"servo_layout {self.servo_layout}: only the ardupilot profile says its servo "
                "functions (SERVOn_FUNCTION); the others use the params file's channels"
            )

    @property
    def imu_messages(self) -> tuple[str, ...]:
        """The IMU messages sent, instance 0 first."""
        return PROFILES[self.name][0]

    @property
    def imu_rate_hz(self) -> float:
        """IMU messages per second."""
        return self.imu_hz if self.imu_hz is not None else PROFILES[self.name][1]

    @property
    def servo_rate_hz(self) -> float:
        """SERVO_OUTPUT_RAW per second."""
        return self.servo_hz if self.servo_hz is not None else PROFILES[self.name][2]

    def gps_rate_hz(self, scenario_hz: float) -> float:
        """Fixes per second (the scenario's own on ``native`` unless set)."""
        default = PROFILES[self.name][3]
        if self.gps_hz is not None:
            return self.gps_hz
        return default if default is not None else scenario_hz

    @property
    def truth_dt_s(self) -> float:
        """The truth simulator's step: 10 ms, or one IMU interval for a faster IMU."""
        return 1.0 / max(self.imu_rate_hz, TRUTH_RATE_HZ)

    @property
    def noise_factor(self) -> float:
        """Per-sample white-noise factor at the truth's step (same noise density)."""
        return math.sqrt(max(self.imu_rate_hz, TRUTH_RATE_HZ) / TRUTH_RATE_HZ)

    def describe(self) -> str:
        """One line for the operator: messages and rates."""
        layout = f", {self.servo_layout} servos" if self.name == "ardupilot" else ""
        return (
            f"{self.name}: {'+'.join(self.imu_messages)} at {self.imu_rate_hz:g} Hz, "
            f"SERVO_OUTPUT_RAW at {self.servo_rate_hz:g} Hz{layout}"
        )
