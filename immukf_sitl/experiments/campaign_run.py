"""Run a campaign's runs through an executor into ``runs.csv``: progress, failures, resume.

One run (:func:`execute_run`) flies its scenario in process (:mod:`.inprocess`), closed or open
loop, stops at the first critical failure if the campaign says so, and returns one row of
``runs.csv`` (:data:`COLUMNS`). A run that raises records its error in the row and the campaign
goes on. Runs are submitted replicate by replicate (all of replicate 0 first), so that a
campaign stopped early holds whole replicates. Rows are appended to ``runs.csv`` as runs
finish; at the end the file is rewritten in the campaign's order, so that it is the same
whatever ran the runs and in whatever order they finished. With ``resume``, runs that already
have an error-free row are not flown again.
"""

from __future__ import annotations

import csv
import json
import math
import subprocess
import sys
import time
from collections.abc import Iterable, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, wait
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

from immukf_sitl.errors import UserError
from immukf_sitl.experiments.campaign import Campaign, RunSpec
from immukf_sitl.experiments.executor import open_executor
from immukf_sitl.experiments.inprocess import InProcessRun, run_inprocess
from immukf_sitl.experiments.metrics import (
    FailureMonitor,
    error_metrics,
    errors_after_declaration,
    identification_metrics,
)
from immukf_sitl.service.filter_models import FilterModel, filter_model
from immukf_sitl.service.pipeline import PipelineConfig

#: The columns of ``runs.csv``, in order (docs/results/paper/report.md defines each).
#: the second fault of a pair run (empty on any other run)
_SECOND_FAULT_COLUMNS = (
    "second_fault",
    "second_t_s",
    "second_observable_t_s",
    "second_detected_t_s",
    "second_detection_delay_s",
    "second_identified_within_1s",
    "second_named_kind",
)
COLUMNS: tuple[str, ...] = (
    "index",
    "run_id",
    "variant",
    "fault",
    "fault_kind",
    "fault_value",
    "paper_index",
    "n_faults",
    "replicate",
    "seed",
    "fault_t_s",
    "loop",
    "air",
    "filter_model",
    "status",
    "failure",
    "failure_t_s",
    "flown_s",
    "est_pos_max_m",
    "est_pos_mse_m2",
    "est_att_max_deg",
    "est_att_mse_deg2",
    "est_att_mse_after_decl_deg2",
    "est_pos_max_after_decl_m",
    "est_att_nees_after_decl",
    "ctrl_pos_max_m",
    "ctrl_pos_mse_m2",
    "ctrl_att_max_deg",
    "ctrl_att_mse_deg2",
    "observable_t_s",
    "detected_t_s",
    "detection_delay_s",
    "identified",
    "identified_ok",
    "identified_within_1s",
    "named_kind",
    "named_size",
    *_SECOND_FAULT_COLUMNS,
    "false_declarations",
    "fault_free_s",
    "false_declarations_fault_free",
    "declarations",
    "declared_at_end",
    "realignments",
    "filter_resets",
    "error",
)
#: the columns pair runs added: a ``runs.csv`` written before them still reads, with them empty
PAIR_COLUMNS = (*_SECOND_FAULT_COLUMNS, "declared_at_end")
#: the columns the survival after a declaration added (read empty from an older file too)
AFTER_DECLARATION_COLUMNS = ("est_att_mse_after_decl_deg2", "est_pos_max_after_decl_m")
#: the column the attitude's consistency after a declaration added
CONSISTENCY_COLUMNS = ("est_att_nees_after_decl",)
#: the column the filters' resets added: mode-matched updates that came out non-finite or with
#: a negative variance and were reset (``FilterDiagnostics``), since the last alignment
RESET_COLUMNS = ("filter_resets",)
_OLDER_HEADERS = tuple(
    tuple(c for c in COLUMNS if c not in added)
    for added in (
        RESET_COLUMNS,
        RESET_COLUMNS + CONSISTENCY_COLUMNS,
        RESET_COLUMNS + CONSISTENCY_COLUMNS + AFTER_DECLARATION_COLUMNS,
        RESET_COLUMNS + CONSISTENCY_COLUMNS + AFTER_DECLARATION_COLUMNS + PAIR_COLUMNS,
    )
)
RUNS_CSV = "runs.csv"
CAMPAIGN_JSON = "campaign.json"


def _cell(value: object) -> str:
    """A CSV cell: floats to 6 significant digits (stable across machines), None empty."""
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return "nan" if math.isnan(value) else f"{value:.6g}"
    return str(value)


def _identity(spec: RunSpec) -> dict[str, object]:
    return {
        "index": spec.index,
        "run_id": spec.run_id,
        "variant": spec.variant,
        "fault": spec.mode.name,
        "fault_kind": spec.fault_kind,
        "fault_value": spec.fault_value,
        "paper_index": spec.mode.paper_index,
        "n_faults": len(spec.mode.channels),
        "replicate": spec.replicate,
        "seed": spec.seed,
        "fault_t_s": spec.fault_t_s,
        "second_fault": spec.second_fault,
        "second_t_s": spec.second_t_s,
        "loop": spec.loop,
        "air": spec.air,
        "filter_model": spec.filter_model,
    }


def filter_resets(run: InProcessRun) -> int | None:
    """Mode-matched updates the flight's filter reset (non-finite, or a negative variance).

    Counted since the last alignment (a re-alignment builds a new bank: ``realignments``);
    None where no bank is running at the end.
    """
    estimator = run.pipeline.estimator
    if estimator is None:
        return None
    diagnostics = estimator.diagnostics
    return diagnostics.nonfinite_state_reset + diagnostics.indefinite_state_reset


def run_filter_model(spec: RunSpec) -> FilterModel:
    """The estimator's filter model of a run: its ``filter_model`` with its ``fault_modes``."""
    return filter_model(spec.filter_model, fault_signature=spec.fault_modes)


def fly(spec: RunSpec) -> tuple[InProcessRun, FailureMonitor]:
    """Fly one run: its variant, fault, loop and filter model, stopped by the failure criterion."""
    scenario = spec.scenario
    config = PipelineConfig(
        variant=spec.variant,
        true_mode=spec.mode if spec.variant == "ukf1" else None,
        filter_model=run_filter_model(spec),
        sensors=scenario.sensors.spec_sheet(),
    )
    monitor = FailureMonitor(spec.failure, config.detector.settle_s)
    run = run_inprocess(scenario, config, closed_loop=spec.loop == "closed", stop=monitor)
    return run, monitor


def execute_run(spec: RunSpec) -> dict[str, str]:
    """One row of ``runs.csv`` for ``spec`` (its error, if it raised)."""
    row: dict[str, object] = dict.fromkeys(COLUMNS)
    row.update(_identity(spec))
    try:
        run, monitor = fly(spec)
        settle_s = run.pipeline.config.detector.settle_s
        row.update(error_metrics(run, settle_s))
        identification = identification_metrics(spec, run, settle_s)
        if spec.variant != "imm":  # a single filter declares nothing: only when it showed
            identification = {"observable_t_s": identification["observable_t_s"]}
        row.update(identification)
        if spec.variant == "imm":
            # a fault-free flight is measured from its own drawn onset on, so that survival
            # compares the same phase of flight, past the alignment's first errors
            declared_t_s = identification["detected_t_s"] if spec.mode.channels else spec.fault_t_s
            row.update(errors_after_declaration(run, settle_s, declared_t_s))
        row["status"] = "critical" if monitor.reason else "stable"
        row["failure"] = monitor.reason or ""
        row["failure_t_s"] = monitor.t_s
        row["flown_s"] = run.records[-1].time_s if run.records else 0.0
        row["realignments"] = run.pipeline.counters.realignments
        row["filter_resets"] = filter_resets(run)
        row["error"] = ""
    except Exception as exc:  # noqa: BLE001 - a failed run is recorded, the campaign goes on
        row["status"] = "error"
        row["error"] = f"{type(exc).__name__}: {exc}".replace("\n", " ")[:300]
    return {k: _cell(row[k]) for k in COLUMNS}


def _row_of(future: Future, spec: RunSpec) -> dict[str, str]:
    """The future's row; a worker that died (not the run raising) gives an error row too."""
    exc = future.exception()
    if exc is None:
        return future.result()
    row: dict[str, object] = dict.fromkeys(COLUMNS)
    row.update(_identity(spec), status="error", error=f"worker: {type(exc).__name__}: {exc}")
    return {k: _cell(row[k]) for k in COLUMNS}


def read_rows(path: Path) -> list[dict[str, str]]:
    """The rows of a ``runs.csv`` (empty if there is none).

    A file written before :data:`PAIR_COLUMNS`, :data:`AFTER_DECLARATION_COLUMNS`,
    :data:`CONSISTENCY_COLUMNS` or :data:`RESET_COLUMNS` existed reads with those cells empty.
    """
    if not path.exists():
        return []
    with path.open(newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        if tuple(reader.fieldnames or ()) not in (COLUMNS, *_OLDER_HEADERS):
            raise UserError(f"{path}: not a runs.csv of this version (columns differ)")
        return [{k: row.get(k, "") for k in COLUMNS} for row in reader]


def write_rows(path: Path, rows: Iterable[dict[str, str]]) -> None:
    """Write ``rows`` as ``runs.csv`` (header first)."""
    with path.open("w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS, lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)


class Progress:
    """A progress line with an ETA on stderr (redrawn in place on a terminal)."""

    def __init__(self, total: int, stream: TextIO | None = None, enabled: bool = True) -> None:
        self.total = total
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = enabled
        self.done = 0
        self.failed = 0
        self.critical = 0
        self.start = time.monotonic()
        self._tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self._last_print = -1.0

    @staticmethod
    def _clock(seconds: float) -> str:
        seconds = int(round(seconds))
        return f"{seconds // 60}m{seconds % 60:02d}s"

    def line(self) -> str:
        """The progress line."""
        elapsed = time.monotonic() - self.start
        eta = elapsed / self.done * (self.total - self.done) if self.done else math.nan
        width = 24
        filled = int(width * self.done / max(self.total, 1))
        bar = "#" * filled + "." * (width - filled)
        eta_text = self._clock(eta) if math.isfinite(eta) else "?"
        return (
            f"experiment: [{bar}] {self.done}/{self.total} runs, {self.critical} critical, "
            f"{self.failed} failed, {self._clock(elapsed)} elapsed, ETA {eta_text}"
        )

    def update(self, row: dict[str, str]) -> None:
        """Count one finished run and redraw."""
        self.done += 1
        self.failed += row["status"] == "error"
        self.critical += row["status"] == "critical"
        if not self.enabled:
            return
        now = time.monotonic()
        if self._tty:
            print("\r" + self.line(), end="", file=self.stream, flush=True)
        elif now - self._last_print >= 10.0 or self.done == self.total:
            print(self.line(), file=self.stream, flush=True)
            self._last_print = now

    def close(self) -> None:
        """End the line on a terminal."""
        if self.enabled and self._tty:
            print(file=self.stream, flush=True)


@dataclass(frozen=True)
class CampaignResult:
    """What a campaign run produced."""

    campaign: Campaign
    rows: tuple[dict[str, str], ...]
    wall_s: float
    flown: int
    skipped: int


def source_commit() -> str:
    """The commit of the estimator that flies the runs (recorded in ``campaign.json``).

    A ``SOURCE_COMMIT`` file beside the package (a ``git archive`` snapshot) wins; otherwise
    ``git rev-parse HEAD`` of the package's repository, with ``+dirty`` when the estimator's
    sources differ from it; ``unknown`` when neither is there.
    """
    root = Path(__file__).resolve().parents[2]
    stamp = root / "SOURCE_COMMIT"
    if stamp.exists():
        return stamp.read_text(encoding="utf-8").strip() or "unknown"
    try:
        head = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "HEAD"],
            capture_output=True,
            text=True,
            timeout=10,
            check=True,
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "-C", str(root), "status", "--porcelain", "--", "immukf_sitl", "sim"],
            capture_output=True,
            text=True,
            timeout=10,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return f"{head}+dirty" if dirty else head


def _check_resume(campaign: Campaign, out_dir: Path, resume: bool) -> list[dict[str, str]]:
    """Rows kept from an earlier run of the same campaign (none unless ``resume``)."""
    stamp = out_dir / CAMPAIGN_JSON
    if not resume:
        return []
    if stamp.exists():
        digest = json.loads(stamp.read_text(encoding="utf-8")).get("digest")
        if digest != campaign.digest:
            raise UserError(
                f"--resume: {out_dir} holds runs of a different campaign file "
                "(its scenario, seed, air or failure criterion changed); use another --out-dir"
            )
    return [row for row in read_rows(out_dir / RUNS_CSV) if not row["error"]]


def run_campaign(
    campaign: Campaign,
    out_dir: Path,
    jobs: int = 1,
    scheduler: str | None = None,
    resume: bool = False,
    progress: bool = True,
    runs: Sequence[RunSpec] | None = None,
) -> CampaignResult:
    """Fly every run of ``campaign`` (or ``runs``) and write ``out_dir/runs.csv``.

    Parameters
    ----------
    campaign : Campaign
    out_dir : Path
        Created if needed; holds ``runs.csv`` and ``campaign.json``.
    jobs : int, optional
        Local worker processes.
    scheduler : str, optional
        Dask scheduler address (instead of local workers).
    resume : bool, optional
        Keep the error-free rows already in ``out_dir`` and fly only the others.
    progress : bool, optional
        Draw the progress line on stderr.
    runs : sequence of RunSpec, optional
        Default ``campaign.runs()``.

    Returns
    -------
    CampaignResult
    """
    start = time.monotonic()
    out_dir.mkdir(parents=True, exist_ok=True)
    specs = tuple(runs) if runs is not None else campaign.runs()
    kept = {row["run_id"]: row for row in _check_resume(campaign, out_dir, resume)}
    wanted = {spec.run_id for spec in specs}
    kept = {k: v for k, v in kept.items() if k in wanted}
    # submitted replicate by replicate: a campaign stopped early (and resumed later) holds
    # whole replicates of every air and fault set, not every replicate of the first air
    todo = sorted(
        (spec for spec in specs if spec.run_id not in kept),
        key=lambda spec: (spec.replicate, spec.index),
    )
    stamp = {
        "campaign": campaign.name,
        "digest": campaign.digest,
        "path": campaign.path,
        "source_commit": source_commit(),
    }
    (out_dir / CAMPAIGN_JSON).write_text(json.dumps(stamp, indent=1) + "\n", encoding="utf-8")
    path = out_dir / RUNS_CSV
    write_rows(path, kept.values())
    bar = Progress(len(todo), enabled=progress)
    rows: dict[str, dict[str, str]] = dict(kept)
    window = 64 if scheduler is not None else 2 * jobs
    with open_executor(jobs, scheduler) as executor, path.open("a", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS, lineterminator="\n")
        queue = iter(todo)
        pending: dict[Future, RunSpec] = {}
        while True:
            while len(pending) < window and (spec := next(queue, None)) is not None:
                pending[executor.submit(execute_run, spec)] = spec
            if not pending:
                break
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                row = _row_of(future, pending.pop(future))
                rows[row["run_id"]] = row
                writer.writerow(row)
                f.flush()
                bar.update(row)
    bar.close()
    ordered = tuple(rows[spec.run_id] for spec in specs)
    write_rows(path, ordered)
    return CampaignResult(
        campaign, ordered, time.monotonic() - start, flown=len(todo), skipped=len(kept)
    )
