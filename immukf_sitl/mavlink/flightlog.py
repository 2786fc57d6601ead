"""Reading and writing the project's telemetry logs (tlogs).

A tlog is a sequence of records: an 8-byte big-endian microsecond timestamp, then one MAVLink
frame. The project writes two kinds:

- a **flight log**: the sensor stream exactly as the estimator received it (HEARTBEAT,
  GPS_RAW_INT, SERVO_OUTPUT_RAW, HIGHRES_IMU with any injected fault), the sim's truth
  (HIL_STATE_QUATERNION and WIND_COV, the total wind it felt, NED m/s; neither travels to the
  estimator) and the fault proxy's
  annotations (STATUSTEXT ``FAULT <kind> <channels> t=<s>`` and ``FAULT END ...``, from the
  proxy's component, also never forwarded), and a first STATUSTEXT ``SCENARIO <name>``. Record
  timestamps are sim time.
- an **estimator log**: what ``serve`` published (ATTITUDE, GLOBAL_POSITION_INT,
  NAMED_VALUE_FLOAT ``MP_*``, NAMED_VALUE_INT ``IMM_FAULT``, STATUSTEXT).
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from immukf_sitl.errors import UserError
from immukf_sitl.mavlink import codec
from immukf_sitl.mavlink.sources import GPS_MESSAGES, StreamSelector
from immukf_sitl.mavlink.tlog import TlogWriter
from immukf_sitl.mavlink.wire import MavMessage, mavlink, open_tlog_reader
from immukf_sitl.samples import ActuatorSample, GpsSample, ImuSample, TruthSample
from immukf_sitl.scenario import FaultSpec
from immukf_sitl.vehicle import vehicle_of_firmware, vehicle_of_mav_type

FAULT_TEXT = re.compile(
    r"^FAULT (?P<end>END )?(?P<kind>\w+) (?P<channels>[xyzpqr+]+) t=(?P<t>[-\d.]+)"
    r"(?: v=(?P<v>[-+\deE.]+))?(?: r=(?P<r>[-+\deE.]+))?(?: i=(?P<i>\d+))?"
)
SCENARIO_TEXT = re.compile(r"^SCENARIO (?P<name>\S+)")


def scenario_annotation(name: str) -> str:
    """STATUSTEXT naming the scenario of a flight log (first record)."""
    return f"SCENARIO {name}"[:50]


def fault_annotation(
    kind: str,
    channels: Iterable[str],
    t_s: float,
    value: float = 0.0,
    end: bool = False,
    rate_hz: float = 0.0,
    imu: int = 0,
) -> str:
    """The proxy's STATUSTEXT marking a fault's start or end (at most 50 characters).

    ``FAULT zero q t=30.000``, ``FAULT bias x+z t=12.500 v=0.2``,
    ``FAULT spikes q t=30.000 v=0.5 r=2``, ``FAULT END zero q t=60.000``, and ``i=1`` at the
    end for a fault of the second IMU. The parameters shrink to 3, then 2, significant digits
    where 6 would not fit.
    """
    text = f"FAULT {'END ' if end else ''}{kind} {'+'.join(channels)} t={t_s:.3f}"
    instance = f" i={imu}" if imu else ""
    for digits in (6, 3, 2):  # fewer digits where 6 do not fit
        full = text
        if value and not end:
            full += f" v={value:.{digits}g}"
        if rate_hz and not end:
            full += f" r={rate_hz:.{digits}g}"
        full += instance
        if len(full) <= 50:
            break
    return full[:50]


@dataclass(frozen=True)
class FaultRecord:
    """A fault annotation of the proxy."""

    kind: str
    channels: tuple[str, ...]
    t_s: float
    value: float = 0.0
    end_t_s: float | None = None
    rate_hz: float = 0.0
    imu: int = 0

    def spec(self) -> FaultSpec:
        """As the scenario's :class:`~immukf_sitl.scenario.FaultSpec`."""
        return FaultSpec(
            self.t_s, self.channels, self.kind, self.value, self.end_t_s, self.rate_hz, self.imu
        )


@dataclass
class FlightLog:
    """A flight log, parsed: the stream in arrival order, truth and faults.

    Every log reader (tlog, DataFlash, ULog) fills one; ``replay`` runs any of them.

    Attributes
    ----------
    stream : list
        IMU samples of one IMU (``imu_source``), GPS fixes and servo outputs, in time order.
    truth, faults : list
        The sim's truth and the fault proxy's annotations (empty in a real autopilot's log).
    bad_records : int
        Records the reader could not decode (corrupt bytes; never a readable record).
    scenario : str or None
        The scenario's name, when the log came from this project's sim.
    kind : str
        ``tlog``, ``dataflash`` or ``ulog``.
    vehicle : str or None
        What the log says flew (:mod:`immukf_sitl.vehicle`), None when it does not say.
    vehicle_evidence : str
        Where ``vehicle`` came from, for messages (``HEARTBEAT type QUADROTOR``).
    imu_source : str
        The IMU stream in ``stream`` (``RAW_IMU id 0``, ``IMU[1]``, ``sensor_combined``).
    imu_sources : dict
        Every IMU stream in the log and its sample count.
    imu_instance : int or None
        The autopilot's instance number of ``imu_source`` (None where the log does not say).
    params : dict
        The autopilot's parameters in the log (PARAM_VALUE, PARM, ULog parameters).
    """

    stream: list[ImuSample | GpsSample | ActuatorSample] = field(default_factory=list)
    truth: list[TruthSample] = field(default_factory=list)
    faults: list[FaultRecord] = field(default_factory=list)
    bad_records: int = 0
    scenario: str | None = None
    kind: str = "tlog"
    vehicle: str | None = None
    vehicle_evidence: str = ""
    imu_source: str = ""
    imu_sources: dict[str, int] = field(default_factory=dict)
    imu_instance: int | None = None
    params: dict[str, float] = field(default_factory=dict)

    def faults_seen(self) -> list[FaultSpec]:
        """The faults of the IMU in ``stream`` (a sibling IMU's fault leaves it healthy)."""
        return [
            f.spec() for f in self.faults if self.imu_instance is None or f.imu == self.imu_instance
        ]


def _messages(path: str | Path) -> Iterable[MavMessage]:
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: no such tlog")
    conn = open_tlog_reader(str(path))
    try:
        while True:
            msg = conn.recv_msg()
            if msg is None:
                return
            yield msg
    finally:
        conn.close()


class Annotations:
    """The proxy's and the sim's texts in a log (``SCENARIO``, ``FAULT``, ``FAULT END``), parsed.

    Every reader feeds it the log's texts in order (STATUSTEXT, DataFlash MSG, ULog logged
    messages), so that a flight written in any format carries its faults and its name.
    """

    def __init__(self) -> None:
        self.faults: list[FaultRecord] = []
        self.scenario: str | None = None
        self._open: dict[tuple[str, tuple[str, ...], int], int] = {}

    def feed(self, text: str) -> None:
        """Take one text (anything that is not an annotation is ignored)."""
        named = SCENARIO_TEXT.match(text)
        if named and self.scenario is None:
            self.scenario = named["name"]
        match = FAULT_TEXT.match(text)
        if not match:
            return
        channels = tuple(match["channels"].split("+"))
        imu = int(match["i"]) if match["i"] else 0
        key = (match["kind"], channels, imu)
        t_s = float(match["t"])
        if match["end"]:
            if key in self._open:
                i = self._open.pop(key)
                self.faults[i] = dataclasses.replace(self.faults[i], end_t_s=t_s)
            return
        self._open[key] = len(self.faults)
        value = float(match["v"]) if match["v"] else 0.0
        rate = float(match["r"]) if match["r"] else 0.0
        self.faults.append(FaultRecord(match["kind"], channels, t_s, value, rate_hz=rate, imu=imu))


def read_flight_log(path: str | Path, imu: int | None = None) -> FlightLog:
    """Parse a tlog: this project's flight logs, and any autopilot's or ground station's.

    Parameters
    ----------
    path : str or pathlib.Path
    imu : int, optional
        The IMU instance to read (:class:`~immukf_sitl.mavlink.sources.StreamSelector`); by
        default the first IMU stream in the log.
    """
    log = FlightLog()
    notes = Annotations()
    select = StreamSelector(imu)
    for msg in _messages(path):
        kind = msg.get_type()
        try:
            if kind in codec.IMU_MESSAGES:
                if select.follows_imu(msg):
                    log.stream.append(codec.decode_imu(msg))
            elif kind in GPS_MESSAGES:
                if select.follows_gps(msg):
                    log.stream.append(codec.decode_gps(msg))
            elif kind == "SERVO_OUTPUT_RAW":
                if getattr(msg, "port", 0) == 0:  # servos 1-16 (port 1 carries 17-32)
                    log.stream.append(codec.decode_servo_output_raw(msg))
            elif kind == "HIL_STATE_QUATERNION":
                log.truth.append(codec.decode_truth(msg))
            elif kind == "WIND_COV" and log.truth:
                t_s, wind = codec.decode_truth_wind(msg)
                if abs(log.truth[-1].t_s - t_s) < 1e-6:  # the truth record of the same step
                    log.truth[-1] = dataclasses.replace(log.truth[-1], wind_ned_mps=wind)
            elif kind == "STATUSTEXT":
                notes.feed(msg.text)
                if log.vehicle is None and vehicle_of_firmware(msg.text):
                    log.vehicle = vehicle_of_firmware(msg.text)
                    log.vehicle_evidence = f'STATUSTEXT "{msg.text.strip()}"'
            elif kind == "HEARTBEAT":
                _note_vehicle(log, msg)
            elif kind == "PARAM_VALUE":
                log.params[msg.param_id] = float(msg.param_value)
            elif kind == "BAD_DATA":
                log.bad_records += 1
        except codec.DecodeError:
            if kind not in GPS_MESSAGES:
                log.bad_records += 1  # a fix without 3D lock is a readable record, not a bad one
    log.faults, log.scenario = notes.faults, notes.scenario
    log.imu_source, log.imu_sources = select.imu_source, select.imu_sources()
    log.imu_instance = select.imu_stream[1] if select.imu_stream is not None else None
    if select.imu_stream is None and select.imu_counts:
        raise UserError(f"{path}: {select.missing_imu()}")
    return log


def _note_vehicle(log: FlightLog, msg: MavMessage) -> None:
    """The vehicle of the first HEARTBEAT that names one.

    A HEARTBEAT's type names the vehicle; a firmware STATUSTEXT, which says less, gives way to it.
    """
    vehicle = vehicle_of_mav_type(msg.type)
    if vehicle is None or log.vehicle_evidence.startswith("HEARTBEAT"):
        return
    log.vehicle = vehicle
    name = mavlink.enums["MAV_TYPE"][msg.type].name.removeprefix("MAV_TYPE_")
    log.vehicle_evidence = f"HEARTBEAT type {name}"


@dataclass
class EstimatorLog:
    """What ``serve`` published, as arrays over time."""

    attitude_t_s: np.ndarray
    euler_rad: np.ndarray
    position_t_s: np.ndarray
    lat_lon_alt: np.ndarray
    probability_t_s: np.ndarray
    probabilities: dict[str, np.ndarray]
    fault_events: list[tuple[float, int]]
    texts: list[str]


def read_estimator_log(path: str | Path) -> EstimatorLog:
    """Parse an estimator tlog."""
    att_t, att, pos_t, pos, texts, events = [], [], [], [], [], []
    probs: dict[int, dict[str, float]] = {}
    for msg in _messages(path):
        kind = msg.get_type()
        if kind == "ATTITUDE":
            att_t.append(msg.time_boot_ms / 1000.0)
            att.append((msg.roll, msg.pitch, msg.yaw))
        elif kind == "GLOBAL_POSITION_INT":
            pos_t.append(msg.time_boot_ms / 1000.0)
            pos.append((msg.lat * 1e-7, msg.lon * 1e-7, msg.alt * 1e-3))
        elif kind == "NAMED_VALUE_FLOAT" and msg.name.startswith("MP_"):
            probs.setdefault(msg.time_boot_ms, {})[msg.name] = msg.value
        elif kind == "NAMED_VALUE_INT" and msg.name == "IMM_FAULT":
            events.append((msg.time_boot_ms / 1000.0, int(msg.value)))
        elif kind == "STATUSTEXT":
            texts.append(msg.text)
    names = sorted({n for row in probs.values() for n in row})
    times = sorted(probs)
    return EstimatorLog(
        np.array(att_t),
        np.array(att).reshape(-1, 3),
        np.array(pos_t),
        np.array(pos).reshape(-1, 3),
        np.array(times) / 1000.0,
        {n: np.array([probs[t].get(n, np.nan) for t in times]) for n in names},
        events,
        texts,
    )


def read_records(path: str | Path) -> list[tuple[float, bytes]]:
    """Raw ``(time_s, frame)`` records of a tlog (frames re-packed as received)."""
    out = []
    conn = open_tlog_reader(str(path))
    try:
        while True:
            msg = conn.recv_msg()
            if msg is None:
                break
            if msg.get_type() == "BAD_DATA":
                continue
            out.append((getattr(msg, "_timestamp", 0.0), bytes(msg.get_msgbuf())))
    finally:
        conn.close()
    return out


def merge_flight_log(
    proxy_tlog: Path, sim_tlog: Path, out_path: Path, truth_hz: float | None = None
) -> int:
    """flight.tlog = the proxy's forwarded stream and annotations + the sim's truth records.

    Both logs are stamped with sim time; records are merged in time order (stream before truth
    at equal times). ``truth_hz`` thins the truth to that rate. Returns the bytes written.
    """
    stream = read_records(proxy_tlog)
    truth = []
    next_truth_s = -1.0
    period = 1.0 / truth_hz if truth_hz else 0.0
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    kept = False
    for t_s, frame in read_records(sim_tlog):
        msgs = parser.parse_buffer(frame) or []
        kind = msgs[0].get_type() if msgs else ""
        if kind == "HIL_STATE_QUATERNION":
            kept = t_s + 1e-9 >= next_truth_s
            if kept:
                truth.append((t_s, frame))
                next_truth_s = t_s + period
        elif kind == "WIND_COV":
            if kept:  # the wind of a truth record that was kept
                truth.append((t_s, frame))
        elif kind == "STATUSTEXT" and SCENARIO_TEXT.match(msgs[0].text):
            truth.append((t_s, frame))
    merged = sorted(
        [(t, 0, i, f) for i, (t, f) in enumerate(stream)]
        + [(t, 1, i, f) for i, (t, f) in enumerate(truth)]
    )
    size = 0
    with TlogWriter(out_path) as writer:
        for t_s, _, _, frame in merged:
            writer.write(frame, t_s)
            size += 8 + len(frame)
    return size
