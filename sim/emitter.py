"""The SITL sensor stream: JSBSim + autopilot + sensor models as MAVLink 2 over UDP.

``immukf-sitl sim SCENARIO --out udpout:HOST:PORT``.

Per simulation step ``k`` (0.01 s), in this order: HEARTBEAT (1 Hz of sim time, first in its
step), GPS_RAW_INT (when a fix is due), SERVO_OUTPUT_RAW (the controls acting from this step, as
PWM through ``params.actuators.controls_to_pwm``) and HIGHRES_IMU (``fields_updated`` = 0x3F), so
that a consumer that steps its filter on HIGHRES_IMU has the step's actuators and fix already.
Every ``time_usec`` is sim time. The sim speaks as system 1, component 1, with a HEARTBEAT of
``MAV_TYPE_FIXED_WING`` and ``MAV_AUTOPILOT_INVALID`` (a vehicle for QGroundControl, which needs
a component-1 heartbeat with a vehicle type, without a flight stack to negotiate with).

Truth never goes on the wire: with ``--tlog FILE`` the sim records a first STATUSTEXT
``SCENARIO <name>`` (:func:`immukf_sitl.mavlink.flightlog.scenario_annotation`), every frame it
sends, and one HIL_STATE_QUATERNION per step (true attitude quaternion, inertial body rates,
position, NED velocity, airspeed, and the true specific force in ``xacc/yacc/zacc`` as mG)
whose ``time_usec`` is the step's sim time, right after the step's frames. Every record is
stamped with its step's sim time (:mod:`immukf_sitl.mavlink.tlog`), so a reader aligns truth and
stream and merges this log with the fault proxy's. The annotation and the truth frames carry
component :data:`TRUTH_COMPONENT_ID` with their own sequence numbers, so the stream of
component 1 has no sequence gaps, in the log or on the wire.

Pacing (the split px4-jsbsim-bridge and ArduPilot's SIM_JSBSim use):

- **lock-step** (default): the estimator replies on its input link one SYSTEM_TIME
  (``time_unix_usec`` 0, ``time_boot_ms`` = time of the last HIGHRES_IMU it processed) per
  processed HIGHRES_IMU; the fault proxy forwards it back to this socket. Step ``k`` is sent only
  once a SYSTEM_TIME from component 191 (MAV_COMP_ID_ONBOARD_COMPUTER) has acknowledged step
  ``k - W`` or later (``W`` = ``--window``, 10 steps): nothing is lost and the sim runs as fast
  as the consumers keep up. After the last step the sim waits for its acknowledgement, so when it
  exits the estimator has processed everything. No acknowledgement for ``--ack-timeout`` (10 s)
  while waiting: a one-line error.
- ``--free-run``: as fast as possible, no waiting (standalone use, tests).
- ``--realtime``: paced to the wall clock (``--speed`` times real time), no waiting.

With ``--signing-key FILE`` every frame is signed (MAVLink 2, pymavlink's signing, link id
:data:`~immukf_sitl.mavlink.wire.SIM_LINK_ID`) and only correctly signed acknowledgements count.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import select
import signal
import sys
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from types import FrameType

from immukf_sitl.errors import UserError
from immukf_sitl.mavlink.codec import statustext_message, truth_message, truth_wind_message
from immukf_sitl.mavlink.flightlog import scenario_annotation
from immukf_sitl.mavlink.signing import LinkSigning, load_key
from immukf_sitl.mavlink.tlog import TlogWriter
from immukf_sitl.mavlink.wire import (
    ESTIMATOR_COMPONENT_ID,
    SIM_COMPONENT_ID,
    SIM_LINK_ID,
    SIM_SYSTEM_ID,
    ConnectionError_,
    MavConnection,
    connect,
    mavlink,
)
from immukf_sitl.models.sensors import IMU_PERIOD_S
from immukf_sitl.options import (
    add_json_argument,
    add_link_arguments,
    add_signing_argument,
    add_tlog_argument,
)
from immukf_sitl.scenario import check_fault_imus, load_scenario
from immukf_sitl.stream_profile import PROFILES, SERVO_LAYOUTS, StreamProfile
from sim.flight import Flight, FlightRecord
from sim.profile_stream import ParamServer, ProfileStream
from sim.scenario_flight import flight_from_scenario, profile_stream

__all__ = [
    "DEFAULT_ACK_TIMEOUT_S",
    "DEFAULT_WINDOW_STEPS",
    "TRUTH_COMPONENT_ID",
    "AckTimeout",
    "EmitterStats",
    "LockStep",
    "SimEmitter",
    "register",
]

#: Where the sim sends by default: the fault proxy's input.
DEFAULT_OUT = "udpout:127.0.0.1:14560"
#: Steps the sim may run ahead of the estimator's last acknowledgement.
DEFAULT_WINDOW_STEPS = 10
#: Seconds without an acknowledgement, while waiting for one, before the sim gives up.
DEFAULT_ACK_TIMEOUT_S = 10.0
#: Component id of the truth frames in the tlog (MAV_COMP_ID_USER1, a private-use id).
TRUTH_COMPONENT_ID = mavlink.MAV_COMP_ID_USER1


class LockStep:
    """Bookkeeping of the estimator's acknowledgements.

    Parameters
    ----------
    window_steps : int
        ``W``: step ``k`` may be sent once step ``k - W`` is acknowledged (``W >= 1``).
    dt_s : float
        Simulation step (s).

    Notes
    -----
    An acknowledgement ``time_boot_ms`` covers every step whose time, rounded to the nearest
    step, is not later: it is converted to a step index with half a step of tolerance, so that
    an estimator that truncates ``time_usec / 1000`` instead of dividing exactly is still read
    right (step times are whole multiples of 10 ms).
    """

    def __init__(self, window_steps: int, dt_s: float = IMU_PERIOD_S) -> None:
        if window_steps < 1:
            raise ValueError(f"window_steps: expected >= 1, got {window_steps}")
        self.window_steps = int(window_steps)
        self.dt_ms = dt_s * 1000.0
        self.acked_step = -1
        self.acks = 0

    def acknowledge(self, time_boot_ms: int) -> None:
        """Record one SYSTEM_TIME acknowledgement."""
        self.acks += 1
        step = int(math.floor(time_boot_ms / self.dt_ms + 0.5))
        self.acked_step = max(self.acked_step, step)

    def may_send(self, step: int) -> bool:
        """Whether step ``step`` may go out (``acked >= step - W``)."""
        return self.acked_step >= step - self.window_steps

    @property
    def acked_time_s(self) -> float:
        """Sim time of the latest acknowledged step (s); -dt before any."""
        return self.acked_step * self.dt_ms / 1000.0


class AckTimeout(UserError):
    """The estimator stopped acknowledging (lock-step): a one-line user error."""


@dataclass(frozen=True)
class EmitterStats:
    """Summary of a sim run (the ``--json`` object).

    Attributes
    ----------
    mode : str
        ``lockstep``, ``free-run`` or ``realtime``.
    steps : int
        Records sent (step 0 included).
    sim_time_s : float
        Sim time of the last record sent (s).
    wall_s : float
        Wall time from the first record to the end (s).
    sent : dict
        Messages sent on the wire by type.
    received : dict
        Messages heard back by type.
    acked_time_s : float or None
        Latest acknowledged sim time (s), ``None`` before any acknowledgement.
    tlog_records : int
        Records written to the tlog (0 without ``--tlog``).
    stopped_by : str or None
        Signal that stopped the run early.
    """

    mode: str
    steps: int
    sim_time_s: float
    wall_s: float
    sent: dict[str, int]
    received: dict[str, int]
    acked_time_s: float | None
    tlog_records: int
    stopped_by: str | None = None

    @property
    def steps_per_s(self) -> float:
        """Steps per wall-clock second."""
        return self.steps / self.wall_s if self.wall_s > 0 else math.inf

    def as_dict(self) -> dict[str, object]:
        """JSON-ready summary."""
        return {
            "mode": self.mode,
            "steps": self.steps,
            "sim_time_s": round(self.sim_time_s, 6),
            "wall_s": round(self.wall_s, 3),
            "steps_per_s": round(self.steps_per_s, 1),
            "sent": dict(self.sent),
            "received": dict(self.received),
            "acked_time_s": self.acked_time_s,
            "tlog_records": self.tlog_records,
            "stopped_by": self.stopped_by,
        }

    def summary_line(self) -> str:
        """One line for people."""
        sent = ", ".join(f"{name} {count}" for name, count in self.sent.items())
        acked = "" if self.acked_time_s is None else f"; acknowledged to {self.acked_time_s:.2f} s"
        stopped = f" (stopped by {self.stopped_by})" if self.stopped_by else ""
        return (
            f"sim: {self.mode}{stopped}: {self.steps} steps ({self.sim_time_s:.2f} s of sim time) "
            f"in {self.wall_s:.2f} s, {self.steps_per_s:.0f} steps/s; sent {sent}{acked}"
        )


class SimEmitter:
    """Flies a :class:`~sim.flight.Flight` and sends each record over a MAVLink connection.

    Parameters
    ----------
    flight : Flight
        Not yet started.
    connection : MavConnection
        A ``udpout`` connection (sends, and receives the acknowledgements on the same socket).
    steps : int
        Steps after step 0 (the run sends ``steps + 1`` records).
    mode : str
        ``lockstep``, ``free-run`` or ``realtime``.
    window_steps : int, optional
        Lock-step window ``W``.
    ack_timeout_s : float, optional
        Lock-step: seconds without an acknowledgement while waiting before :class:`AckTimeout`.
    speed : float, optional
        Realtime: multiple of the wall clock.
    tlog : TlogWriter, optional
        Recorder of everything sent plus the truth.
    progress_period_s : float, optional
        Wall seconds between progress lines on stderr (``0``: none).
    scenario_name : str, optional
        Name in the tlog's first record.
    """

    MODES = ("lockstep", "free-run", "realtime")

    def __init__(
        self,
        flight: Flight,
        connection: MavConnection,
        steps: int,
        mode: str = "lockstep",
        window_steps: int = DEFAULT_WINDOW_STEPS,
        ack_timeout_s: float = DEFAULT_ACK_TIMEOUT_S,
        speed: float = 1.0,
        tlog: TlogWriter | None = None,
        progress_period_s: float = 3.0,
        scenario_name: str = "",
        stream: ProfileStream | None = None,
        params: ParamServer | None = None,
    ) -> None:
        if mode not in self.MODES:
            raise ValueError(f"mode: expected one of {', '.join(self.MODES)}, got {mode!r}")
        self.flight = flight
        self.connection = connection
        self.steps = int(steps)
        self.mode = mode
        self.lockstep = LockStep(window_steps, flight.driver.dt_s)
        self.ack_timeout_s = float(ack_timeout_s)
        self.speed = float(speed)
        self.tlog = tlog
        self.progress_period_s = float(progress_period_s)
        self.scenario_name = scenario_name
        native = stream is None
        self.stream = ProfileStream(StreamProfile(), flight.params.actuators) if native else stream
        self.params = params
        #: the last step that carried an IMU message (the last one the estimator acknowledges)
        self._last_imu_step = 0
        self.sent: Counter[str] = Counter()
        self.received: Counter[str] = Counter()
        self.stop_signal = 0
        self._truth_file = self._TlogFile(tlog)
        self._truth_mav = mavlink.MAVLink(self._truth_file, SIM_SYSTEM_ID, TRUTH_COMPONENT_ID)
        self._fd = connection.fd

    class _TlogFile:
        """File-like adapter: a pymavlink encoder that writes into the tlog (truth only)."""

        def __init__(self, tlog: TlogWriter | None) -> None:
            self.tlog = tlog
            self.time_s = 0.0

        def write(self, buf: bytes) -> None:
            if self.tlog is not None:
                self.tlog.write(buf, self.time_s)

    # -- acknowledgements ----------------------------------------------------------------------

    def poll(self) -> None:
        """Read everything waiting on the socket; note SYSTEM_TIME acknowledgements."""
        conn = self.connection
        while True:
            message = conn.recv_msg()
            if message is None:
                return
            kind = message.get_type()
            self.received[kind] += 1
            if kind == "SYSTEM_TIME" and message.get_srcComponent() == ESTIMATOR_COMPONENT_ID:
                self.lockstep.acknowledge(int(message.time_boot_ms))
                continue
            if kind in ("COMMAND_LONG", "REQUEST_DATA_STREAM"):
                answers = self.stream.on_request(message)
            elif self.params is not None and kind.startswith("PARAM_REQUEST"):
                answers = self.params.answer(message)
            else:
                continue
            for answer in answers:
                conn.mav.send(answer)
                self.sent[answer.get_type()] += 1

    def _wait_for_ack(self, step: int, time_s: float) -> None:
        """Block until ``step`` may be sent (lock-step), or raise :class:`AckTimeout`."""
        lock = self.lockstep
        self.poll()
        last_ack_count = lock.acks
        waited_since = time.monotonic()
        while not lock.may_send(step):
            if self.stop_signal:
                return
            now = time.monotonic()
            if lock.acks != last_ack_count:
                last_ack_count, waited_since = lock.acks, now
            remaining = waited_since + self.ack_timeout_s - now
            if remaining <= 0.0:
                heard = (
                    f"last acknowledged sim time {lock.acked_time_s:.2f} s"
                    if lock.acks
                    else "none received"
                )
                raise AckTimeout(
                    f"no lock-step acknowledgement (SYSTEM_TIME from component "
                    f"{ESTIMATOR_COMPONENT_ID}) for {self.ack_timeout_s:g} s at sim time "
                    f"{time_s:.2f} s ({heard}): is `immukf-sitl serve` running downstream of "
                    f"{self.connection.address}? Use --free-run (or --realtime) to send without "
                    "waiting"
                )
            select.select([self._fd], [], [], min(remaining, 0.2))
            self.poll()

    # -- the loop ------------------------------------------------------------------------------

    def _send(self, record: FlightRecord) -> None:
        mav = self.connection.mav
        for message in self.stream.messages(record):
            mav.send(message)
            self.sent[message.get_type()] += 1
            if self.tlog is not None:
                self.tlog.write(message.get_msgbuf(), record.time_s)
        if self.tlog is not None:
            self._truth_file.time_s = record.time_s
            self._truth_mav.send(truth_message(record.truth.sample()))
            self._truth_mav.send(truth_wind_message(record.truth.sample()))

    def _progress(self, record: FlightRecord, started: float, sent_steps: int) -> None:
        wall = time.monotonic() - started
        rate = sent_steps / wall if wall > 0 else 0.0
        acked = f", acknowledged {self.lockstep.acked_time_s:.2f} s" if self.lockstep.acks else ""
        total_s = self.steps * self.flight.driver.dt_s
        print(
            f"sim: t = {record.time_s:.2f} / {total_s:.2f} s, {rate:.0f} steps/s{acked}",
            file=sys.stderr,
            flush=True,
        )
        if self.tlog is not None:
            self.tlog.flush()

    def run(self) -> EmitterStats:
        """Fly and send every record; returns the summary.

        Raises
        ------
        AckTimeout
            Lock-step only: the estimator stopped acknowledging.
        """
        record = self.flight.start()
        if self.tlog is not None:
            self._truth_mav.send(statustext_message(scenario_annotation(self.scenario_name)))
        dt_s = self.flight.driver.dt_s
        started = time.monotonic()
        next_progress = started + self.progress_period_s
        sent_steps = 0
        sent_time_s = 0.0
        stopped_by: str | None = None
        for step in range(self.steps + 1):
            if step > 0:
                record = self.flight.step()
            if self.mode == "lockstep":
                self._wait_for_ack(step, record.time_s)
            elif self.mode == "realtime":
                delay = started + step * dt_s / self.speed - time.monotonic()
                if delay > 0.0:
                    time.sleep(delay)
                self.poll()
            else:
                self.poll()
            if self.stop_signal:
                stopped_by = signal.Signals(self.stop_signal).name
                break
            self._send(record)
            if self.stream.sent_imu:
                self._last_imu_step = step
            sent_steps += 1
            sent_time_s = record.time_s
            if self.progress_period_s > 0.0 and time.monotonic() >= next_progress:
                self._progress(record, started, sent_steps)
                next_progress += self.progress_period_s
        if self.mode == "lockstep" and stopped_by is None:
            self._wait_for_ack(self._last_imu_step + self.lockstep.window_steps, record.time_s)
            if self.stop_signal:
                stopped_by = signal.Signals(self.stop_signal).name
        if self.tlog is not None:
            self.tlog.flush()
        wall = time.monotonic() - started
        return EmitterStats(
            mode=self.mode,
            steps=sent_steps,
            sim_time_s=sent_time_s,
            wall_s=wall,
            sent=dict(self.sent),
            received=dict(self.received),
            acked_time_s=self.lockstep.acked_time_s if self.lockstep.acks else None,
            tlog_records=self.tlog.records if self.tlog is not None else 0,
            stopped_by=stopped_by,
        )


# -- command line ------------------------------------------------------------------------------


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``immukf-sitl sim``."""
    parser = subparsers.add_parser(
        "sim",
        help="fly a scenario in JSBSim and send the sensor stream as MAVLink 2",
        description=(
            "Fly a scenario (JSBSim Aerosonde, PID autopilot, B&M sensor noise) and send, per "
            "0.01 s step, GPS_RAW_INT (when due), SERVO_OUTPUT_RAW and HIGHRES_IMU, plus a "
            "1 Hz HEARTBEAT (system 1, component 1, fixed wing), with time_usec = sim time. "
            "Default lock-step: step k goes out once the estimator has acknowledged step "
            "k - WINDOW with a SYSTEM_TIME (component 191, time_boot_ms = last HIGHRES_IMU "
            "processed), so nothing is lost. Truth (HIL_STATE_QUATERNION) only goes to --tlog."
        ),
        epilog=(
            "examples: immukf-sitl sim scenarios/q_gyro_zeroed.yaml --out "
            "udpout:127.0.0.1:14560 --tlog sim.tlog;  immukf-sitl sim "
            "scenarios/fault_free.yaml --realtime --speed 2"
        ),
    )
    parser.add_argument("scenario", metavar="SCENARIO", help="scenario YAML file")
    add_link_arguments(
        parser, None, DEFAULT_OUT, out_help="where to send: udpout:HOST:PORT (the proxy or serve)"
    )
    pacing = parser.add_mutually_exclusive_group()
    pacing.add_argument(
        "--realtime",
        action="store_true",
        help="pace to the wall clock (times --speed); no acknowledgements needed",
    )
    pacing.add_argument(
        "--free-run",
        action="store_true",
        help="send as fast as possible without waiting for acknowledgements",
    )
    parser.add_argument(
        "--speed",
        type=float,
        default=None,
        metavar="X",
        help="with --realtime: X times real time (default 1)",
    )
    add_tlog_argument(parser, "every frame sent plus the truth")
    parser.add_argument(
        "--out-dir",
        default=None,
        metavar="DIR",
        help="where a perturbed airframe's JSBSim aircraft is written (scenario 'airframe:'; "
        "default: a temporary directory)",
    )
    parser.add_argument(
        "--window",
        type=int,
        default=DEFAULT_WINDOW_STEPS,
        metavar="STEPS",
        help="lock-step: steps sent ahead of the last acknowledgement (default: %(default)s)",
    )
    parser.add_argument(
        "--ack-timeout",
        type=float,
        default=DEFAULT_ACK_TIMEOUT_S,
        metavar="S",
        help="lock-step: give up after S s without an acknowledgement (default: %(default)s)",
    )
    parser.add_argument(
        "--duration",
        type=float,
        default=None,
        metavar="S",
        help="sim time to fly (s; default: the scenario's duration_s)",
    )
    add_profile_arguments(parser)
    add_signing_argument(parser)
    add_json_argument(parser)
    parser.set_defaults(handler=run_sim)


def add_profile_arguments(parser: argparse.ArgumentParser) -> None:
    """``--profile`` and its rates: the stream an autopilot would send (default: the scenario's)."""
    group = parser.add_argument_group("autopilot stream (default: the scenario's profile)")
    group.add_argument(
        "--profile",
        choices=tuple(PROFILES),
        default=None,
        help="speak as: native (HIGHRES_IMU 100 Hz, servo 100 Hz), ardupilot (RAW_IMU + "
        "SCALED_IMU2 50 Hz in mG and mrad/s, servo 10 Hz, GPS 5 Hz, ArduPlane HEARTBEAT, "
        "SERVOn_* answered) or px4 (HIGHRES_IMU 250 Hz, servo 10 Hz, GPS 5 Hz, PX4 HEARTBEAT)",
    )
    for flag, text in (
        ("--imu-hz", "IMU messages per second (20-1000)"),
        ("--servo-hz", "SERVO_OUTPUT_RAW per second"),
        ("--gps-hz", "GPS fixes per second"),
    ):
        group.add_argument(flag, type=float, default=None, metavar="HZ", help=text)
    group.add_argument(
        "--servo-layout",
        choices=SERVO_LAYOUTS,
        default=None,
        help="ardupilot profile: ArduPlane's conventional AETR outputs, elevons or a V-tail",
    )


def profile_argv(profile: StreamProfile) -> list[str]:
    """The command line that makes ``sim`` speak as ``profile`` (what ``run`` hands it)."""
    argv = ["--profile", profile.name, "--servo-layout", profile.servo_layout]
    for flag, value in (
        ("--imu-hz", profile.imu_hz),
        ("--servo-hz", profile.servo_hz),
        ("--gps-hz", profile.gps_hz),
    ):
        if value is not None:
            argv += [flag, repr(value)]
    return argv


def profile_from_args(args: argparse.Namespace, scenario_profile: StreamProfile) -> StreamProfile:
    """The scenario's profile with the command line's choices on top (one-line errors)."""
    changes = {
        key: getattr(args, attr)
        for key, attr in (
            ("name", "profile"),
            ("imu_hz", "imu_hz"),
            ("servo_hz", "servo_hz"),
            ("gps_hz", "gps_hz"),
            ("servo_layout", "servo_layout"),
        )
        if getattr(args, attr, None) is not None
    }
    if "name" in changes and changes["name"] != scenario_profile.name:
        scenario_profile = StreamProfile()  # another autopilot: none of the scenario's rates
    try:
        return dataclasses.replace(scenario_profile, **changes)
    except ValueError as exc:
        raise UserError(f"--profile: {exc}") from None


def _check_args(args: argparse.Namespace) -> None:
    if args.speed is not None and not args.realtime:
        raise UserError("--speed needs --realtime")
    if args.speed is not None and not (math.isfinite(args.speed) and args.speed > 0.0):
        raise UserError(f"--speed must be a positive number, got {args.speed}")
    if args.window < 1:
        raise UserError(f"--window must be at least 1 step, got {args.window}")
    if not (math.isfinite(args.ack_timeout) and args.ack_timeout > 0.0):
        raise UserError(
            f"--ack-timeout must be a positive number of seconds, got {args.ack_timeout}"
        )
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0.0):
        raise UserError(f"--duration must be a positive number of seconds, got {args.duration}")
    if not args.out_url.startswith("udpout:"):
        raise UserError(
            f"--out {args.out_url!r}: expected udpout:HOST:PORT (the sim sends there and hears the "
            "acknowledgements on the same socket)"
        )


def run_sim(args: argparse.Namespace) -> int:
    """Handler of ``immukf-sitl sim``."""
    _check_args(args)
    signing = LinkSigning(load_key(args.signing_key)) if args.signing_key else None
    scenario = load_scenario(args.scenario)
    duration_s = args.duration if args.duration is not None else scenario.duration_s
    mode = "realtime" if args.realtime else "free-run" if args.free_run else "lockstep"
    profile = profile_from_args(args, scenario.profile)
    check_fault_imus(dataclasses.replace(scenario, profile=profile))
    flight = flight_from_scenario(
        scenario, out_dir=Path(args.out_dir) if args.out_dir is not None else None, profile=profile
    )
    stream, params = profile_stream(flight, profile)
    steps = int(round(duration_s / flight.driver.dt_s))
    try:
        connection = connect(args.out_url, SIM_SYSTEM_ID, SIM_COMPONENT_ID, input_=False)
    except ConnectionError_ as exc:
        raise UserError(str(exc)) from None
    if signing is not None:
        signing.enable(connection, SIM_LINK_ID)
    tlog = TlogWriter(args.tlog) if args.tlog else None
    emitter = SimEmitter(
        flight,
        connection,
        steps,
        mode=mode,
        window_steps=args.window,
        ack_timeout_s=args.ack_timeout,
        speed=args.speed if args.speed is not None else 1.0,
        tlog=tlog,
        scenario_name=scenario.name,
        stream=stream,
        params=params,
    )

    def on_signal(signum: int, frame: FrameType | None) -> None:
        emitter.stop_signal = signum

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    print(
        f"sim: {scenario.name}, {duration_s:g} s, {mode}, {profile.describe()} -> {args.out_url}"
        + (f", tlog {args.tlog}" if args.tlog else "")
        + (", signing on" if signing else ", signing off"),
        file=sys.stderr,
        flush=True,
    )
    try:
        stats = emitter.run()
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        if tlog is not None:
            tlog.close()
        connection.close()
    print(stats.summary_line(), file=sys.stderr, flush=True)
    if flight.airframe_factors:
        factors = ", ".join(f"{k} x{v:.3f}" for k, v in sorted(flight.airframe_factors.items()))
        print(f"sim: airframe differs from the book: {factors}", file=sys.stderr, flush=True)
    if args.json:
        signed = {"signing": signing.counters.as_dict()} if signing is not None else {}
        summary = {**stats.as_dict(), "airframe": flight.airframe_factors, **signed}
        print(json.dumps(summary), flush=True)
    if stats.stopped_by is not None:
        return 128 + int(signal.Signals[stats.stopped_by])
    return 0
