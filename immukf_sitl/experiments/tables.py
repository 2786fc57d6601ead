"""The paper's tables from ``runs.csv`` rows, and the campaign's JSON summary.

- Table 1: UKF-2 against UKF-3, fault-free: estimate and control error, max and MSE, position
  (m) and attitude (deg), each the mean over the replicates;
- Table 2: the 64 fault sets in the paper's order (N faults, index I, channels C as 1=x .. 6=r)
  with a mark per variant: ``✓`` every replicate maintained flight, ``×`` none did, ``k/n``
  otherwise; ``n/a`` where a variant did not fly that set; a summary line per N as the paper's;
- Table 3: UKF-1 against UKF-4 (the IMM) over the 7 single cases, as Table 1.

Tables use the rows of the campaign's first loop and first air entry (a campaign over several
prints its other rows only in ``runs.csv``), all fault times and replicates pooled.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

from immukf_sitl.estimation.fault_modes import IMU_CHANNELS, all_fault_modes, single_fault_modes
from immukf_sitl.experiments.metrics import false_declaration_rate, poisson_rate_upper_95

Row = dict[str, str]
VARIANT_TITLES = {"ukf1": "UKF-1", "ukf2": "UKF-2", "ukf3": "UKF-3", "imm": "UKF-4"}
#: ``(row label, column of runs.csv)`` of Tables 1 and 3, position then attitude
ERROR_ROWS = (
    ("Est. error", "Max", "est_pos_max_m", "est_att_max_deg"),
    ("Est. error", "MSE", "est_pos_mse_m2", "est_att_mse_deg2"),
    ("Ctrl. error", "Max", "ctrl_pos_max_m", "ctrl_att_max_deg"),
    ("Ctrl. error", "MSE", "ctrl_pos_mse_m2", "ctrl_att_mse_deg2"),
)


def _float(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        return math.nan


def mean(rows: Iterable[Row], column: str) -> float:
    """Mean of a numeric column over rows that have a value (nan if none)."""
    values = [_float(r[column]) for r in rows]
    values = [v for v in values if math.isfinite(v)]
    return sum(values) / len(values) if values else math.nan


def fmt(value: float) -> str:
    """A table number: 4 significant digits, ``–`` for none."""
    return "–" if not math.isfinite(value) else f"{value:.4g}"


def table_rows(rows: Sequence[Row]) -> list[Row]:
    """The rows tables use: the first loop and air of the campaign, no failed runs."""
    if not rows:
        return []
    loop, air = rows[0]["loop"], rows[0]["air"]
    return [r for r in rows if r["loop"] == loop and r["air"] == air and r["status"] != "error"]


def _select(rows: Sequence[Row], variant: str, fault: str) -> list[Row]:
    return [r for r in rows if r["variant"] == variant and r["fault"] == fault]


def error_table(rows: Sequence[Row], columns: Sequence[tuple[str, str, str]]) -> list[list[str]]:
    """Rows of a Table-1-like grid: label, then position and attitude per ``(title, v, f)``."""
    out = []
    for label, stat, pos_col, att_col in ERROR_ROWS:
        cells = [label, stat]
        for col in (pos_col, att_col):
            for _, variant, fault in columns:
                cells.append(fmt(mean(_select(rows, variant, fault), col)))
        out.append(cells)
    return out


def _markdown(header: Sequence[str], body: Iterable[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(cells) + " |" for cells in body]
    return "\n".join(lines) + "\n"


def _csv(header: Sequence[str], body: Iterable[Sequence[str]]) -> str:
    return "\n".join(",".join(cells) for cells in [header, *body]) + "\n"


def _error_header(titles: Sequence[str]) -> list[str]:
    return (
        ["Result", ""]
        + [f"position {t} (m, m²)" for t in titles]
        + [f"attitude {t} (deg, deg²)" for t in titles]
    )


def table1(rows: Sequence[Row]) -> tuple[str, str]:
    """Table 1 (UKF-2 vs UKF-3, fault-free) as Markdown and CSV."""
    columns = [("UKF-2", "ukf2", "none"), ("UKF-3", "ukf3", "none")]
    header = _error_header([c[0] for c in columns])
    body = error_table(table_rows(rows), columns)
    counts = [len(_select(table_rows(rows), v, f)) for _, v, f in columns]
    note = f"\nMeans over {counts[0]} (UKF-2) and {counts[1]} (UKF-3) fault-free runs.\n"
    return _markdown(header, body) + note, _csv(header, body)


def table3(rows: Sequence[Row]) -> str:
    """Table 3 (UKF-1 vs UKF-4 over the 7 single cases) as Markdown."""
    rows = table_rows(rows)
    header = ["Fault", "Result", ""] + _error_header(["UKF-1", "UKF-4"])[2:]
    body = []
    for mode in single_fault_modes():
        grid = error_table(rows, [("UKF-1", "ukf1", mode.name), ("UKF-4", "imm", mode.name)])
        for i, cells in enumerate(grid):
            body.append([mode.name if i == 0 else "", *cells])
    return _markdown(header, body)


def stability_mark(rows: Sequence[Row]) -> str:
    """``✓`` all stable, ``×`` none, ``k/n`` between, ``n/a`` no runs."""
    if not rows:
        return "n/a"
    stable = sum(r["status"] == "stable" for r in rows)
    if stable == len(rows):
        return "✓"
    if stable == 0:
        return "×"
    return f"{stable}/{len(rows)}"


def table2(rows: Sequence[Row]) -> str:
    """Table 2 (64 fault sets, stable or critical per variant) as Markdown."""
    rows = table_rows(rows)
    variants = ("ukf1", "ukf2", "ukf3", "imm")
    header = ["N", "I", "C", "faults"] + [VARIANT_TITLES[v] for v in variants]
    body = []
    summaries = []
    modes = all_fault_modes()
    for n in range(len(IMU_CHANNELS) + 1):
        group = [m for m in modes if len(m.channels) == n]
        for mode in group:
            code = ",".join(str(IMU_CHANNELS.index(c) + 1) for c in mode.channels) or "–"
            marks = [stability_mark(_select(rows, v, mode.name)) for v in variants]
            body.append([str(n), str(mode.paper_index), code, mode.name, *marks])
        summaries.append(_group_summary(n, group, rows))
    text = _markdown(header, body)
    text += "\n" + "\n".join(f"- {line}" for line in summaries) + "\n"
    text += (
        "\n✓: every replicate maintained flight; ×: every replicate was a critical failure; "
        "k/n: k of n maintained flight; n/a: not flown.\n"
    )
    return text


def _group_summary(n: int, group: Sequence, rows: Sequence[Row]) -> str:
    """The paper's line under each group of Table 2 ("UKF-2/3 unstable for 12/15")."""
    parts = []
    for variant in ("ukf1", "ukf2", "ukf3", "imm"):
        flown = [m for m in group if _select(rows, variant, m.name)]
        if not flown:
            continue
        unstable = [m for m in flown if stability_mark(_select(rows, variant, m.name)) != "✓"]
        parts.append(f"{VARIANT_TITLES[variant]} not stable for {len(unstable)}/{len(flown)}")
    return f"{n} fault(s): " + ("; ".join(parts) if parts else "not flown")


def summary_json(name: str, rows: Sequence[Row], wall_s: float) -> dict[str, object]:
    """The ``--json`` object (README, "Results").

    Its ``imm_identification.false_declarations`` are the declarations made in fault-free
    flight, each distinct flight once (runs that share a seed fly one flight until their
    faults), over ``fault_free_hours``, with the rate's 95 % upper bound;
    ``wrong_declarations`` are the declarations of a channel that had not failed at any time,
    summed over the runs (a wrong channel named after the fault counts there).
    """
    variants: dict[str, object] = {}
    for variant in ("ukf1", "ukf2", "ukf3", "imm"):
        mine = [r for r in rows if r["variant"] == variant and r["status"] != "error"]
        if not mine:
            continue
        variants[variant] = {
            "runs": len(mine),
            "stable": sum(r["status"] == "stable" for r in mine),
            "critical": sum(r["status"] == "critical" for r in mine),
            "est_att_mse_deg2_mean": _json_number(mean(mine, "est_att_mse_deg2")),
            "est_pos_mse_m2_mean": _json_number(mean(mine, "est_pos_mse_m2")),
            "ctrl_pos_mse_m2_mean": _json_number(mean(mine, "ctrl_pos_mse_m2")),
        }
    imm = [r for r in rows if r["variant"] == "imm" and r["status"] != "error"]
    # runs that share a seed fly one flight until their faults: each flight counts once
    rate = false_declaration_rate(imm)
    false = int(rate["declarations"])
    delays = [_float(r["detection_delay_s"]) for r in imm if r["detection_delay_s"]]
    return {
        "campaign": name,
        "runs": len(rows),
        "failed_runs": sum(r["status"] == "error" for r in rows),
        "wall_s": round(wall_s, 1),
        "variants": variants,
        "imm_identification": {
            "cases": len(imm),
            "identified": sum(r["identified_ok"] == "true" for r in imm),
            "identified_within_1s": sum(r["identified_within_1s"] == "true" for r in imm),
            "false_declarations": false,
            "fault_free_hours": _json_number(rate["hours"]),
            "false_declarations_per_hour": _json_number(rate["per_hour"]),
            "false_declarations_per_hour_upper_95": _json_number(
                poisson_rate_upper_95(false, rate["hours"])
            ),
            "wrong_declarations": sum(int(r["false_declarations"] or 0) for r in imm),
            "detection_delay_s_median": _json_number(_median(delays)),
            "detection_delay_s_max": _json_number(max(delays) if delays else math.nan),
        },
    }


def _median(values: Sequence[float]) -> float:
    if not values:
        return math.nan
    ordered = sorted(values)
    mid = len(ordered) // 2
    return ordered[mid] if len(ordered) % 2 else 0.5 * (ordered[mid - 1] + ordered[mid])


def _json_number(value: float) -> float | None:
    return None if not math.isfinite(value) else round(value, 6)
