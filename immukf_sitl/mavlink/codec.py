"""Conversions between MAVLink messages and the SI records of :mod:`immukf_sitl.samples`.

Every message the project builds or reads field by field is converted here (the serve loop, the
sim's emitter, the proxy and the log readers call these; nothing else touches message fields).
Units on the wire (MAVLink common): HIGHRES_IMU m/s^2 and rad/s; GPS_RAW_INT lat/lon degE7,
alt mm, vel cm/s, cog cdeg (0..35999, 65535 unknown), and HIL_GPS the same with vn, ve, vd
cm/s; SERVO_OUTPUT_RAW us; HIL_STATE_QUATERNION degE7, mm, cm/s and mG.
"""

from __future__ import annotations

import math

import numpy as np

from immukf_sitl.mavlink.signing import frame_signature_fields
from immukf_sitl.mavlink.wire import MavMessage, mavlink
from immukf_sitl.models.earth import isa_density_unchecked
from immukf_sitl.samples import ActuatorSample, GpsSample, ImuSample, TruthSample

#: HIGHRES_IMU fields_updated bits of the six inertial channels (XACC..ZGYRO).
IMU_FIELDS_BITS = 0x3F
GPS_COG_UNKNOWN = 65535
#: Beyond these a reading is not a measurement but a corrupt packet (16 g, 2000 deg/s).
MAX_ACCEL_MPS2 = 16 * 9.80665
MAX_RATE_RADPS = math.radians(2000.0)
N_SERVO_CHANNELS = 16
#: Standard gravity: specific force in mG for HIL_STATE_QUATERNION (MAVLink common).
G0_MPS2 = 9.80665
#: ISA sea-level density: indicated airspeed from the true airspeed (kg/m^3).
RHO_SEA_LEVEL_KGPM3 = 1.225


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


#: The IMU messages the autopilots send: HIGHRES_IMU (PX4, this project's sim; SI floats),
#: RAW_IMU (ArduPilot fills it scaled, in the units of SCALED_IMU) and SCALED_IMU, SCALED_IMU2,
#: SCALED_IMU3 (mG and mrad/s in int16, ``time_boot_ms``).
IMU_MESSAGES = ("HIGHRES_IMU", "RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3")
#: The instance of the scaled messages that carry none in their fields.
_SCALED_INSTANCE = {"SCALED_IMU": 0, "SCALED_IMU2": 1, "SCALED_IMU3": 2}
#: One mG in m/s^2 and one mrad/s in rad/s: the integer units of RAW_IMU and SCALED_IMU*.
MG_MPS2 = G0_MPS2 / 1000.0
MRAD_RADPS = 1e-3


def imu_instance(msg: MavMessage) -> int:
    """Which IMU of the autopilot a message is from (``id``; SCALED_IMU2 is 1, SCALED_IMU3 2)."""
    kind = msg.get_type()
    if kind in _SCALED_INSTANCE:
        return _SCALED_INSTANCE[kind]
    return int(getattr(msg, "id", 0) or 0)


def decode_imu(msg: MavMessage) -> ImuSample:
    """Any of :data:`IMU_MESSAGES` to an :class:`ImuSample` in SI units.

    RAW_IMU and SCALED_IMU* carry int16 mG and mrad/s (a quantum of 0.0098 m/s^2 and
    0.001 rad/s); RAW_IMU's time is ``time_usec``, the scaled ones' ``time_boot_ms``.
    Raises :class:`DecodeError` on unusable fields.
    """
    kind = msg.get_type()
    if kind == "HIGHRES_IMU":
        return decode_highres_imu(msg)
    time_s = msg.time_usec * 1e-6 if kind == "RAW_IMU" else msg.time_boot_ms * 1e-3
    accel = np.array([msg.xacc, msg.yacc, msg.zacc], dtype=float) * MG_MPS2
    gyro = np.array([msg.xgyro, msg.ygyro, msg.zgyro], dtype=float) * MRAD_RADPS
    if np.max(np.abs(accel)) > MAX_ACCEL_MPS2 or np.max(np.abs(gyro)) > MAX_RATE_RADPS:
        raise DecodeError(f"{kind} value beyond any sensor's range")
    return ImuSample(time_s, accel, gyro)


def _imu_wire_fields(kind: str, sample: ImuSample) -> dict[str, float | int]:
    """The six inertial fields of ``kind`` for ``sample``, in its units and quantisation."""
    a, g = sample.accel_mps2, sample.gyro_radps
    if kind == "HIGHRES_IMU":
        values = [float(v) for v in (*a, *g)]
    else:
        values = [_int16(v / MG_MPS2) for v in a] + [_int16(v / MRAD_RADPS) for v in g]
    names = ("xacc", "yacc", "zacc", "xgyro", "ygyro", "zgyro")
    return dict(zip(names, values, strict=True))


def imu_message(kind: str, sample: ImuSample, instance: int = 0) -> MavMessage:
    """``sample`` as one of :data:`IMU_MESSAGES`, quantised as the autopilots send it.

    The magnetometer fields are zero (the estimator does not use them); RAW_IMU and HIGHRES_IMU
    carry ``instance`` in ``id``, SCALED_IMU2/3 are instances 1 and 2 by their name.
    """
    if kind == "HIGHRES_IMU":
        return highres_imu_message(sample, instance)
    fields = _imu_wire_fields(kind, sample)
    six = [fields[n] for n in ("xacc", "yacc", "zacc", "xgyro", "ygyro", "zgyro")]
    if kind == "RAW_IMU":
        return mavlink.MAVLink_raw_imu_message(usec(sample.time_s), *six, 0, 0, 0, instance, 0)
    boot_ms = int(round(sample.time_s * 1000.0)) & 0xFFFFFFFF
    factory = {
        "SCALED_IMU": mavlink.MAVLink_scaled_imu_message,
        "SCALED_IMU2": mavlink.MAVLink_scaled_imu2_message,
        "SCALED_IMU3": mavlink.MAVLink_scaled_imu3_message,
    }[kind]
    return factory(boot_ms, *six, 0, 0, 0, 0)


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


def hil_gps_message(sample: GpsSample, satellites: int = 12) -> MavMessage:
    """HIL_GPS of a fix that carries its vertical velocity (GPS_RAW_INT has no field for it).

    HIL_GPS is MAVLink's raw-receiver message with the NED velocity (``vn``, ``ve``, ``vd``,
    cm/s); ``vn`` and ``ve`` are the ground speed along the course.
    """
    if sample.velocity_down_mps is None:
        raise ValueError("HIL_GPS needs the fix's vertical velocity")
    speed_cmps = sample.ground_speed_mps * 100.0
    return mavlink.MAVLink_hil_gps_message(
        usec(sample.time_s),
        int(sample.fix_type),
        int(round(sample.lat_deg * 1e7)),
        int(round(sample.lon_deg * 1e7)),
        int(round(sample.alt_m * 1000.0)),
        70,  # eph: HDOP x 100
        120,  # epv: VDOP x 100
        max(0, min(65534, int(round(speed_cmps)))),
        _cmps(speed_cmps * math.cos(sample.course_rad)),
        _cmps(speed_cmps * math.sin(sample.course_rad)),
        _cmps(sample.velocity_down_mps * 100.0),
        int(round(math.degrees(sample.course_rad) * 100.0)) % 36000,
        satellites,
    )


def gps_message(sample: GpsSample) -> MavMessage:
    """The message of a fix: HIL_GPS where it carries its vertical velocity, else GPS_RAW_INT."""
    return (
        gps_raw_int_message(sample) if sample.velocity_down_mps is None else hil_gps_message(sample)
    )


def _cmps(value_cmps: float) -> int:
    """A velocity component in HIL_GPS's int16 cm/s, saturated."""
    return max(-32767, min(32767, int(round(value_cmps))))


def decode_gps(msg: MavMessage) -> GpsSample:
    """GPS_RAW_INT, GPS2_RAW or HIL_GPS to a :class:`GpsSample` (HIL_GPS's with ``vD``).

    Raises :class:`DecodeError` without a 3D fix, a ground speed and a course.
    """
    kind = msg.get_type()
    if msg.fix_type < mavlink.GPS_FIX_TYPE_3D_FIX:
        raise DecodeError(f"{kind} fix_type {msg.fix_type} is not a 3D fix")
    if msg.cog == GPS_COG_UNKNOWN or msg.vel == 65535:
        raise DecodeError(f"{kind} has no ground speed or course")
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
        msg.vd / 100.0 if kind == "HIL_GPS" else None,
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
    """ZYX Euler angles (roll, pitch, yaw) to a unit quaternion ``[w, x, y, z]`` (MAVLink order).

    The closed form of ``Rz(yaw) Ry(pitch) Rx(roll)``, equal to scipy's
    ``Rotation.from_euler("ZYX", [yaw, pitch, roll])`` to rounding; it is on serve's path to
    every ATTITUDE_QUATERNION, where scipy's object costs ten times as much.
    """
    roll, pitch, yaw = (0.5 * float(a) for a in euler_rad)
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return np.array(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ]
    )


def quaternion_to_euler(q_wxyz: np.ndarray) -> np.ndarray:
    """Unit quaternion ``[w, x, y, z]`` to ZYX Euler angles (roll, pitch, yaw)."""
    from scipy.spatial.transform import Rotation

    w, x, y, z = q_wxyz
    return Rotation.from_quat([x, y, z, w]).as_euler("ZYX")[::-1]


def heartbeat_message(mav_type: int, autopilot: int = mavlink.MAV_AUTOPILOT_INVALID) -> MavMessage:
    """HEARTBEAT of a vehicle or component of ``mav_type``, active (default: no flight stack)."""
    return mavlink.MAVLink_heartbeat_message(mav_type, autopilot, 0, 0, mavlink.MAV_STATE_ACTIVE, 3)


def statustext_message(text: str, severity: int = mavlink.MAV_SEVERITY_INFO) -> MavMessage:
    """STATUSTEXT of at most 50 characters (longer texts are cut)."""
    return mavlink.MAVLink_statustext_message(severity, text[:50].encode())


def _int16(value: float) -> int:
    return int(max(-32768, min(32767, round(value))))


def _uint16(value: float) -> int:
    return int(max(0, min(65535, round(value))))


def truth_message(truth: TruthSample) -> MavMessage:
    """HIL_STATE_QUATERNION of the sim's truth (for the tlog only, never sent).

    Attitude quaternion ``[w, x, y, z]`` of the ZYX Euler angles (body FRD to NED); rates are the
    inertial body rates a gyro measures (rad/s); ``vx, vy, vz`` NED velocity (cm/s);
    ``xacc..zacc`` the true specific force at the IMU (mG).
    """
    velocity_cmps = np.asarray(truth.velocity_ned_mps) * 100.0
    force_mg = np.asarray(truth.specific_force_mps2) / G0_MPS2 * 1000.0
    density = float(isa_density_unchecked(truth.alt_m))
    indicated_mps = truth.airspeed_mps * math.sqrt(density / RHO_SEA_LEVEL_KGPM3)
    rates = truth.rates_radps
    return mavlink.MAVLink_hil_state_quaternion_message(
        usec(truth.t_s),
        [float(c) for c in euler_to_quaternion(truth.euler_rad)],
        float(rates[0]),
        float(rates[1]),
        float(rates[2]),
        int(round(truth.lat_deg * 1e7)),
        int(round(truth.lon_deg * 1e7)),
        int(round(truth.alt_m * 1000.0)),
        *(_int16(v) for v in velocity_cmps),
        _uint16(indicated_mps * 100.0),
        _uint16(truth.airspeed_mps * 100.0),
        *(_int16(f) for f in force_mg),
    )


def truth_wind_message(truth: TruthSample) -> MavMessage:
    """WIND_COV of the total wind the aircraft felt (truth, for the tlog only, never sent).

    ``wind_x, wind_y, wind_z`` are NED (m/s), ``time_usec`` the truth's; the variances are 0
    (it is the truth) and ``wind_alt`` the height above the ellipsoid (m).
    """
    wind = np.asarray(truth.wind_ned_mps, dtype=float)
    return mavlink.MAVLink_wind_cov_message(
        usec(truth.t_s), float(wind[0]), float(wind[1]), float(wind[2]), 0.0, 0.0,
        float(truth.alt_m), 0.0, 0.0,
    )  # fmt: skip


def decode_truth_wind(msg: MavMessage) -> tuple[float, np.ndarray]:
    """WIND_COV of the truth to ``(t_s, wind_ned_mps)``."""
    return msg.time_usec * 1e-6, np.array([msg.wind_x, msg.wind_y, msg.wind_z], dtype=float)


def decode_truth(msg: MavMessage) -> TruthSample:
    """HIL_STATE_QUATERNION to a :class:`TruthSample`."""
    return TruthSample(
        t_s=msg.time_usec * 1e-6,
        lat_deg=msg.lat * 1e-7,
        lon_deg=msg.lon * 1e-7,
        alt_m=msg.alt * 1e-3,
        euler_rad=quaternion_to_euler(np.array(msg.attitude_quaternion, dtype=float)),
        rates_radps=np.array([msg.rollspeed, msg.pitchspeed, msg.yawspeed]),
        velocity_ned_mps=np.array([msg.vx, msg.vy, msg.vz]) / 100.0,
        specific_force_mps2=np.array([msg.xacc, msg.yacc, msg.zacc]) * (G0_MPS2 / 1000.0),
        airspeed_mps=msg.true_airspeed / 100.0,
    )


def repack_imu(original: MavMessage, sample: ImuSample, signing_key: bytes | None = None) -> bytes:
    """A frame like ``original`` (any of :data:`IMU_MESSAGES`) with the six channels of ``sample``.

    The channels are written in the message's own units and quantisation; every other field
    (time, magnetometer, pressure, ``fields_updated``, ``id``), the source system and component,
    the sequence number and the protocol version are kept. A signed ``original`` (one whose
    signature the caller's parser verified) is signed again with ``signing_key`` by pymavlink,
    with its own link id and timestamp, so that it stays in its sender's stream; without a key
    the frame goes out unsigned.
    """
    kind = original.get_type()
    names = original.get_fieldnames()
    values = {name: getattr(original, name) for name in names}
    values.update(_imu_wire_fields(kind, sample))
    message = getattr(mavlink, f"MAVLink_{kind.lower()}_message")(*(values[n] for n in names))
    encoder = mavlink.MAVLink(None, original.get_srcSystem(), original.get_srcComponent())
    encoder.seq = original.get_seq()
    frame = original.get_msgbuf()
    mavlink1 = frame[0] == mavlink.PROTOCOL_MARKER_V1
    if signing_key is not None and original.get_signed():
        encoder.signing.secret_key = signing_key
        encoder.signing.sign_outgoing = True
        encoder.signing.link_id, encoder.signing.timestamp = frame_signature_fields(frame)
    return bytes(message.pack(encoder, force_mavlink1=mavlink1))
