"""The fault proxy: a scenario's IMU faults injected into the IMU stream.

It sits between the sim and the estimator: ``immukf-sitl proxy SCENARIO --in URL --out URL``.

Two layers, as a Gymnasium wrapper sits on an environment:

- :class:`FaultInjector` is pure: it takes an :class:`~immukf_sitl.samples.ImuSample` and returns
  the faulted one (the same object when no fault acts), with its own seeded random generator. It
  runs in-process as well (pipeline experiments, tests).
- :class:`FaultProxy` is a thin UDP shell around it. Datagrams from the sim (``--in``, a
  ``udpin`` the sim sends to) go to the estimator (``--out``, a ``udpout``); datagrams coming back
  from the estimator on that socket (its ``SYSTEM_TIME`` acknowledgements of the lock-step, and
  anything else) go back to the sim. Everything is forwarded as the raw bytes received
  (sequence numbers, source ids, signatures and even malformed bytes untouched), except that an
  IMU frame (HIGHRES_IMU, RAW_IMU, SCALED_IMU, SCALED_IMU2 or SCALED_IMU3: whatever the sim's
  profile sends) on which a fault acts is replaced in its datagram by the faulted message, in
  the message's own units and quantisation,
  re-packed with the original source system, component and sequence number and the original
  ``fields_updated`` (clearing those bits would hand the estimator the answer).

With ``--signing-key FILE`` (MAVLink 2 signing, :mod:`immukf_sitl.mavlink.signing`) the proxy
checks the signature of every frame from the sim; a faulted IMU frame is signed again by
pymavlink with the key, with the original frame's link id and timestamp (it stays in the sim's
stream). A frame that fails the check (unsigned, wrong signature, replayed) is never faulted
nor re-signed: it is forwarded as it came, and the estimator rejects it.

Fault kinds, from ``t_s`` until ``end_t_s`` (or the end), on each of the fault's channels:
``zero`` (the paper's), ``stuck``, ``bias``, ``drift``, ``scale``, ``noise`` and ``spikes``, as
:mod:`immukf_sitl.fault_kinds` defines them; the noise the kinds add or report is that sensor's
(``scenario.sensors.imu`` sigma).

Several faults apply in file order, each to the output of the previous ones. A fault takes one
IMU (its ``imu``, the first by default), as a real failure does: on a profile that sends two
(ArduPilot's RAW_IMU and SCALED_IMU2) the other stays healthy.

With ``--tlog FILE`` the proxy records the stream exactly as it forwards it to the estimator
(faults included), one record per frame stamped with the frame's sim time, after a first
STATUSTEXT ``SCENARIO <name>`` and with a STATUSTEXT ``FAULT <kind> <channels> t=<s>`` at each
fault's onset and ``FAULT END ...`` at its end (:mod:`immukf_sitl.mavlink.flightlog`), from the
proxy's component and never forwarded. Merged by record time with the sim's tlog (which holds the
truth), it is the flight log that ``replay`` reads.
"""

from __future__ import annotations

import argparse
import json
import select
import signal
import socket
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from types import FrameType

import numpy as np

from immukf_sitl.errors import UserError
from immukf_sitl.estimation.fault_modes import IMU_CHANNELS
from immukf_sitl.fault_kinds import spike_schedule
from immukf_sitl.mavlink.codec import (
    IMU_MESSAGES,
    DecodeError,
    decode_imu,
    imu_instance,
    repack_imu,
    statustext_message,
)
from immukf_sitl.mavlink.flightlog import fault_annotation, scenario_annotation
from immukf_sitl.mavlink.signing import LinkSigning, load_key
from immukf_sitl.mavlink.tlog import TlogWriter
from immukf_sitl.mavlink.wire import (
    PROXY_COMPONENT_ID,
    SIM_SYSTEM_ID,
    ConnectionError_,
    MavConnection,
    connect,
    mavlink,
)
from immukf_sitl.models.sensors import ImuSpec
from immukf_sitl.options import (
    add_json_argument,
    add_link_arguments,
    add_signing_argument,
    add_tlog_argument,
)
from immukf_sitl.samples import ImuSample
from immukf_sitl.scenario import FaultSpec, Scenario, load_scenario

__all__ = [
    "FAULT_STREAM_INDEX",
    "FaultInjector",
    "FaultProxy",
    "ProxyStats",
    "fault_rng",
    "register",
]

#: Child of ``numpy.random.SeedSequence(scenario.seed)`` that feeds the proxy's noise. The sim's
#: :class:`~sim.flight.Flight` spawns children 0 (IMU) and 1 (GPS); the proxy's stream is
#: independent of both, and the same seed gives the same faulted stream.
FAULT_STREAM_INDEX = 2

#: Where the sim sends by default (the proxy listens there).
DEFAULT_IN = "udpin:127.0.0.1:14560"
#: The estimator's input by default.
DEFAULT_OUT = "udpout:127.0.0.1:14561"


def fault_rng(seed: int) -> np.random.Generator:
    """The proxy's generator for a scenario seed (child ``FAULT_STREAM_INDEX`` of its sequence)."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(FAULT_STREAM_INDEX,)))


class FaultInjector:
    """Applies a fault schedule to IMU samples: same interface in and out.

    Parameters
    ----------
    faults : sequence of FaultSpec
        The schedule (``scenario.faults``), applied in order.
    imu_noise : ImuSpec
        Sensor noise: the standard deviation of the noise a ``zero`` fault reports.
    rng : numpy.random.Generator
        Source of that noise (:func:`fault_rng` of the scenario's seed).
    """

    def __init__(
        self, faults: Sequence[FaultSpec], imu_noise: ImuSpec, rng: np.random.Generator
    ) -> None:
        self.faults = tuple(faults)
        self.imu_noise = imu_noise
        self._rng = rng
        sigma = [imu_noise.accel_sigma_mps2] * 3 + [imu_noise.gyro_sigma_radps] * 3
        self._sigma = np.array(sigma, dtype=float)
        self._index = [
            np.array([IMU_CHANNELS.index(c) for c in fault.channels], dtype=int)
            for fault in self.faults
        ]
        self._held: list[np.ndarray | None] = [None] * len(self.faults)
        self._last_t_s: list[float | None] = [None] * len(self.faults)

    @classmethod
    def from_scenario(cls, scenario: Scenario) -> FaultInjector:
        """The injector of a scenario: its faults, IMU noise and seed."""
        return cls(scenario.faults, scenario.sensors.imu, fault_rng(scenario.seed))

    def active(self, time_s: float) -> tuple[FaultSpec, ...]:
        """The faults that act at ``time_s``."""
        return tuple(f for f in self.faults if f.active(time_s))

    def apply(self, sample: ImuSample, imu: int = 0) -> ImuSample:
        """The sample as the faulty IMU reports it.

        Parameters
        ----------
        sample : ImuSample
            The healthy sample (its ``time_s`` is the sim clock the schedule refers to).
        imu : int
            The IMU instance it is from: only that IMU's faults act on it.

        Returns
        -------
        ImuSample
            ``sample`` itself when no fault acts, else a new sample with the faulted channels.
        """
        t = sample.time_s
        values: np.ndarray | None = None
        for i, fault in enumerate(self.faults):
            if fault.imu != imu:
                continue
            if not fault.active(t):
                self._held[i] = None  # a later onset holds its own value
                self._last_t_s[i] = None
                continue
            if values is None:
                values = sample.as_array()
            values[self._index[i]] = self._faulted(i, fault, t, values[self._index[i]])
        if values is None:
            return sample
        return ImuSample(t, values[:3], values[3:])

    def _faulted(self, i: int, fault: FaultSpec, t: float, healthy: np.ndarray) -> np.ndarray:
        """Fault ``i``'s channels as they read at ``t``, from their ``healthy`` readings."""
        kind, sigma = fault.kind, self._sigma[self._index[i]]
        if kind == "zero":
            return sigma * self._rng.standard_normal(healthy.size)
        if kind == "stuck":
            if self._held[i] is None:
                self._held[i] = healthy.copy()
            return self._held[i]
        if kind == "bias":
            return healthy + fault.value
        if kind == "drift":
            return healthy + fault.value * (t - fault.t_s)
        if kind == "scale":
            return healthy * fault.value
        if kind == "noise":  # the sensor's own noise is in the reading: add the rest in quadrature
            extra = np.sqrt(fault.value**2 - 1.0) * sigma
            return healthy + extra * self._rng.standard_normal(healthy.size)
        if kind == "spikes":  # every spike since the previous sample lands on this one
            last = self._last_t_s[i]
            self._last_t_s[i] = t
            since = fault.t_s if last is None else last + 1e-9
            _, sizes = spike_schedule(fault.t_s, fault.value, fault.rate_hz, since, t + 1e-9)
            return healthy + sizes.sum()
        raise ValueError(f"fault kind {kind!r}: unknown")  # the scenario loader admits no other


@dataclass(frozen=True)
class ProxyStats:
    """What the proxy did (the ``--json`` object).

    Attributes
    ----------
    to_estimator, to_sim : int
        Datagrams forwarded in each direction.
    modified : int
        IMU messages replaced by their faulted version.
    bad : int
        Datagrams from the sim with malformed bytes or an unusable IMU message (forwarded as
        they came; the estimator counts them too).
    """

    to_estimator: int
    to_sim: int
    modified: int
    bad: int

    @property
    def forwarded(self) -> int:
        """Datagrams forwarded in both directions."""
        return self.to_estimator + self.to_sim

    def as_dict(self) -> dict[str, int]:
        """The counts, with ``forwarded``."""
        return {"forwarded": self.forwarded, **asdict(self)}


class FaultProxy:
    """The UDP shell: forwards both ways, injecting faults into the IMU messages on the way down.

    Parameters
    ----------
    injector : FaultInjector
        The fault schedule.
    upstream : MavConnection
        ``udpin`` connection the sim sends to (replies go back to the sim's address).
    downstream : MavConnection
        ``udpout`` connection to the estimator (its replies arrive on the same socket).
    tlog : TlogWriter, optional
        Recorder of the forwarded stream and the fault annotations.
    scenario_name : str, optional
        Name in the tlog's first record.
    signing : LinkSigning, optional
        Check the sim's signatures and sign faulted frames again (None: signing off).
    """

    def __init__(
        self,
        injector: FaultInjector,
        upstream: MavConnection | None,
        downstream: MavConnection | None,
        tlog: TlogWriter | None = None,
        scenario_name: str = "",
        signing: LinkSigning | None = None,
    ) -> None:
        self.injector = injector
        self.upstream = upstream
        self.downstream = downstream
        self.tlog = tlog
        self.signing = signing
        self._parser = self._new_parser()
        self._annotator = mavlink.MAVLink(None, SIM_SYSTEM_ID, PROXY_COMPONENT_ID)
        self._active: set[int] = set()
        self._time_s = 0.0
        if tlog is not None:
            self._annotate(scenario_annotation(scenario_name), 0.0)
        self._to_estimator = 0
        self._to_sim = 0
        self._modified = 0
        self._bad = 0
        #: every IMU message of every profile (HIGHRES_IMU, RAW_IMU, SCALED_IMU*) is read; a
        #: fault acts on its own IMU instance only
        self._imu_types = {getattr(mavlink, f"MAVLINK_MSG_ID_{kind}") for kind in IMU_MESSAGES}

    def _new_parser(self) -> mavlink.MAVLink:
        """A robust parser (checking signatures with the key, if any)."""
        if self.signing is not None:
            return self.signing.parser()
        parser = mavlink.MAVLink(None)
        parser.robust_parsing = True
        return parser

    def _annotate(self, text: str, time_s: float) -> None:
        assert self.tlog is not None
        message = statustext_message(text)
        self.tlog.write(message.pack(self._annotator), time_s)
        self._annotator.seq = (self._annotator.seq + 1) % 256

    def _note_transitions(self, time_s: float) -> None:
        """Annotate fault onsets and ends in the tlog (at the first sample that shows them)."""
        active = {i for i, f in enumerate(self.injector.faults) if f.active(time_s)}
        if active == self._active:
            return
        for i in sorted(active - self._active):
            fault = self.injector.faults[i]
            self._annotate(
                fault_annotation(
                    fault.kind,
                    fault.channels,
                    fault.t_s,
                    fault.value,
                    rate_hz=fault.rate_hz,
                    imu=fault.imu,
                ),
                time_s,
            )
        for i in sorted(self._active - active):
            fault = self.injector.faults[i]
            end_s = fault.end_t_s if fault.end_t_s is not None else time_s
            end_text = fault_annotation(fault.kind, fault.channels, end_s, end=True, imu=fault.imu)
            self._annotate(end_text, time_s)
        self._active = active

    @property
    def stats(self) -> ProxyStats:
        """Counts so far."""
        return ProxyStats(self._to_estimator, self._to_sim, self._modified, self._bad)

    def transform(self, datagram: bytes) -> bytes:
        """The datagram to forward to the estimator for one datagram from the sim.

        Never raises on malformed input: unparseable bytes are counted and passed on as they
        came. IMU frames on which a fault acts are spliced out and replaced. With a
        tlog, every parsed frame is recorded as forwarded.
        """
        parser = self._parser
        try:
            messages = parser.parse_buffer(datagram) or []
        except Exception:  # pymavlink raises assorted errors on garbage: never crash
            self._bad += 1
            self._parser = self._new_parser()
            return datagram
        bad = parser.buf_len() > 0  # a truncated frame left in the parser
        if bad:  # UDP carries whole frames: the rest must not join the next datagram
            self._parser = self._new_parser()
        out = datagram
        position = 0
        frames: list[tuple[bytes, float]] = []
        for message in messages:
            if message.get_type() == "BAD_DATA":
                bad = True
                continue
            frame = bytes(message.get_msgbuf())
            time_usec = getattr(message, "time_usec", None)
            if isinstance(time_usec, int):
                self._time_s = time_usec * 1e-6
            if message.get_msgId() in self._imu_types:
                try:
                    sample = decode_imu(message)
                except DecodeError:
                    bad = True
                    sample = None
                if sample is not None:
                    self._time_s = sample.time_s  # SCALED_IMU* carry time_boot_ms
                    if self.tlog is not None:
                        self._note_transitions(sample.time_s)
                    faulted = self.injector.apply(sample, imu_instance(message))
                    if faulted is not sample:
                        start = out.find(frame, position)
                        if start >= 0:
                            replacement = repack_imu(
                                message,
                                faulted,
                                self.signing.key if self.signing is not None else None,
                            )
                            out = out[:start] + replacement + out[start + len(frame) :]
                            position = start + len(replacement)
                            frame = replacement
                            self._modified += 1
                        else:  # pragma: no cover - pymavlink keeps the received bytes
                            bad = True
            frames.append((frame, self._time_s))
        if bad:
            self._bad += 1
        if self.tlog is not None:
            for frame, time_s in frames:
                self.tlog.write(frame, time_s)
        return out

    def pump(self, timeout_s: float) -> int:
        """Forward whatever arrives within ``timeout_s``; returns the datagrams handled."""
        up, down = self.upstream, self.downstream
        assert up is not None and down is not None
        try:
            readable, _, _ = select.select([up.fd, down.fd], [], [], timeout_s)
        except InterruptedError:  # pragma: no cover - PEP 475 retries; kept for safety
            return 0
        handled = 0
        if up.fd in readable:
            while True:
                datagram = up.recv()
                if not datagram:
                    break
                down.write(self.transform(bytes(datagram)))
                self._to_estimator += 1
                handled += 1
        if down.fd in readable:
            while True:
                datagram = down.recv()
                if not datagram:
                    break
                up.write(datagram)  # back to the sim's address, as received
                self._to_sim += 1
                handled += 1
        return handled


# -- command line ------------------------------------------------------------------------------


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``immukf-sitl proxy``."""
    parser = subparsers.add_parser(
        "proxy",
        help="forward MAVLink from the sim to the estimator, injecting a scenario's IMU faults",
        description=(
            "Forward MAVLink 2 between the sim and the estimator, both ways, byte for byte, "
            "except the IMU channels the scenario's faults act on: zero (0 plus the "
            "sensor's noise), stuck, bias or drift, from each fault's t_s (sim clock). "
            "fields_updated is kept. Stops on SIGINT/SIGTERM and prints what it forwarded."
        ),
        epilog=(
            "example: immukf-sitl proxy scenarios/q_gyro_zeroed.yaml "
            "--in udpin:127.0.0.1:14560 --out udpout:127.0.0.1:14561"
        ),
    )
    parser.add_argument("scenario", metavar="SCENARIO", help="scenario YAML file")
    add_link_arguments(
        parser,
        DEFAULT_IN,
        DEFAULT_OUT,
        in_help="where the sim sends to",
        out_help="the estimator's input",
    )
    add_tlog_argument(parser, "the stream as forwarded (faults included) with fault annotations")
    add_signing_argument(parser)
    add_json_argument(parser, "the counts at exit")
    parser.set_defaults(handler=run_proxy)


def _describe(fault: FaultSpec) -> str:
    until = f" until {fault.end_t_s:g} s" if fault.end_t_s is not None else ""
    value = f" {fault.value:g}" if fault.kind not in ("zero", "stuck") else ""
    if fault.kind == "spikes":
        value += f" at {fault.rate_hz:g} Hz"
    return f"{'+'.join(fault.channels)} {fault.kind}{value} at {fault.t_s:g} s{until}"


def _enlarge_receive_buffer(conn: MavConnection, size_bytes: int = 4 << 20) -> None:
    """Absorb bursts (a free-running sim) without drops: the kernel caps it at rmem_max."""
    try:
        conn.port.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, size_bytes)
    except (AttributeError, OSError):  # pragma: no cover - not a socket connection
        pass


def run_proxy(args: argparse.Namespace) -> int:
    """Handler of ``immukf-sitl proxy``."""
    signing = LinkSigning(load_key(args.signing_key)) if args.signing_key else None
    scenario = load_scenario(args.scenario)
    if not args.in_url.startswith("udpin:"):
        raise UserError(f"--in {args.in_url!r}: expected udpin:HOST:PORT (the sim sends to it)")
    if not args.out_url.startswith("udpout:"):
        raise UserError(f"--out {args.out_url!r}: expected udpout:HOST:PORT (the estimator)")
    try:
        upstream = connect(args.in_url, SIM_SYSTEM_ID, PROXY_COMPONENT_ID)
        downstream = connect(args.out_url, SIM_SYSTEM_ID, PROXY_COMPONENT_ID, input_=False)
    except ConnectionError_ as exc:
        raise UserError(str(exc)) from None
    tlog = TlogWriter(args.tlog) if args.tlog else None
    for conn in (upstream, downstream):
        _enlarge_receive_buffer(conn)
    proxy = FaultProxy(
        FaultInjector.from_scenario(scenario),
        upstream,
        downstream,
        tlog=tlog,
        scenario_name=scenario.name,
        signing=signing,
    )
    stop = {"signal": 0}

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop["signal"] = signum

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    faults = "; ".join(_describe(f) for f in scenario.faults) or "none"
    print(
        f"proxy: {args.in_url} -> {args.out_url}, faults of {scenario.name}: {faults}, "
        f"{'signing on' if signing else 'signing off'}",
        file=sys.stderr,
        flush=True,
    )
    started = time.perf_counter()
    next_flush = time.monotonic() + 1.0
    try:
        while not stop["signal"]:
            proxy.pump(0.2)
            if tlog is not None and time.monotonic() >= next_flush:
                tlog.flush()
                next_flush += 1.0
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        upstream.close()
        downstream.close()
        if tlog is not None:
            tlog.close()
    elapsed = time.perf_counter() - started
    stats = proxy.stats
    print(
        f"proxy: stopped by {signal.Signals(stop['signal']).name} after {elapsed:.1f} s: "
        f"forwarded {stats.to_estimator} datagrams to the estimator and {stats.to_sim} "
        f"to the sim; modified {stats.modified} IMU messages; bad {stats.bad}",
        file=sys.stderr,
        flush=True,
    )
    if args.json:
        signed = {"signing": signing.counters.as_dict()} if signing is not None else {}
        print(json.dumps({**stats.as_dict(), **signed}), flush=True)
    return 0
