"""A campaign's ``report.md`` and ``matrix.md`` rendered from its rows and summaries.

The prose lives in templates (``templates/*.md``, :class:`string.Template`), filled with the
numbers computed here; nothing is typed by hand but the paper's own numbers (its Tables 1-3,
``paper_tables.yaml``).
"""

from __future__ import annotations

import math
import string
from collections.abc import Callable, Sequence
from importlib import resources

import yaml

from immukf_sitl.experiments.campaign import Campaign, UniformFaultTimes
from immukf_sitl.experiments.campaign_summary import (
    KIND_FAULT_FREE_HOURS,
    KIND_MEDIAN_DELAY_S,
    KIND_NAMED_SHARE,
    KIND_SIZE_ERROR,
    MATRIX_IDENTIFIED_SHARE,
    MATRIX_WITHIN_S,
    PAIRS_SECOND_SHARE,
    SURVIVAL_ATTITUDE_RATIO,
    SURVIVAL_POSITION_M,
    _float,
    pair_gap_label,
)
from immukf_sitl.experiments.tables import (
    ERROR_ROWS,
    Row,
    fmt,
    mean,
    stability_mark,
    table_rows,
)


def _paper_tables() -> dict:
    """The paper's Tables 1-3 (``paper_tables.yaml``), as tuples."""
    text = resources.files("immukf_sitl.experiments").joinpath("paper_tables.yaml").read_text()
    return yaml.safe_load(text)


_PAPER = _paper_tables()
#: The paper's Table 1: (position UKF-2, position UKF-3, attitude UKF-2, attitude UKF-3) per
#: row of :data:`~immukf_sitl.experiments.tables.ERROR_ROWS`.
PAPER_TABLE1 = tuple(tuple(row) for row in _PAPER["table1"])
#: The paper's Table 3: per fault, (position UKF-1, position UKF-4, attitude UKF-1, UKF-4) per
#: row of ``ERROR_ROWS``.
PAPER_TABLE3 = {
    fault: tuple(tuple(row) for row in grid) for fault, grid in _PAPER["table3"].items()
}
#: The paper's Table 2 summaries: fault sets where UKF-2/3 were unstable, by number of faults.
PAPER_TABLE2_UNSTABLE = {int(n): tuple(v) for n, v in _PAPER["table2_unstable"].items()}


def render(template: str, **values: object) -> str:
    """The text of ``templates/<template>.md`` with ``$name`` filled from ``values``."""
    path = resources.files("immukf_sitl.experiments").joinpath("templates", f"{template}.md")
    return string.Template(path.read_text(encoding="utf-8")).substitute(values)


def _paper_table1_markdown() -> str:
    header = "| Result | | position UKF-2 | position UKF-3 | attitude UKF-2 | attitude UKF-3 |\n"
    lines = [header, "|---|---|---|---|---|---|\n"]
    for (label, stat, _, _), values in zip(ERROR_ROWS, PAPER_TABLE1, strict=True):
        lines.append(f"| {label} | {stat} | " + " | ".join(f"{v:g}" for v in values) + " |\n")
    return "".join(lines)


def _paper_table3_markdown() -> str:
    lines = [
        "| Fault | Result | | position UKF-1 | position UKF-4 | attitude UKF-1 | "
        "attitude UKF-4 |\n",
        "|---|---|---|---|---|---|---|\n",
    ]
    for fault, grid in PAPER_TABLE3.items():
        for i, ((label, stat, _, _), values) in enumerate(zip(ERROR_ROWS, grid, strict=True)):
            cells = " | ".join(f"{v:g}" for v in values)
            lines.append(f"| {fault if i == 0 else ''} | {label} | {stat} | {cells} |\n")
    return "".join(lines)


def _ratio_text(a: float, b: float) -> str:
    if not (math.isfinite(a) and math.isfinite(b)) or b == 0:
        return "–"
    return f"{a / b:.2f}×"


def _table1_discussion(rows: Sequence[Row]) -> str:
    sel = table_rows(rows)
    ukf2 = [r for r in sel if r["variant"] == "ukf2" and r["fault"] == "none"]
    ukf3 = [r for r in sel if r["variant"] == "ukf3" and r["fault"] == "none"]
    if not ukf2 or not ukf3:
        return "The campaign flew no fault-free UKF-2 and UKF-3 pair.\n"
    att2, att3 = mean(ukf2, "est_att_mse_deg2"), mean(ukf3, "est_att_mse_deg2")
    pos2, pos3 = mean(ukf2, "est_pos_mse_m2"), mean(ukf3, "est_pos_mse_m2")
    ctl2, ctl3 = mean(ukf2, "ctrl_att_mse_deg2"), mean(ukf3, "ctrl_att_mse_deg2")
    return render(
        "table1_discussion",
        att2=fmt(att2),
        att3=fmt(att3),
        att_ratio=_ratio_text(att3, att2),
        better="smaller" if att2 < att3 else "larger",
        pos2=fmt(pos2),
        pos3=fmt(pos3),
        ctl2=fmt(ctl2),
        ctl3=fmt(ctl3),
        ctl_ratio=_ratio_text(ctl3, ctl2),
        ctl_pos2=fmt(mean(ukf2, "ctrl_pos_mse_m2")),
    )


def _percent(fraction: float) -> str:
    return f"{100.0 * fraction:.0f} %"


def _table3_discussion(rows: Sequence[Row]) -> str:
    sel = table_rows(rows)
    pairs = []  # (fault, ours UKF-1, ours UKF-4, paper UKF-1, paper UKF-4) of est. att. MSE
    smaller = total = 0
    for fault, grid in PAPER_TABLE3.items():
        ukf1 = [r for r in sel if r["variant"] == "ukf1" and r["fault"] == fault]
        imm = [r for r in sel if r["variant"] == "imm" and r["fault"] == fault]
        if not ukf1 or not imm:
            continue
        for (_, _, pos_col, att_col), paper in zip(ERROR_ROWS[:2], grid[:2], strict=True):
            ours = (mean(ukf1, pos_col), mean(imm, pos_col), mean(ukf1, att_col))
            ours += (mean(imm, att_col),)
            smaller += sum(o < p for o, p in zip(ours, paper, strict=True))
            total += 4
        pairs.append(
            (fault, mean(ukf1, "est_att_mse_deg2"), mean(imm, "est_att_mse_deg2"), *grid[1][2:])
        )
    if not pairs:
        return "The campaign flew no UKF-1 and UKF-4 pair over the single cases.\n"
    worst = max(pairs, key=lambda p: p[2] / p[1] if p[1] > 0 else 0.0)
    imm_better = [p[0] for p in pairs if p[2] < p[1]]
    best_gain = max((1.0 - p[2] / p[1] for p in pairs if 0 < p[2] < p[1]), default=0.0)
    paper_imm_better = [p[0] for p in pairs if p[4] < p[3]]
    return render(
        "table3_discussion",
        smaller=smaller,
        total=total,
        worst_ratio=_ratio_text(worst[2], worst[1]),
        worst_fault=worst[0],
        worst_imm=fmt(worst[2]),
        worst_ukf1=fmt(worst[1]),
        imm_better=", ".join(imm_better) or "no fault",
        paper_imm_better=", ".join(paper_imm_better),
        best_gain=_percent(best_gain),
    )


def _table2_discussion(rows: Sequence[Row]) -> str:
    sel = table_rows(rows)
    lines = []
    for n, (paper_bad, paper_total) in PAPER_TABLE2_UNSTABLE.items():
        groups = range(n, 7) if n == 4 else (n,)
        for variant in ("ukf2", "ukf3"):
            cells = {}
            for r in sel:
                if r["variant"] == variant and int(r["n_faults"]) in groups:
                    cells.setdefault(r["fault"], []).append(r)
            if not cells:
                continue
            bad = sum(stability_mark(c) != "✓" for c in cells.values())
            label = f"{n}" if n < 4 else "4-6"
            lines.append(
                f"- {label} faults, {variant.upper().replace('UKF', 'UKF-')}: not stable for "
                f"{bad}/{len(cells)} fault sets (paper, UKF-2/3: {paper_bad}/{paper_total})"
            )
    ukf1 = [r for r in sel if r["variant"] == "ukf1"]
    ukf1_bad = sorted({r["fault"] for r in ukf1 if r["status"] != "stable"})
    imm = [r for r in sel if r["variant"] == "imm"]
    imm_bad = sorted({r["fault"] for r in imm if r["status"] != "stable"})
    text = "\n".join(lines) + "\n"
    if ukf1:
        text += (
            f"- UKF-1 (matched): {'stable in every run' if not ukf1_bad else 'not stable for '}"
            f"{', '.join(ukf1_bad)} (paper: stable for all 64).\n"
        )
    if imm:
        text += (
            f"- UKF-4 (IMM): {'stable in every run' if not imm_bad else 'not stable for '}"
            f"{', '.join(imm_bad)} (paper: stable for all 7 single cases).\n"
        )
    single = [
        r
        for r in sel
        if r["variant"] in ("ukf2", "ukf3") and r["n_faults"] == "1" and r["status"] != "stable"
    ]
    failed_single = sorted({r["fault"] for r in single})
    text += render("single_faults", failed_single=", ".join(failed_single) or "none")
    if ukf1_bad:
        common = set(ukf1_bad[0].split("+"))
        for name in ukf1_bad[1:]:
            common &= set(name.split("+"))
        failed = [r for r in ukf1 if r["status"] != "stable"]
        after = [float(r["failure_t_s"]) - float(r["fault_t_s"]) for r in failed]
        text += render(
            "ukf1_failures",
            n_failed=len(failed),
            n_runs=len(ukf1),
            common="+".join(c for c in "xyzpqr" if c in common) or "no channel in common",
            after_min=f"{min(after):.1f}",
            after_max=f"{max(after):.1f}",
            pos_max=fmt(max(_float(r["est_pos_max_m"]) for r in failed)),
        )
    return text


def _imm_discussion(summary: dict) -> str:
    ident = summary["imm_identification"]
    if not ident["cases"]:
        return "The campaign flew no IMM runs.\n"
    return render(
        "imm_discussion",
        cases=ident["cases"],
        identified=ident["identified"],
        within_1s=ident["identified_within_1s"],
        delay_median=fmt(ident["detection_delay_s_median"] or math.nan),
        delay_max=fmt(ident["detection_delay_s_max"] or math.nan),
        false_declarations=ident["false_declarations"],
        hours=fmt(ident["fault_free_hours"] or 0.0),
        per_hour=fmt(ident["false_declarations_per_hour"] or 0.0),
        upper=fmt(ident["false_declarations_per_hour_upper_95"] or math.nan),
        wrong=ident["wrong_declarations"],
    )


def _wall_text(summary: dict) -> str:
    """The wall time, and the runs it does not cover when some were kept from an earlier run."""
    text = f"{summary['wall_s']:.0f} s"
    kept = int(summary.get("resumed") or 0)
    if kept:
        text += f" for the runs flown here ({kept} kept from an earlier invocation, not timed)"
    return text


def _header(campaign: Campaign, summary: dict, command: str) -> dict[str, object]:
    """What every report's head names: the campaign, the command, the runs flown and failed."""
    return {
        "name": campaign.name,
        "command": command,
        "description": campaign.description,
        "runs": summary["runs"],
        "failed_runs": summary["failed_runs"],
    }


def paper_report(
    campaign: Campaign,
    rows: Sequence[Row],
    summary: dict,
    command: str,
    t1: str,
    t2: str,
    t3: str,
    caption: str | None,
) -> str:
    """``report.md`` of a paper campaign: Tables 1-3 beside the paper's, with the discussion."""
    variants = summary["variants"]
    counts = ", ".join(
        f"{name}: {v['runs']} runs, {v['stable']} stable, {v['critical']} critical"
        for name, v in variants.items()
    )
    scenario = campaign.figure_run() or (campaign.runs()[0] if rows else None)
    flight = (
        f"{scenario.scenario.duration_s:g} s flights, faults at "
        f"{', '.join(f'{t:g}' for t in campaign.fault_times_s)} s"
        if scenario is not None
        else ""
    )
    failure = campaign.failure
    stop_text = (
        "A run stops there, so a failed run's errors cover its flight up to the failure."
        if failure.stop
        else ""
    )
    figure_text = (
        f"![Fig. 2](fig2.png)\n\nFig. 2: {caption}.\n" if caption else "No figure run flown.\n"
    )
    return render(
        "paper_report",
        **_header(campaign, summary, command),
        flight=flight,
        loops=", ".join(campaign.loops),
        replicates=campaign.replicates,
        wall_s=_wall_text(summary),
        counts=counts,
        lateral_m=f"{failure.lateral_m:g}",
        vertical_m=f"{failure.vertical_m:g}",
        ground_alt_m=f"{failure.ground_alt_m:g}",
        estimate_position_m=f"{failure.estimate_position_m:g}",
        estimate_attitude_deg=f"{failure.estimate_attitude_deg:g}",
        stop_text=stop_text,
        table1=t1,
        paper_table1=_paper_table1_markdown(),
        table1_discussion=_table1_discussion(rows),
        table2=t2,
        table2_discussion=_table2_discussion(rows),
        table3=t3,
        paper_table3=_paper_table3_markdown(),
        table3_discussion=_table3_discussion(rows),
        imm_discussion=_imm_discussion(summary),
        figure_text=figure_text,
    )


def _n(value: object, digits: str = ".3g") -> str:
    return "–" if value is None else format(value, digits)


def _pct(num: int, den: int) -> str:
    return "–" if not den else f"{100.0 * num / den:.0f} %"


def _identification_lines(groups: list[tuple[str, dict]]) -> list[str]:
    lines = [
        f"**Identified within {MATRIX_WITHIN_S:g} s of becoming observable** (IMM, single "
        "zeroed channels: the first declaration at or after the fault names the channel, "
        "at most 1 s after the later of the fault and the moment it became observable):\n",
        "| air | observable | identified ≤ 1 s | share | identified later | wrong mode "
        "first | missed | not observable | ended before the fault | delay median / max (s) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for air, g in groups:
        i = g["identification"]
        lines.append(
            f"| {air} | {i['observable']} | {i['identified_within_1s']} | "
            f"{_pct(i['identified_within_1s'], i['observable'])} | {i['identified_later']} | "
            f"{i['wrong_mode_first']} | {i['missed']} | {i['not_observable']} | "
            f"{i['ended_before_fault']} | "
            f"{_n(i['detection_delay_s_median'])} / {_n(i['detection_delay_s_max'])} |"
        )
    lines += [
        "\nBy channel (identified ≤ 1 s / observable):\n",
        "| air | x | y | z | p | q | r |",
        "|---|---|---|---|---|---|---|",
    ]
    for air, g in groups:
        ch = g["identification"]["by_channel"]
        cells = " | ".join(f"{c['identified_within_1s']}/{c['observable']}" for c in ch.values())
        lines.append(f"| {air} | {cells} |")
    return lines + _survival_lines(groups)


def _survival_lines(groups: list[tuple[str, dict]]) -> list[str]:
    """Per air and channel: survived of the runs with a fault-free twin, and their median ratio.

    The ratio is the attitude MSE after the declaration over the twin's; no table when no run
    has a twin.
    """
    if not any(
        c.get("with_fault_free_twin")
        for _, g in groups
        for c in g["identification"]["by_channel"].values()
    ):
        return []
    lines = [
        f"\nSurvived by channel (survived / with a fault-free twin; in brackets the median "
        f"attitude MSE after the declaration over the twin's, {SURVIVAL_ATTITUDE_RATIO:g} at "
        "most to survive):\n",
        "| air | x | y | z | p | q | r |",
        "|---|---|---|---|---|---|---|",
    ]
    for air, g in groups:
        cells = []
        for c in g["identification"]["by_channel"].values():
            ratio = c["attitude_ratio_median"]
            shown = (
                "" if ratio is None else f" ({ratio:.2g}x)" if ratio < 10 else f" ({ratio:.0f}x)"
            )
            cells.append(f"{c['survived']}/{c['with_fault_free_twin']}{shown}")
        lines.append(f"| {air} | {' | '.join(cells)} |")
    return lines + _consistency_lines(groups)


def _consistency_lines(groups: list[tuple[str, dict]]) -> list[str]:
    """Per air and channel: the median attitude NEES per axis after the declaration.

    Beside them the fault-free flights' from their drawn onset; no table when no run has one.
    """
    rows = []
    for air, g in groups:
        ident = g["identification"]
        medians = [ident.get("fault_free_attitude_nees_median")] + [
            c.get("attitude_nees_median") for c in ident["by_channel"].values()
        ]
        rows.append((air, medians))
    if all(m is None for _, medians in rows for m in medians):
        return []
    lines = [
        "\nAttitude consistency after the declaration (median over the runs of the attitude "
        "error squared over the filter's own variance, per axis: 1 when its sigmas are right, "
        "9 when the errors run three times them):\n",
        "| air | fault-free | x | y | z | p | q | r |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for air, medians in rows:
        cells = " | ".join("–" if m is None else f"{m:.3g}" for m in medians)
        lines.append(f"| {air} | {cells} |")
    return lines


def _kind_lines(overall: dict) -> list[str]:
    """Per fault kind (all airs): the identification, naming and survival figures.

    Zero-only campaigns have none.
    """
    kinds = overall["identification"].get("by_kind", {})
    if set(kinds) <= {"zero"}:
        return []
    lines = [
        "\n**By fault kind** (all airs; the size error is the median relative error of the "
        "named size where the kind was named right, for bias, drift and scale; survived: "
        f"declared, not lost, the attitude MSE after the declaration at most "
        f"{SURVIVAL_ATTITUDE_RATIO:g} times the same air's and airframe's fault-free flight's "
        f"from its own drawn onset on, and the position error after it under "
        f"{SURVIVAL_POSITION_M:g} m, over the runs that have that flight):\n",
        "| kind | observable | identified within 1 s | median delay | named right | size error "
        "| runs lost | survived |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for kind, k in kinds.items():
        n = k["observable"]
        twinned = k.get("with_fault_free_twin", 0)
        delay = k.get("detection_delay_s_median")
        lines.append(
            f"| {kind} | {n} | {k['identified_within_1s']} ({_pct(k['identified_within_1s'], n)})"
            f" | {'–' if delay is None else f'{delay:.2f} s'}"
            f" | {k['named_right']} ({_pct(k['named_right'], n)}) | "
            f"{_n(k['size_error_median'], '.1%')} | {k.get('lost', 0)} | "
            f"{k.get('survived', 0)}/{twinned} |"
        )
    return lines


def _pair_lines(data: dict) -> list[str]:
    """The pairs table of a filter model (none when it flew no pair)."""
    if "pairs" not in data:
        return []
    lines = [
        f"\n**Pairs** (IMM, all airs; two channels, the second failing at once or a gap after "
        f"the first; a channel counts as identified when the declaration that added it to the "
        f"declared set came at most {MATRIX_WITHIN_S:g} s after it became observable; "
        "declarations outside the pair count from the first fault on):\n",
        "| second fault | runs | first ≤ 1 s / observable | second ≤ 1 s / observable | share "
        "| second delay median (s) | both declared at the end | declarations outside the pair "
        "| runs lost |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for label, g in data["pairs"]["by_gap"].items():
        lines.append(
            f"| {label} | {g['runs']} | "
            f"{g['first_identified_within_1s']}/{g['first_observable']} | "
            f"{g['second_identified_within_1s']}/{g['second_observable']} | "
            f"{_pct(g['second_identified_within_1s'], g['second_observable'])} | "
            f"{_n(g['second_detection_delay_s_median'])} | {g['both_declared_at_end']} | "
            f"{g['declarations_outside_pair']} | {g['lost']} |"
        )
    return lines


def _pair_acceptance_lines(data: dict, mark: Callable[[bool], str]) -> list[str]:
    """The pairs' criterion in the acceptance list (none when the model flew no pair)."""
    if "pairs" not in data:
        return []
    pairs = data["pairs"]
    shares = ", ".join(
        f"{label} {_pct(g['second_identified_within_1s'], g['second_observable'])} "
        f"({g['second_identified_within_1s']}/{g['second_observable']})"
        for label, g in pairs["by_gap"].items()
    )
    return [
        f"- ≥ {100 * PAIRS_SECOND_SHARE:.0f} % of the observable second faults of a pair "
        f"identified within {MATRIX_WITHIN_S:g} s, at every gap: {shares}: "
        f"{mark(pairs['acceptance']['second_identified_within_1s'])}."
    ]


def _kind_acceptance_lines(data: dict, mark: Callable[[bool], str]) -> list[str]:
    """Each fault kind's criteria in the acceptance list (none for a zero-only campaign)."""
    done, false = data["acceptance"], data["overall"]["false_declarations"]
    if "kinds" not in done:
        return []
    lines = [
        f"- zero false declarations in at least {KIND_FAULT_FREE_HOURS:g} h of fault-free "
        f"flight: {false['declarations']} in {_n(false['hours'], '.3f')} h: "
        f"{mark(done['no_false_declarations_in_3h'])}.",
        f"- every fault kind (the table by fault kind): ≥ {100 * MATRIX_IDENTIFIED_SHARE:.0f} % "
        f"identified within {MATRIX_WITHIN_S:g} s with a median delay ≤ "
        f"{KIND_MEDIAN_DELAY_S:g} s; named right in ≥ {100 * KIND_NAMED_SHARE:.0f} % (size "
        f"error ≤ {100 * KIND_SIZE_ERROR:.0f} % for bias, drift and scale); every run survived:\n",
        "  | kind | identified within 1 s | named right | survived |",
        "  |---|---|---|---|",
    ]
    for kind, ok in done["kinds"].items():
        lines.append(
            f"  | {kind} | {mark(ok['identified_within_1s'])} | {mark(ok['named_right'])} "
            f"| {mark(ok['survived'])} |"
        )
    return lines


def _false_declaration_lines(groups: list[tuple[str, dict]]) -> list[str]:
    lines = [
        "\n**False declarations in fault-free flight** (IMM; from the end of the settling "
        "period to the fault, or to the end of a fault-free flight; the runs of one replicate, "
        "air and loop fly the same flight until their faults, so each such flight counts once, "
        "for its longest fault-free time):\n",
        "| air | fault-free flight (h) | declarations | per hour | 95 % upper bound per hour "
        "| flights with any | modes |",
        "|---|---|---|---|---|---|---|",
    ]
    for air, g in groups:
        f = g["false_declarations"]
        modes = ", ".join(f"{m} {n}" for m, n in f["by_mode"].items()) or "none"
        lines.append(
            f"| {air} | {_n(f['hours'], '.3f')} | {f['declarations']} | "
            f"{_n(f['per_hour'], '.1f')} | {_n(f.get('per_hour_upper_95'), '.2f')} | "
            f"{f['flights_with_declarations']}/{f['flights']} | "
            f"{modes} |"
        )
    return lines


def _attitude_lines(data: dict, groups: list[tuple[str, dict]]) -> list[str]:
    loops = {f["loop"] for f in data["flights"]}
    flown = (
        "the autopilot flies on truth, so the variants estimate the very same flight"
        if loops == {"open"}
        else "each variant flies its own closed loop on the same airframe, air and noise"
        if loops == {"closed"}
        else "open loop: the very same flight; closed: each variant its own"
    )
    lines = [
        f"\n**Attitude estimate error on the fault-free flights** (deg, deg²; {flown}; "
        "the mean rows give "
        "the largest max, the mean MSE, and the IMM/UKF-2 ratio of the MSE summed over the "
        "flights both flew, with the worst ratio of a flight whose UKF-2 stayed stable; a "
        "critical run's errors cover "
        "its flight up to the failure, so its ratio compares unequal windows):\n",
        "| air | loop | replicate | IMM max | UKF-2 max | UKF-3 max | IMM MSE | UKF-2 MSE | "
        "UKF-3 MSE | IMM/UKF-2 MSE |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for f in data["flights"]:

        def flag(variant: str, flight: dict = f) -> str:
            status = flight[f"{variant}_status"]
            return "" if status in ("stable", None) else f" ({status})"

        lines.append(
            f"| {f['air']} | {f['loop']} | {f['replicate']} | "
            f"{_n(f['imm_att_max_deg'])}{flag('imm')} | "
            f"{_n(f['ukf2_att_max_deg'])}{flag('ukf2')} | "
            f"{_n(f['ukf3_att_max_deg'])}{flag('ukf3')} | "
            f"{_n(f['imm_att_mse_deg2'])} | {_n(f['ukf2_att_mse_deg2'])} | "
            f"{_n(f['ukf3_att_mse_deg2'])} | {_n(f['imm_over_ukf2_mse'], '.2f')} |"
        )
    for air, g in groups:
        a = g["attitude"]
        lines.append(
            f"| {air} | | mean | {_n(a['imm_att_max_deg_max'])} (max) | "
            f"{_n(a['ukf2_att_max_deg_max'])} (max) | {_n(a['ukf3_att_max_deg_max'])} (max) | "
            f"{_n(a['imm_att_mse_deg2_mean'])} | {_n(a['ukf2_att_mse_deg2_mean'])} | "
            f"{_n(a['ukf3_att_mse_deg2_mean'])} | {_n(a['imm_over_ukf2_mse_of_means'], '.2f')} "
            f"(worst {_n(a['imm_over_ukf2_mse_worst'], '.2f')}) |"
        )
    return lines


def _acceptance_lines(data: dict) -> list[str]:
    o = data["overall"]
    i, f, a = o["identification"], o["false_declarations"], o["attitude"]
    done = data["acceptance"]

    def mark(ok: bool) -> str:
        return "met" if ok else "**not met**"

    lines = [
        "\n**Acceptance criteria** against this matrix:\n",
        f"- ≥ 95 % of the observable single faults identified within 1.0 s: "
        f"{_pct(i['identified_within_1s'], i['observable'])} "
        f"({i['identified_within_1s']}/{i['observable']}): "
        f"{mark(done['identified_within_1s'])}.",
        f"- zero false declarations in at least 1 h of fault-free flight: "
        f"{f['declarations']} in {_n(f['hours'], '.3f')} h: "
        f"{mark(done['no_false_declarations_in_1h'])}.",
        f"- IMM attitude MSE within 1.2× of UKF-2's on the same fault-free flight: "
        f"{a['flights_within_ratio']}/{a['flights_compared']} flights with a stable UKF-2, "
        f"{a['flights_ukf2_critical']} flights without a reference (UKF-2 critical) "
        f"(ratio of the means over all flights "
        f"{_n(a['imm_over_ukf2_mse_of_means'], '.2f')}, worst "
        f"{_n(a['imm_over_ukf2_mse_worst'], '.2f')}): "
        f"{mark(done['attitude_within_1_2x_of_ukf2'])}.",
    ]
    lines += _pair_acceptance_lines(data, mark)
    lines += _kind_acceptance_lines(data, mark)
    critical = data["critical"]
    if critical:
        lines.append(f"\n**Critical failures** ({len(critical)} runs; a run stops there):\n")
        for c in critical:
            lines.append(f"- `{c['run_id']}`: {c['failure']} at {c['failure_t_s']:.2f} s")
    else:
        lines.append("\nNo run ended in a critical failure.")
    return lines


def matrix_markdown(summary: dict[str, object]) -> str:
    """The real-air matrix tables (one section per filter model) from :func:`matrix_summary`."""
    parts = []
    for model, data in summary.items():
        groups = list(data["airs"].items()) + [("**all**", data["overall"])]
        lines = [f"### Filter model `{model}`\n"]
        lines += _identification_lines(groups)
        lines += _kind_lines(data["overall"])
        lines += _pair_lines(data)
        lines += _false_declaration_lines(groups)
        lines += _attitude_lines(data, groups)
        lines += _acceptance_lines(data)
        parts.append("\n".join(lines) + "\n")
    return "\n".join(parts)


def matrix_report(
    campaign: Campaign,
    summary: dict,
    command: str,
    tables: str,
    commit: str,
    caption: str | None,
) -> str:
    """``report.md`` of a real-air matrix campaign: what was flown, the definitions, the tables."""
    times = campaign.fault_times_s
    when = (
        f"a time drawn in [{times.lo_s:g}, {times.hi_s:g}] s per (replicate, air, channel)"
        if isinstance(times, UniformFaultTimes)
        else f"{', '.join(f'{t:g}' for t in times)} s"
    )
    if campaign.imm_pairs():
        gaps = ", ".join(pair_gap_label(g) for g in campaign.pair_gaps_s)
        when += f"; the second channel of a pair {gaps}"
    return render(
        "matrix_report",
        **_header(campaign, summary, command),
        replicates=campaign.replicates,
        airs=", ".join(a.name for a in campaign.air),
        filter_models=", ".join(campaign.filter_models),
        when=when,
        wall_s=_wall_text(summary),
        commit=commit,
        tables=tables,
        figure_text=f"![Fig. 2](fig2.png)\n\nFig. 2: {caption}.\n" if caption else "",
    )
