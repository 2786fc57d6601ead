"""Helpers of the flown tests: a shipped scenario with other faults, flown in process (JSBSim and
the estimator, lock-step), and its summary as ``--json`` gives it; or written with its fault
moved, for the tests that fly it through the CLI."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import yaml

from immukf_sitl.experiments.inprocess import run_inprocess
from immukf_sitl.scenario import ExpectSpec, FaultSpec, load_scenario
from immukf_sitl.service.filter_models import FilterModel
from immukf_sitl.service.pipeline import PipelineConfig

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"


def fly(
    name: str,
    model: FilterModel,
    faults: tuple[FaultSpec, ...],
    duration_s: float,
    expect: ExpectSpec | None = None,
) -> dict:
    """``scenarios/<name>`` with ``faults`` instead of its own, flown ``duration_s`` seconds on
    ``model`` with the scenario's spec sheet."""
    base = load_scenario(SCENARIOS / name)
    scenario = dataclasses.replace(base, faults=faults, expect=expect)
    config = PipelineConfig(filter_model=model, sensors=base.sensors.spec_sheet())
    return run_inprocess(scenario, config, duration_s=duration_s).summary().to_json()


def with_fault_at(name: str, t_s: float, out_dir: Path) -> Path:
    """``scenarios/<name>``, whose one fault starts at ``t_s`` instead, written to ``out_dir``.

    The shipped scenarios fault at 30 s; from 14 s they fly the climbing right turn, where every
    channel reads away from zero, so a test checks the same detection in 16 s less of flight.
    """
    spec = yaml.safe_load((SCENARIOS / name).read_text())
    (fault,) = spec["faults"]
    fault["t_s"] = float(t_s)
    path = Path(out_dir) / f"{Path(name).stem}_at_{t_s:g}s.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    return path


def thinned(stream: list, kind: type, period_s: float) -> list:
    """Every sample of ``kind`` at least ``period_s`` after the last kept; the rest as is."""
    out, next_s = [], -1.0
    for sample in stream:
        if isinstance(sample, kind):
            if sample.time_s + 1e-6 < next_s:
                continue
            next_s = sample.time_s + period_s
        out.append(sample)
    return out
