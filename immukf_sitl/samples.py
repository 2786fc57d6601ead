"""Sensor, actuator and truth samples in SI units: what the MAVLink layer decodes and the sim emits.

Plain frozen records with no MAVLink in them; :mod:`immukf_sitl.mavlink.codec` converts them to
and from HIGHRES_IMU, GPS_RAW_INT, SERVO_OUTPUT_RAW and (truth, for logs only)
HIL_STATE_QUATERNION.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


def _readonly_vector(values: object, n: int, name: str) -> np.ndarray:
    arr = np.array(values, dtype=float)
    if arr.shape != (n,):
        raise ValueError(f"{name}: expected {n} values, got shape {arr.shape}")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class ImuSample:
    """One HIGHRES_IMU sample.

    Attributes
    ----------
    time_s : float
        Sample time since the sender's boot (s).
    accel_mps2 : ndarray, shape (3,)
        Specific force, body FRD (m/s^2): about ``(0, 0, -9.8)`` in level flight.
    gyro_radps : ndarray, shape (3,)
        Body rates p, q, r (rad/s).
    """

    time_s: float
    accel_mps2: np.ndarray
    gyro_radps: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "accel_mps2", _readonly_vector(self.accel_mps2, 3, "accel"))
        object.__setattr__(self, "gyro_radps", _readonly_vector(self.gyro_radps, 3, "gyro"))

    def as_array(self) -> np.ndarray:
        """The six IMU channels ``[f_x, f_y, f_z, p, q, r]`` (docs/conventions.md)."""
        return np.concatenate([self.accel_mps2, self.gyro_radps])


@dataclass(frozen=True)
class GpsSample:
    """One GPS fix (GPS_RAW_INT, GPS2_RAW or HIL_GPS; a log's GPS record).

    Attributes
    ----------
    time_s : float
        Fix time since the sender's boot (s).
    lat_deg, lon_deg : float
        WGS-84 latitude and longitude (deg).
    alt_m : float
        Height (m). The project treats the ellipsoid as mean sea level (no geoid model): the sim
        writes the same value to ``alt`` and ``alt_ellipsoid``.
    ground_speed_mps : float
        Horizontal speed over the ground (m/s).
    course_rad : float
        Course over the ground (rad, 0 north, clockwise), in [-pi, pi).
    fix_type : int
        GPS_FIX_TYPE (3 = 3D fix).
    velocity_down_mps : float or None
        Vertical velocity over the ground, NED down (m/s); None where the source does not
        carry it (GPS_RAW_INT has no field for it).
    """

    time_s: float
    lat_deg: float
    lon_deg: float
    alt_m: float
    ground_speed_mps: float
    course_rad: float
    fix_type: int = 3
    velocity_down_mps: float | None = None


@dataclass(frozen=True)
class ActuatorSample:
    """One SERVO_OUTPUT_RAW: PWM per channel (channel 1 first).

    Attributes
    ----------
    time_s : float
        Time since the sender's boot (s).
    pwm_us : tuple of int
        Pulse widths of channels 1..16 (us); 0 means unused.
    """

    time_s: float
    pwm_us: tuple[int, ...]


@dataclass(frozen=True)
class TruthSample:
    """The simulation's truth at one step, as a flight log holds it (never sent to the estimator).

    Attributes
    ----------
    t_s : float
        Sim time (s).
    lat_deg, lon_deg, alt_m : float
        WGS-84 position (deg, deg, m above the ellipsoid).
    euler_rad : ndarray, shape (3,)
        Roll, pitch, yaw (ZYX).
    rates_radps : ndarray, shape (3,)
        Inertial body rates p, q, r (what a gyro measures).
    velocity_ned_mps : ndarray, shape (3,)
        Velocity over the ground, NED.
    specific_force_mps2 : ndarray, shape (3,)
        True specific force at the IMU, body FRD.
    airspeed_mps : float
        True airspeed.
    wind_ned_mps : ndarray, shape (3,)
        Total wind the aircraft feels (steady plus turbulence), NED.
    """

    t_s: float
    lat_deg: float
    lon_deg: float
    alt_m: float
    euler_rad: np.ndarray
    rates_radps: np.ndarray
    velocity_ned_mps: np.ndarray
    specific_force_mps2: np.ndarray
    airspeed_mps: float = 0.0
    wind_ned_mps: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def channel(self, index: int) -> float:
        """True value of IMU channel ``index`` (x, y, z specific force; p, q, r)."""
        return float(self.specific_force_mps2[index] if index < 3 else self.rates_radps[index - 3])
