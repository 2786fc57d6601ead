"""Fly chosen runs of a campaign and record what the fault namer saw, to re-name them offline.

The namer (:mod:`immukf_sitl.service.fault_naming`) names a declared channel from the readings,
the re-based prediction and its variance over seconds after the declaration. Flying a run
takes a minute; naming its recorded windows again takes milliseconds. This tool flies the
runs (in process, as ``immukf-sitl experiment`` does) with the namer's calls recorded, and
writes next to each run's ``runs.csv`` row a pickle of the calls in order:

- ``("declared", t_s, channel, baseline)``: a declaration, with the channel's healthy
  :class:`~immukf_sitl.service.fault_naming.Roughness` (or None);
- ``("baselines", t_s, roughnesses)``: beside each declaration, every channel's healthy
  roughness over the same seconds;
- ``("imu", t_s, readings)``: the six readings of a step while a channel is pending;
- ``("observe", t_s, channel, z, h, s2)``: one step of a pending channel;
- ``("cancel", t_s, channel)``: a release;
- ``("named", t_s, channel, kind, size)``: what the namer published.

``tools/rename.py`` feeds them to the current namer and compares its names with the truth.

    python tools/record_naming.py scenarios/campaigns/fault_kinds.yaml out/naming \
        --kinds bias scale --replicates 0 1 2 --jobs 2
"""

from __future__ import annotations

import argparse
import csv
import pickle
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np

from immukf_sitl.experiments.campaign import Campaign, RunSpec, load_campaign
from immukf_sitl.experiments.campaign_run import COLUMNS, execute_run
from immukf_sitl.service import fault_naming

#: the calls of the run this worker flies now (the class is wrapped once per process)
_LOG: list[tuple] = []


def _recording(log: list[tuple]) -> None:
    """Wrap :class:`FaultNamer` so that every call a pipeline makes is appended to ``log``.

    A release's ``cancel`` is recorded too; so are the namer's own cancels inside
    ``observe``, which a replay repeats harmlessly (the channel is no longer pending then).
    """
    namer = fault_naming.FaultNamer
    declared, observe, cancel = namer.declared, namer.observe, namer.cancel

    def declared_logged(self, mode_index, channel, t_s):  # noqa: ANN001, ANN202
        declared(self, mode_index, channel, t_s)
        log.append(("declared", t_s, channel, self._baselines.get(channel)))
        before = [(t, v) for t, v in self._recent if t <= t_s - fault_naming.BASELINE_GUARD_S]
        if before:
            t, v = np.array([b[0] for b in before]), np.array([b[1] for b in before])
            log.append(("baselines", t_s, [fault_naming.roughness(t, v[:, i]) for i in range(6)]))

    def observe_logged(self, t_s, imu, innovations, variances):  # noqa: ANN001, ANN202
        log.append(("imu", t_s, np.array(imu, dtype=float)))
        for i, (j, _) in self._pending.items():
            z = float(imu[i])
            log.append(("observe", t_s, i, z, z - float(innovations[j, i]), float(variances[j, i])))
        names = observe(self, t_s, imu, innovations, variances)
        log.extend(("named", t_s, i, name.kind, name.size) for i, name in names)
        return names

    def cancel_logged(self, channel=None):  # noqa: ANN001, ANN202
        for c in list(self._pending) if channel is None else [channel]:
            if c in self._pending:
                log.append(("cancel", None, c))
        cancel(self, channel)

    namer.declared, namer.observe, namer.cancel = declared_logged, observe_logged, cancel_logged


def _fly(spec: RunSpec, out_dir: str) -> dict[str, str]:
    """Fly ``spec`` with the namer recorded; its row, the record pickled beside."""
    if not getattr(fault_naming.FaultNamer, "_recorded", False):
        _recording(_LOG)
        fault_naming.FaultNamer._recorded = True
    _LOG.clear()
    log = _LOG
    row = execute_run(spec)
    name = spec.run_id.replace("/", "_")
    with open(Path(out_dir) / f"{name}.pkl", "wb") as f:
        pickle.dump({"run_id": spec.run_id, "row": row, "log": log}, f)
    return row


def select(
    campaign: Campaign, kinds: list[str] | None, replicates: list[int] | None,
    channels: list[str] | None, airs: list[str] | None,
) -> list[RunSpec]:  # fmt: skip
    """The campaign's faulted runs of those kinds, replicates, channels and airs (None: all)."""
    return [
        spec for spec in campaign.runs()
        if spec.mode.channels
        and (kinds is None or spec.fault_kind in kinds)
        and (replicates is None or spec.replicate in replicates)
        and (channels is None or spec.mode.name in channels)
        and (airs is None or spec.air in airs)
    ]  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("campaign", help="campaign YAML")
    parser.add_argument("out_dir", help="where runs.csv and the records go")
    parser.add_argument("--kinds", nargs="+", help="fault kinds to fly (default all)")
    parser.add_argument("--replicates", nargs="+", type=int, help="replicates (default all)")
    parser.add_argument("--channels", nargs="+", help="fault sets, e.g. q x (default all)")
    parser.add_argument("--airs", nargs="+", help="air entries by name (default all)")
    parser.add_argument("--ids", nargs="+", help="only these run ids")
    parser.add_argument("--jobs", type=int, default=1, help="worker processes (default 1)")
    args = parser.parse_args(argv)
    campaign = load_campaign(args.campaign)
    specs = select(campaign, args.kinds, args.replicates, args.channels, args.airs)
    if args.ids:
        specs = [s for s in specs if s.run_id in args.ids]
    out = Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    done = {p.stem for p in out.glob("*.pkl")}
    todo = [s for s in specs if s.run_id.replace("/", "_") not in done]
    print(f"record_naming: {len(todo)} of {len(specs)} runs to fly", file=sys.stderr)
    path = out / "runs.csv"
    fresh = not path.exists()
    with path.open("a", newline="") as f, ProcessPoolExecutor(args.jobs) as pool:
        writer = csv.DictWriter(f, fieldnames=COLUMNS, lineterminator="\n")
        if fresh:
            writer.writeheader()
        futures = [pool.submit(_fly, spec, str(out)) for spec in todo]
        for k, future in enumerate(as_completed(futures), 1):
            row = future.result()
            writer.writerow(row)
            f.flush()
            print(
                f"  {k}/{len(todo)} {row['run_id']}: named {row['named_kind']} "
                f"{row['named_size']} (true {row['fault_value']})", file=sys.stderr,
            )  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
