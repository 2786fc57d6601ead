"""Campaign files, the experiment command, its metrics and its executors (closed loop)."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest

from immukf_sitl.cli import main
from immukf_sitl.errors import UserError
from immukf_sitl.experiments import campaign_run
from immukf_sitl.experiments.campaign import CampaignError, load_campaign, parse_campaign
from immukf_sitl.experiments.campaign_run import COLUMNS, Progress, read_rows, run_campaign

ROOT = Path(__file__).resolve().parents[1]
CAMPAIGNS = ROOT / "scenarios" / "campaigns"
QUICK = CAMPAIGNS / "quick.yaml"

SCENARIO = {
    "duration_s": 8,
    "flight_plan": {
        "waypoints": [
            {"north_m": 110, "east_m": 0, "alt_m": 150},
            {"north_m": 260, "east_m": 180, "alt_m": 165},
        ]
    },
}


def tiny(**changes: object) -> dict:
    data = {
        "name": "tiny",
        "seed": 7,
        "replicates": 1,
        "scenario": SCENARIO,
        "variants": {"ukf1": ["q"], "ukf2": ["none", "q"]},
        "fault_times_s": [4.5],
    }
    data.update(changes)
    return data


# -- the file ------------------------------------------------------------------------------------


def test_shipped_campaigns_expand_to_the_papers_study() -> None:
    paper = load_campaign(CAMPAIGNS / "paper.yaml")
    runs = paper.runs()
    by_variant = {v: sum(r.variant == v for r in runs) for v in ("ukf1", "ukf2", "ukf3", "imm")}
    assert by_variant == {"ukf1": 320, "ukf2": 320, "ukf3": 320, "imm": 35}
    assert len({r.run_id for r in runs}) == len(runs) == 995
    assert [r.index for r in runs] == list(range(995))
    assert all(r.loop == "closed" for r in runs)
    # every variant and fault set of a replicate sees the same seed (common random numbers)
    assert {r.seed for r in runs if r.replicate == 2} == {paper.replicate_seed(2)}
    assert len({paper.replicate_seed(k) for k in range(5)}) == 5
    q = next(r for r in runs if r.variant == "ukf1" and r.mode.name == "x+q")
    assert q.scenario.faults[0].channels == ("x", "q") and q.scenario.faults[0].t_s == 5.0
    none = next(r for r in runs if r.mode.name == "none")
    assert none.scenario.faults == ()
    assert len(load_campaign(QUICK).runs()) == 24
    # the paper's study flies the paper's zero modes; a campaign says so, or gets the default
    assert {r.fault_modes for r in load_campaign(QUICK).runs()} == {"zero"}
    assert {r.fault_modes for r in parse_campaign(tiny(fault_modes="untrusted"), "c").runs()} == {
        "untrusted"
    }


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"replicates": 0}, r"replicates: expected an integer >= 1, got 0"),
        ({"variants": {"ukf5": "single"}}, r"variants\.ukf5: unknown variant"),
        ({"variants": {"ukf2": "all_63"}}, r"variants\.ukf2: expected all_64, single or a list"),
        ({"variants": {"ukf2": ["q", "w"]}}, r"variants\.ukf2: expected fault modes .* got 'w'"),
        ({"variants": {"imm": ["x+q"]}}, r"variants\.imm: the IMM's bank holds the 7 single"),
        (
            {"variants": {"imm": "pairs"}},
            r"variants\.imm: the IMM's bank holds the 7 single modes with fault_modes: zero; "
            r"got x\+y \(pairs need fault_modes: untrusted\)",
        ),
        (
            {"variants": {"imm": ["x+y+z"]}, "fault_modes": "untrusted"},
            r"variants\.imm: the IMM flies single faults and pairs; got x\+y\+z",
        ),
        (
            {"variants": {"imm": "pairs"}, "fault_modes": "untrusted", "pair_gaps_s": [0, -1]},
            r"pair_gaps_s: expected a list of distinct numbers >= 0, got \[0, -1\]",
        ),
        (
            {"variants": {"imm": "pairs"}, "fault_modes": "untrusted", "pair_gaps_s": ["soon"]},
            r"pair_gaps_s: expected a list of distinct numbers >= 0, got \['soon'\]",
        ),
        (
            {"variants": {"imm": "pairs"}, "fault_modes": "untrusted", "pair_gaps_s": [0, 3.5]},
            r"pair_gaps_s: expected the second fault before the scenario's end \(8 s\), "
            r"got 8 s \(4\.5 \+ 3\.5\)",
        ),
        ({"pair_gaps_s": [0, 10]}, r"pair_gaps_s: only for pair runs"),
        ({"loop": ["closed", "sideways"]}, r"loop: expected closed, open or a list of both"),
        ({"fault_times_s": [9.0]}, r"fault_times_s: expected times before the scenario's end"),
        ({"seeds": 3}, r"seeds: unknown field \(expected one of"),
        ({"failure": {"lateral_m": "far"}}, r"failure\.lateral_m: expected a number"),
        ({"air": [{"name": "w", "wind": {"speed_mps": 99}}]}, r"wind\.speed_mps: expected"),
        ({"scenario": {"duration_s": 8}}, r"flight_plan: required field is missing"),
        ({"fault_times_s": {"uniform": [6, 2]}}, r"fault_times_s: expected a list of times or"),
        ({"fault_times_s": {"uniform": [2]}}, r"fault_times_s: expected a list of times or"),
        ({"fault_times_s": {"normal": [2, 3]}}, r"fault_times_s: expected a list of times or"),
        ({"fault_times_s": {"uniform": [2, 9]}}, r"fault_times_s: expected times before the"),
        ({"filter_model": "exact"}, r"filter_model: expected paper or real-air, or a list"),
        ({"filter_model": ["paper", "paper"]}, r"filter_model: expected paper or real-air"),
        ({"report": "tables"}, r"report: expected paper or matrix, got 'tables'"),
        ({"fault_modes": "stuck"}, r"fault_modes: expected untrusted or zero, got 'stuck'"),
        ({"fault_kinds": [{"kind": "frozen"}]}, r"fault_kinds\[0\]\.kind: expected one of zero"),
        ({"fault_kinds": [{"kind": "bias"}]}, r"fault_kinds\[0\]: expected accel: and gyro:"),
        (
            {"fault_kinds": [{"kind": "zero", "gyro": [0.1, 0.2]}]},
            r"fault_kinds\[0\]\.gyro: value: kind zero takes none",
        ),
        (
            {"fault_kinds": [{"kind": "bias", "accel": [1, 0.5], "gyro": [0.1, 0.2]}]},
            r"fault_kinds\[0\]\.accel: expected a range \[lo, hi\] with lo < hi",
        ),
        (
            {"fault_kinds": [{"kind": "noise", "accel": [0.5, 3], "gyro": [2, 3]}]},
            r"fault_kinds\[0\]\.accel: value: expected the factor on the noise sigma",
        ),
        (
            {"fault_kinds": [{"kind": "spikes", "accel": [1, 2], "gyro": [0.1, 0.2]}]},
            r"fault_kinds\[0\]\.accel: rate_hz: expected spikes per second",
        ),
    ],
)
def test_a_bad_campaign_gets_one_line_naming_the_field(changes: dict, message: str) -> None:
    with pytest.raises(CampaignError, match=message) as info:
        parse_campaign(tiny(**changes), "c.yaml").runs()
    assert "\n" not in str(info.value) and str(info.value).startswith("c.yaml: ")


def test_a_bad_campaign_file_is_a_one_line_command_error(tmp_path: Path, capsys) -> None:
    path = tmp_path / "c.yaml"
    path.write_text("name: c\nseed: 1\nreplicates: 1\nscenario: nowhere.yaml\nvariants: {}\n")
    assert main(["experiment", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert (
        err == f"immukf-sitl experiment: error: {path}: scenario: no such scenario file "
        "'nowhere.yaml'"
    )


# -- the quick campaign, once, closed loop (CI: under 3 minutes) --------------------------------


@pytest.fixture(scope="module")
def quick(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, list[dict], Path]:
    out = tmp_path_factory.mktemp("quick")
    import contextlib
    import io

    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        status = main(["experiment", str(QUICK), "--jobs", "2", "--out-dir", str(out), "--json"])
    assert status == 0
    return json.loads(stdout.getvalue()), read_rows(out / "runs.csv"), out


@pytest.mark.slow
def test_quick_writes_every_output_and_the_json_contract(quick) -> None:
    summary, rows, out = quick
    for name in ("runs.csv", "table1.md", "table1.csv", "table2.md", "table3.md", "fig2.png"):
        assert (out / name).stat().st_size > 0, name
    report = (out / "report.md").read_text()
    assert "## Table 2" in report and "The paper's:" in report and "fig2.png" in report
    assert summary["campaign"] == "quick" and summary["runs"] == 24 == len(rows)
    assert summary["failed_runs"] == 0 and summary["wall_s"] > 0
    assert set(summary["variants"]) == {"ukf1", "ukf2", "ukf3", "imm"}
    for v in summary["variants"].values():
        assert set(v) >= {"runs", "stable", "critical", "est_att_mse_deg2_mean",
                          "est_pos_mse_m2_mean", "ctrl_pos_mse_m2_mean"}  # fmt: skip
    ident = summary["imm_identification"]
    assert set(ident) >= {"cases", "identified_within_1s", "false_declarations_per_hour"}
    table2 = (out / "table2.md").read_text().splitlines()
    assert sum(line.startswith("| ") for line in table2) == 65  # header and 64 fault sets


@pytest.mark.slow
def test_quick_matched_filter_and_imm_maintain_flight(quick) -> None:
    _, rows, _ = quick
    ukf1 = [r for r in rows if r["variant"] == "ukf1"]
    assert len(ukf1) == 9 and all(r["status"] == "stable" for r in ukf1)
    imm = [r for r in rows if r["variant"] == "imm"]
    assert [r["fault"] for r in imm] == ["none", "x", "y", "z", "p", "q", "r"]
    assert all(r["status"] == "stable" for r in imm)
    assert all(r["identified_ok"] == "true" for r in imm), [r["identified"] for r in imm]
    assert all(r["identified_within_1s"] == "true" for r in imm)
    assert all(r["false_declarations"] == "0" for r in imm)
    assert max(float(r["est_att_max_deg"]) for r in ukf1 + imm) < 5.0
    # no mode-matched update of these flights needed a reset
    assert all(r["filter_resets"] == "0" for r in ukf1 + imm), [r["filter_resets"] for r in imm]


@pytest.mark.slow
def test_quick_mismatched_filters_fail_on_a_dead_gyro(quick) -> None:
    _, rows, _ = quick
    for variant in ("ukf2", "ukf3"):
        fault_free = next(r for r in rows if r["variant"] == variant and r["fault"] == "none")
        assert fault_free["status"] == "stable"
        gyro = [r for r in rows if r["variant"] == variant and r["fault"] in ("p", "q", "r")]
        critical = [r for r in gyro if r["status"] == "critical"]
        assert critical, variant
        assert all(r["failure"] in ("corridor", "ground", "diverged") for r in critical)
        # a critical run stops at its failure
        assert all(float(r["flown_s"]) == pytest.approx(float(r["failure_t_s"])) for r in critical)


# -- executors, resume and failed runs on a tiny campaign ---------------------------------------


def _tiny_campaign(tmp_path: Path):
    path = tmp_path / "tiny.yaml"
    import yaml

    path.write_text(yaml.safe_dump(tiny()))
    return load_campaign(path)


@pytest.mark.slow
def test_runs_csv_is_identical_with_one_job_two_jobs_and_a_dask_cluster(tmp_path: Path) -> None:
    distributed = pytest.importorskip("distributed")
    campaign = _tiny_campaign(tmp_path)
    one = run_campaign(campaign, tmp_path / "one", jobs=1, progress=False)
    two = run_campaign(campaign, tmp_path / "two", jobs=2, progress=False)
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster:
        dask = run_campaign(
            campaign, tmp_path / "dask", scheduler=cluster.scheduler_address, progress=False
        )
    assert len(one.rows) == 3 and all(r["error"] == "" for r in one.rows)
    text = (tmp_path / "one" / "runs.csv").read_text()
    assert (tmp_path / "two" / "runs.csv").read_text() == text
    assert (tmp_path / "dask" / "runs.csv").read_text() == text
    assert one.rows == two.rows == dask.rows
    by_fault = {(r["variant"], r["fault"]): r for r in one.rows}
    assert by_fault[("ukf1", "q")]["status"] == "stable"
    # same replicate, same seed: the fault-free UKF-2 flew what the matched UKF-1 would
    assert by_fault[("ukf2", "none")]["seed"] == by_fault[("ukf1", "q")]["seed"]


@pytest.mark.slow
def test_resume_flies_only_what_is_missing_and_a_failed_run_is_recorded(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    campaign = _tiny_campaign(tmp_path)
    real_fly = campaign_run.fly

    def flaky(spec):
        if spec.variant == "ukf2" and spec.mode.name == "q":
            raise RuntimeError("JSBSim exploded")
        return real_fly(spec)

    monkeypatch.setattr(campaign_run, "fly", flaky)
    first = run_campaign(campaign, tmp_path / "out", progress=False)
    failed = [r for r in first.rows if r["status"] == "error"]
    assert [r["run_id"] for r in failed] == ["ukf2/q/r0/t4.5/closed/default/paper"]
    assert failed[0]["error"] == "RuntimeError: JSBSim exploded"
    assert sum(r["status"] != "error" for r in first.rows) == 2
    monkeypatch.setattr(campaign_run, "fly", real_fly)
    second = run_campaign(campaign, tmp_path / "out", resume=True, progress=False)
    assert (second.flown, second.skipped) == (1, 2)
    assert all(r["error"] == "" for r in second.rows)
    assert second.rows[:2] == first.rows[:2]
    with open(tmp_path / "out" / "runs.csv", newline="") as f:
        assert tuple(next(csv.reader(f))) == COLUMNS
    # the report's wall time is this invocation's, and it says which runs it does not cover
    from immukf_sitl.experiments.campaign_report import write_outputs

    write_outputs(campaign, second.rows, tmp_path / "out", second.wall_s, "cmd", False, 2)
    report = (tmp_path / "out" / "report.md").read_text()
    assert "s for the runs flown here (2 kept from an earlier invocation, not timed)." in report


def test_resume_refuses_another_campaigns_directory(tmp_path: Path) -> None:
    campaign = _tiny_campaign(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    (out / "campaign.json").write_text(json.dumps({"digest": "something else"}))
    with pytest.raises(UserError, match="holds runs of a different campaign"):
        run_campaign(campaign, out, resume=True, progress=False)


def test_progress_line_counts_and_estimates_the_rest() -> None:
    import io

    stream = io.StringIO()
    bar = Progress(4, stream=stream)
    bar.update({"status": "stable"})
    bar.update({"status": "critical"})
    line = bar.line()
    assert "2/4 runs, 1 critical, 0 failed" in line and "ETA " in line and "ETA ?" not in line
    assert stream.getvalue().startswith("experiment: [")


# -- the real-air matrix: filter models, drawn fault times, airframe draws, its metrics -----------


def matrix_campaign(**changes: object):
    scenario = dict(SCENARIO, duration_s=120, airframe={"uncertainty": {"aero": 0.1}})
    data = tiny(
        scenario=scenario,
        replicates=3,
        variants={"ukf2": ["none", "q"], "ukf3": ["none"], "imm": "single"},
        fault_times_s={"uniform": [20, 80]},
        filter_model=["paper", "real-air"],
        air=[{"name": "calm"}, {"name": "windy", "wind": {"speed_mps": 6}}],
        report="matrix",
    )
    data.update(changes)
    return parse_campaign(data, "m.yaml")


def test_drawn_fault_times_are_shared_by_a_cell_and_differ_between_cells() -> None:
    campaign = matrix_campaign()
    runs = campaign.runs()
    assert len(runs) == 2 * 2 * (2 + 1 + 7) * 3 == len({r.run_id for r in runs})
    assert {r.run_id.rsplit("/", 1)[1] for r in runs} == {"paper", "real-air"}
    cells: dict[tuple, set[float]] = {}
    for r in runs:
        assert 20.0 <= r.fault_t_s <= 80.0
        assert r.fault_t_s == pytest.approx(round(r.fault_t_s, 2), abs=1e-9)
        if r.mode.bits:
            assert r.scenario.faults[0].t_s == r.fault_t_s
        cells.setdefault((r.replicate, r.air, r.mode.name), set()).add(r.fault_t_s)
    # UKF-2, the IMM and both filter models of one cell lose the channel at the same moment
    assert all(len(times) == 1 for times in cells.values())
    q = {(rep, air): t for (rep, air, mode), (t,) in cells.items() if mode == "q"}
    assert len(set(q.values())) == len(q) == 6  # across replicates and airs
    calm_r0 = {mode: t for (rep, air, mode), (t,) in cells.items() if (rep, air) == (0, "calm")}
    assert len(set(calm_r0.values())) == 7  # across fault sets
    # deterministic, independent of which variants and models fly, changed by the seed
    again = matrix_campaign(variants={"imm": ["q"]}, filter_model="real-air").runs()
    assert {(r.replicate, r.air): r.fault_t_s for r in again} == q
    other = matrix_campaign(seed=8).runs()
    assert {r.fault_t_s for r in other if r.mode.name == "q"}.isdisjoint(q.values())


def test_listed_fault_times_still_make_an_axis() -> None:
    campaign = matrix_campaign(fault_times_s=[30, 45.5], filter_model="paper", air=None)
    runs = campaign.runs()
    assert sorted({r.fault_t_s for r in runs}) == [30.0, 45.5]
    assert len(runs) == 2 * (2 + 1 + 7) * 3
    assert campaign.filter_models == ("paper",) and runs[0].filter_model == "paper"
    assert parse_campaign(tiny(), "t.yaml").filter_models == ("paper",)  # the default


def test_the_digest_changes_with_the_filter_model_and_the_fault_time_draw() -> None:
    base = matrix_campaign(filter_model="paper").digest
    assert matrix_campaign(filter_model="real-air").digest != base
    assert matrix_campaign(filter_model="paper", fault_times_s={"uniform": [20, 70]}).digest != base
    assert matrix_campaign(filter_model="paper").digest == base


def test_replicate_r_is_airframe_draw_r_in_every_air() -> None:
    from immukf_sitl.models.airframe import airframe_factors
    from immukf_sitl.models.params import load_aircraft_params

    params = load_aircraft_params()
    factors = {}
    for r in matrix_campaign().runs():
        drawn = airframe_factors(params, r.scenario.airframe, r.scenario.seed)
        factors.setdefault(r.replicate, []).append(drawn)
    for draws in factors.values():
        assert draws[0] and all(d == draws[0] for d in draws)
    assert factors[0][0] != factors[1][0] != factors[2][0]


def test_the_filter_model_chooses_the_tuning_of_the_run(monkeypatch: pytest.MonkeyPatch) -> None:
    from immukf_sitl.service.filter_models import PaperModel, RealAirModel

    seen = []

    def capture(scenario, config, **kwargs):
        seen.append(config.filter_model)
        raise RuntimeError("not flown")

    monkeypatch.setattr(campaign_run, "run_inprocess", capture)
    runs = matrix_campaign().runs()
    for model in ("paper", "real-air"):
        spec = next(r for r in runs if r.filter_model == model and r.variant == "imm")
        row = campaign_run.execute_run(spec)
        assert row["filter_model"] == model and row["error"] == "RuntimeError: not flown"
    assert seen == [PaperModel(), RealAirModel()]
    assert seen[0] != seen[1]


def test_fault_free_window_and_false_declaration_rate() -> None:
    from immukf_sitl.experiments.metrics import false_declaration_rate, fault_free_window_s

    assert fault_free_window_s(1.0, 3.0, 45.0, 120.0) == (4.0, 45.0)
    assert fault_free_window_s(1.0, 3.0, None, 120.0) == (4.0, 120.0)
    assert fault_free_window_s(1.0, 3.0, 45.0, 30.0) == (4.0, 30.0)  # stopped before the fault
    start, end = fault_free_window_s(None, 3.0, None, 120.0)
    assert end <= start
    rows = [
        {"fault_free_s": "116", "false_declarations_fault_free": "2"},
        {"fault_free_s": "40.5", "false_declarations_fault_free": "1"},
        {"fault_free_s": "", "false_declarations_fault_free": ""},  # a single filter
        {"fault_free_s": "3.5", "false_declarations_fault_free": "0"},
    ]
    rate = false_declaration_rate(rows)
    assert rate["declarations"] == 3
    assert rate["hours"] == pytest.approx(160.0 / 3600.0)
    assert rate["per_hour"] == pytest.approx(3 * 3600.0 / 160.0)  # 67.5 per hour
    assert math.isnan(false_declaration_rate(rows[2:3])["per_hour"])
    assert rate["flights"] == 3 and rate["flights_with_declarations"] == 2  # no seed: each its own


def test_false_declarations_count_each_common_random_number_flight_once() -> None:
    """A replicate's runs in one air fly the same flight until their faults (one seed: airframe,
    noise, turbulence), so a false declaration before the faults is one event and the flight's
    fault-free time counts once, for its longest window. By hand: the q at 26.55 s was seen by
    the fault-free run (110 s) and by two faulted runs (faults at 40 and 63.85 s), an x at 70 s
    only by the fault-free run; the same seed in another air is another flight."""
    from immukf_sitl.experiments.metrics import false_declaration_rate, fault_free_flights

    def row(air: str, fault: str, fault_t: str, exposure: str, declarations: str) -> dict:
        return {
            "seed": "84783481", "air": air, "loop": "closed", "variant": "imm",
            "filter_model": "real-air", "fault": fault, "fault_t_s": fault_t,
            "fault_free_s": exposure, "declarations": declarations,
            "false_declarations_fault_free": str(len(declarations.split())),
        }  # fmt: skip

    rows = [
        row("light", "none", "43.68", "110", "q@26.55 x@70.00"),
        row("light", "x", "40.00", "30", "q@26.55"),
        row("light", "y", "63.85", "53.85", "q@26.55 y@64.00"),  # y@64 is after its fault
        row("calm", "none", "20.00", "110", ""),
    ]
    rows[2]["false_declarations_fault_free"] = "1"
    flights = sorted(fault_free_flights(rows), key=lambda f: f.exposure_s)
    assert [f.exposure_s for f in flights] == [110.0, 110.0]
    assert sorted(f.declarations for f in flights) == [(), ("q@26.55", "x@70.00")]
    rate = false_declaration_rate(rows)
    assert rate["declarations"] == 2 and rate["hours"] == pytest.approx(220.0 / 3600.0)
    assert rate["flights"] == 2 and rate["flights_with_declarations"] == 1
    # counted per run, as before: 4 declarations in 303.85 s
    assert sum(int(r["false_declarations_fault_free"]) for r in rows) == 4


def test_the_json_summary_counts_false_declarations_per_distinct_flight() -> None:
    """``experiment --json`` gives the report's rate, not one pooled over the runs' whole
    flights. By hand: three runs of one seed fly one flight until their faults (longest
    fault-free window 110 s, one q at 26.55 s seen by two of them); a second seed flies 90 s
    with none. 1 in 200 s is 18 per hour, bounded at 95 % by chi2(0.95, 4) / 2 = 4.744 events
    in 200 s (Garwood)."""
    from immukf_sitl.experiments.tables import summary_json

    def row(seed: str, fault: str, exposure: str, declarations: str, early: int, wrong: int):
        return _row(
            seed=seed, variant="imm", loop="closed", fault=fault, fault_t_s="40.00",
            fault_free_s=exposure, declarations=declarations, flown_s="150",
            false_declarations=str(wrong), false_declarations_fault_free=str(early),
        )  # fmt: skip

    rows = [
        row("7", "none", "110", "q@26.55", 1, 1),
        row("7", "x", "36", "q@26.55", 1, 1),
        row("7", "y", "36", "y@41.00", 0, 0),  # its own channel, after its fault
        row("8", "none", "90", "", 0, 0),
        row("8", "z", "36", "z@41.00 p@52.00", 0, 1),  # p declared after the fault
    ]
    ident = summary_json("hand", rows, 1.0)["imm_identification"]
    assert ident["false_declarations"] == 1
    assert ident["fault_free_hours"] == pytest.approx(200.0 / 3600.0, abs=1e-6)  # 6 places
    assert ident["false_declarations_per_hour"] == pytest.approx(18.0)
    chi2_95_dof_4 = 9.487729  # chi2.ppf(0.95, 4), from a printed table
    assert ident["false_declarations_per_hour_upper_95"] == pytest.approx(
        chi2_95_dof_4 / 2.0 / (200.0 / 3600.0), rel=1e-5
    )
    assert ident["wrong_declarations"] == 3  # the q twice (two runs) and the p


def _row(**cells: str) -> dict[str, str]:
    row = dict.fromkeys(COLUMNS, "")
    row.update(status="stable", filter_model="real-air", air="calm", replicate="0")
    row.update(cells)
    return row


def test_matrix_summary_on_a_hand_made_run_set() -> None:
    from immukf_sitl.experiments.campaign_render import matrix_markdown
    from immukf_sitl.experiments.campaign_summary import matrix_summary, pre_fault_declarations

    def imm(fault: str, **cells: str) -> dict[str, str]:
        return _row(variant="imm", fault=fault, fault_t_s="40", **cells)

    rows = [
        imm("none", fault_free_s="117", false_declarations_fault_free="1", declarations="q@50.00",
            est_att_max_deg="2", est_att_mse_deg2="1.5", est_att_nees_after_decl="1.2"),
        _row(variant="ukf2", fault="none", est_att_max_deg="1", est_att_mse_deg2="1.0"),
        _row(variant="ukf3", fault="none", est_att_max_deg="3", est_att_mse_deg2="4.0"),
        imm("q", observable_t_s="41", detection_delay_s="0.4", identified="q",
            identified_ok="true", identified_within_1s="true", fault_free_s="37",
            false_declarations_fault_free="1", declarations="x@30.00 q@41.40",
            est_att_nees_after_decl="4.5"),
        imm("p", observable_t_s="42", detection_delay_s="1.6", identified="p",
            identified_ok="true", identified_within_1s="false", fault_free_s="37",
            false_declarations_fault_free="0", declarations="p@43.60"),
        imm("y", observable_t_s="", identified="none", identified_ok="false",
            identified_within_1s="false", fault_free_s="37", false_declarations_fault_free="0",
            flown_s="120"),
        imm("x", observable_t_s="", identified="none", identified_ok="false", flown_s="30",
            identified_within_1s="false", fault_free_s="27", false_declarations_fault_free="0",
            status="critical", failure="diverged", failure_t_s="30"),
        imm("r", observable_t_s="45", identified="x", identified_ok="false",
            identified_within_1s="false", fault_free_s="37", false_declarations_fault_free="0",
            declarations="x@46.00", status="critical", failure="diverged", failure_t_s="47"),
        imm("z", status="error"),  # failed to run: left out
    ]  # fmt: skip
    assert pre_fault_declarations(rows[3]) == ["x"]
    assert pre_fault_declarations(rows[0]) == ["q"]
    assert pre_fault_declarations(rows[6]) == []
    summary = matrix_summary(rows)["real-air"]
    ident = summary["overall"]["identification"]
    counts = (ident["observable"], ident["identified_within_1s"], ident["not_observable"])
    assert counts == (3, 1, 1) and ident["ended_before_fault"] == 1
    assert (ident["identified_later"], ident["wrong_mode_first"], ident["missed"]) == (1, 1, 0)
    assert ident["identified_within_1s_share"] == pytest.approx(1 / 3)
    assert ident["by_channel"]["q"] == {
        "observable": 1,
        "identified_within_1s": 1,
        "with_fault_free_twin": 1,
        "survived": 0,  # a row without the error after its declaration: nothing to survive with
        "attitude_ratio_median": None,
        "attitude_nees_median": 4.5,
    }
    assert ident["by_channel"]["p"]["attitude_nees_median"] is None
    assert ident["fault_free_attitude_nees_median"] == pytest.approx(1.2)
    false = summary["overall"]["false_declarations"]
    assert false["declarations"] == 2 and false["hours"] == pytest.approx(292.0 / 3600.0, abs=1e-6)
    assert false["by_mode"] == {"q": 1, "x": 1} and false["flights_with_declarations"] == 2
    (flight,) = summary["flights"]
    assert flight["imm_over_ukf2_mse"] == pytest.approx(1.5)
    att = summary["overall"]["attitude"]
    assert att["flights_within_ratio"] == 0 and att["flights_compared"] == 1
    assert att["flights_ukf2_critical"] == 0
    assert summary["acceptance"] == {
        "identified_within_1s": False,
        "no_false_declarations_in_1h": False,
        "attitude_within_1_2x_of_ukf2": False,
    }
    assert [c["failure"] for c in summary["critical"]] == ["diverged", "diverged"]
    text = matrix_markdown(matrix_summary(rows))
    assert "### Filter model `real-air`" in text and "| calm | 3 | 1 | 33 % |" in text
    assert "| calm | 3 | 1 | 33 % | 1 | 1 | 0 | 1 | 1 |" in text
    assert "| 1.50 |" in text and "**not met**" in text
    assert "| calm | 1.2 | – | – | – | – | 4.5 | – |" in text  # attitude consistency


def test_matrix_attitude_pairs_the_variants_of_one_flight_only() -> None:
    """Open loop the variants estimate the same flight, closed each flies its own: the IMM/UKF-2
    ratio pairs rows of one loop, and the report says which comparison it is."""
    from immukf_sitl.experiments.campaign_render import matrix_markdown
    from immukf_sitl.experiments.campaign_summary import matrix_summary

    def flight(loop: str, imm_mse: str, ukf2_mse: str) -> list[dict[str, str]]:
        return [
            _row(variant="imm", fault="none", loop=loop, est_att_mse_deg2=imm_mse),
            _row(variant="ukf2", fault="none", loop=loop, est_att_mse_deg2=ukf2_mse),
        ]

    both = matrix_summary(flight("closed", "3.0", "2.0") + flight("open", "2.0", "2.0"))
    ratios = {f["loop"]: f["imm_over_ukf2_mse"] for f in both["real-air"]["flights"]}
    assert ratios == {"closed": pytest.approx(1.5), "open": pytest.approx(1.0)}
    same = matrix_summary(flight("open", "2.2", "2.0"))
    assert same["real-air"]["acceptance"]["attitude_within_1_2x_of_ukf2"] is True
    assert "the very same flight" in matrix_markdown(same)
    assert "its own closed loop" in matrix_markdown(matrix_summary(flight("closed", "1", "1")))


def test_a_partial_runs_csv_gets_its_matrix_report(tmp_path: Path, capsys) -> None:
    import yaml

    from immukf_sitl.experiments import campaign_report
    from immukf_sitl.experiments.campaign_run import write_rows

    path = tmp_path / "m.yaml"
    data = yaml.safe_load((CAMPAIGNS / "real_air.yaml").read_text())
    path.write_text(yaml.safe_dump(data))
    runs = load_campaign(path).runs()
    imm_q = next(r for r in runs if r.variant == "imm" and r.mode.name == "q")
    rows = [
        _row(run_id=imm_q.run_id, variant="imm", fault="q", fault_t_s=f"{imm_q.fault_t_s:g}",
             observable_t_s="50", detection_delay_s="0.3", identified="q",
             identified_ok="true", identified_within_1s="true", fault_free_s="40",
             false_declarations_fault_free="0"),
        _row(run_id="imm/q/r9/t1/closed/calm/real-air"),  # not this campaign's: left out
    ]  # fmt: skip
    write_rows(tmp_path / "runs.csv", rows)
    assert campaign_report.main([str(path), str(tmp_path)]) == 0
    assert capsys.readouterr().out.strip().endswith(f"1 of {len(runs)} runs")
    report = (tmp_path / "report.md").read_text()
    assert "the real-air matrix" in report and "| calm | 1 | 1 | 100 % |" in report
    assert (tmp_path / "delays.png").stat().st_size > 0
    matrix = json.loads((tmp_path / "matrix.json").read_text())
    assert matrix["real-air"]["overall"]["false_declarations"]["hours"] == pytest.approx(
        40 / 3600, abs=1e-6
    )


def test_shipped_real_air_campaigns_are_issue_9s_matrix() -> None:
    real = load_campaign(CAMPAIGNS / "real_air.yaml")
    runs = real.runs()
    assert len(runs) == 4 * 3 * (7 + 1 + 1) and real.report == "matrix"
    assert {r.filter_model for r in runs} == {"real-air"}
    assert [a.name for a in real.air] == ["calm", "wind6-light", "wind10-moderate"]
    imm = [r for r in runs if r.variant == "imm"]
    assert len(imm) == 84 and all(20 <= r.fault_t_s <= 80 for r in imm)
    assert {r.scenario.duration_s for r in runs} == {120.0}
    assert all(r.scenario.sensors.imu.bias_instability for r in runs)
    assert all(r.scenario.airframe.uncertainty.aero == 0.10 for r in runs)
    paper = load_campaign(CAMPAIGNS / "real_air_paper.yaml").runs()
    assert [(r.seed, r.fault_t_s, r.air) for r in paper] == [
        (r.seed, r.fault_t_s, r.air) for r in runs
    ]
    assert {r.filter_model for r in paper} == {"paper"}
    twin = load_campaign(CAMPAIGNS / "real_air_twin.yaml").runs()
    assert len(twin) == 27 and all(r.scenario.wind.speed_mps == 0 for r in twin)
    assert all(not r.scenario.sensors.imu.bias_instability for r in twin)
    assert all(r.scenario.airframe.uncertainty.aero == 0 for r in twin)
    twin_paper = load_campaign(CAMPAIGNS / "real_air_twin_paper.yaml").runs()
    assert [r.fault_t_s for r in twin_paper] == [r.fault_t_s for r in twin]


def test_the_false_declaration_bound_is_the_exact_poisson_one() -> None:
    """Zero events in T hours bound the rate by -ln(0.05) / T (about 3 / T); with events, the
    Garwood bound, checked against the Poisson CDF it inverts."""
    from scipy.stats import poisson

    from immukf_sitl.experiments.metrics import poisson_rate_upper_95

    assert poisson_rate_upper_95(0, 1.339) == pytest.approx(-math.log(0.05) / 1.339)
    assert poisson_rate_upper_95(0, 3.0) < 1.0  # the issue's "below 1 per hour" needs 3 h
    for events in (1, 4):
        bound = poisson_rate_upper_95(events, 2.0)
        assert poisson.cdf(events, bound * 2.0) == pytest.approx(0.05, abs=1e-9)
    assert math.isnan(poisson_rate_upper_95(0, 0.0))


def test_fault_kinds_are_an_axis_with_sizes_drawn_in_their_ranges() -> None:
    kinds = [
        {"kind": "zero"},
        {"kind": "bias", "accel": [0.5, 2.0], "gyro": [0.02, 0.1]},
        {"kind": "scale", "accel": [0.3, 0.8], "gyro": [0.3, 0.8]},
    ]
    data = tiny(variants={"imm": "single"}, replicates=2, fault_kinds=kinds)
    runs = parse_campaign(data, "c.yaml").runs()
    # fault-free once per replicate, each of 6 channels once per kind and replicate
    assert len(runs) == 2 * (1 + 6 * 3) and len({r.run_id for r in runs}) == len(runs)
    bias = [r for r in runs if r.fault_kind == "bias"]
    gyro = [abs(r.fault_value) for r in bias if r.mode.name in ("p", "q", "r")]
    accel = [abs(r.fault_value) for r in bias if r.mode.name in ("x", "y", "z")]
    assert all(0.02 <= v <= 0.1 for v in gyro) and all(0.5 <= v <= 2.0 for v in accel)
    assert {r.scenario.faults[0].kind for r in bias} == {"bias"}
    scale = [r.fault_value for r in runs if r.fault_kind == "scale"]
    assert all(0.3 <= v <= 0.8 for v in scale)  # a gain: no sign
    zero = [r for r in runs if r.fault_kind == "zero" and r.mode.bits]
    assert all(r.scenario.faults[0].value == 0.0 for r in zero)
    assert not any("/zero" in r.run_id for r in runs)  # zero runs keep their ids
    again = parse_campaign(data, "c.yaml").runs()
    assert [r.fault_value for r in again] == [r.fault_value for r in runs]  # seeded


def test_single_fault_campaigns_keep_their_runs_sizes_and_times() -> None:
    """Run ids, drawn times and drawn sizes recorded from the code before pair runs existed:
    a results directory of fault_kinds.yaml must still --resume, and its sizes mean the same."""
    runs = load_campaign(CAMPAIGNS / "fault_kinds.yaml").runs()
    assert len(runs) == 387 == len({r.run_id for r in runs})
    recorded = {
        0: ("imm/none/r0/t48.17/closed/calm/real-air", 48.17, 0.0),
        9: ("imm/x/r0/t31.58/closed/calm/real-air/bias", 31.58, -0.513986),
        13: ("imm/x/r1/t46.05/closed/calm/real-air/drift", 46.05, -0.158336),
        22: ("imm/x/r1/t46.05/closed/calm/real-air/spikes", 46.05, -1.860187),
        74: ("imm/p/r2/t63.36/closed/calm/real-air/bias", 63.36, 0.018331),
        83: ("imm/p/r2/t63.36/closed/calm/real-air/noise", 63.36, 5.72586),
        101: ("imm/q/r2/t31.9/closed/calm/real-air/scale", 31.9, 0.799348),
        333: ("imm/p/r0/t76.13/closed/wind10-moderate/real-air/drift", 76.13, -0.010238),
        386: ("imm/r/r2/t72.47/closed/wind10-moderate/real-air/spikes", 72.47, -0.469385),
    }
    for index, (run_id, t_s, value) in recorded.items():
        r = runs[index]
        assert (r.run_id, r.fault_t_s, r.fault_value) == (run_id, t_s, value)
    assert runs[386].scenario.faults[0].rate_hz == 2.0
    # UKF-1's multi-channel sets still fail at once, one fault per sensor kind
    kinds = [{"kind": "bias", "accel": [0.1, 2.0], "gyro": [0.01, 0.1]}]
    data = tiny(variants={"ukf1": ["x+q", "x+y", "p+q+r"]}, fault_kinds=kinds,
                fault_times_s={"uniform": [1, 7]})  # fmt: skip
    faults = {
        r.run_id: [(f.t_s, f.channels, f.value) for f in r.scenario.faults]
        for r in parse_campaign(data, "c.yaml").runs()
    }
    assert faults == {
        "ukf1/x+y/r0/t4.85/closed/default/paper/bias": [(4.85, ("x", "y"), -1.20469)],
        "ukf1/x+q/r0/t1.82/closed/default/paper/bias": [
            (1.82, ("x",), 0.636411),
            (1.82, ("q",), -0.063207),
        ],
        "ukf1/p+q+r/r0/t3.17/closed/default/paper/bias": [(3.17, ("p", "q", "r"), -0.014274)],
    }


# -- pairs: two channels failing one after the other or at once (untrusted modes) ----------------

BIAS = {"kind": "bias", "accel": [0.1, 2.0], "gyro": [0.01, 0.1]}


def pair_campaign(**changes: object):
    from immukf_sitl.estimation.fault_modes import single_fault_modes
    from immukf_sitl.experiments.campaign import pair_fault_modes

    scenario = dict(SCENARIO, duration_s=120)
    modes = [m.name for m in single_fault_modes() + pair_fault_modes()]
    data = tiny(
        scenario=scenario,
        replicates=2,
        variants={"ukf2": ["x+q"], "imm": modes},
        fault_modes="untrusted",
        fault_kinds=[{"kind": "zero"}, BIAS],
        fault_times_s={"uniform": [20, 70]},
        pair_gaps_s=[0, 10],
        air=[{"name": "calm"}, {"name": "windy", "wind": {"speed_mps": 6}}],
    )
    data.update(changes)
    return parse_campaign(data, "p.yaml")


def test_imm_pairs_are_the_15_two_channel_sets_in_table_2_order() -> None:
    campaign = pair_campaign(variants={"imm": "pairs"})
    ((variant, modes),) = campaign.variants
    assert variant == "imm" and [m.name for m in modes] == [
        "x+y", "x+z", "x+p", "x+q", "x+r", "y+z", "y+p", "y+q", "y+r", "z+p", "z+q", "z+r",
        "p+q", "p+r", "q+r",
    ]  # fmt: skip
    assert [m.paper_index for m in modes] == list(range(8, 23))
    listed = pair_campaign(variants={"imm": ["p+r", "x+q"]})
    assert [m.name for m in listed.variants[0][1]] == ["x+q", "p+r"]


def test_pairs_fly_each_gap_and_kind_while_singles_fly_once() -> None:
    runs = pair_campaign().runs()
    imm = [r for r in runs if r.variant == "imm"]
    pairs = [r for r in imm if r.pair_gap_s is not None]
    # per air and replicate: fault-free once, 6 singles x 2 kinds, 15 pairs x 2 kinds x 2 gaps
    assert len(imm) == 2 * 2 * (1 + 6 * 2 + 15 * 2 * 2) == 4 * 73
    assert len(pairs) == 4 * 60 and {r.pair_gap_s for r in pairs} == {0.0, 10.0}
    assert all(len(r.mode.channels) == 2 for r in pairs)
    assert all(r.pair_gap_s is None and r.second_fault is None for r in imm if r not in pairs)
    # UKF-2 flies its two-channel set at once, as one fault, without a gap axis
    ukf2 = [r for r in runs if r.variant == "ukf2"]
    assert len(ukf2) == 2 * 2 * 2 and all(r.pair_gap_s is None for r in ukf2)
    assert all(r.scenario.faults[0].t_s == r.scenario.faults[-1].t_s for r in ukf2)
    assert len({r.run_id for r in runs}) == len(runs)
    assert [r.index for r in runs] == list(range(len(runs)))
    xq = [r.run_id for r in pairs if r.mode.name == "x+q" and r.air == "calm"]
    assert sum("+g10/" in i for i in xq) == sum("+g0/" in i for i in xq) == 4


def test_the_second_channel_of_a_pair_fails_gap_seconds_after_the_first() -> None:
    runs = pair_campaign().runs()
    cells: dict[tuple, set[float]] = {}
    for r in runs:
        if r.pair_gap_s is None:
            continue
        first, second = r.scenario.faults
        assert first.channels == r.mode.channels[:1] and second.channels == r.mode.channels[1:]
        assert first.t_s == r.fault_t_s and 20.0 <= r.fault_t_s <= 70.0
        assert second.t_s == pytest.approx(r.fault_t_s + r.pair_gap_s, abs=1e-9)
        assert r.second_fault == second.channels[0] and r.second_t_s == second.t_s
        assert r.fault_value == first.value and first.kind == second.kind == r.fault_kind
        # the same onset for both gaps and kinds of a cell: the gap is all that differs
        cells.setdefault((r.replicate, r.air, r.mode.name), set()).add(r.fault_t_s)
    assert len(cells) == 2 * 2 * 15 and all(len(times) == 1 for times in cells.values())


def test_each_channel_of_a_pair_draws_its_own_size_in_its_sensors_range() -> None:
    runs = pair_campaign().runs()
    bias = [r for r in runs if r.pair_gap_s is not None and r.fault_kind == "bias"]
    sizes: dict[str, list[float]] = {"accel": [], "gyro": []}
    for r in bias:
        for fault in r.scenario.faults:
            sensor = "accel" if fault.channels[0] in "xyz" else "gyro"
            sizes[sensor].append(fault.value)
    assert all(0.1 <= abs(v) <= 2.0 for v in sizes["accel"])  # m/s^2
    assert all(0.01 <= abs(v) <= 0.1 for v in sizes["gyro"])  # rad/s
    assert min(sizes["gyro"]) < 0 < max(sizes["gyro"]) and min(sizes["accel"]) < 0
    # two gyros of one pair get two draws, and a channel's size differs between its pairs
    pq = next(r for r in bias if r.mode.name == "p+q")
    assert pq.scenario.faults[0].value != pq.scenario.faults[1].value
    x_sizes = {r.scenario.faults[0].value for r in bias if r.mode.channels[0] == "x"}
    assert len(x_sizes) == 5 * 2 * 2  # 5 pairs x 2 airs x 2 replicates (both gaps alike)
    zero = [r for r in runs if r.pair_gap_s is not None and r.fault_kind == "zero"]
    assert {f.value for r in zero for f in r.scenario.faults} == {0.0}


def test_pair_runs_do_not_depend_on_what_else_the_campaign_flies() -> None:
    """Times and sizes come from the seed, the cell and the channel, not from a run's index:
    a campaign of one pair, or its runs in another order (--jobs), flies the same faults."""

    def faults(runs) -> dict[str, tuple]:
        return {r.run_id: r.scenario.faults for r in runs if r.pair_gap_s is not None}

    full = faults(pair_campaign().runs())
    alone = faults(pair_campaign(variants={"imm": ["x+q"]}, air=[{"name": "calm"}]).runs())
    assert len(alone) == 2 * 2 * 2 and all(full[k] == v for k, v in alone.items())
    assert faults(pair_campaign().runs()) == full
    assert faults(pair_campaign(seed=8).runs()) != full


def test_a_pair_figure_run_flies_the_first_gap() -> None:
    campaign = pair_campaign(figure={"variant": "imm", "fault": "x+q"}, pair_gaps_s=[5, 10])
    spec = campaign.figure_run()
    assert spec is not None and spec.pair_gap_s == 5.0 and spec.second_t_s == spec.fault_t_s + 5


def _fake_run(spec, events: list, end_s: float = 4.0):
    """A flown run's stand-in: a summary of ``events`` over level flight with q at 0.05 rad/s
    and a 0.5 m/s^2 x specific force (a zeroed x or q shows at once), first estimate at 0 s."""
    from types import SimpleNamespace

    import numpy as np

    from immukf_sitl.experiments.report import EstimateTrack, summarize
    from immukf_sitl.samples import TruthSample
    from immukf_sitl.service.timing import TimingStats

    truth = [
        TruthSample(k * 0.01, 47.0, 8.0, 150.0, np.array([0.1, 0.05, 1.0]),
                    np.array([0.0, 0.05, 0.0]), np.array([25.0, 0.0, 0.0]),
                    np.array([0.5, 0.0, -9.8]))
        for k in range(int(end_s / 0.01))
    ]  # fmt: skip
    t = np.array([s.t_s for s in truth])
    lla = np.array([(s.lat_deg, s.lon_deg, s.alt_m) for s in truth])
    track = EstimateTrack(t, np.array([s.euler_rad for s in truth]), t, lla)
    summary = summarize(spec.scenario.name, spec.scenario.faults, truth, events, track,
                        TimingStats())  # fmt: skip
    history = SimpleNamespace(outputs=[SimpleNamespace(t_s=0.0)], events=lambda: events)
    return SimpleNamespace(
        summary=lambda: summary, history=history, records=[SimpleNamespace(time_s=end_s)]
    )


def test_the_metrics_of_a_pair_run_describe_the_first_fault_then_the_second() -> None:
    from immukf_sitl.estimation.fault_modes import FaultMode
    from immukf_sitl.experiments.metrics import identification_metrics
    from immukf_sitl.service.detection import DetectionEvent

    def event(kind: str, channel: str, t_s: float, after: str) -> DetectionEvent:
        mode, declared = FaultMode.from_name(channel), FaultMode.from_name(after)
        return DetectionEvent(kind, mode, t_s, 0.99, declared_after=declared)

    data = tiny(variants={"imm": ["x+q"]}, fault_modes="untrusted", fault_times_s=[1.0],
                pair_gaps_s=[0, 1.5])  # fmt: skip
    at_once, later = parse_campaign(data, "c.yaml").runs()
    assert (later.pair_gap_s, later.second_t_s) == (1.5, 2.5)
    events = [
        event("detected", "y", 0.5, "y"),  # before any fault
        event("cleared", "y", 0.8, "none"),
        event("detected", "x", 1.3, "x"),
        event("detected", "z", 2.0, "x+z"),  # a healthy channel beside x
        event("detected", "q", 3.1, "x+z+q"),
        event("cleared", "z", 3.5, "x+q"),
    ]
    m = identification_metrics(later, _fake_run(later, events))
    assert (m["identified"], m["identified_ok"], m["identified_within_1s"]) == ("x", True, True)
    assert m["observable_t_s"] == 1.0 and m["detection_delay_s"] == pytest.approx(0.3)
    assert m["second_observable_t_s"] == 2.5 and m["second_detected_t_s"] == 3.1
    assert m["second_detection_delay_s"] == pytest.approx(0.6)
    assert m["second_identified_within_1s"] is True and m["second_named_kind"] is None
    assert (m["false_declarations"], m["false_declarations_fault_free"]) == (2, 1)
    assert m["declared_at_end"] == "x+q" and m["declarations"] == "y@0.50 x@1.30 z@2.00 q@3.10"
    # at once, q declared first: the first declaration is not the first channel's, and x,
    # declared 0.9 s after it showed, is not "identified" though the second is within 1 s
    events = [event("detected", "q", 1.2, "q"), event("detected", "x", 1.9, "x+q")]
    m = identification_metrics(at_once, _fake_run(at_once, events))
    assert (m["identified"], m["identified_ok"], m["identified_within_1s"]) == ("q", False, False)
    assert m["detection_delay_s"] == pytest.approx(0.9)
    assert m["second_detection_delay_s"] == pytest.approx(0.2)
    assert m["second_identified_within_1s"] is True and m["false_declarations"] == 0
    # the second channel never declared: not identified, the first still is
    only_x = [event("detected", "x", 1.3, "x")]
    m = identification_metrics(later, _fake_run(later, only_x))
    assert m["second_detected_t_s"] is None and m["second_identified_within_1s"] is False
    assert m["identified_within_1s"] is True and m["declared_at_end"] == "x"


def test_a_pair_runs_row_names_its_second_fault_and_single_rows_leave_it_empty(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    def not_flown(scenario, config, **kwargs):
        raise RuntimeError("not flown")

    monkeypatch.setattr(campaign_run, "run_inprocess", not_flown)
    data = tiny(variants={"imm": ["q", "x+q"]}, fault_modes="untrusted", fault_times_s=[1.0],
                pair_gaps_s=[1.5])  # fmt: skip
    single, pair = (campaign_run.execute_run(s) for s in parse_campaign(data, "c.yaml").runs())
    assert pair["run_id"] == "imm/x+q/r0/t1+g1.5/closed/default/paper"
    assert (pair["second_fault"], pair["second_t_s"], pair["fault_t_s"]) == ("q", "2.5", "1")
    assert all(single[c] == "" for c in campaign_run.PAIR_COLUMNS)
    assert list(pair) == list(COLUMNS)


@pytest.mark.parametrize(
    "missing",
    [campaign_run.RESET_COLUMNS,
     campaign_run.RESET_COLUMNS + campaign_run.CONSISTENCY_COLUMNS,
     campaign_run.RESET_COLUMNS + campaign_run.CONSISTENCY_COLUMNS
     + campaign_run.AFTER_DECLARATION_COLUMNS,
     campaign_run.RESET_COLUMNS + campaign_run.CONSISTENCY_COLUMNS + campaign_run.PAIR_COLUMNS
     + campaign_run.AFTER_DECLARATION_COLUMNS],
    ids=["before-resets", "before-consistency", "before-survival", "before-pairs"],
)  # fmt: skip
def test_a_runs_csv_written_before_later_columns_still_reads(
    tmp_path: Path, missing: tuple[str, ...]
) -> None:
    old = [c for c in COLUMNS if c not in missing]
    path = tmp_path / "runs.csv"
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=old, lineterminator="\n")
        writer.writeheader()
        writer.writerow(dict.fromkeys(old, "1"))
    (row,) = read_rows(path)
    assert list(row) == list(COLUMNS) and row["index"] == "1"
    assert all(row[c] == "" for c in missing)
    path.write_text("index,run_id\n0,a\n")
    with pytest.raises(UserError, match="columns differ"):
        read_rows(path)


def test_errors_after_a_declaration_cover_the_flight_from_it_on() -> None:
    """A 1 deg attitude error before the declaration at 5 s and a 3-4-0 deg one (5 deg) after:
    the MSE after it is exactly 25 deg^2; the position error 2 m before, 7 m after. With sigmas
    of 1, 2 and 1 deg (3 deg in roll before) the normalised errors squared after it are 9, 4
    and 0, a mean of 13/3 per axis."""
    from types import SimpleNamespace

    from immukf_sitl.experiments.metrics import errors_after_declaration

    times = np.round(np.arange(0.0, 10.0, 0.01), 2)
    records, estimates, outputs = [], [], []
    for t in times:
        truth = SimpleNamespace(position_ned_m=np.zeros(3), euler_rad=np.zeros(3))
        records.append(SimpleNamespace(time_s=float(t), autopilot=object(), truth=truth))
        after = t >= 5.0
        euler = np.radians([3.0, 4.0, 0.0]) if after else np.radians([1.0, 0.0, 0.0])
        position = np.array([0.0, 7.0 if after else 2.0, 0.0])
        estimates.append(SimpleNamespace(time_s=float(t), position_ned_m=position, euler_rad=euler))
        sigma = np.radians([1.0, 2.0, 1.0] if after else [3.0, 2.0, 1.0])
        outputs.append(SimpleNamespace(t_s=float(t), nav=SimpleNamespace(euler_sigma_rad=sigma)))
    history = SimpleNamespace(outputs=outputs)
    run = SimpleNamespace(records=records, estimates=estimates, history=history)
    out = errors_after_declaration(run, settle_s=1.0, declared_t_s=5.0)
    assert out["est_att_mse_after_decl_deg2"] == pytest.approx(25.0)
    assert out["est_pos_max_after_decl_m"] == pytest.approx(7.0)
    assert out["est_att_nees_after_decl"] == pytest.approx(13.0 / 3.0)
    # a step the estimator gave no sigma for is left out, not counted as consistent
    history.outputs = outputs[:700]
    assert errors_after_declaration(run, 1.0, 5.0)["est_att_nees_after_decl"] == pytest.approx(
        13.0 / 3.0
    )
    assert errors_after_declaration(run, 1.0, None) == {
        "est_att_mse_after_decl_deg2": None,
        "est_pos_max_after_decl_m": None,
        "est_att_nees_after_decl": None,
    }


def test_survival_per_kind_compares_with_the_same_airs_fault_free_twin() -> None:
    """Survived: declared, stable, attitude MSE after the declaration at most 1.5 times the
    twin's (same air, airframe draw and loop) and position error under 20 m."""
    from immukf_sitl.experiments.campaign_render import matrix_markdown
    from immukf_sitl.experiments.campaign_summary import matrix_summary

    def imm(fault: str, kind: str, after_att: str, after_pos: str, **cells: str):
        cells.setdefault("detection_delay_s", "0.5")
        return _row(variant="imm", fault=fault, fault_kind=kind, fault_t_s="40",
                    observable_t_s="41", est_att_mse_after_decl_deg2=after_att,
                    est_pos_max_after_decl_m=after_pos, **cells)  # fmt: skip

    rows = [
        _row(variant="imm", fault="none", est_att_mse_deg2="2.0"),
        _row(variant="imm", fault="none", air="light", est_att_mse_deg2="4.0"),
        imm("q", "bias", "2.9", "5", detection_delay_s="0.2"),  # 1.45x: survived
        imm("p", "bias", "3.1", "5", detection_delay_s="0.4"),  # 1.55x: not
        imm("x", "bias", "5.9", "25", air="light", detection_delay_s="0.9"),  # 25 m: not
        imm("y", "bias", "0.1", "1", replicate="1"),  # no fault-free twin: not counted
        imm("r", "drift", "1.0", "1", status="critical", failure="diverged"),  # lost
        imm("z", "drift", "", "", detection_delay_s=""),  # never declared: not survived
    ]
    kinds = matrix_summary(rows)["real-air"]["overall"]["identification"]["by_kind"]
    bias, drift = kinds["bias"], kinds["drift"]
    assert (bias["survived"], bias["with_fault_free_twin"], bias["lost"]) == (1, 3, 0)
    assert bias["detection_delay_s_median"] == pytest.approx(0.45)
    assert (drift["survived"], drift["with_fault_free_twin"], drift["lost"]) == (0, 2, 1)
    # the twin's error from its own onset on, where it has one, not its whole flight's
    onset = [{**rows[0], "est_att_mse_after_decl_deg2": "1.9"}, *rows[1:]]
    by_onset = matrix_summary(onset)["real-air"]["overall"]["identification"]["by_kind"]
    assert by_onset["bias"]["survived"] == 0  # q: 2.9 > 1.5 x 1.9
    onset[0]["est_att_mse_after_decl_deg2"] = "2.0"
    assert (
        matrix_summary(onset)["real-air"]["overall"]["identification"]["by_kind"]["bias"][
            "survived"
        ]
        == 1
    )
    text = matrix_markdown(matrix_summary(rows))
    assert "| bias | 4 | 0 (0 %) | 0.45 s | 0 (0 %) | – | 0 | 1/3 |" in text
    # by channel: q 2.9 / 2.0 survived; p 3.1 / 2.0 not; r lost at 1.0 / 2.0; z never declared
    channels = matrix_summary(rows)["real-air"]["airs"]["calm"]["identification"]["by_channel"]
    assert (channels["q"]["survived"], channels["q"]["with_fault_free_twin"]) == (1, 1)
    assert channels["q"]["attitude_ratio_median"] == pytest.approx(1.45)
    assert (channels["p"]["survived"], channels["r"]["survived"]) == (0, 0)
    assert channels["z"]["attitude_ratio_median"] is None and channels["z"]["survived"] == 0
    assert channels["y"]["with_fault_free_twin"] == 0  # replicate 1 flew no fault-free twin
    assert "| calm | 0/0 | 0/0 | 0/1 | 0/1 (1.6x) | 1/1 (1.4x) | 0/1 (0.5x) |" in text
    assert "| wind6-light |" not in text and "| light | 0/1 (1.5x) |" in text
    assert "  | bias | **not met** | **not met** | **not met** |" in text
    assert "- zero false declarations in at least 3 h of fault-free flight: 0 in" in text
    assert matrix_summary(rows)["real-air"]["acceptance"]["no_false_declarations_in_3h"] is False
    flown = [{**r, "fault_free_s": "5400", "false_declarations_fault_free": "0"} for r in rows[:2]]
    long_enough = matrix_summary(flown + rows[2:])["real-air"]["acceptance"]  # 3.0 h, none
    assert long_enough["no_false_declarations_in_3h"] is True
    one = [{**flown[0], "false_declarations_fault_free": "1"}, flown[1]]
    assert (
        matrix_summary(one + rows[2:])["real-air"]["acceptance"]["no_false_declarations_in_3h"]
        is False
    )
    # the same bias runs, each in time, named with its size and flown on as its twin
    fine = [
        {**r, "identified_within_1s": "true", "named_kind": "bias", "fault_value": "0.1",
         "named_size": "0.11", "est_att_mse_after_decl_deg2": "1.0",
         "est_pos_max_after_decl_m": "1", "detection_delay_s": "0.2"}
        for r in rows[2:5]
    ]  # fmt: skip
    ok = matrix_summary(rows[:2] + fine)["real-air"]["acceptance"]["kinds"]["bias"]
    assert ok == {"identified_within_1s": True, "named_right": True, "survived": True}
    late = [{**r, "detection_delay_s": "0.31"} for r in fine]  # a median over 0.3 s
    assert not matrix_summary(rows[:2] + late)["real-air"]["acceptance"]["kinds"]["bias"][
        "identified_within_1s"
    ]
    sized = [{**r, "named_size": "0.121"} for r in fine]  # 21 % off
    assert not matrix_summary(rows[:2] + sized)["real-air"]["acceptance"]["kinds"]["bias"][
        "named_right"
    ]


def test_the_matrix_summary_gives_pairs_per_gap_apart_from_the_single_faults() -> None:
    from immukf_sitl.experiments.campaign_render import matrix_markdown
    from immukf_sitl.experiments.campaign_summary import matrix_summary

    def pair(fault: str, second_t: str, **cells: str) -> dict[str, str]:
        second = fault.split("+")[1]
        return _row(variant="imm", fault=fault, fault_t_s="40", second_fault=second,
                    second_t_s=second_t, n_faults="2", **cells)  # fmt: skip

    single = _row(variant="imm", fault="q", fault_t_s="40", observable_t_s="41",
                  detection_delay_s="0.4", identified="q", identified_ok="true",
                  identified_within_1s="true", fault_free_s="37",
                  false_declarations_fault_free="0")  # fmt: skip
    rows = [
        pair("x+q", "40", observable_t_s="40.1", detection_delay_s="0.3",
             second_observable_t_s="40.2", second_detection_delay_s="0.5",
             second_identified_within_1s="true", declared_at_end="x+q",
             declarations="x@40.40 q@40.70"),
        pair("p+r", "40", observable_t_s="40.1", detection_delay_s="1.4",
             second_observable_t_s="41", second_detection_delay_s="0.2",
             second_identified_within_1s="true", declared_at_end="p+r+y",
             declarations="r@41.20 p@41.50 y@45.00"),
        pair("x+y", "40", second_identified_within_1s="false", declared_at_end="none",
             status="critical", failure="diverged", failure_t_s="42"),
        pair("x+q", "50", observable_t_s="40.1", detection_delay_s="0.2",
             second_observable_t_s="50.1", second_detection_delay_s="2.0",
             second_identified_within_1s="false", declared_at_end="x+q",
             declarations="z@30.00 x@40.30 q@52.10"),
        pair("y+z", "50", observable_t_s="40.5", detection_delay_s="0.4",
             second_observable_t_s="50.3", second_detection_delay_s="0.6",
             second_identified_within_1s="true", declared_at_end="y",
             declarations="y@40.90 z@50.90 r@51.00"),
        pair("p+q", "50", status="error"),  # failed to run: left out
        single,
    ]  # fmt: skip
    summary = matrix_summary(rows)["real-air"]
    # the single-fault identification holds the single fault only
    assert summary["overall"]["identification"]["observable"] == 1
    assert summary["overall"]["identification"]["faulted_runs"] == 1
    by_gap = summary["pairs"]["by_gap"]
    assert list(by_gap) == ["at once", "after 10 s"]
    assert by_gap["at once"] == {
        "gap_s": 0.0,
        "runs": 3,
        "first_observable": 2,
        "first_identified_within_1s": 1,
        "second_observable": 2,
        "second_identified_within_1s": 2,
        "second_identified_within_1s_share": 1.0,
        "second_detection_delay_s_median": pytest.approx(0.35),
        "both_declared_at_end": 2,
        "declarations_outside_pair": 1,
        "lost": 1,
    }
    later = by_gap["after 10 s"]
    assert (later["runs"], later["first_identified_within_1s"], later["first_observable"]) == (
        2, 2, 2,
    )  # fmt: skip
    assert (later["second_identified_within_1s"], later["second_observable"]) == (1, 2)
    assert later["second_detection_delay_s_median"] == pytest.approx(1.3)
    assert (later["both_declared_at_end"], later["declarations_outside_pair"]) == (1, 1)
    assert summary["pairs"]["acceptance"] == {"second_identified_within_1s": False}
    at_once = matrix_summary(rows[:3])["real-air"]["pairs"]
    assert at_once["acceptance"] == {"second_identified_within_1s": True}
    text = matrix_markdown(matrix_summary(rows))
    assert "**Pairs**" in text
    assert "| at once | 3 | 1/2 | 2/2 | 100 % | 0.35 | 2 | 1 | 1 |" in text
    assert "| after 10 s | 2 | 2/2 | 1/2 | 50 % | 1.3 | 1 | 1 | 0 |" in text
    assert "at every gap: at once 100 % (2/2), after 10 s 50 % (1/2): **not met**." in text
    # a campaign without pairs keeps its summary and tables as they were
    alone = matrix_summary([single])
    assert "pairs" not in alone["real-air"] and "Pairs" not in matrix_markdown(alone)


def test_the_shipped_pairs_campaign_and_its_report_from_a_partial_runs_csv(
    tmp_path: Path, capsys
) -> None:
    import shutil

    from immukf_sitl.experiments import campaign_report
    from immukf_sitl.experiments.campaign_run import write_rows

    path = tmp_path / "fault_pairs.yaml"
    shutil.copy(CAMPAIGNS / "fault_pairs.yaml", path)
    campaign = load_campaign(path)
    runs = campaign.runs()
    assert len(runs) == 15 * 2 * 2 * 3 == len({r.run_id for r in runs})
    assert (campaign.seed, campaign.replicates, campaign.fault_modes) == (37, 1, "untrusted")
    assert campaign.pair_gaps_s == (0.0, 10.0) and campaign.report == "matrix"
    assert all(r.pair_gap_s is not None and r.second_t_s < 80.0 for r in runs)
    assert campaign.figure_run() is not None
    at_once, later = (next(r for r in runs if r.pair_gap_s == g) for g in (0.0, 10.0))
    rows = [
        _row(run_id=spec.run_id, variant="imm", fault=spec.mode.name,
             fault_t_s=f"{spec.fault_t_s:g}", second_fault=spec.second_fault,
             second_t_s=f"{spec.second_t_s:g}", observable_t_s="30",
             detection_delay_s="0.3", second_observable_t_s="40",
             second_detection_delay_s="0.4", second_identified_within_1s="true",
             declared_at_end=spec.mode.name, fault_free_s="20",
             false_declarations_fault_free="0")
        for spec in (at_once, later)
    ]  # fmt: skip
    write_rows(tmp_path / "runs.csv", rows)
    assert campaign_report.main([str(path), str(tmp_path)]) == 0
    assert capsys.readouterr().out.strip().endswith(f"2 of {len(runs)} runs")
    report = (tmp_path / "report.md").read_text()
    assert "the second channel of a pair at once, after 10 s" in report
    assert "| at once | 1 | 1/1 | 1/1 | 100 % | 0.4 | 1 | 0 | 0 |" in report
    assert "| after 10 s | 1 | 1/1 | 1/1 | 100 % | 0.4 | 1 | 0 | 0 |" in report
    matrix = json.loads((tmp_path / "matrix.json").read_text())
    assert matrix["real-air"]["pairs"]["acceptance"] == {"second_identified_within_1s": True}
