"""ArduPilot DataFlash ``.bin`` logs: read into a :class:`FlightLog`, and written from one.

A DataFlash log is a sequence of records, each ``0xA3 0x95 <type>`` and a packed little-endian
body. It describes itself: FMT records (type 128) give every other type's name, length, format
characters and field names, so the reader (pymavlink's :class:`~pymavlink.DFReader.DFReader_binary`,
the one ArduPilot's tools use) needs no table of its own; the format characters set the scaling
(``L`` int32 1e-7 deg, ``e`` int32 x 100, ``c`` int16 x 100).

What the reader takes: IMU (one instance, ``I``; IMU2/IMU3 and a missing ``I`` in older logs),
GPS instance 0 with a 3D fix or better (its vertical speed ``VZ``, NED down, only where the GPA
record of the same fix says the receiver has one, ``VV`` 1: a receiver without logs 0), RCOU,
PARM, the firmware string (MSG or VER) and every MSG text, for the ``SCENARIO`` and ``FAULT``
annotations.

The writer exists so that the project's simulated flights (with injected faults) can be
replayed as ArduPilot logs in tests, since no public fixed-wing log with an IMU fault is at
hand. It writes, all with ArduPilot's message names, formats, field names and units:

- FMT records first (FMT's own, then each type's), then UNIT, MULT and FMTU records, so that
  tools show units and index the ``I`` instance field as they do for a real log;
- a MSG with the firmware string and a VER that says the same (version, build type), because
  that is how a reader learns what flew;
- PARM records of ``params`` (``Default`` NaN: no default is known), and a MSG
  ``SCENARIO <name>``, as the project's tlogs carry the scenario;
- the stream: IMU with ``I`` = 0, gyro (rad/s) and accel (m/s^2) as float32, health 1 and the
  stream's rate; GPS instance 0 with the sample's fix type, Lat/Lng in 1e-7 deg, Alt in cm,
  Spd in m/s, GCrs in deg [0, 360) (NSats 10, HDop 1, GPS week 0: the sim has no calendar),
  VZ the fix's vertical velocity (0 without one), and after it a GPA whose VV says whether it
  had one;
  RCOU with channels 1..14 (ArduPilot logs 15..18 in RCO2, which this writer leaves out);
- the fault annotations as MSG texts at their times (start and ``FAULT END``), as the fault
  proxy's STATUSTEXT in a tlog.

Every record after the header is in time order (``TimeUS``, us since boot). The sim's truth
is not written: it stays in the tlog.
"""

from __future__ import annotations

import dataclasses
import math
import re
import struct
from collections import Counter
from pathlib import Path

import numpy as np

from immukf_sitl.errors import UserError
from immukf_sitl.mavlink.flightlog import Annotations, FlightLog, fault_annotation
from immukf_sitl.mavlink.wire import DFMessage, DFReader_binary
from immukf_sitl.samples import ActuatorSample, GpsSample, ImuSample
from immukf_sitl.vehicle import vehicle_of_firmware

HEAD = b"\xa3\x95"
FMT_TYPE = 128

#: struct code of each format character the writer uses (LogStructure.h)
_STRUCT_CODES = {
    "b": "b", "B": "B", "H": "H", "C": "H", "I": "I", "f": "f", "d": "d", "Q": "Q",
    "n": "4s", "N": "16s", "Z": "64s", "c": "h", "e": "i", "L": "i",
}  # fmt: skip

_RCOU_COLUMNS = "TimeUS," + ",".join(f"C{i}" for i in range(1, 15))
#: name: (type, format, columns, units, multipliers): ArduPilot 4.5's formats; the type numbers
#: are this writer's (each log defines its own in its FMT records, and they vary by version)
_FORMATS: dict[str, tuple[int, str, str, str, str]] = {
    "FMT": (FMT_TYPE, "BBnNZ", "Type,Length,Name,Format,Columns", "-b---", "-----"),
    "PARM": (32, "QNff", "TimeUS,Name,Value,Default", "s---", "F---"),
    "MSG": (35, "QZ", "TimeUS,Message", "s-", "F-"),
    "RCOU": (38, "Q" + "H" * 14, _RCOU_COLUMNS, "s" + "Y" * 14, "F" + "-" * 14),
    "FMTU": (60, "QBNN", "TimeUS,FmtType,UnitIds,MultIds", "s---", "F---"),
    "UNIT": (61, "QbZ", "TimeUS,Id,Label", "s--", "F--"),
    "MULT": (62, "Qbd", "TimeUS,Id,Mult", "s--", "F--"),
    "GPS": (
        70, "QBBIHBcLLeffffB", "TimeUS,I,Status,GMS,GWk,NSats,HDop,Lat,Lng,Alt,Spd,GCrs,VZ,Yaw,U",
        "s#-s-S-DUmnhnh-", "F--C-0BGGB000--",
    ),
    "GPA": (
        71, "QBCCCCfBIH", "TimeUS,I,VDop,HAcc,VAcc,SAcc,YAcc,VV,SMS,Delta",
        "s#-mmnd-s-", "F-------C-",
    ),
    "IMU": (
        131, "QBffffffIIfBBHH", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz",
        "s#EEEooo--O--zz", "F-000000-----00",
    ),
    "VER": (
        176, "QBHBBBBIZHBB", "TimeUS,BT,BST,Maj,Min,Pat,FWT,GH,FWS,APJ,BU,FV",
        "s-----------", "F-----------",
    ),
}  # fmt: skip
#: the units and multipliers the formats above refer to (ArduPilot's log_Units, log_Multipliers)
_UNITS = {"-": "", "#": "instance", "s": "s", "E": "rad/s", "o": "m/s/s", "O": "degC", "z": "Hz",
          "Y": "us", "S": "satellites", "D": "deglatitude", "U": "deglongitude", "m": "m",
          "n": "m/s", "h": "degheading", "b": "B", "d": "deg"}  # fmt: skip
_MULTIPLIERS = {"-": 0.0, "0": 1.0, "B": 1e-2, "C": 1e-3, "F": 1e-6, "G": 1e-7}
#: VER.BU (APM_BUILD_*) of each vehicle class
_BUILD_TYPES = {"ground rover": 1, "multicopter": 2, "fixed-wing": 3, "antenna tracker": 4,
                "submarine": 7, "airship": 12, "helicopter": 13}  # fmt: skip
_IMU_NAMES = {"IMU": 0, "IMU2": 1, "IMU3": 2}  # IMU2/IMU3: logs before the ``I`` field
_GPS_3D_FIX = 3


def is_dataflash(head: bytes) -> bool:
    """Whether a file's first bytes are a DataFlash log's: a record header and an FMT record."""
    return head[:3] == HEAD + bytes((FMT_TYPE,))


def _time_s(msg: DFMessage, ms_ok: bool = True) -> float | None:
    """A record's time since boot (s): ``TimeUS``, or ``TimeMS`` in old logs; None if neither.

    An old GPS record's ``TimeMS`` is the GPS time of week, not time since boot: ``ms_ok``
    False for those.
    """
    columns = msg.fmt.colhash
    if "TimeUS" in columns:
        return msg.TimeUS / 1e6
    if ms_ok and "TimeMS" in columns:
        return msg.TimeMS / 1e3
    return None


def _field(msg: DFMessage, *names: str, default: float = 0.0) -> float:
    """The first of ``names`` the record has (field names differ between versions)."""
    for name in names:
        if name in msg.fmt.colhash:
            return getattr(msg, name)
    return default


def _wrap_pi(angle_rad: float) -> float:
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


def read_dataflash(path: str | Path, imu: int | None = None) -> FlightLog:
    """Parse an ArduPilot DataFlash ``.bin`` log (see the module docstring).

    Parameters
    ----------
    path : str or Path
        The log.
    imu : int or None
        The IMU instance (``I``) whose samples go into the stream; None: the first instance
        that has samples.

    Returns
    -------
    FlightLog
        ``kind="dataflash"``; ``bad_records`` counts records that were skipped as corrupt and
        a last record cut short.

    Raises
    ------
    UserError
        For a missing file, a file that is not a DataFlash log, and an ``imu`` not in the log.
    """
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: no such log")
    with path.open("rb") as handle:
        if not is_dataflash(handle.read(3)):
            raise UserError(f"{path}: not an ArduPilot DataFlash log (no FMT record at its start)")
    try:
        reader = DFReader_binary(str(path))
    except Exception as exc:  # DFReader raises bare Exceptions for a malformed FMT record
        raise UserError(f"{path}: unreadable DataFlash log ({exc})") from None
    log = FlightLog(kind="dataflash")
    notes = Annotations()
    items: list[tuple[int, ImuSample | GpsSample | ActuatorSample]] = []  # (IMU instance or -1)
    vertical: set[float] = set()  # times of the fixes whose GPA says VZ is measured
    try:
        while True:
            start = reader.offset
            msg = reader.recv_msg()
            if msg is None:
                log.bad_records += int(start < reader.data_len)  # a record cut short
                break
            log.bad_records += int(reader.offset - msg.fmt.len > start)  # bytes skipped
            _take(msg, log, notes, items, vertical)
    finally:
        reader.close()
    items = [_vertical_checked(item, vertical) for item in items]
    counts = Counter(instance for instance, _ in items if instance >= 0)
    log.imu_sources = {f"IMU[{k}]": n for k, n in sorted(counts.items())}
    if imu is None:
        imu = min(counts, default=None)
    elif imu not in counts:
        there = ", ".join(log.imu_sources) or "no IMU records"
        raise UserError(f"{path}: no IMU[{imu}] in this log (it has {there})")
    if imu is not None:
        log.imu_source, log.imu_instance = f"IMU[{imu}]", imu
    chosen = [s for instance, s in items if instance < 0 or instance == imu]
    log.stream = sorted(chosen, key=lambda s: s.time_s)  # stable: file order at equal times
    log.faults, log.scenario = notes.faults, notes.scenario
    return log


def _take(
    m: DFMessage,
    log: FlightLog,
    notes: Annotations,
    items: list[tuple[int, ImuSample | GpsSample | ActuatorSample]],
    vertical: set[float],
) -> None:
    """File one record into the log being read (a GPA's ``VV`` into ``vertical``)."""
    kind = m.get_type()  # fields as attributes, the format characters' multipliers applied
    if kind in _IMU_NAMES:
        t_s = _time_s(m)
        if t_s is not None:
            instance = int(_field(m, "I", default=_IMU_NAMES[kind]))
            accel = (m.AccX, m.AccY, m.AccZ)
            gyro = (m.GyrX, m.GyrY, m.GyrZ)
            items.append((instance, ImuSample(t_s, accel, gyro)))
    elif kind == "GPS":
        t_s = _time_s(m, ms_ok=False)
        status = int(_field(m, "Status"))
        if t_s is not None and int(_field(m, "I")) == 0 and status >= _GPS_3D_FIX:
            course_rad = _wrap_pi(math.radians(_field(m, "GCrs", "Crs", "COG")))
            lat, lon = _field(m, "Lat"), _field(m, "Lng", "Lon")
            speed = _field(m, "Spd", "Speed")
            vz = _field(m, "VZ", default=math.nan)
            fix = GpsSample(t_s, lat, lon, _field(m, "Alt"), speed, course_rad, status, vz)
            items.append((-1, fix))
    elif kind == "GPA":
        t_s = _time_s(m, ms_ok=False)
        if t_s is not None and int(_field(m, "I")) == 0 and int(_field(m, "VV")) == 1:
            vertical.add(t_s)
    elif kind == "RCOU":
        t_s = _time_s(m)
        if t_s is not None:
            pwm = tuple(int(_field(m, f"C{i}")) for i in range(1, 17))  # C15, C16: zero
            items.append((-1, ActuatorSample(t_s, pwm)))
    elif kind == "PARM":
        log.params[m.Name] = float(m.Value)
    elif kind in ("MSG", "VER"):
        text = m.Message if kind == "MSG" else m.FWS
        if kind == "MSG":
            notes.feed(text)
        if log.vehicle is None and (vehicle := vehicle_of_firmware(text)) is not None:
            log.vehicle, log.vehicle_evidence = vehicle, f'firmware "{text.strip()}"'


class _Packer:
    """Records of the formats in :data:`_FORMATS`, header included."""

    def __init__(self) -> None:
        self._structs = {
            name: struct.Struct("<" + "".join(_STRUCT_CODES[c] for c in spec[1]))
            for name, spec in _FORMATS.items()
        }

    def record(self, name: str, *values: object) -> bytes:
        """One record: ``0xA3 0x95 <type>`` and the packed values (str as ASCII bytes)."""
        packed = [v.encode("ascii") if isinstance(v, str) else v for v in values]
        return HEAD + bytes((_FORMATS[name][0],)) + self._structs[name].pack(*packed)

    def header(self) -> list[bytes]:
        """FMT records of every format (FMT's own first), then UNIT, MULT and FMTU."""
        out = []
        for name, (type_id, fmt, columns, _, _) in _FORMATS.items():
            length = 3 + self._structs[name].size
            out.append(self.record("FMT", type_id, length, name, fmt, columns))
        out += [self.record("UNIT", 0, ord(k), label) for k, label in _UNITS.items()]
        out += [self.record("MULT", 0, ord(k), mult) for k, mult in _MULTIPLIERS.items()]
        for type_id, _, _, units, mults in _FORMATS.values():
            out.append(self.record("FMTU", 0, type_id, units, mults))
        return out


def _time_us(t_s: float) -> int:
    time_us = round(t_s * 1e6)
    if time_us < 0:
        raise ValueError(f"time {t_s} s: DataFlash times are unsigned (us since boot)")
    return time_us


def _ver_record(packer: _Packer, firmware: str) -> bytes:
    """VER: board SITL, the firmware string's version, build type of its vehicle, type DEV."""
    version = re.search(r"V(\d+)\.(\d+)\.(\d+)", firmware)
    major, minor, patch = (int(v) for v in version.groups()) if version else (0, 0, 0)
    build = _BUILD_TYPES.get(vehicle_of_firmware(firmware) or "", 5)  # 5: APM_BUILD_UNKNOWN
    return packer.record("VER", 0, 3, 0, major, minor, patch, 0, 0, firmware, 0, build, 0)


def write_dataflash(
    path: str | Path,
    log: FlightLog,
    firmware: str = "ArduPlane V4.5.7 (immukf-sitl writer)",
    params: dict[str, float] | None = None,
) -> int:
    """Write ``log`` as an ArduPilot DataFlash ``.bin`` log (see the module docstring).

    Parameters
    ----------
    path : str or Path
        The log to write (replaced if it exists).
    log : FlightLog
        Its stream, scenario and faults are written.
    firmware : str
        The firmware string of MSG and VER: what a reader takes the vehicle to be.
    params : dict or None
        Parameters to write as PARM records (float32; names of at most 16 characters).

    Returns
    -------
    int
        The bytes written.
    """
    packer = _Packer()
    records = packer.header()
    records.append(packer.record("MSG", 0, firmware))
    records.append(_ver_record(packer, firmware))
    for name, value in (params or {}).items():
        if len(name) > 16:
            raise ValueError(f"parameter {name}: DataFlash names have at most 16 characters")
        records.append(packer.record("PARM", 0, name, value, math.nan))
    if log.scenario:
        records.append(packer.record("MSG", 0, f"SCENARIO {log.scenario}"))
    timed = [(_time_us(s.time_s), i, s) for i, s in enumerate(log.stream)]
    imu_times = [s.time_s for s in log.stream if isinstance(s, ImuSample)]
    step_s = float(np.median(np.diff(imu_times))) if len(imu_times) > 1 else 0.0
    rate_hz = min(round(1.0 / step_s), 65535) if step_s > 0 else 0  # IMU.GHz, IMU.AHz
    for fault in log.faults_seen():  # the faults of the IMU written (as IMU 0)
        start = fault_annotation(
            fault.kind, fault.channels, fault.t_s, fault.value, rate_hz=fault.rate_hz
        )
        timed.append((_time_us(fault.t_s), len(timed), start))
        if fault.end_t_s is not None:
            end = fault_annotation(fault.kind, fault.channels, fault.end_t_s, end=True)
            timed.append((_time_us(fault.end_t_s), len(timed), end))
    for time_us, _, item in sorted(timed, key=lambda r: (r[0], r[1])):
        records.append(_stream_record(packer, time_us, item, rate_hz))
    data = b"".join(records)
    Path(path).write_bytes(data)
    return len(data)


def _vertical_checked(
    item: tuple[int, ImuSample | GpsSample | ActuatorSample], vertical: set[float]
) -> tuple[int, ImuSample | GpsSample | ActuatorSample]:
    """A fix keeps its ``VZ`` only where its GPA said the receiver measures it."""
    instance, sample = item
    if isinstance(sample, GpsSample) and sample.velocity_down_mps is not None:
        measured = sample.time_s in vertical and math.isfinite(sample.velocity_down_mps)
        if not measured:
            return instance, dataclasses.replace(sample, velocity_down_mps=None)
    return item


def _stream_record(
    packer: _Packer, time_us: int, item: ImuSample | GpsSample | ActuatorSample | str, rate_hz: int
) -> bytes:
    if isinstance(item, str):
        return packer.record("MSG", time_us, item)
    if isinstance(item, ImuSample):
        gyro, accel = item.gyro_radps, item.accel_mps2
        return packer.record(
            "IMU", time_us, 0, *gyro, *accel, 0, 0, 25.0, 1, 1, rate_hz, rate_hz
        )  # no errors, 25 degC, healthy
    if isinstance(item, GpsSample):
        course_deg = math.degrees(item.course_rad) % 360.0
        vz = item.velocity_down_mps
        fix = packer.record(
            "GPS", time_us, 0, min(max(int(item.fix_type), 0), 255), 0, 0, 10, 100,
            round(item.lat_deg * 1e7), round(item.lon_deg * 1e7), round(item.alt_m * 100.0),
            item.ground_speed_mps, course_deg, 0.0 if vz is None else vz, 0.0, 1,
        )  # fmt: skip
        sample_ms = (time_us // 1000) & 0xFFFFFFFF
        accuracy = packer.record(
            "GPA", time_us, 0, 120, 0, 0, 0, 0.0, int(vz is not None), sample_ms, 0
        )
        return fix + accuracy
    if isinstance(item, ActuatorSample):
        pwm = [*item.pwm_us[:14], *[0] * max(0, 14 - len(item.pwm_us))]
        return packer.record("RCOU", time_us, *pwm)
    raise TypeError(f"not a stream sample: {type(item).__name__}")
