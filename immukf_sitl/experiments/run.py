"""``immukf-sitl run SCENARIO``: the whole chain on loopback, recorded and summarised.

Starts three processes on free loopback UDP ports — ``serve`` (the estimator), ``proxy`` (fault
injection) and ``sim`` (JSBSim) — in lock-step (or ``--realtime``), listens to the estimator's
output like a ground station to show progress, and when the flight ends writes into ``--out``:

- ``flight.tlog``: the sensor stream as the estimator received it (faults included), the sim's
  truth and the fault annotations (``immukf-sitl replay`` reads it);
- ``estimator.tlog``: everything the estimator published;
- ``summary.png``: mode probabilities and attitude error over time;
- ``summary.json``: the summary (also printed with ``--json``).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

from immukf_sitl.errors import UserError
from immukf_sitl.experiments.report import (
    EstimateTrack,
    EventRecord,
    human_summary,
    plot_summary,
    summarize,
)
from immukf_sitl.mavlink.flightlog import merge_flight_log, read_estimator_log, read_flight_log
from immukf_sitl.mavlink.listener import GroundStationListener
from immukf_sitl.mavlink.serve import add_filter_arguments
from immukf_sitl.scenario import Scenario, load_scenario

#: How long serve (which compiles its kernels first) and proxy may take to bind their ports.
READY_TIMEOUT_S = 120.0
#: If run itself dies, its serve exits once input has stopped this long (a backstop).
ORPHAN_IDLE_EXIT_S = 30.0
#: The sim's lock-step patience: generous, since run watches its children itself.
ACK_TIMEOUT_S = 60.0

FILTER_OPTIONS = (
    "variant",
    "true_mode",
    "threshold",
    "dwell",
    "clear_threshold",
    "clear_dwell",
    "settle",
    "recovery_probability",
    "params",
)


@dataclass
class Child:
    """A subprocess whose stderr is collected (and echoed when asked) by a thread."""

    name: str
    proc: subprocess.Popen
    echo: bool
    lines: deque = field(default_factory=lambda: deque(maxlen=200))

    def __post_init__(self) -> None:
        self._thread = threading.Thread(target=self._pump, daemon=True)
        self._thread.start()

    def _pump(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            line = line.rstrip()
            self.lines.append(line)
            if self.echo:
                print(f"  [{self.name}] {line}", file=sys.stderr, flush=True)

    def wait_ready(self, prefix: str, timeout_s: float) -> None:
        """Block until the child prints a line starting with ``prefix`` (its ports are bound)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if any(line.startswith(prefix) for line in list(self.lines)):
                return
            if self.proc.poll() is not None:
                raise UserError(f"{self.name} failed to start: {self.last_error()}")
            time.sleep(0.02)
        raise UserError(f"{self.name} did not report ready within {timeout_s:.0f} s")

    def stop(self, timeout_s: float = 15.0) -> str:
        """SIGINT, wait, kill if needed; returns stdout."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
        try:
            out, _ = self.proc.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            out, _ = self.proc.communicate()
        self._thread.join(timeout=2.0)
        return out or ""

    def last_error(self) -> str:
        """The child's last stderr line (its one-line error, if it failed)."""
        return self.lines[-1] if self.lines else "(no output)"


def free_udp_ports(n: int) -> list[int]:
    """``n`` distinct loopback UDP ports that were free a moment ago."""
    import socket

    socks = []
    for _ in range(n):
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", 0))
        socks.append(s)
    ports = [s.getsockname()[1] for s in socks]
    for s in socks:
        s.close()
    return ports


def spawn_cli(name: str, argv: list[str], echo: bool = False) -> Child:
    """Start ``immukf-sitl ARGV`` with this interpreter; stderr collected by a thread."""
    cmd = [sys.executable, "-m", "immukf_sitl.cli", *argv]
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(
        cmd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        stdin=subprocess.DEVNULL,
        text=True,
        env=env,
    )
    return Child(name, proc, echo)


def _filter_argv(args: argparse.Namespace) -> list[str]:
    argv = []
    for name in FILTER_OPTIONS:
        value = getattr(args, name)
        if value is not None:
            argv += [f"--{name.replace('_', '-')}", str(value)]
    return argv


def run_scenario(
    scenario: Scenario,
    scenario_path: str,
    out_dir: Path,
    args: argparse.Namespace,
) -> dict:
    """Run the three processes, merge the logs and summarise (see the module docstring)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    p_proxy, p_est, p_run = free_udp_ports(3)
    sim_tlog, proxy_tlog = out_dir / "sim.tlog", out_dir / "proxy.tlog"
    flight_tlog, est_tlog = out_dir / "flight.tlog", out_dir / "estimator.tlog"
    echo = args.verbose
    serve_argv = ["serve", "--in", f"udpin:127.0.0.1:{p_est}", "--out",
                  f"udpout:127.0.0.1:{p_run}", "--tlog", str(est_tlog), "--json",
                  "--stats-interval", "0", "--idle-exit", str(ORPHAN_IDLE_EXIT_S),
                  *_filter_argv(args)]  # fmt: skip
    for gcs in args.gcs or []:
        serve_argv += ["--out", gcs]
    sim_argv = ["sim", scenario_path, "--out", f"udpout:127.0.0.1:{p_proxy}",
                "--tlog", str(sim_tlog), "--json", "--ack-timeout", str(ACK_TIMEOUT_S)]  # fmt: skip
    if args.realtime:
        sim_argv += ["--realtime"] + (
            ["--speed", str(args.speed)] if args.speed is not None else []
        )
    if args.duration:
        sim_argv += ["--duration", str(args.duration)]
    duration_s = args.duration or scenario.duration_s

    listener = GroundStationListener(f"udpin:127.0.0.1:{p_run}")
    children: list[Child] = []
    started = time.monotonic()
    try:
        serve = spawn_cli("serve", serve_argv, echo)
        children.append(serve)
        proxy = spawn_cli("proxy", ["proxy", scenario_path, "--in", f"udpin:127.0.0.1:{p_proxy}",
                                 "--out", f"udpout:127.0.0.1:{p_est}", "--tlog",
                                 str(proxy_tlog), "--json"], echo)  # fmt: skip
        children.append(proxy)
        for child, ready in ((serve, "serve: ready"), (proxy, "proxy:")):
            child.wait_ready(ready, READY_TIMEOUT_S)
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
        time.sleep(0.3)
        listener.poll()
        serve_out = serve.stop()
        proxy_out = proxy.stop()
    finally:
        for child in children:
            if child.proc.poll() is None:
                child.proc.kill()
    wall_s = time.monotonic() - started
    serve_stats = _last_json(serve_out, "serve")
    sim_stats = _last_json(sim_out, "sim")
    proxy_stats = _last_json(proxy_out, "proxy")

    merge_flight_log(proxy_tlog, sim_tlog, flight_tlog, args.truth_hz)
    if not args.keep_intermediate:
        sim_tlog.unlink(missing_ok=True)
        proxy_tlog.unlink(missing_ok=True)
    flight = read_flight_log(flight_tlog)
    est = read_estimator_log(est_tlog)
    events = [
        EventRecord(e["kind"], e["mode"], e["t_s"], e["probability"])
        for e in serve_stats.get("events", [])
    ]
    track = EstimateTrack(est.attitude_t_s, est.euler_rad, est.position_t_s, est.lat_lon_alt)
    summary = summarize(
        scenario.name,
        scenario.faults,
        flight.truth,
        events,
        track,
        serve_stats.get("step_us", {}),
        scenario.sensors.imu,
        scenario.expect,
        settle_s=args.settle,
    )
    summary["lag_us"] = serve_stats.get("lag_us")
    summary["variant"] = args.variant
    summary["wall_s"] = round(wall_s, 2)
    summary["sim_time_s"] = duration_s
    summary["received_truth_messages"] = serve_stats.get("received", {}).get(
        "HIL_STATE_QUATERNION", 0
    )
    summary["stream"] = {
        "sim": sim_stats.get("sent"),
        "proxy": {k: v for k, v in proxy_stats.items() if k != "sent"},
        "estimator": serve_stats.get("counters"),
        "bad_packets": serve_stats.get("bad_packets"),
    }
    png = out_dir / "summary.png"
    plot_summary(str(png), summary, est.probability_t_s, est.probabilities, flight.truth, track)
    summary["files"] = {
        "flight_tlog": str(flight_tlog),
        "estimator_tlog": str(est_tlog),
        "plot": str(png),
    }
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=2))
    return summary


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
    parser.add_argument("scenario", metavar="SCENARIO", help="scenario YAML file")
    parser.add_argument(
        "--out", default=None, help="output directory (default out/<scenario name>)"
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    parser.add_argument(
        "--realtime", action="store_true", help="pace the sim to the wall clock (for watching)"
    )
    parser.add_argument("--speed", type=float, default=None, help="with --realtime: X times")
    parser.add_argument("--duration", type=float, default=None, help="override duration_s")
    parser.add_argument(
        "--gcs",
        action="append",
        default=None,
        help="also publish to this ground station (e.g. udpout:127.0.0.1:14550); repeatable",
    )
    parser.add_argument(
        "--truth-hz",
        type=float,
        default=None,
        help="thin the truth in flight.tlog to this rate (default: every step)",
    )
    parser.add_argument(
        "--keep-intermediate",
        action="store_true",
        help="keep sim.tlog and proxy.tlog beside the merged flight.tlog",
    )
    parser.add_argument("--verbose", action="store_true", help="echo the children's stderr")
    add_filter_arguments(parser)
    parser.set_defaults(handler=_main, variant="imm")


def _terminate(signum: int, frame: object) -> None:
    """SIGTERM behaves like Ctrl-C, so that run's cleanup stops its children."""
    raise KeyboardInterrupt


def _main(args: argparse.Namespace) -> int:
    signal.signal(signal.SIGTERM, _terminate)
    scenario = load_scenario(args.scenario)
    if args.speed is not None and (not args.realtime or not 0.0 < args.speed <= 100.0):
        raise UserError("--speed: expected a factor in (0, 100], with --realtime")
    if args.duration is not None and not 1.0 <= args.duration <= scenario.duration_s:
        raise UserError(f"--duration: expected 1..{scenario.duration_s} s, got {args.duration}")
    if args.truth_hz is not None and not 0.0 < args.truth_hz <= 100.0:
        raise UserError(f"--truth-hz: expected a rate in (0, 100], got {args.truth_hz}")
    out_dir = Path(args.out) if args.out else Path("out") / Path(scenario.name).name
    if out_dir.exists() and not out_dir.is_dir():
        raise UserError(f"--out {out_dir}: exists and is not a directory")
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"--out {out_dir}: cannot create: {exc.strerror}") from None
    duration_s = args.duration or scenario.duration_s
    print(f"run: {scenario.name} ({duration_s:g} s) -> {out_dir}", file=sys.stderr)
    summary = run_scenario(scenario, args.scenario, out_dir, args)
    print(human_summary(summary), file=sys.stderr)
    print(f"run: wrote {out_dir}/ (flight.tlog, estimator.tlog, summary.png)", file=sys.stderr)
    if args.json:
        print(json.dumps(summary))
    return 0
