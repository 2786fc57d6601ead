"""PX4 ULog (``.ulg``) flight logs: read with pyulog into a FlightLog, and written from one.

Reading takes what the estimator needs from PX4's uORB topics: the IMU from ``sensor_combined``
(or one ``vehicle_imu`` instance), GPS fixes from ``vehicle_gps_position`` or ``sensor_gps``,
PWM from ``actuator_outputs`` instance 0, the vehicle class from ``vehicle_status``, the
parameters, and the logged strings, whose ``SCENARIO``/``FAULT`` annotations give the faults.

Writing puts a :class:`~immukf_sitl.mavlink.flightlog.FlightLog` into a ULog file with PX4's
topic names, field names, units and field layout (fields ordered by size, padded to 8 bytes, as
PX4's logger writes them), the annotations as logged strings at their times. It exists so that
the project's simulated flights, with their injected faults, can be replayed as PX4 logs in
tests, since no public fixed-wing log with an IMU fault is at hand. The sim's truth is not
written: a PX4 log has none.
"""

from __future__ import annotations

import contextlib
import io
import math
import struct
from pathlib import Path

import numpy as np
from pyulog import ULog

from immukf_sitl.errors import UserError
from immukf_sitl.mavlink.flightlog import (
    Annotations,
    FlightLog,
    fault_annotation,
    scenario_annotation,
)
from immukf_sitl.samples import ActuatorSample, GpsSample, ImuSample
from immukf_sitl.vehicle import FIXED_WING, MULTICOPTER, vehicle_of_mav_type

#: File magic of every ULog, followed by the format version (1) and the start time (uint64 us)
MAGIC = b"ULog\x01\x12\x35"
_VERSION = 1
_ACCEL_INVALID = 0x7FFFFFFF  # sensor_combined.RELATIVE_TIMESTAMP_INVALID
_LOG_INFO = ord("6")  # logged-string level INFO (PX4 writes the ASCII digit)
_CODES = {"int8_t": "b", "uint8_t": "B", "int16_t": "h", "uint16_t": "H", "int32_t": "i",
          "uint32_t": "I", "int64_t": "q", "uint64_t": "Q", "float": "f", "double": "d",
          "bool": "?", "char": "c"}  # fmt: skip
_TOPICS = ["sensor_combined", "vehicle_imu", "vehicle_gps_position", "sensor_gps",
           "actuator_outputs", "vehicle_status"]  # fmt: skip

#: The layouts written, in PX4's order (uORB msg definitions, fields sorted by size)
SENSOR_COMBINED = ("uint64_t timestamp", "float[3] gyro_rad", "uint32_t gyro_integral_dt",
                   "int32_t accelerometer_timestamp_relative", "float[3] accelerometer_m_s2",
                   "uint32_t accelerometer_integral_dt", "uint8_t accelerometer_clipping",
                   "uint8_t gyro_clipping", "uint8_t accel_calibration_count",
                   "uint8_t gyro_calibration_count")  # fmt: skip
ACTUATOR_OUTPUTS = ("uint64_t timestamp", "uint32_t noutputs", "float[16] output")
VEHICLE_GPS_POSITION = ("uint64_t timestamp", "uint64_t time_utc_usec", "int32_t lat",
                        "int32_t lon", "int32_t alt", "int32_t alt_ellipsoid",
                        "float s_variance_m_s", "float c_variance_rad", "float eph", "float epv",
                        "float hdop", "float vdop", "int32_t noise_per_ms",
                        "int32_t jamming_indicator", "float vel_m_s", "float vel_n_m_s",
                        "float vel_e_m_s", "float vel_d_m_s", "float cog_rad",
                        "int32_t timestamp_time_relative", "float heading", "float heading_offset",
                        "uint8_t fix_type", "uint8_t jamming_state", "bool vel_ned_valid",
                        "uint8_t satellites_used", "uint8_t selected")  # fmt: skip
VEHICLE_STATUS = ("uint64_t timestamp", "uint8_t vehicle_type", "bool is_vtol",
                  "uint8_t system_type", "uint8_t system_id", "uint8_t component_id")  # fmt: skip


def is_ulog(head: bytes) -> bool:
    """Whether a file's first bytes are a ULog's (its 7-byte magic)."""
    return head[: len(MAGIC)] == MAGIC


def _message(kind: str, payload: bytes) -> bytes:
    """One ULog message: uint16 payload size, uint8 type, payload."""
    return struct.pack("<HB", len(payload), ord(kind)) + payload


def _key_value(type_name: str, key: str, value: bytes) -> bytes:
    key_bytes = f"{type_name} {key}".encode()
    return bytes([len(key_bytes)]) + key_bytes + value


class ULogWriter:
    """A ULog file assembled in memory: definitions first, then timed records in time order."""

    def __init__(self) -> None:
        self._definitions: list[bytes] = []
        self._topics: dict[str, tuple[int, struct.Struct, list[tuple[str, int]]]] = {}
        self._timed: list[tuple[int, int, bytes]] = []

    def info(self, key: str, text: str) -> None:
        """An information message (``sys_name``, ``ver_sw``) of type ``char[n]``."""
        raw = text.encode()
        self._definitions.append(_message("I", _key_value(f"char[{len(raw)}]", key, raw)))

    def param(self, name: str, value: float) -> None:
        """An initial parameter: int32 for an integer value, float (float32) otherwise."""
        if isinstance(value, (int, np.integer)):
            entry = _key_value("int32_t", name, struct.pack("<i", int(value)))
        else:
            entry = _key_value("float", name, struct.pack("<f", float(value)))
        self._definitions.append(_message("P", entry))

    def topic(self, name: str, fields: tuple[str, ...]) -> None:
        """A topic's format (``"float[3] gyro_rad"``...), padded to 8 bytes like PX4's."""
        layout, codes = [], "<"
        for spec in fields:
            ctype, field_name = spec.split()
            base, _, count = ctype.partition("[")
            n = int(count.rstrip("]")) if count else 0
            layout.append((field_name, n))
            codes += f"{n or ''}{_CODES[base]}"
        body = struct.Struct(codes)
        pad = -body.size % 8
        text = name + ":" + "".join(f"{s};" for s in fields)
        text += f"uint8_t[{pad}] _padding0;" if pad else ""
        self._definitions.append(_message("F", text.encode()))
        self._topics[name] = (len(self._topics), body, layout)

    def data(self, name: str, t_us: int, **values: object) -> None:
        """One record of a topic at ``t_us``: fields not given are 0, trailing padding unwritten."""
        msg_id, body, layout = self._topics[name]
        flat: list[object] = []
        for field_name, count in layout:
            value = t_us if field_name == "timestamp" else values.get(field_name, 0)
            flat.extend(value if count else [value])  # type: ignore[arg-type]
        record = _message("D", struct.pack("<H", msg_id) + body.pack(*flat))
        self._timed.append((t_us, len(self._timed), record))

    def text(self, t_us: int, text: str) -> None:
        """A logged string (level INFO) at ``t_us``."""
        record = _message("L", struct.pack("<BQ", _LOG_INFO, t_us) + text.encode())
        self._timed.append((t_us, len(self._timed), record))

    def write(self, path: str | Path) -> int:
        """Write the file; returns the bytes written."""
        start_us = min((t for t, _, _ in self._timed), default=0)
        out = [MAGIC, bytes([_VERSION]), struct.pack("<Q", start_us)]
        out.append(_message("B", bytes(16) + struct.pack("<3Q", 0, 0, 0)))  # no flags, no append
        out += self._definitions
        out += [_message("A", struct.pack("<BH", 0, i) + name.encode())
                for name, (i, _, _) in self._topics.items()]  # fmt: skip
        out += [record for _, _, record in sorted(self._timed)]
        blob = b"".join(out)
        Path(path).write_bytes(blob)
        return len(blob)


def _us(t_s: float) -> int:
    return int(round(t_s * 1e6))


def _status_of(system_type: int) -> tuple[int, bool]:
    """PX4's ``vehicle_type`` (1 rotary wing, 2 fixed wing) and ``is_vtol`` of a MAV_TYPE."""
    vtol = system_type in (19, 20, 21, 22, 23, 24, 25, 47)
    kind = vehicle_of_mav_type(system_type)
    return {FIXED_WING: 2, MULTICOPTER: 1, "helicopter": 1, "airship": 4}.get(kind, 0), vtol


def write_ulog(
    path: str | Path, log: FlightLog, system_type: int = 1, params: dict[str, float] | None = None
) -> int:
    """Write a flight log as a PX4 ULog (see the module docstring).

    Parameters
    ----------
    path : str or Path
        The ``.ulg`` file to write.
    log : FlightLog
        The stream (IMU, GPS, PWM), its faults and scenario; ``log.params`` are written too.
    system_type : int
        MAV_TYPE of ``vehicle_status.system_type`` (1 fixed wing, 2 quadrotor).
    params : dict, optional
        Parameters over ``log.params``: an int is written as int32, anything else as float.

    Returns
    -------
    int
        Bytes written.
    """
    w = ULogWriter()
    w.info("sys_name", "PX4")
    w.info("ver_sw", "immukf-sitl writer")
    for name, value in {**log.params, **(params or {})}.items():
        w.param(name, value)
    for name, fields in (("sensor_combined", SENSOR_COMBINED), ("actuator_outputs",
                         ACTUATOR_OUTPUTS), ("vehicle_gps_position", VEHICLE_GPS_POSITION),
                         ("vehicle_status", VEHICLE_STATUS)):  # fmt: skip
        w.topic(name, fields)
    imu_us = [_us(s.time_s) for s in log.stream if isinstance(s, ImuSample)]
    last_us = 2 * imu_us[0] - imu_us[1] if len(imu_us) > 1 else (imu_us or [0])[0]  # 1st dt
    for s in log.stream:
        t_us = _us(s.time_s)
        if isinstance(s, ImuSample):
            dt_us, last_us = max(t_us - last_us, 0), t_us
            w.data("sensor_combined", t_us, gyro_rad=s.gyro_radps, gyro_integral_dt=dt_us,
                   accelerometer_m_s2=s.accel_mps2, accelerometer_integral_dt=dt_us)  # fmt: skip
        elif isinstance(s, GpsSample):
            alt_mm = int(round(s.alt_m * 1e3))
            vd = s.velocity_down_mps
            w.data("vehicle_gps_position", t_us, lat=int(round(s.lat_deg * 1e7)),
                   lon=int(round(s.lon_deg * 1e7)), alt=alt_mm, alt_ellipsoid=alt_mm,
                   vel_m_s=s.ground_speed_mps, cog_rad=s.course_rad, fix_type=s.fix_type,
                   vel_n_m_s=s.ground_speed_mps * math.cos(s.course_rad),
                   vel_e_m_s=s.ground_speed_mps * math.sin(s.course_rad),
                   vel_d_m_s=0.0 if vd is None else vd, vel_ned_valid=vd is not None,
                   heading=math.nan, heading_offset=math.nan)  # fmt: skip
        elif isinstance(s, ActuatorSample):
            pwm = [float(p) for p in s.pwm_us[:16]] + [0.0] * (16 - min(len(s.pwm_us), 16))
            used = max((k + 1 for k, p in enumerate(pwm) if p), default=0)
            w.data("actuator_outputs", t_us, noutputs=used, output=pwm)
    times_us = [_us(s.time_s) for s in log.stream] or [0]
    vehicle_type, vtol = _status_of(system_type)
    for t_us in range(min(times_us), max(times_us) + 1, 1_000_000):  # 1 Hz, as PX4 about does
        w.data("vehicle_status", t_us, vehicle_type=vehicle_type, is_vtol=vtol,
               system_type=system_type, system_id=1, component_id=1)  # fmt: skip
    if log.scenario:
        w.text(min(times_us), scenario_annotation(log.scenario))
    for f in log.faults_seen():  # the faults of the IMU written (as sensor_combined)
        w.text(_us(f.t_s), fault_annotation(f.kind, f.channels, f.t_s, f.value, False, f.rate_hz))
        if f.end_t_s is not None:
            w.text(_us(f.end_t_s), fault_annotation(f.kind, f.channels, f.end_t_s, end=True))
    return w.write(path)


def _load(path: Path) -> ULog:
    """The pyulog parse of the topics needed (its warnings on stdout kept off the user's)."""
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            return ULog(str(path), _TOPICS)
    except Exception as exc:  # pyulog raises plain Exception, struct.error... on a broken file
        reason = (str(exc).splitlines() or [type(exc).__name__])[0]
        raise UserError(f"{path}: unreadable ULog file ({reason})") from None


def _vec(data: dict[str, np.ndarray], name: str, n: int = 3) -> np.ndarray:
    return np.column_stack([data[f"{name}[{k}]"].astype(float) for k in range(n)])


def _imu_streams(ulog: ULog) -> dict[str, dict[str, np.ndarray]]:
    streams = {f"{d.name}[{d.multi_id}]": d.data for d in ulog.data_list if d.name == "vehicle_imu"}
    combined = [d.data for d in ulog.data_list if d.name == "sensor_combined" and d.multi_id == 0]
    return ({"sensor_combined": combined[0]} if combined else {}) | streams  # by instance


def _imu_samples(name: str, data: dict[str, np.ndarray]) -> list[ImuSample]:
    """IMU samples of sensor_combined (rates, specific force) or a vehicle_imu (deltas / dt)."""
    if name == "sensor_combined":
        t_us, gyro = data["timestamp"], _vec(data, "gyro_rad")
        accel = _vec(data, "accelerometer_m_s2")
        rel = data.get("accelerometer_timestamp_relative")
        ok = rel != _ACCEL_INVALID if rel is not None else np.ones(len(t_us), bool)
    else:
        t_us = data.get("timestamp_sample", data["timestamp"])
        dt_gyro_s = data["delta_angle_dt"].astype(float)[:, None] * 1e-6
        dt_accel_s = data["delta_velocity_dt"].astype(float)[:, None] * 1e-6
        ok = (dt_gyro_s[:, 0] > 0) & (dt_accel_s[:, 0] > 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            gyro = _vec(data, "delta_angle") / dt_gyro_s
            accel = _vec(data, "delta_velocity") / dt_accel_s
    return [ImuSample(int(t_us[k]) * 1e-6, accel[k], gyro[k]) for k in np.flatnonzero(ok)]


def _dataset(ulog: ULog, *names: str) -> dict[str, np.ndarray] | None:
    """Instance 0 of the first of ``names`` in the log."""
    for name in names:
        for d in ulog.data_list:
            if d.name == name and d.multi_id == 0:
                return d.data
    return None


def _gps_samples(ulog: ULog) -> list[GpsSample]:
    """3D fixes of vehicle_gps_position or sensor_gps (int degE7/mm or the newer doubles).

    Each with its ``vel_d_m_s`` (NED down) where ``vel_ned_valid`` says the receiver gave it.
    """
    data = _dataset(ulog, "vehicle_gps_position", "sensor_gps")
    if data is None:
        return []
    if "latitude_deg" in data:
        lat, lon, alt = data["latitude_deg"], data["longitude_deg"], data["altitude_msl_m"]
    else:
        lat, lon, alt = data["lat"] * 1e-7, data["lon"] * 1e-7, data["alt"] * 1e-3
    course = (data["cog_rad"].astype(float) + math.pi) % (2.0 * math.pi) - math.pi
    speed, fix, t_us = data["vel_m_s"].astype(float), data["fix_type"], data["timestamp"]
    down = np.full(len(t_us), np.nan)
    if "vel_d_m_s" in data and "vel_ned_valid" in data:  # NED down, where the receiver has it
        down = np.where(data["vel_ned_valid"] != 0, data["vel_d_m_s"].astype(float), np.nan)
    return [
        GpsSample(int(t_us[k]) * 1e-6, float(lat[k]), float(lon[k]), float(alt[k]),
                  float(speed[k]), float(course[k]), int(fix[k]),
                  float(down[k]) if math.isfinite(down[k]) else None)
        for k in np.flatnonzero(fix >= 3)
    ]  # fmt: skip


def _actuator_samples(ulog: ULog) -> list[ActuatorSample]:
    """PWM of actuator_outputs instance 0 (channels past ``noutputs`` are 0)."""
    data = _dataset(ulog, "actuator_outputs")
    if data is None:
        return []
    n_channels = sum(1 for key in data if key.startswith("output["))
    out = np.nan_to_num(_vec(data, "output", n_channels))
    out[np.arange(n_channels)[None, :] >= data["noutputs"][:, None]] = 0.0
    pwm = np.rint(out).astype(int)
    return [ActuatorSample(int(t) * 1e-6, tuple(int(p) for p in row))
            for t, row in zip(data["timestamp"], pwm, strict=True)]  # fmt: skip


def _vehicle(ulog: ULog, params: dict[str, float]) -> tuple[str | None, str]:
    """What flew: vehicle_status system_type, else its vehicle_type/is_vtol, else MAV_TYPE."""
    status = _dataset(ulog, "vehicle_status") or {}
    if "system_type" in status:
        mav_type = int(status["system_type"][-1])
        if vehicle_of_mav_type(mav_type):
            return vehicle_of_mav_type(mav_type), f"vehicle_status system_type {mav_type}"
    if "is_vtol" in status and status["is_vtol"].any():
        return FIXED_WING, "vehicle_status is_vtol"
    if "vehicle_type" in status:
        kind = int(status["vehicle_type"][-1])
        if kind in (1, 2):
            return (MULTICOPTER, FIXED_WING)[kind - 1], f"vehicle_status vehicle_type {kind}"
    if "MAV_TYPE" in params and vehicle_of_mav_type(int(params["MAV_TYPE"])):
        mav_type = int(params["MAV_TYPE"])
        return vehicle_of_mav_type(mav_type), f"parameter MAV_TYPE {mav_type}"
    return None, ""


def read_ulog(path: str | Path, imu: int | None = None) -> FlightLog:
    """Parse a PX4 ULog into a :class:`~immukf_sitl.mavlink.flightlog.FlightLog`.

    Parameters
    ----------
    path : str or Path
        The ``.ulg`` file. A truncated file gives its whole records (pyulog stops at the cut).
    imu : int, optional
        ``vehicle_imu`` instance to take the IMU from; None takes ``sensor_combined`` (or, in
        a log without it, the first ``vehicle_imu``).

    Returns
    -------
    FlightLog
        ``kind="ulog"``; ``bad_records`` is 1 when pyulog found corruption (it does not count).

    Raises
    ------
    UserError
        A missing file, a file that is not a ULog or that pyulog cannot parse, or an ``imu``
        instance that is not in the log.
    """
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: no such log")
    with path.open("rb") as handle:
        if not is_ulog(handle.read(len(MAGIC))):
            raise UserError(f"{path}: not a PX4 ULog file (it does not begin with 'ULog')")
    ulog = _load(path)
    params = dict(ulog.initial_parameters)
    params.update({name: value for _, name, value in ulog.changed_parameters})
    log = FlightLog(kind="ulog", params=params, bad_records=int(bool(ulog.file_corruption)))
    streams = _imu_streams(ulog)
    log.imu_sources = {name: len(data["timestamp"]) for name, data in streams.items()}
    if imu is not None:
        log.imu_source = f"vehicle_imu[{imu}]"
        if log.imu_source not in streams:
            there = ", ".join(f"{n} ({c} samples)" for n, c in log.imu_sources.items())
            raise UserError(f"{path}: no {log.imu_source} in this log; it has {there or 'no IMU'}")
    else:
        log.imu_source = next(iter(streams), "")
    if log.imu_source:  # sensor_combined is the primary IMU's, instance 0
        prefix = "vehicle_imu["
        is_instance = log.imu_source.startswith(prefix)
        log.imu_instance = int(log.imu_source[len(prefix) : -1]) if is_instance else 0
    try:
        imu_samples = _imu_samples(log.imu_source, streams[log.imu_source]) if streams else []
        # at equal times a step's servo outputs and fix come before the IMU sample that steps
        # the filter (the order the sim and the autopilots send them in)
        stream = [*_gps_samples(ulog), *_actuator_samples(ulog), *imu_samples]
    except KeyError as exc:  # a topic of another layout than PX4's
        raise UserError(f"{path}: a ULog topic lacks the field {exc}") from None
    log.stream = sorted(stream, key=lambda s: s.time_s)  # stable: the order above at ties
    log.vehicle, log.vehicle_evidence = _vehicle(ulog, params)
    texts = [(m.timestamp, m.message) for m in ulog.logged_messages]
    texts += [(m.timestamp, m.message) for ms in ulog.logged_messages_tagged.values() for m in ms]
    notes = Annotations()
    for _, text in sorted(texts, key=lambda item: item[0]):
        notes.feed(text)
    log.faults, log.scenario = notes.faults, notes.scenario
    return log
