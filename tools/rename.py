"""Name recorded failures again with the current namer, and score the names against the truth.

``tools/record_naming.py`` records every call a flight's pipeline made to its
:class:`~immukf_sitl.service.fault_naming.FaultNamer`. This tool feeds them, in order, to a
fresh namer of the current code and takes, for the run's faulty channel, the last name its
first declaration received (as ``runs.csv``'s ``named_kind`` does). Only the naming is
replayed: where a name changes, the flight after it (which holds a named drift rate or gain)
would have differed, so a flown campaign has the last word.

    python tools/rename.py out/naming CAMPAIGN.yaml         # named right and size error, by kind
    python tools/rename.py out/naming CAMPAIGN.yaml --runs  # and a line per run renamed
"""

from __future__ import annotations

import argparse
import csv
import math
import pickle
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from immukf_sitl.experiments.campaign import load_campaign
from immukf_sitl.models.sensors import DETECTABLE_SIGMAS, ImuSpec
from immukf_sitl.service.fault_naming import FaultNamer

CHANNELS = "xyzpqr"
SIZED = ("bias", "drift", "scale")


def replay(log: list[tuple], namer: FaultNamer, channel: int) -> tuple[str, float | None] | None:
    """The last name ``channel``'s first declaration gets when ``log`` is fed to ``namer``."""
    name: tuple[str, float | None] | None = None
    declarations = 0
    group: list[tuple] = []

    def flush() -> None:
        nonlocal name
        if not group:
            return
        t_s = group[0][1]
        z, innovations, variances = np.zeros(6), np.zeros((1, 6)), np.ones((1, 6))
        for _, _, i, zi, hi, s2 in group:
            z[i], innovations[0, i], variances[0, i] = zi, zi - hi, s2
        group.clear()
        for i, named in namer.observe(t_s, z, innovations, variances):
            if i == channel and declarations == 1:
                name = (named.kind, named.size)

    seen: list[tuple] = []
    for entry in log:
        if entry[0] != "observe":
            seen.append(entry)
        if entry[0] == "observe":
            if group and entry[1] != group[0][1]:
                flush()
            group.append(entry)
            continue
        flush()
        if entry[0] == "imu":
            namer.record(entry[1], entry[2])
        elif entry[0] == "declared":
            _, t_s, i, baseline = entry
            namer.declared(0, i, t_s)
            namer._baselines[i] = baseline  # the recorded healthy roughness
            declarations += i == channel
        elif entry[0] == "baselines":
            i = next(e[2] for e in reversed(seen) if e[0] == "declared")
            namer._flight_baselines[i] = entry[2]
            namer._baselines[i] = entry[2][i]
        elif entry[0] == "cancel":
            namer.cancel(entry[2])
    flush()
    return name


def rename(path: Path, imu: ImuSpec) -> dict[str, object]:
    """One recorded run named again (``imu``: its spec sheet): truth, flown and replayed name."""
    with path.open("rb") as f:
        record = pickle.load(f)
    row = record["row"]
    namer = FaultNamer(imu.sigmas, bands=DETECTABLE_SIGMAS * imu.band_sigmas)
    channel = CHANNELS.index(row["fault"]) if row["fault"] in CHANNELS else None
    name = None if channel is None else replay(record["log"], namer, channel)
    return {
        "run_id": row["run_id"],
        "kind": row["fault_kind"],
        "value": float(row["fault_value"] or 0.0),
        "flown": (
            row["named_kind"] or None,
            float(row["named_size"]) if row["named_size"] else None,
        ),
        "replayed": name,
    }


def _size_error(kind: str, value: float, name: tuple[str, float | None] | None) -> float | None:
    if name is None or name[0] != kind or kind not in SIZED or name[1] is None or value == 0.0:
        return None
    return abs(name[1] - value) / abs(value)


def _same(a: tuple[str | None, float | None] | None, b: tuple[str, float | None] | None) -> bool:
    """Whether two names agree (sizes to the six digits ``runs.csv`` keeps)."""
    a = a if a is not None and a[0] is not None else None
    if a is None or b is None:
        return a is b
    sizes = [math.nan if s is None else float(s) for s in (a[1], b[1])]
    return a[0] == b[0] and (
        all(math.isnan(s) for s in sizes) or math.isclose(*sizes, rel_tol=1e-5)
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("records", help="the folder tools/record_naming.py wrote")
    parser.add_argument("campaign", help="the campaign the records flew (for its spec sheet)")
    parser.add_argument("--runs", action="store_true", help="list each run whose name changed")
    parser.add_argument("--csv", help="write one row per run here")
    args = parser.parse_args(argv)
    paths = sorted(Path(args.records).glob("*.pkl"))
    if not paths:
        print(f"rename: no records (*.pkl) in {args.records}", file=sys.stderr)
        return 2
    imu = load_campaign(args.campaign).runs()[0].scenario.sensors.spec_sheet().imu
    runs = [rename(p, imu) for p in paths]
    table: dict[str, dict[str, list]] = defaultdict(lambda: defaultdict(list))
    for run in runs:
        for which in ("flown", "replayed"):
            name = run[which]
            table[run["kind"]][which].append(name is not None and name[0] == run["kind"])
            err = _size_error(run["kind"], run["value"], name)
            if err is not None:
                table[run["kind"]][which + "_err"].append(err)
        if args.runs and not _same(run["flown"], run["replayed"]):
            print(f"{run['run_id']}: true {run['value']:+.4g}, flown {run['flown']}, "
                  f"now {run['replayed']}")  # fmt: skip
    print("| kind | runs | named right, flown | now | size error (median), flown | now |")
    print("|---|---|---|---|---|---|")
    for kind, cols in sorted(table.items()):
        med = {w: np.median(cols[w + "_err"]) if cols[w + "_err"] else math.nan
               for w in ("flown", "replayed")}  # fmt: skip
        print(f"| {kind} | {len(cols['flown'])} | {sum(cols['flown'])} | {sum(cols['replayed'])}"
              f" | {100 * med['flown']:.1f} % | {100 * med['replayed']:.1f} % |")  # fmt: skip
    if args.csv:
        with open(args.csv, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(
                ["run_id", "kind", "value", "flown_kind", "flown_size", "kind_now", "size_now"]
            )
            for run in runs:
                now = run["replayed"] or (None, None)
                w.writerow([run["run_id"], run["kind"], run["value"], *run["flown"], *now])
    return 0


if __name__ == "__main__":
    sys.exit(main())
