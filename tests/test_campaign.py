"""Campaign files, the experiment command, its metrics and its executors (closed loop)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

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


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"replicates": 0}, r"replicates: expected an integer >= 1, got 0"),
        ({"variants": {"ukf5": "single"}}, r"variants\.ukf5: unknown variant"),
        ({"variants": {"ukf2": "all_63"}}, r"variants\.ukf2: expected all_64, single or a list"),
        ({"variants": {"ukf2": ["q", "w"]}}, r"variants\.ukf2: expected fault modes .* got 'w'"),
        ({"variants": {"imm": ["x+q"]}}, r"variants\.imm: the IMM's bank holds the 7 single"),
        ({"loop": ["closed", "sideways"]}, r"loop: expected closed, open or a list of both"),
        ({"fault_times_s": [9.0]}, r"fault_times_s: expected times before the scenario's end"),
        ({"seeds": 3}, r"seeds: unknown field \(expected one of"),
        ({"failure": {"lateral_m": "far"}}, r"failure\.lateral_m: expected a number"),
        ({"air": [{"name": "w", "wind": {"speed_mps": 99}}]}, r"wind\.speed_mps: expected"),
        ({"scenario": {"duration_s": 8}}, r"flight_plan: required field is missing"),
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
    assert [r["run_id"] for r in failed] == ["ukf2/q/r0/t4.5/closed/default"]
    assert failed[0]["error"] == "RuntimeError: JSBSim exploded"
    assert sum(r["status"] != "error" for r in first.rows) == 2
    monkeypatch.setattr(campaign_run, "fly", real_fly)
    second = run_campaign(campaign, tmp_path / "out", resume=True, progress=False)
    assert (second.flown, second.skipped) == (1, 2)
    assert all(r["error"] == "" for r in second.rows)
    assert second.rows[:2] == first.rows[:2]
    with open(tmp_path / "out" / "runs.csv", newline="") as f:
        assert tuple(next(csv.reader(f))) == COLUMNS


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
