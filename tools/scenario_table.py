"""Fly scenarios through the whole UDP chain and print one Markdown table row each.

    python tools/scenario_table.py scenarios/*_windy*.yaml [--out-dir out/table]

Each row is one ``immukf-sitl run SCENARIO --json`` (lock-step, seeded): the fault, when it
became observable and was detected, the false declarations, the attitude and position errors
and the filter's step time. README's results tables are made with it; progress goes to stderr.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

HEADER = (
    "| scenario | fault | observable | detected | delay | false declarations | "
    "attitude max / MSE (deg, deg²) | position max / MSE (m, m²) | step median (µs) |\n"
    "|---|---|---|---|---|---|---|---|---|"
)


def _cell(value: float | None, fmt: str) -> str:
    return "–" if value is None else format(value, fmt)


def row(summary: dict) -> str:
    """The table row of one run's summary."""
    faults = summary["faults"]
    fault = faults[0] if faults else None
    err = summary["est_error"]
    modes = sorted({d["mode"] for d in summary["false_alarm_detections"]})
    false = f"{summary['false_alarms']}" + (f" ({', '.join(modes)})" if modes else "")
    return (
        f"| {summary['scenario']} "
        f"| {fault['mode'] + ' ' + fault['kind'] + ' at ' + format(fault['t_s'], 'g') + ' s' if fault else '–'} "  # noqa: E501
        f"| {_cell(fault and fault['observable_t_s'], '.2f')} "
        f"| {_cell(fault and fault['detected_t_s'], '.2f')} "
        f"| {_cell(fault and fault['detection_delay_s'], '.2f')} "
        f"| {false} "
        f"| {_cell(err['att_max_deg'], '.2f')} / {_cell(err['att_mse_deg2'], '.3g')} "
        f"| {_cell(err['pos_max_m'], '.1f')} / {_cell(err['pos_mse_m2'], '.3g')} "
        f"| {_cell(summary['step_us']['median'], '.0f')} |"
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenarios", nargs="+", help="scenario YAML files")
    parser.add_argument("--out-dir", default="out/table", help="run directories go here")
    args = parser.parse_args()
    rows = []
    for path in args.scenarios:
        out_dir = Path(args.out_dir) / Path(path).stem
        start = time.monotonic()
        proc = subprocess.run(
            [sys.executable, "-m", "immukf_sitl.cli", "run", path, "--json",
             "--out-dir", str(out_dir)],
            capture_output=True,
            text=True,
        )  # fmt: skip
        if proc.returncode != 0:
            print(f"{path}: failed: {proc.stderr.strip().splitlines()[-1]}", file=sys.stderr)
            return 1
        rows.append(row(json.loads(proc.stdout)))
        print(f"{path}: {time.monotonic() - start:.0f} s", file=sys.stderr, flush=True)
    print(HEADER)
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
