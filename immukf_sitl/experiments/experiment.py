"""``immukf-sitl experiment CAMPAIGN.yaml``: a Monte Carlo campaign, its tables and its report.

Wires the pieces together: the campaign file (:mod:`.campaign`), the runs through one executor
(:mod:`.campaign_run`, :mod:`.executor`), then the tables, Fig. 2 and ``report.md``
(:mod:`.campaign_report`). Progress goes to stderr; ``--json`` prints one object on stdout.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from immukf_sitl.experiments.campaign import load_campaign
from immukf_sitl.experiments.campaign_report import write_outputs
from immukf_sitl.experiments.campaign_run import run_campaign
from immukf_sitl.options import add_json_argument


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``experiment`` subcommand."""
    parser = subparsers.add_parser(
        "experiment",
        help="run a Monte Carlo campaign (variants x fault sets x seeds), tables and report",
        description=(
            "Fly every run of a campaign file in process (JSBSim, sensors, fault injection, "
            "the estimator and the autopilot, no sockets), closed loop unless the file says "
            "open, and write runs.csv, table1.md/.csv, table2.md, table3.md, fig2.png and "
            "report.md into --out-dir. Each run is seeded from the campaign's seed and its "
            "replicate, so results are the same whatever --jobs or --scheduler. A run that "
            "fails records its error and the campaign goes on. See scenarios/campaigns/."
        ),
    )
    parser.add_argument("campaign", help="campaign YAML file (e.g. scenarios/campaigns/quick.yaml)")
    parser.add_argument(
        "--jobs", type=int, default=1, help="local worker processes (default 1: this process)"
    )
    parser.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDRESS",
        help="run on a Dask cluster instead, e.g. tcp://HOST:8786 (pip install "
        "'immukf-sitl[cluster]'; start workers with --nthreads 1)",
    )
    parser.add_argument(
        "--out-dir", default=None, help="output directory (default results/<campaign name>/)"
    )
    parser.add_argument(
        "--resume",
        action="store_true",
        help="keep the runs already in --out-dir (those without an error) and fly the rest",
    )
    parser.add_argument(
        "--no-figure", action="store_true", help="do not re-fly the run of fig2.png"
    )
    add_json_argument(parser, "the campaign's summary")
    parser.set_defaults(handler=_main)


def _main(args: argparse.Namespace) -> int:
    campaign = load_campaign(args.campaign)
    out_dir = Path(args.out_dir) if args.out_dir else Path("results") / campaign.name
    where = f"Dask at {args.scheduler}" if args.scheduler else f"{args.jobs} job(s)"
    print(
        f"experiment: {campaign.name}: {len(campaign.runs())} runs on {where} -> {out_dir}/",
        file=sys.stderr,
    )
    result = run_campaign(
        campaign, out_dir, jobs=args.jobs, scheduler=args.scheduler, resume=args.resume
    )
    command = f"immukf-sitl experiment {args.campaign}"
    summary = write_outputs(
        campaign, result.rows, out_dir, result.wall_s, command, figure=not args.no_figure,
        resumed=result.skipped,
    )  # fmt: skip
    summary["flown"] = result.flown
    for name, v in summary["variants"].items():
        print(
            f"experiment: {name}: {v['stable']}/{v['runs']} stable, {v['critical']} critical",
            file=sys.stderr,
        )
    print(
        f"experiment: wrote {out_dir}/ (runs.csv, table1.md, table2.md, table3.md, report.md) "
        f"in {result.wall_s:.0f} s",
        file=sys.stderr,
    )
    if args.json:
        print(json.dumps(summary))
    return 0
