"""Soak: an hour of simulated flight through the whole UDP chain, lock-step, watched for drift.

    python tools/soak.py [--scenario tools/soak_1h.yaml] [--duration S] [--no-sign] [--json]

Starts ``serve``, ``proxy`` and ``sim`` as ``run`` does (MAVLink 2 signing on by default, no
tlogs), follows the estimator's output like a ground station, and samples the resident memory
(VmRSS) of the three processes every ``--sample-every`` wall seconds. At the end it reports:

- resident memory of each process when the flight starts, after the first ``--warm-up`` s of sim
  time (the kernels have run every path once, the timing windows have begun to fill), at each
  10-minute mark and at the end; the growth from the warm-up sample to the end;
- serve's filter step time and lag (median, p99, max) per 10 minutes of sim time;
- every counter of the three processes.

It fails (exit status 1) when any process grew by 5 % or more after the warm-up, or when a
counter moved that a clean flight never moves (drops, gaps, bad packets, rejections,
re-alignments, restarts, send errors, proxy errors). Not a unit test: it takes 35-55 minutes
of wall time on a 2-core machine. docs/performance.md holds the measured figures.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from immukf_sitl.errors import UserError  # noqa: E402
from immukf_sitl.experiments.processes import Child, free_udp_ports, spawn_cli  # noqa: E402
from immukf_sitl.mavlink.listener import GroundStationListener  # noqa: E402
from immukf_sitl.mavlink.serve import READY, WARMING_UP  # noqa: E402
from immukf_sitl.mavlink.signing import write_key  # noqa: E402
from immukf_sitl.scenario import load_scenario  # noqa: E402

#: serve counters a clean flight moves; every other one must stay at 0 (servo times unwrap
#: in a flight longer than 71.6 min: SERVO_OUTPUT_RAW's 32-bit microseconds).
MOVING = {"imu_samples", "gps_fixes", "actuator_samples", "steps", "actuator_unwrapped"}
MAX_GROWTH = 0.05


def rss_kib(pid: int) -> int | None:
    """Resident set size of a process (KiB), from /proc; None once it has gone."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except OSError:
        return None
    return None


def chain_argv(scenario: str, ports: list[int], key: str | None, ack_timeout_s: float) -> dict:
    """The three processes' command lines (ports: proxy in, serve in, ground station)."""
    p_proxy, p_est, p_gcs = ports
    argv = {
        "serve": ["serve", "--in", f"udpin:127.0.0.1:{p_est}", "--out",
                  f"udpout:127.0.0.1:{p_gcs}", "--json", "--stats-interval", "60",
                  "--idle-exit", "60"],
        "proxy": ["proxy", scenario, "--in", f"udpin:127.0.0.1:{p_proxy}", "--out",
                  f"udpout:127.0.0.1:{p_est}", "--json"],
        "sim": ["sim", scenario, "--out", f"udpout:127.0.0.1:{p_proxy}", "--json",
                "--ack-timeout", str(ack_timeout_s)],
    }  # fmt: skip
    if key is not None:
        for name in argv:
            argv[name] += ["--signing-key", key]
    return argv


def last_json(stdout: str, name: str) -> dict:
    """The last JSON object a child printed."""
    for line in reversed(stdout.strip().splitlines()):
        if line.startswith("{"):
            return json.loads(line)
    raise UserError(f"{name} printed no JSON summary")


def fly(args: argparse.Namespace) -> dict:
    """Fly the soak; returns the report (memory samples, serve/proxy/sim JSON, wall time)."""
    scenario = load_scenario(args.scenario)
    duration_s = args.duration or scenario.duration_s
    out_dir = Path(args.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    key = None
    if not args.no_sign:
        key = str(out_dir / "signing.key")
        write_key(key)
    ports = free_udp_ports(3)
    argv = chain_argv(args.scenario, ports, key, 120.0)
    if args.duration:
        argv["sim"] += ["--duration", str(args.duration)]
    listener = GroundStationListener(f"udpin:127.0.0.1:{ports[2]}")
    children: dict[str, Child] = {}
    samples: list[dict] = []
    started = time.monotonic()
    try:
        children["serve"] = spawn_cli("serve", argv["serve"], echo=args.verbose)
        children["proxy"] = spawn_cli("proxy", argv["proxy"], echo=args.verbose)
        children["serve"].wait_ready(READY, 120.0, busy=WARMING_UP, busy_timeout_s=900.0)
        children["proxy"].wait_ready("proxy:", 60.0)
        children["sim"] = spawn_cli("sim", argv["sim"], echo=args.verbose)
        next_sample = 0.0
        while children["sim"].proc.poll() is None:
            listener.poll()
            for name in ("serve", "proxy"):
                if children[name].proc.poll() is not None:
                    raise UserError(f"{name} stopped: {children[name].last_error()}")
            now = time.monotonic()
            if now >= next_sample:
                rss = {name: rss_kib(child.proc.pid) for name, child in children.items()}
                samples.append({"wall_s": round(now - started, 1), "t_s": listener.t_s, **rss})
                print(
                    f"soak: t={listener.t_s:7.1f}/{duration_s:.0f} s  wall {now - started:6.0f} s"
                    f"  RSS MiB " + "  ".join(f"{n} {v / 1024:.1f}" for n, v in rss.items() if v),
                    file=sys.stderr,
                    flush=True,
                )
                next_sample = now + args.sample_every
            time.sleep(0.05)
        wall_s = time.monotonic() - started
        time.sleep(0.5)
        listener.poll()
        final = {name: rss_kib(children[name].proc.pid) for name in ("serve", "proxy")}
        samples.append({"wall_s": round(wall_s, 1), "t_s": listener.t_s, **final, "sim": None})
        sim_out = children["sim"].stop()
        if children["sim"].proc.returncode != 0:
            raise UserError(f"sim failed: {children['sim'].last_error()}")
        serve_out = children["serve"].stop()
        proxy_out = children["proxy"].stop()
    finally:
        for child in children.values():
            if child.proc.poll() is None:
                child.proc.kill()
        listener.close()
    return {
        "scenario": scenario.name,
        "sim_time_s": duration_s,
        "wall_s": round(wall_s, 1),
        "signing": key is not None,
        "memory_kib": samples,
        "serve": last_json(serve_out, "serve"),
        "proxy": last_json(proxy_out, "proxy"),
        "sim": last_json(sim_out, "sim"),
    }


def memory_findings(samples: list[dict], warm_up_s: float, window_s: float) -> dict:
    """RSS at the start, after the warm-up, at each window mark and at the end; growth."""
    out: dict[str, dict] = {}
    for name in ("serve", "proxy", "sim"):
        series = [(s["t_s"], s[name]) for s in samples if s.get(name)]
        if not series:
            continue
        warm = next((v for t, v in series if t >= warm_up_s), series[-1][1])
        marks = {}
        for t, v in series:
            mark = int(t // window_s)
            marks.setdefault(mark, v)
        end = series[-1][1]
        out[name] = {
            "start_kib": series[0][1],
            "warm_kib": warm,
            "end_kib": end,
            "growth_after_warm_up": (end - warm) / warm,
            "at_window_starts_kib": {f"{m * window_s:.0f}": v for m, v in sorted(marks.items())},
        }
    return out


def moved_counters(report: dict) -> dict[str, int]:
    """Every counter that moved although a clean flight never moves it."""
    serve = report["serve"]
    counters = serve["counters"].items()
    moved = {f"serve.counters.{k}": v for k, v in counters if v and k not in MOVING}
    for k in ("bad_packets", "decode_errors", "ignored", "send_errors", "pack_errors"):
        if serve.get(k):
            moved[f"serve.{k}"] = serve[k]
    for k, v in serve.get("signing", {}).items():
        if k != "enabled" and v:
            moved[f"serve.signing.{k}"] = v
    if serve.get("received", {}).get("BAD_DATA"):
        moved["serve.received.BAD_DATA"] = serve["received"]["BAD_DATA"]
    if report["proxy"].get("bad"):
        moved["proxy.bad"] = report["proxy"]["bad"]
    for name in ("proxy", "sim"):
        for k, v in report[name].get("signing", {}).items():
            if v:
                moved[f"{name}.signing.{k}"] = v
    if report["sim"].get("received", {}).get("BAD_DATA"):
        moved["sim.received.BAD_DATA"] = report["sim"]["received"]["BAD_DATA"]
    return moved


def describe(report: dict) -> str:
    """The report for people (Markdown tables)."""
    lines = [
        f"soak: {report['scenario']}, {report['sim_time_s']:.0f} s of sim time in "
        f"{report['wall_s']:.0f} s of wall time, signing {'on' if report['signing'] else 'off'}",
        "",
        "| process | RSS start (MiB) | after warm-up | end | growth after warm-up |",
        "|---|---|---|---|---|",
    ]
    for name, m in report["memory"].items():
        lines.append(
            f"| {name} | {m['start_kib'] / 1024:.1f} | {m['warm_kib'] / 1024:.1f} | "
            f"{m['end_kib'] / 1024:.1f} | {100 * m['growth_after_warm_up']:+.2f} % |"
        )
    lines += [
        "",
        "| sim time (s) | steps | step median / p99 / max (us) | lag median / p99 / max (us) |",
        "|---|---|---|---|",
    ]
    for w in report["serve"].get("windows", []):
        s, g = w["step_us"], w["lag_us"]
        lines.append(
            f"| {w['t_start_s']:.0f}-{w['t_end_s']:.0f}{' (partial)' if w.get('partial') else ''}"
            f" | {s['n']} | {s['median']} / {s['p99']} / {s['max']} | "
            f"{g['median']} / {g['p99']} / {g['max']} |"
        )
    serve = report["serve"]
    lines += [
        "",
        f"serve counters: {json.dumps(serve['counters'])}",
        f"serve: bad_packets {serve['bad_packets']}, decode_errors {serve['decode_errors']}, "
        f"ignored {serve['ignored']}, send_errors {serve['send_errors']}, pack_errors "
        f"{serve['pack_errors']}, signing {json.dumps(serve.get('signing'))}",
        f"serve received: {json.dumps(serve['received'])}",
        f"serve filter diagnostics: {json.dumps(serve.get('filter_diagnostics'))}",
        f"serve events: {len(serve.get('events', []))}",
        f"proxy: {json.dumps(report['proxy'])}",
        f"sim: sent {json.dumps(report['sim'].get('sent'))}, received "
        f"{json.dumps(report['sim'].get('received'))}, signing "
        f"{json.dumps(report['sim'].get('signing'))}",
        "",
        "unexpected counters: " + (json.dumps(report["unexpected_counters"]) or "none"),
        f"verdict: {'PASS' if report['passed'] else 'FAIL'}",
    ]
    return "\n".join(lines)


def main() -> int:
    """Fly, report, and return 0 when memory stayed flat and no unexpected counter moved."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default=str(REPO / "tools" / "soak_1h.yaml"))
    parser.add_argument("--duration", type=float, default=None, help="sim seconds (default all)")
    parser.add_argument("--no-sign", action="store_true", help="fly without MAVLink 2 signing")
    parser.add_argument("--warm-up", type=float, default=60.0, help="sim s before the RSS baseline")
    parser.add_argument("--sample-every", type=float, default=10.0, help="wall s between samples")
    parser.add_argument("--out-dir", default="/tmp/immukf-soak", help="where the key goes")
    parser.add_argument("--json", action="store_true", help="print the report as JSON on stdout")
    parser.add_argument("--verbose", action="store_true", help="echo the children's stderr")
    args = parser.parse_args()
    try:
        report = fly(args)
    except UserError as exc:
        print(f"soak: error: {exc}", file=sys.stderr)
        return 2
    report["memory"] = memory_findings(report["memory_kib"], args.warm_up, 600.0)
    report["unexpected_counters"] = moved_counters(report)
    flat = all(m["growth_after_warm_up"] < MAX_GROWTH for m in report["memory"].values())
    report["passed"] = flat and not report["unexpected_counters"]
    print(describe(report), file=sys.stderr)
    if args.json:
        print(json.dumps(report))
    return 0 if report["passed"] else 1


if __name__ == "__main__":
    sys.exit(main())
