"""Any flight log in: its format told from its first bytes, then checked for what replay needs.

``replay`` takes a MAVLink tlog (this project's, a ground station's, a companion computer's),
an ArduPilot DataFlash ``.bin`` or a PX4 ULog ``.ulg``. :func:`read_log` reads each with its
community's reader into one :class:`~immukf_sitl.mavlink.flightlog.FlightLog`;
:func:`check_replayable` then says, in one line, what stops a replay: a vehicle that is not a
fixed-wing aircraft, a missing IMU, servo or GPS stream (named as that format names it, with
the autopilot setting that turns it on), or an IMU too slow for detection.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from immukf_sitl.errors import UserError
from immukf_sitl.logs.dataflash import is_dataflash, read_dataflash
from immukf_sitl.logs.ulog import is_ulog, read_ulog
from immukf_sitl.mavlink.flightlog import FlightLog, read_flight_log
from immukf_sitl.samples import ActuatorSample, GpsSample, ImuSample
from immukf_sitl.vehicle import require_fixed_wing

#: What each format calls the three streams, and how an autopilot is made to record them.
STREAM_NAMES = {
    "tlog": {
        "imu": "IMU message (HIGHRES_IMU, RAW_IMU or SCALED_IMU*; ArduPilot: SRn_RAW_SENS)",
        "servo": "SERVO_OUTPUT_RAW (ArduPilot: SRn_RC_CHAN)",
        "gps": "GPS_RAW_INT with a 3D fix (ArduPilot: SRn_EXT_STAT)",
    },
    "dataflash": {
        "imu": "IMU record (LOG_BITMASK IMU)",
        "servo": "RCOU record (LOG_BITMASK RCOUT)",
        "gps": "GPS record with a 3D fix (LOG_BITMASK GPS)",
    },
    "ulog": {
        "imu": "sensor_combined or vehicle_imu topic",
        "servo": "actuator_outputs topic",
        "gps": "vehicle_gps_position or sensor_gps topic with a 3D fix",
    },
}


def read_log(path: str | Path, imu: int | None = None) -> FlightLog:
    """Read a tlog, a DataFlash ``.bin`` or a ULog ``.ulg``, told apart by their content.

    Parameters
    ----------
    path : str or pathlib.Path
    imu : int, optional
        The IMU instance to read; by default the log's first.

    Raises
    ------
    UserError
        One line: no such file, or a file that none of the readers can read.
    """
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: no such log")
    with open(path, "rb") as file:
        head = file.read(64)
    if is_ulog(head):
        return read_ulog(path, imu)
    if is_dataflash(head):
        return read_dataflash(path, imu)
    log = read_flight_log(path, imu)
    if not (log.stream or log.truth or log.vehicle or log.params):
        raise UserError(
            f"{path}: not a flight log (a MAVLink tlog, an ArduPilot DataFlash .bin or a PX4 "
            f"ULog .ulg); {log.bad_records} unreadable records"
        )
    return log


def imu_rate_hz(log: FlightLog) -> float | None:
    """The IMU's rate in the log: 1 / the median interval of its samples (None under 2)."""
    times = np.array([s.time_s for s in log.stream if isinstance(s, ImuSample)])
    if times.size < 2:
        return None
    intervals = np.diff(times)
    intervals = intervals[intervals > 0.0]
    return 1.0 / float(np.median(intervals)) if intervals.size else None


def rate_hint(log: FlightLog) -> str:
    """What raises the IMU's rate, for the log's format and message."""
    if log.kind == "dataflash":
        return "ArduPilot logs the IMU at its loop rate with LOG_BITMASK IMU set"
    if log.kind == "ulog":
        return "PX4: raise SDLOG_PROFILE to log sensor_combined at full rate"
    if log.imu_source.startswith("HIGHRES_IMU"):
        return "PX4: MAV_n_MODE Onboard or SET_MESSAGE_INTERVAL; or replay the .ulg log"
    return "ArduPilot: raise SRn_RAW_SENS (or SET_MESSAGE_INTERVAL); or replay the .bin log"


def check_replayable(log: FlightLog, path: str | Path, min_imu_rate_hz: float) -> None:
    """Refuse, in one line, a log that replay cannot run on.

    Raises
    ------
    UserError
        A vehicle that is not fixed-wing; no IMU, servo or GPS stream; an IMU slower than
        ``min_imu_rate_hz`` (the rate it sees, the rate it needs, the setting to raise).
    """
    require_fixed_wing(str(path), log.vehicle, log.vehicle_evidence)
    names = STREAM_NAMES[log.kind]
    missing = [
        names[key]
        for key, kind in (("imu", ImuSample), ("servo", ActuatorSample), ("gps", GpsSample))
        if not any(isinstance(s, kind) for s in log.stream)
    ]
    if missing:
        raise UserError(f"{path}: no {' and no '.join(missing)} in it: the estimator needs it")
    rate = imu_rate_hz(log)
    if rate is not None and rate < 0.95 * min_imu_rate_hz:  # 5 %: a jittery stream's median
        raise UserError(
            f"{path}: {log.imu_source or 'the IMU'} at {rate:.1f} Hz: detection needs at least "
            f"{min_imu_rate_hz:.0f} Hz ({rate_hint(log)})"
        )
