"""``immukf-sitl run SCENARIO``: the whole chain on loopback, recorded and summarised.

Starts three processes on free loopback UDP ports — ``serve`` (the estimator), ``proxy`` (fault
injection) and ``sim`` (JSBSim) — in lock-step (or ``--realtime``), listens to the estimator's
output like a ground station to show progress, and when the flight ends writes into
``--out-dir``:

- ``flight.tlog``: the sensor stream as the estimator received it (faults included), the sim's
  truth and the fault annotations (``immukf-sitl replay`` reads it);
- ``estimator.tlog``: everything the estimator published;
- ``summary.png``: mode probabilities and attitude error over time;
- ``summary.json``: the summary (also printed with ``--json``);
- ``signing.key``: with ``--sign``, the run's MAVLink 2 signing key (owner-only).

With ``--sign`` (or ``--signing-key FILE``) all three processes sign what they send and accept
only correctly signed input; the summary's ``stream.signing`` holds what each rejected.
``lag_us`` is serve's: from the arrival of an IMU datagram at its socket to the departure of
the ATTITUDE computed from it (median, p99, max over the last 10 minutes of ATTITUDE). With
``--realtime`` a loaded machine can leave serve seconds behind the air; when the sim ends, serve
is stopped only once it has estimated the flight's last sample (or its output has stalled).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import signal
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from immukf_sitl.errors import UserError
from immukf_sitl.experiments.processes import Child, free_udp_ports, spawn_cli
from immukf_sitl.experiments.report import (
    EstimateTrack,
    Summary,
    human_summary,
    plot_summary,
    summarize,
)
from immukf_sitl.mavlink.flightlog import merge_flight_log, read_estimator_log, read_flight_log
from immukf_sitl.mavlink.listener import GroundStationListener
from immukf_sitl.mavlink.publish import OutputRates
from immukf_sitl.mavlink.serve import READY as SERVE_READY
from immukf_sitl.mavlink.serve import WARMING_UP as SERVE_WARMING_UP
from immukf_sitl.mavlink.signing import load_key, write_key
from immukf_sitl.options import RunOptions
from immukf_sitl.scenario import Scenario, check_fault_imus, load_scenario, sensors_to_yaml
from immukf_sitl.service.detection import DetectionEvent
from immukf_sitl.service.timing import TimingStats
from sim.emitter import add_profile_arguments, profile_argv, profile_from_args

#: How long serve and proxy may take to bind their ports.
READY_TIMEOUT_S = 120.0
#: How long serve may then take to compile its numba kernels (seconds with a warm cache; a cold
#: one took over two minutes on the 2-core machine under load): it says when it starts.
WARM_UP_TIMEOUT_S = 900.0
#: If run itself dies, its serve exits once input has stopped this long (a backstop).
ORPHAN_IDLE_EXIT_S = 30.0
#: The sim's lock-step patience: generous, since run watches its children itself.
ACK_TIMEOUT_S = 60.0
#: After the sim's last sample, serve is stopped once its published time reaches the flight's end,
#: or has not advanced for this long (with --realtime on a loaded machine it was once 15 s behind
#: the air when the sim ended: stopping it then dropped a third of the flight, fault included).
CATCH_UP_QUIET_S = 5.0


@dataclass(frozen=True)
class ChainResult:
    """What the three processes reported (their ``--json`` objects) and the wall time."""

    serve: dict
    sim: dict
    proxy: dict
    wall_s: float


@dataclass(frozen=True)
class RunFiles:
    """The files of one run in its output directory."""

    out_dir: Path

    @property
    def sim_tlog(self) -> Path:
        """The sim's own tlog (sent frames and truth)."""
        return self.out_dir / "sim.tlog"

    @property
    def proxy_tlog(self) -> Path:
        """The proxy's tlog (forwarded stream and fault annotations)."""
        return self.out_dir / "proxy.tlog"

    @property
    def flight_tlog(self) -> Path:
        """The merged flight log that ``replay`` reads."""
        return self.out_dir / "flight.tlog"

    @property
    def estimator_tlog(self) -> Path:
        """What the estimator published."""
        return self.out_dir / "estimator.tlog"

    @property
    def sensors(self) -> Path:
        """The sensor spec sheet handed to the estimator (``--sensors``)."""
        return self.out_dir / "sensors.yaml"

    @property
    def signing_key(self) -> Path:
        """The run's own signing key (``--sign``)."""
        return self.out_dir / "signing.key"

    @property
    def plot(self) -> Path:
        """Mode probabilities and attitude error over time."""
        return self.out_dir / "summary.png"


def signing_key_path(options: RunOptions, files: RunFiles) -> str | None:
    """The key file every process signs with: the user's, a new one (``--sign``), or None."""
    if options.signing_key_path is not None:
        load_key(options.signing_key_path)  # a bad file is a one-line error before anything runs
        return options.signing_key_path
    if options.sign:
        write_key(files.signing_key)
        return str(files.signing_key)
    return None


def fly_chain(scenario: Scenario, options: RunOptions, files: RunFiles) -> ChainResult:
    """Start serve, proxy and sim on free ports, show progress, stop them when the sim ends."""
    key = signing_key_path(options, files)
    p_proxy, p_est, p_run = free_udp_ports(3)
    echo = options.verbose
    serve_argv = ["serve", "--in", f"udpin:127.0.0.1:{p_est}", "--out",
                  f"udpout:127.0.0.1:{p_run}", "--tlog", str(files.estimator_tlog), "--json",
                  "--stats-interval", "0", "--idle-exit", str(ORPHAN_IDLE_EXIT_S),
                  *options.filter.to_argv()]  # fmt: skip
    for gcs in options.gcs:
        serve_argv += ["--out", gcs]
    if options.realtime_priority is not None:
        serve_argv += ["--realtime-priority", str(options.realtime_priority)]
    proxy_argv = ["proxy", options.scenario_path, "--in", f"udpin:127.0.0.1:{p_proxy}",
                  "--out", f"udpout:127.0.0.1:{p_est}", "--tlog", str(files.proxy_tlog),
                  "--json"]  # fmt: skip
    sim_argv = ["sim", options.scenario_path, "--out", f"udpout:127.0.0.1:{p_proxy}",
                "--tlog", str(files.sim_tlog), "--json", "--out-dir", str(files.out_dir),
                "--ack-timeout", str(ACK_TIMEOUT_S), *profile_argv(scenario.profile)]  # fmt: skip
    if options.realtime:
        sim_argv += ["--realtime"]
        if options.speed is not None:
            sim_argv += ["--speed", str(options.speed)]
    if options.duration_s:
        sim_argv += ["--duration", str(options.duration_s)]
    if key is not None:
        for argv in (serve_argv, proxy_argv, sim_argv):
            argv += ["--signing-key", key]
    duration_s = options.duration_s or scenario.duration_s

    listener = GroundStationListener(f"udpin:127.0.0.1:{p_run}")
    children: list[Child] = []
    started = time.monotonic()
    try:
        serve = spawn_cli("serve", serve_argv, echo)
        children.append(serve)
        proxy = spawn_cli("proxy", proxy_argv, echo)
        children.append(proxy)
        serve.wait_ready(
            SERVE_READY, READY_TIMEOUT_S, busy=SERVE_WARMING_UP, busy_timeout_s=WARM_UP_TIMEOUT_S
        )
        proxy.wait_ready("proxy:", READY_TIMEOUT_S)
        sim = spawn_cli("sim", sim_argv, echo)
        children.append(sim)
        last_report = 0.0
        while sim.proc.poll() is None:
            listener.poll()
            for child in (serve, proxy):
                if child.proc.poll() is not None:
                    raise UserError(f"{child.name} stopped during the flight: {child.last_error()}")
            now = time.monotonic()
            if now - last_report >= 2.0:
                print(listener.line(duration_s), file=sys.stderr, flush=True)
                last_report = now
            time.sleep(0.05)
        sim_out = sim.stop()
        if sim.proc.returncode != 0:
            raise UserError(f"sim failed: {sim.last_error()}")
        _await_estimator(listener, serve, duration_s)
        time.sleep(0.3)
        listener.poll()
        serve_out = serve.stop()
        proxy_out = proxy.stop()
    finally:
        for child in children:
            if child.proc.poll() is None:
                child.proc.kill()
        listener.close()
    return ChainResult(
        serve=_last_json(serve_out, "serve"),
        sim=_last_json(sim_out, "sim"),
        proxy=_last_json(proxy_out, "proxy"),
        wall_s=time.monotonic() - started,
    )


def _await_estimator(listener: GroundStationListener, serve: Child, end_t_s: float) -> None:
    """Let serve work through what still waits in its socket once the sim has sent its last sample.

    Returns when its published time reaches ``end_t_s`` (less one probability period), or has
    not advanced for CATCH_UP_QUIET_S; says on stderr how far it got if it fell short.
    """
    end_heard_t_s = end_t_s - 1.0 / OutputRates.probabilities_hz - 1e-3
    heard_t_s, advanced, last_report = listener.t_s, time.monotonic(), 0.0
    while listener.t_s < end_heard_t_s:
        if serve.proc.poll() is not None:
            raise UserError(f"serve stopped before the flight's end: {serve.last_error()}")
        listener.poll()
        now = time.monotonic()
        if listener.t_s > heard_t_s:
            heard_t_s, advanced = listener.t_s, now
        elif now - advanced >= CATCH_UP_QUIET_S:
            if heard_t_s < end_t_s - 1.0:
                print(
                    f"run: the estimator's output stopped at t={heard_t_s:.1f} of {end_t_s:.1f} s "
                    f"(nothing new for {CATCH_UP_QUIET_S:g} s)",
                    file=sys.stderr,
                    flush=True,
                )
            return
        if now - last_report >= 2.0:
            print(
                f"{listener.line(end_t_s)}  (sim done, the estimator catching up)",
                file=sys.stderr,
                flush=True,
            )
            last_report = now
        time.sleep(0.05)


def run_scenario(scenario: Scenario, options: RunOptions, out_dir: Path) -> Summary:
    """Fly the chain, merge the logs and summarise (see the module docstring)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    files = RunFiles(out_dir)
    if options.filter.sensors_path is None:
        # the filter is told what the scenario's spec sheet says, never its true biases
        files.sensors.write_text(sensors_to_yaml(scenario.sensors.spec_sheet()))
        sensors = dataclasses.replace(
            options.filter, sensors=scenario.sensors.spec_sheet(), sensors_path=str(files.sensors)
        )
        options = dataclasses.replace(options, filter=sensors)
    chain = fly_chain(scenario, options, files)
    merge_flight_log(files.proxy_tlog, files.sim_tlog, files.flight_tlog, options.truth_hz)
    if not options.keep_intermediate:
        files.sim_tlog.unlink(missing_ok=True)
        files.proxy_tlog.unlink(missing_ok=True)
    flight = read_flight_log(files.flight_tlog)
    est = read_estimator_log(files.estimator_tlog)
    serve_stats = chain.serve
    events = [DetectionEvent.from_json(e) for e in serve_stats.get("events", [])]
    track = EstimateTrack(est.attitude_t_s, est.euler_rad, est.position_t_s, est.lat_lon_alt)
    followed = flight.imu_instance  # serve follows the first IMU stream, as the log reader does
    seen = [f for f in scenario.faults if followed is None or f.imu == followed]
    if len(seen) < len(scenario.faults):
        print(
            f"run: {len(scenario.faults) - len(seen)} fault(s) on another IMU than the one "
            f"serve follows ({flight.imu_source}): injected, not scored",
            file=sys.stderr,
        )
    summary = summarize(
        scenario.name,
        seen,
        flight.truth,
        events,
        track,
        TimingStats.from_json(serve_stats.get("step_us")),
        scenario.sensors.imu,
        scenario.expect,
        settle_s=options.filter.detector.settle_s,
    )
    summary = dataclasses.replace(
        summary,
        variant=options.filter.variant,
        lag_us=TimingStats.from_json(serve_stats.get("lag_us")),
        wall_s=chain.wall_s,
        sim_time_s=options.duration_s or scenario.duration_s,
        received_truth_messages=serve_stats.get("received", {}).get("HIL_STATE_QUATERNION", 0)
        + serve_stats.get("received", {}).get("WIND_COV", 0),
        airframe=chain.sim.get("airframe", {}),
        wind=dataclasses.asdict(scenario.wind),
        stream={
            "sim": chain.sim.get("sent"),
            "proxy": {k: v for k, v in chain.proxy.items() if k not in ("sent", "signing")},
            "estimator": serve_stats.get("counters"),
            "bad_packets": serve_stats.get("bad_packets"),
            "estimator_lag_us": serve_stats.get("lag_us"),
            "estimator_windows": serve_stats.get("windows"),
            "signing": {
                "serve": serve_stats.get("signing"),
                "proxy": chain.proxy.get("signing"),
                "sim": chain.sim.get("signing"),
            },
        },
        files={
            "flight_tlog": str(files.flight_tlog),
            "estimator_tlog": str(files.estimator_tlog),
            "plot": str(files.plot),
        },
    )
    plot_summary(
        str(files.plot), summary, est.probability_t_s, est.probabilities, flight.truth, track
    )
    (out_dir / "summary.json").write_text(json.dumps(summary_json(summary), indent=2))
    return summary


def summary_json(summary: Summary) -> dict:
    """The summary's JSON with serve's whole lag record (its max and count too)."""
    out = summary.to_json()
    if summary.stream is not None and summary.stream.get("estimator_lag_us"):
        out["lag_us"] = summary.stream["estimator_lag_us"]
    return out


def _last_json(stdout: str, name: str) -> dict:
    for line in reversed(stdout.strip().splitlines()):
        if line.startswith("{"):
            try:
                return json.loads(line)
            except json.JSONDecodeError:
                break
    raise UserError(f"{name} printed no JSON summary")


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``run`` subcommand."""
    parser = subparsers.add_parser(
        "run",
        help="fly a scenario through sim -> proxy -> serve on loopback and summarise",
        description=(
            "Start the sim (JSBSim), the fault proxy and the estimator service on free loopback "
            "UDP ports, fly SCENARIO lock-step (or --realtime), show progress, record "
            "flight.tlog and estimator.tlog, and end with a summary (faults, detections with "
            "delays from observability, false alarms, estimation errors, step time) and "
            "summary.png. Exit status 0 when the run completed, whatever was detected."
        ),
        epilog="example: immukf-sitl run scenarios/q_gyro_zeroed.yaml --json",
    )
    RunOptions.add_arguments(parser)
    add_profile_arguments(parser)
    parser.set_defaults(handler=_main)


def _terminate(signum: int, frame: object) -> None:
    """SIGTERM behaves like Ctrl-C, so that run's cleanup stops its children."""
    raise KeyboardInterrupt


def _main(args: argparse.Namespace) -> int:
    signal.signal(signal.SIGTERM, _terminate)
    options = RunOptions.from_args(args)
    scenario = load_scenario(options.scenario_path)
    scenario = dataclasses.replace(scenario, profile=profile_from_args(args, scenario.profile))
    check_fault_imus(scenario)
    if options.duration_s is not None and not 1.0 <= options.duration_s <= scenario.duration_s:
        raise UserError(
            f"--duration: expected 1..{scenario.duration_s} s, got {options.duration_s}"
        )
    out_dir = options.out_dir or Path("out") / Path(scenario.name).name
    if out_dir.exists() and not out_dir.is_dir():
        raise UserError(f"--out-dir {out_dir}: exists and is not a directory")
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"--out-dir {out_dir}: cannot create: {exc.strerror}") from None
    duration_s = options.duration_s or scenario.duration_s
    print(f"run: {scenario.name} ({duration_s:g} s) -> {out_dir}", file=sys.stderr)
    summary = run_scenario(scenario, options, out_dir)
    print(human_summary(summary), file=sys.stderr)
    lag = (summary.stream or {}).get("estimator_lag_us") or {}
    if lag.get("n"):
        print(
            f"  serve lag, IMU datagram in to ATTITUDE out: median {lag['median']:.0f} us, "
            f"p99 {lag['p99']:.0f} us, max {lag['max']:.0f} us ({lag['n']} ATTITUDE)",
            file=sys.stderr,
        )
    print(f"run: wrote {out_dir}/ (flight.tlog, estimator.tlog, summary.png)", file=sys.stderr)
    if args.json:
        print(json.dumps(summary_json(summary)))
    return 0
