"""``immukf-sitl serve``: the estimator service on MAVLink.

Consumes any autopilot's IMU stream (:mod:`immukf_sitl.mavlink.sources`), GPS_RAW_INT or
GPS2_RAW and SERVO_OUTPUT_RAW from ``--in``, runs the IMM-UKF
(:class:`~immukf_sitl.service.pipeline.EstimatorPipeline`) once per IMU sample and publishes the
fused state, the mode probabilities and detection events to every ``--out`` (a ground station).
On its input link it answers each IMU sample with a SYSTEM_TIME whose ``time_boot_ms`` is that
sample's time: the lock-step acknowledgement the sim waits for.

It never crashes on what arrives: bad CRCs, malformed or non-finite fields, out-of-order or
duplicate samples, gaps and a ground station's own traffic are counted and reported in the
periodic stats line and in ``--json``.

With ``--signing-key FILE`` it signs everything it sends (MAVLink 2 signing, pymavlink's) and
uses only correctly signed frames from its input; unsigned frames, wrong signatures and replays
are counted (:mod:`immukf_sitl.mavlink.signing`) and never reach the filter.

Each UDP datagram is read with its kernel receive time and parsed on its own (a truncated frame
never swallows the next datagram). The lag is the time from the arrival of an IMU
datagram at the socket (queueing included) to the moment the ATTITUDE computed from it has left,
for every sample that publishes one.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import select
import signal
import struct
import sys
import time
from collections import Counter, deque
from dataclasses import dataclass, field
from typing import TextIO

from immukf_sitl.errors import UserError
from immukf_sitl.mavlink import codec
from immukf_sitl.mavlink.publish import OutputRates, Publisher, heartbeat
from immukf_sitl.mavlink.servo_params import ServoParamRequest
from immukf_sitl.mavlink.signing import LinkSigning, load_key
from immukf_sitl.mavlink.sources import GPS_MESSAGES, StreamSelector, rate_hint
from immukf_sitl.mavlink.stream_requests import StreamRequest
from immukf_sitl.mavlink.tlog import TlogWriter
from immukf_sitl.mavlink.wire import (
    ESTIMATOR_COMPONENT_ID,
    ESTIMATOR_LINK_ID,
    ESTIMATOR_SYSTEM_ID,
    ConnectionError_,
    DatagramReader,
    MavConnection,
    MavMessage,
    connect,
    is_udp,
    mavlink,
)
from immukf_sitl.models.servo_map import ControlMap, control_map_source
from immukf_sitl.options import (
    FilterOptions,
    add_json_argument,
    add_link_arguments,
    add_signing_argument,
    add_tlog_argument,
)
from immukf_sitl.service.pipeline import EstimateOutput, EstimatorPipeline
from immukf_sitl.service.timing import (
    REPORT_WINDOW_S,
    SimTimeWindows,
    TimingStats,
    lag_statistics,
)

HELP = """\
Run the IMM-UKF estimator on a MAVLink stream and publish its results.

Consumes an IMU stream (HIGHRES_IMU, RAW_IMU, SCALED_IMU, SCALED_IMU2 or SCALED_IMU3, at
20 Hz to 1 kHz; --imu picks the instance), GPS_RAW_INT or GPS2_RAW and SERVO_OUTPUT_RAW from
--in, runs the filter at its 10 ms step on the IMU's timestamps (a slower IMU's sample is a
longer step, a faster one is averaged over each step; servo outputs are stale after three of
their own intervals; below 20 Hz of IMU decisions are held and a STATUSTEXT says so), and
publishes to every --out: HEARTBEAT, ATTITUDE, ATTITUDE_QUATERNION,
GLOBAL_POSITION_INT (fused), NAMED_VALUE_FLOAT MP_NONE, MP_AX, MP_AY, MP_AZ, MP_P, MP_Q, MP_R
(mode probabilities), NAMED_VALUE_INT IMM_FAULT and STATUSTEXT on each detection and clearing.
Each IMU sample is acknowledged up the input link with a SYSTEM_TIME (lock-step with the sim).
Bad packets, out-of-order samples and gaps are counted in the stats line, never fatal.

example:
  immukf-sitl serve --in udpin:127.0.0.1:14561 --out udpout:127.0.0.1:14550
"""

_ATTITUDE_ID = mavlink.MAVLINK_MSG_ID_ATTITUDE
DEFAULT_IN = "udpin:127.0.0.1:14561"
DEFAULT_OUT = "udpout:127.0.0.1:14550"
#: serve's start-up lines on stderr: the ports are bound and the kernels are being compiled,
#: then it is ready for samples (``run`` waits for the second, patiently after the first).
WARMING_UP = "serve: warming up"
READY = "serve: ready"
STATS_WINDOW = 20_000
#: Lags kept for the statistics: 10 minutes of ATTITUDE at its default 50 Hz.
LAG_WINDOW = 30_000


@dataclass
class ServiceStats:
    """Counters and timings of the service (the stats line and ``--json``)."""

    received: Counter = field(default_factory=Counter)
    bad_packets: int = 0
    decode_errors: int = 0
    ignored: int = 0
    send_errors: int = 0
    pack_errors: int = 0
    #: servo outputs held back while the vehicle's SERVOn_* parameters were being asked for
    servo_before_map: int = 0
    step_us: deque = field(default_factory=lambda: deque(maxlen=STATS_WINDOW))
    lag_us: deque = field(default_factory=lambda: deque(maxlen=LAG_WINDOW))
    events: list = field(default_factory=list)

    def timing(self) -> dict:
        """Step time (mean, median, p99) and lag (the same and max, count) in us, recent."""
        return {
            "step_us": TimingStats.of(self.step_us).to_json(),
            "lag_us": lag_statistics(self.lag_us),
        }


class EstimatorService:
    """The serve loop around a pipeline, its connections and a publisher.

    Parameters
    ----------
    pipeline : EstimatorPipeline
    inbound : MavConnection
        Where the sensor stream arrives (acknowledgements go back the same way).
    outbound : list of MavConnection
        Ground stations.
    publisher : Publisher
    tlog_path : str, optional
        Record everything published here (record time: the IMU time it belongs to).
    log : text stream
        Where the stats line goes (stderr).
    stats_interval_s : float
        Wall seconds between stats lines (0: never).
    signing : LinkSigning, optional
        Sign what is sent and accept only correctly signed input (None: signing off).
    report_window_s : float
        Sim time per entry of ``windows`` in :meth:`summary`.
    streams : StreamSelector, optional
        Which IMU and GPS streams to follow (default: the first of each that arrives).
    request_streams : bool
        Ask the autopilot for the streams and rates detection needs, and report what arrived.
    """

    def __init__(
        self,
        pipeline: EstimatorPipeline,
        inbound: MavConnection,
        outbound: list[MavConnection],
        publisher: Publisher,
        tlog_path: str | None = None,
        log: TextIO = sys.stderr,
        stats_interval_s: float = 5.0,
        signing: LinkSigning | None = None,
        report_window_s: float = REPORT_WINDOW_S,
        streams: StreamSelector | None = None,
        request_streams: bool = False,
    ) -> None:
        self.pipeline = pipeline
        self.inbound = inbound
        self.outbound = outbound
        self.publisher = publisher
        self.stats = ServiceStats()
        self.log = log
        self.stats_interval_s = stats_interval_s
        self.signing = signing
        self.windows = SimTimeWindows(report_window_s)
        self._mav = mavlink.MAVLink(None, ESTIMATOR_SYSTEM_ID, ESTIMATOR_COMPONENT_ID)
        if signing is not None:
            if hasattr(inbound, "setup_signing"):
                signing.enable(inbound, ESTIMATOR_LINK_ID)
            signing.watch(self._mav)
        self._parser = self._new_parser()
        self.streams = streams if streams is not None else StreamSelector()
        self._reader = DatagramReader(inbound) if is_udp(inbound) else None
        self._tlog = TlogWriter(tlog_path) if tlog_path else None
        self._clock_s = 0.0
        self._last_stats = time.monotonic()
        self._last_wall_heartbeat = 0.0
        self._last_data_wall = 0.0
        self._last_output: EstimateOutput | None = None
        self._stop = False
        self.stream_request = StreamRequest() if request_streams else None
        #: an ArduPilot vehicle's SERVOn_* parameters, asked for unless --servo-map gave a map
        self.servo_params: ServoParamRequest | None = (
            None if isinstance(pipeline.control_map, ControlMap) else ServoParamRequest()
        )

    # -- receiving -------------------------------------------------------------------------

    def _new_parser(self) -> mavlink.MAVLink:
        if self.signing is not None:
            return self.signing.parser()
        parser = mavlink.MAVLink(None)
        parser.robust_parsing = True
        return parser

    def on_datagram(self, data: bytes, arrival_ns: int) -> bool:
        """Parse one datagram and process its frames; whether any frame was accepted.

        Parameters
        ----------
        data : bytes
            The datagram as received.
        arrival_ns : int
            When it arrived (``time.time_ns()`` clock; the kernel's stamp where there is one).
        """
        parser = self._parser
        try:
            messages = parser.parse_buffer(data) or []
        except Exception:  # pymavlink raises assorted errors on garbage: never crash
            self.stats.bad_packets += 1
            self._parser = self._new_parser()
            return False
        if parser.buf_len() > 0:  # a frame cut short: UDP carries whole frames, drop the rest
            self.stats.bad_packets += 1
            self._parser = self._new_parser()
        accepted = False
        for msg in messages:
            accepted = self.handle(msg, arrival_ns) or accepted
        return accepted

    def handle(self, msg: MavMessage, received_ns: int) -> bool:
        """Process one parsed message; whether it was a frame (not bad data or a rejection).

        ``received_ns`` is its datagram's arrival on the ``time.time_ns()`` clock.
        """
        kind = msg.get_type()
        self.stats.received[kind] += 1
        if kind == "BAD_DATA":
            if not LinkSigning.is_rejection(msg):  # the signing check counted its own
                self.stats.bad_packets += 1
            return False
        stamp_us = getattr(msg, "time_usec", None)
        if stamp_us is not None and kind != "SERVO_OUTPUT_RAW":  # SERVO's is 32-bit: wraps
            self._clock_s = stamp_us * 1e-6

        if msg.get_srcComponent() == ESTIMATOR_COMPONENT_ID:
            self.stats.ignored += 1  # our own traffic looped back
            return True
        try:
            if kind in codec.IMU_MESSAGES:
                if self.streams.follows_imu(msg):
                    self._on_imu(codec.decode_imu(msg), msg, received_ns)
                else:
                    self.stats.ignored += 1  # another IMU, or the same one in another message
            elif kind in GPS_MESSAGES:
                if self.streams.follows_gps(msg):
                    self.pipeline.on_gps(codec.decode_gps(msg))
                else:
                    self.stats.ignored += 1
            elif kind == "SERVO_OUTPUT_RAW":
                if self._awaiting_servo_map():
                    self.stats.servo_before_map += 1
                else:
                    self.pipeline.on_actuators(codec.decode_servo_output_raw(msg))
            elif kind == "PARAM_VALUE":
                if self.servo_params is not None:
                    self.servo_params.on_param_value(msg)
                    self.servo_map_tick()
            elif kind == "COMMAND_ACK":
                if self.stream_request is not None:
                    self.stream_request.on_command_ack(msg)
            elif kind == "HEARTBEAT":
                if self.servo_params is not None:
                    self.servo_params.on_heartbeat(msg)
                if self.stream_request is not None:
                    self.stream_request.on_heartbeat(msg)
                # route the vehicle's heartbeat to the ground stations: QGroundControl creates a
                # vehicle only from a component-1 heartbeat, then shows our messages beside it
                for conn in self.outbound:
                    self._send(conn, bytes(msg.get_msgbuf()))
            else:
                self.stats.ignored += 1
        except codec.DecodeError:
            self.stats.decode_errors += 1
            if kind in codec.IMU_MESSAGES:  # processed (and dropped): the sim may go on
                stamp_s = msg.time_usec * 1e-6 if hasattr(msg, "time_usec") else None
                self._acknowledge(stamp_s if stamp_s is not None else msg.time_boot_ms * 1e-3)
        return True

    def _awaiting_servo_map(self) -> bool:
        """Whether an ArduPilot vehicle's servo parameters are still being asked for."""
        request = self.servo_params
        return request is not None and request.target is not None and not request.done

    def servo_map_tick(self, now_s: float | None = None) -> None:
        """Ask for the servo parameters still missing; once all are in, use their map.

        A map that leaves a control surface unassigned raises
        :class:`~immukf_sitl.models.servo_map.ServoMapError` (one line, exit 2): the filter
        cannot run on controls it cannot read.
        """
        request = self.servo_params
        if request is None or request.target is None:
            return
        for msg in request.requests(time.monotonic() if now_s is None else now_s):
            self._send(self.inbound, msg.pack(self._mav))
        if not request.done:
            return
        self.servo_params = None
        servo_map = request.servo_map()
        if servo_map is None:
            short = "IMM: no SERVOn_* answered, params file's map"
            text = (
                "the vehicle answered no SERVOn_* parameter: using "
                f"{control_map_source(self.pipeline.control_map)} (--servo-map FILE sets them)"
            )
        else:
            self.pipeline.control_map = ControlMap(servo_map, self.pipeline.params)
            short = "IMM: servo map from the vehicle's SERVOn_*"
            text = "servo map from " + ", ".join(
                f"SERVO{o.channel} {o.name}" for o in servo_map.outputs
            )
        self._say(f"serve: {text}")
        self._publish([codec.statustext_message(short, mavlink.MAV_SEVERITY_INFO)])

    def stream_request_tick(self, now_s: float) -> None:
        """Send the stream requests that are due; report once what arrived."""
        request = self.stream_request
        if request is None:
            return
        for msg in request.requests(now_s):
            self._send(self.inbound, msg.pack(self._mav))
        if request.report_due(now_s):
            p = self.pipeline
            rates = {name: p.imu_rate.rate_hz for name in ("RAW_IMU", "HIGHRES_IMU")}
            rates |= {
                "SERVO_OUTPUT_RAW": p.actuator_rate.rate_hz,
                "GPS_RAW_INT": p.gps_rate.rate_hz,
            }
            self._say(f"serve: {request.report(rates)}")

    def _say_notices(self) -> None:
        """The pipeline's notices, once each: on stderr and as STATUSTEXT to the stations."""
        for text in self.pipeline.take_notices():
            self._say(f"serve: {text}")
            self._publish([codec.statustext_message(f"IMM: {text}", mavlink.MAV_SEVERITY_WARNING)])

    def _on_imu(self, sample, msg: MavMessage, received_ns: int) -> None:
        if not self.pipeline.counters.imu_samples:
            self.pipeline.imu_label = self.streams.imu_source
            self.pipeline.rate_hint = rate_hint(msg.get_type())
        out = self.pipeline.on_imu(sample)
        if self.pipeline.notices:
            self._say_notices()
        self._last_data_wall = time.monotonic()
        attitude_sent_ns = None
        if out is not None:
            attitude_sent_ns = self._publish(self.publisher.messages(out))
            self.stats.step_us.append(out.step_us)
            self.stats.events.extend(out.events)
            self._last_output = out
            for event in out.events:
                self._say(f"serve: t={event.t_s:.2f} s {event.text()}")
        self._acknowledge(sample.time_s)
        lag_us = None
        if attitude_sent_ns is not None:
            lag_us = (attitude_sent_ns - received_ns) / 1e3
            self.stats.lag_us.append(lag_us)
        self.windows.add(sample.time_s, out.step_us if out is not None else None, lag_us)

    def _acknowledge(self, t_s: float) -> None:
        """SYSTEM_TIME back up the input link: processed up to ``t_s``."""
        ack = mavlink.MAVLink_system_time_message(0, int(round(t_s * 1000.0)) & 0xFFFFFFFF)
        self._send(self.inbound, ack.pack(self._mav))

    # -- sending ---------------------------------------------------------------------------

    def _send(self, conn: MavConnection, buf: bytes) -> None:
        try:
            conn.write(buf)
        except OSError:
            self.stats.send_errors += 1

    def _publish(self, msgs: list[MavMessage]) -> int | None:
        """Send to every ground station; when the ATTITUDE has left (``time.time_ns()``)."""
        attitude_sent_ns = None
        for msg in msgs:
            try:
                buf = msg.pack(self._mav)
            except (struct.error, OverflowError, ValueError):
                self.stats.pack_errors += 1  # a field out of its wire range: not published
                continue
            for conn in self.outbound:
                self._send(conn, buf)
            if attitude_sent_ns is None and msg.get_msgId() == _ATTITUDE_ID:
                attitude_sent_ns = time.time_ns()
            if self._tlog is not None:
                self._tlog.write(buf, self._clock_s)
        return attitude_sent_ns

    # -- the loop --------------------------------------------------------------------------

    def poll(self, timeout_s: float) -> int:
        """Wait up to ``timeout_s`` for input and process everything available."""
        handled = 0
        readable, _, _ = select.select([self.inbound.port.fileno()], [], [], timeout_s)
        if not readable:
            return 0
        reader = self._reader
        if reader is None:  # not UDP: pymavlink reads the stream; the stamp is the read time
            while not self._stop:
                received_ns = time.time_ns()
                msg = self.inbound.recv_msg()
                if msg is None:
                    break
                self.handle(msg, received_ns)
                handled += 1
            return handled
        while not self._stop:  # a flood must not keep a stop request waiting
            datagram = reader.read()
            if datagram is None:
                break
            data, arrival_ns, sender = datagram
            if self.on_datagram(data, arrival_ns):
                reader.accept_peer(sender)
            handled += 1
        return handled

    def stop(self) -> None:
        """Ask :meth:`run` to return after the current poll."""
        self._stop = True

    def run(self, idle_exit_s: float = 0.0) -> None:
        """Serve until :meth:`stop`, or until input stops for ``idle_exit_s`` (when > 0)."""
        last_input: float | None = None  # idle time counts once input has begun
        while not self._stop:
            if self.poll(0.2):
                last_input = time.monotonic()
            now = time.monotonic()
            self.servo_map_tick(now)
            self.stream_request_tick(now)
            if now - self._last_wall_heartbeat >= 1.0 and now - self._last_data_wall > 1.0:
                self._publish([heartbeat()])  # no data flowing: still visible to a GCS
                self._last_wall_heartbeat = now
            if self.stats_interval_s and now - self._last_stats >= self.stats_interval_s:
                self._say(self.stats_line())
                self._last_stats = now
            if idle_exit_s > 0 and last_input is not None and now - last_input > idle_exit_s:
                break
        if self._tlog is not None:
            self._tlog.close()

    # -- reporting -------------------------------------------------------------------------

    def stats_line(self) -> str:
        """One line: progress, timing, and what was dropped or bad."""
        c = self.pipeline.counters
        timing = self.stats.timing()
        step, lag = timing["step_us"], timing["lag_us"]
        t = f"{self._last_output.t_s:.1f}" if self._last_output else "-"
        mode = self.pipeline.detector.declared if self.pipeline.detector else None

        def fmt(v: float | None) -> str:
            return "-" if v is None else f"{v:.0f}"

        if self.signing is None:
            signing = "signing off"
        else:
            s = self.signing.counters
            signing = (
                f"signing on: unsigned_rejected={s.unsigned_rejected} "
                f"bad_signature={s.bad_signature} replayed={s.replayed}"
            )
        return (
            f"serve: t={t} s steps={c.steps} step mean {fmt(step['mean'])} us "
            f"p99 {fmt(step['p99'])} us lag median {fmt(lag['median'])} "
            f"p99 {fmt(lag['p99'])} max {fmt(lag['max'])} us "
            f"dropped={c.out_of_order} servo_dropped={c.actuator_out_of_order} "
            f"gps_dropped={c.gps_out_of_order} vd_unused={c.gps_velocity_down_unused} "
            f"gaps={c.gap_steps} bad={self.stats.bad_packets} "
            f"decode_err={self.stats.decode_errors} ignored={self.stats.ignored} "
            f"send_err={self.stats.send_errors + self.stats.pack_errors} "
            f"realigned={c.realignments} restarts={c.restarts} "
            f"fault={mode.name if mode else 'none'} {signing}"
        )

    def summary(self) -> dict:
        """Everything for ``--json``."""
        c = self.pipeline.counters
        est = self.pipeline.estimator
        return {
            "variant": self.pipeline.config.variant,
            "aligned": self.pipeline.aligned,
            "counters": vars(c).copy(),
            "received": dict(self.stats.received),
            "imu_source": self.streams.imu_source,
            "imu_sources": self.streams.imu_sources(),
            "imu_rate_hz": self.pipeline.imu_rate.rate_hz,
            "servo_rate_hz": self.pipeline.actuator_rate.rate_hz,
            "gps_rate_hz": self.pipeline.gps_rate.rate_hz,
            "bad_packets": self.stats.bad_packets,
            "decode_errors": self.stats.decode_errors,
            "ignored": self.stats.ignored,
            "send_errors": self.stats.send_errors,
            "pack_errors": self.stats.pack_errors,
            "servo_map": control_map_source(self.pipeline.control_map),
            "servo_before_map": self.stats.servo_before_map,
            **self.stats.timing(),
            "lag_from": "kernel receive" if self._kernel_stamps() else "socket read",
            "signing": {
                "enabled": self.signing is not None,
                **(self.signing.counters.as_dict() if self.signing is not None else {}),
            },
            "windows": self.windows.report(),
            "filter_diagnostics": est.diagnostics.as_dict() if est is not None else None,
            "events": [e.to_json() for e in self.stats.events],
        }

    def _kernel_stamps(self) -> bool:
        return self._reader is not None and self._reader.kernel_stamps

    def _say(self, text: str) -> None:
        print(text, file=self.log, flush=True)


# -- command line ----------------------------------------------------------------------------


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``serve`` subcommand."""
    parser = subparsers.add_parser(
        "serve",
        help="run the IMM-UKF estimator service on a MAVLink stream",
        description=HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_link_arguments(
        parser,
        DEFAULT_IN,
        DEFAULT_OUT,
        in_help="sensor stream, a pymavlink connection string",
        out_help="ground station to publish to",
        repeat_out=True,
    )
    add_tlog_argument(parser, "every published message")
    parser.add_argument(
        "--attitude-hz", type=float, default=OutputRates.attitude_hz, help="ATTITUDE rate"
    )
    parser.add_argument(
        "--position-hz",
        type=float,
        default=OutputRates.position_hz,
        help="GLOBAL_POSITION_INT rate",
    )
    parser.add_argument(
        "--probabilities-hz",
        type=float,
        default=OutputRates.probabilities_hz,
        help="NAMED_VALUE_FLOAT mode-probability rate",
    )
    parser.add_argument(
        "--stats-interval", type=float, default=5.0, help="seconds between stats lines (0: none)"
    )
    parser.add_argument(
        "--idle-exit",
        type=float,
        default=0.0,
        help="exit once input has stopped for this many seconds (default 0: run until interrupted)",
    )
    parser.add_argument(
        "--report-window",
        type=float,
        default=REPORT_WINDOW_S,
        metavar="S",
        help="sim seconds per entry of 'windows' (step time, lag) in --json (default %(default)s)",
    )
    parser.add_argument(
        "--realtime-priority",
        type=int,
        default=None,
        metavar="PRIO",
        help="run under SCHED_FIFO at PRIO (1-99; Linux, needs CAP_SYS_NICE): the filter step "
        "preempts ordinary processes as flight software's would (docs/performance.md)",
    )
    parser.add_argument(
        "--imu",
        type=int,
        default=None,
        metavar="N",
        help="IMU instance to follow (0 first: RAW_IMU/HIGHRES_IMU id N, SCALED_IMU2 is 1, "
        "SCALED_IMU3 2; default: the first IMU stream that arrives)",
    )
    parser.add_argument(
        "--request-streams",
        action="store_true",
        help="ask the autopilot (ArduPilot or PX4, from its HEARTBEAT) for its IMU at 50 Hz, "
        "SERVO_OUTPUT_RAW at 25 Hz and GPS_RAW_INT at 5 Hz: SET_MESSAGE_INTERVAL, else "
        "REQUEST_DATA_STREAM; after 5 s one line says what arrived at what rate",
    )
    add_signing_argument(parser)
    add_json_argument(parser, "the statistics at exit")
    FilterOptions.add_arguments(parser)
    parser.set_defaults(handler=_main)


def _set_realtime_priority(priority: int) -> None:
    """SCHED_FIFO at ``priority`` for this process; a one-line error where it is not allowed."""
    if not hasattr(os, "sched_setscheduler"):
        raise UserError("--realtime-priority: SCHED_FIFO is not available on this platform")
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except PermissionError:
        raise UserError("--realtime-priority: not permitted (needs CAP_SYS_NICE)") from None


def _main(args: argparse.Namespace) -> int:
    signing = LinkSigning(load_key(args.signing_key)) if args.signing_key else None
    if args.realtime_priority is not None and not 1 <= args.realtime_priority <= 99:
        raise UserError(f"--realtime-priority: expected 1..99, got {args.realtime_priority}")
    if args.imu is not None and args.imu < 0:
        raise UserError(f"--imu: expected an instance >= 0, got {args.imu}")
    options = FilterOptions.from_args(args)
    pipeline = options.pipeline()
    out_urls = args.out_url or [DEFAULT_OUT]
    for name in ("attitude_hz", "position_hz", "probabilities_hz"):
        if not 0.0 < getattr(args, name) <= 100.0 or not math.isfinite(getattr(args, name)):
            raise UserError(f"--{name.replace('_', '-')}: expected a rate in (0, 100] Hz")
    rates = OutputRates(args.attitude_hz, args.position_hz, args.probabilities_hz)
    if not (math.isfinite(args.report_window) and args.report_window > 0.0):
        raise UserError(
            f"--report-window: expected a positive number of seconds, got {args.report_window}"
        )
    try:
        inbound = connect(args.in_url, ESTIMATOR_SYSTEM_ID, ESTIMATOR_COMPONENT_ID)
        outbound = [
            connect(url, ESTIMATOR_SYSTEM_ID, ESTIMATOR_COMPONENT_ID, input_=False)
            for url in out_urls
        ]
    except ConnectionError_ as exc:
        raise UserError(str(exc)) from None
    service = EstimatorService(
        pipeline,
        inbound,
        outbound,
        Publisher(rates),
        tlog_path=args.tlog,
        stats_interval_s=args.stats_interval,
        signing=signing,
        report_window_s=args.report_window,
        streams=StreamSelector(args.imu),
        request_streams=args.request_streams,
    )
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: service.stop())
    print(
        f"{WARMING_UP} {options.variant} (numba compiles its kernels on the first start on a "
        "machine: minutes on a cold cache under load, then cached)",
        file=sys.stderr,
        flush=True,
    )
    pipeline.warm_up()
    print(
        f"{READY}: {options.variant} on {args.in_url} -> {', '.join(out_urls)}, "
        f"{'signing on' if signing else 'signing off'}",
        file=sys.stderr,
        flush=True,
    )
    if args.realtime_priority is not None:
        _set_realtime_priority(args.realtime_priority)
    service.run(idle_exit_s=args.idle_exit)
    print(service.stats_line(), file=sys.stderr)
    if args.json:
        print(json.dumps(service.summary()))
    return 0
