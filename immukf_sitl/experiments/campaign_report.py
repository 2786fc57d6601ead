"""A campaign's outputs from its ``runs.csv``: the tables, the figures and ``report.md``.

Everything is regenerated from the rows (and one re-flown run for Fig. 2), so the report follows
the estimator as it changes. :mod:`~immukf_sitl.experiments.campaign_summary` computes the
real-air matrix, :mod:`~immukf_sitl.experiments.campaign_render` writes the prose and tables,
:mod:`~immukf_sitl.experiments.campaign_plots` draws the figures; this module writes the files.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from immukf_sitl.experiments.campaign import Campaign
from immukf_sitl.experiments.campaign_plots import (
    plot_delays,
    write_figure,
)
from immukf_sitl.experiments.campaign_render import (
    matrix_markdown,
    matrix_report,
    paper_report,
)
from immukf_sitl.experiments.campaign_run import CAMPAIGN_JSON
from immukf_sitl.experiments.campaign_summary import (
    matrix_summary,
)
from immukf_sitl.experiments.tables import (
    Row,
    summary_json,
    table1,
    table2,
    table3,
)


def write_outputs(
    campaign: Campaign,
    rows: Sequence[Row],
    out_dir: Path,
    wall_s: float,
    command: str,
    figure: bool = True,
    resumed: int = 0,
) -> dict[str, object]:
    """Write the tables, ``fig2.png`` and ``report.md``; return the ``--json`` object.

    ``wall_s`` is this invocation's; ``resumed`` runs were kept from an earlier one
    (``--resume``), whose time it does not hold, and the report says so.

    A campaign with ``report: matrix`` gets the real-air matrix measurement instead of the paper's
    comparison in ``report.md``, and ``matrix.json``, ``matrix.md`` and ``delays.png``.
    """
    summary = summary_json(campaign.name, rows, wall_s)
    summary["resumed"] = resumed
    if campaign.report == "matrix":
        return _write_matrix(campaign, rows, out_dir, summary, command, figure)
    t1_md, t1_csv = table1(rows)
    (out_dir / "table1.md").write_text(t1_md, encoding="utf-8")
    (out_dir / "table1.csv").write_text(t1_csv, encoding="utf-8")
    t2 = table2(rows)
    (out_dir / "table2.md").write_text(t2, encoding="utf-8")
    t3 = table3(rows)
    (out_dir / "table3.md").write_text(t3, encoding="utf-8")
    caption = write_figure(campaign, out_dir / "fig2.png") if figure else None
    report = paper_report(campaign, rows, summary, command, t1_md, t2, t3, caption)
    (out_dir / "report.md").write_text(report, encoding="utf-8")
    summary["out_dir"] = str(out_dir)
    return summary


def _write_matrix(
    campaign: Campaign,
    rows: Sequence[Row],
    out_dir: Path,
    summary: dict[str, object],
    command: str,
    figure: bool,
) -> dict[str, object]:
    import json

    matrix = matrix_summary(rows)
    tables = matrix_markdown(matrix)
    (out_dir / "matrix.md").write_text(tables, encoding="utf-8")
    (out_dir / "matrix.json").write_text(json.dumps(matrix, indent=1) + "\n", encoding="utf-8")
    plot_delays(rows, out_dir / "delays.png")
    caption = write_figure(campaign, out_dir / "fig2.png") if figure else None
    stamp_path = out_dir / CAMPAIGN_JSON
    stamp = json.loads(stamp_path.read_text(encoding="utf-8")) if stamp_path.exists() else {}
    commit = stamp.get("source_commit", "unknown")
    report = matrix_report(campaign, summary, command, tables, commit, caption)
    (out_dir / "report.md").write_text(report, encoding="utf-8")
    summary["matrix"] = matrix
    summary["source_commit"] = commit
    summary["out_dir"] = str(out_dir)
    return summary


def main(argv: Sequence[str] | None = None) -> int:
    """Rewrite a campaign's report from the ``runs.csv`` it has, without flying anything.

    ``python -m immukf_sitl.experiments.campaign_report CAMPAIGN.yaml OUT_DIR``: the rows so far
    of a campaign still running or stopped early (no figure; wall time 0).
    """
    import argparse
    import sys

    from immukf_sitl.errors import UserError
    from immukf_sitl.experiments.campaign import load_campaign
    from immukf_sitl.experiments.campaign_run import RUNS_CSV, read_rows

    parser = argparse.ArgumentParser(description=main.__doc__)
    parser.add_argument("campaign")
    parser.add_argument("out_dir")
    args = parser.parse_args(argv)
    try:
        campaign = load_campaign(args.campaign)
        out_dir = Path(args.out_dir)
        rows = read_rows(out_dir / RUNS_CSV)
    except UserError as exc:
        print(f"campaign_report: {exc}", file=sys.stderr)
        return 2
    order = {spec.run_id: spec.index for spec in campaign.runs()}
    rows = sorted((r for r in rows if r["run_id"] in order), key=lambda r: order[r["run_id"]])
    command = f"python -m immukf_sitl.experiments.campaign_report {args.campaign} {out_dir}"
    write_outputs(campaign, rows, out_dir, 0.0, command, figure=False)
    print(f"{out_dir}/report.md: {len(rows)} of {len(order)} runs")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
