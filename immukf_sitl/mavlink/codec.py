"""Conversions between MAVLink messages and the SI samples of :mod:`immukf_sitl.samples`.

Units on the wire (MAVLink common): HIGHRES_IMU m/s^2 and rad/s; GPS_RAW_INT lat/lon degE7,
alt mm, vel cm/s, cog cdeg (0..35999, 65535 unknown); SERVO_OUTPUT_RAW us.
"""

from __future__ import annotations

import math

import numpy as np

from immukf_sitl.mavlink.wire import MavMessage, mavlink
from immukf_sitl.samples import ActuatorSample, GpsSample, ImuSample

#: HIGHRES_IMU fields_updated bits of the six inertial channels (XACC..ZGYRO).
IMU_FIELDS_BITS = 0x3F
GPS_COG_UNKNOWN = 65535
#: Beyond these a reading is not a measurement but a corrupt packet (16 g, 2000 deg/s).
MAX_ACCEL_MPS2 = 16 * 9.80665
MAX_RATE_RADPS = math.radians(2000.0)
N_SERVO_CHANNELS = 16


class DecodeError(ValueError):
    """A message whose fields are not usable (NaN, out of range): counted as a bad packet."""


def usec(time_s: float) -> int:
    """Seconds to the integer microseconds of a MAVLink ``time_usec`` field."""
    return int(round(time_s * 1e6))


def highres_imu_message(sample: ImuSample, imu_id: int = 0) -> MavMessage:
    """HIGHRES_IMU with the six inertial channels set and flagged in ``fields_updated``."""
    a, g = sample.accel_mps2, sample.gyro_radps
    nan = float("nan")
    return mavlink.MAVLink_highres_imu_message(
        usec(sample.time_s),
        float(a[0]), float(a[1]), float(a[2]),
        float(g[0]), float(g[1]), float(g[2]),
        nan, nan, nan, nan, nan, nan, nan,
        IMU_FIELDS_BITS,
        imu_id,
    )  # fmt: skip


def decode_highres_imu(msg: MavMessage) -> ImuSample:
    """HIGHRES_IMU to an :class:`ImuSample`; raises :class:`DecodeError` on unusable fields."""
    if msg.fields_updated & IMU_FIELDS_BITS != IMU_FIELDS_BITS:
        raise DecodeError(f"HIGHRES_IMU fields_updated {msg.fields_updated:#x} lacks the IMU bits")
    values = (msg.xacc, msg.yacc, msg.zacc, msg.xgyro, msg.ygyro, msg.zgyro)
    if not all(math.isfinite(v) for v in values):
        raise DecodeError("HIGHRES_IMU has a non-finite inertial field")
    if (
        max(abs(v) for v in values[:3]) > MAX_ACCEL_MPS2
        or max(abs(v) for v in values[3:]) > MAX_RATE_RADPS
    ):
        raise DecodeError("HIGHRES_IMU value beyond any sensor's range")
    return ImuSample(msg.time_usec * 1e-6, values[:3], values[3:])


def gps_raw_int_message(sample: GpsSample, satellites: int = 12) -> MavMessage:
    """GPS_RAW_INT of a fix; the height goes to both ``alt`` and ``alt_ellipsoid``."""
    course_cdeg = int(round(math.degrees(sample.course_rad) * 100.0)) % 36000
    alt_mm = int(round(sample.alt_m * 1000.0))
    return mavlink.MAVLink_gps_raw_int_message(
        usec(sample.time_s),
        int(sample.fix_type),
        int(round(sample.lat_deg * 1e7)),
        int(round(sample.lon_deg * 1e7)),
        alt_mm,
        70,  # eph: HDOP x 100 (unitless)
        120,  # epv: VDOP x 100
        max(0, min(65534, int(round(sample.ground_speed_mps * 100.0)))),
        course_cdeg,
        satellites,
        alt_mm,
    )


def decode_gps_raw_int(msg: MavMessage) -> GpsSample:
    """GPS_RAW_INT to a :class:`GpsSample`; raises :class:`DecodeError` without a 3D fix."""
    if msg.fix_type < mavlink.GPS_FIX_TYPE_3D_FIX:
        raise DecodeError(f"GPS_RAW_INT fix_type {msg.fix_type} is not a 3D fix")
    if msg.cog == GPS_COG_UNKNOWN or msg.vel == 65535:
        raise DecodeError("GPS_RAW_INT has no ground speed or course")
    alt_mm = msg.alt_ellipsoid if getattr(msg, "alt_ellipsoid", 0) else msg.alt
    course = math.radians(msg.cog / 100.0)
    course = (course + math.pi) % (2.0 * math.pi) - math.pi
    return GpsSample(
        msg.time_usec * 1e-6,
        msg.lat * 1e-7,
        msg.lon * 1e-7,
        alt_mm * 1e-3,
        msg.vel / 100.0,
        course,
        int(msg.fix_type),
    )


def servo_output_raw_message(sample: ActuatorSample) -> MavMessage:
    """SERVO_OUTPUT_RAW of 16 channels (``time_usec`` is 32-bit: it wraps after 71 minutes)."""
    pwm = list(sample.pwm_us) + [0] * (N_SERVO_CHANNELS - len(sample.pwm_us))
    return mavlink.MAVLink_servo_output_raw_message(
        usec(sample.time_s) & 0xFFFFFFFF, 0, *pwm[:N_SERVO_CHANNELS]
    )


def decode_servo_output_raw(msg: MavMessage) -> ActuatorSample:
    """SERVO_OUTPUT_RAW to an :class:`ActuatorSample`."""
    pwm = tuple(int(getattr(msg, f"servo{i}_raw", 0)) for i in range(1, N_SERVO_CHANNELS + 1))
    return ActuatorSample(msg.time_usec * 1e-6, pwm)


def euler_to_quaternion(euler_rad: np.ndarray) -> np.ndarray:
    """ZYX Euler angles (roll, pitch, yaw) to a unit quaternion ``[w, x, y, z]`` (MAVLink order)."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_euler("ZYX", np.asarray(euler_rad)[::-1]).as_quat()
    return np.array([w, x, y, z])


def quaternion_to_euler(q_wxyz: np.ndarray) -> np.ndarray:
    """Unit quaternion ``[w, x, y, z]`` to ZYX Euler angles (roll, pitch, yaw)."""
    from scipy.spatial.transform import Rotation

    w, x, y, z = q_wxyz
    return Rotation.from_quat([x, y, z, w]).as_euler("ZYX")[::-1]
