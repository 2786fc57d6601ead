"""Helper of the flown tests: a shipped scenario with other faults, flown in process (JSBSim and
the estimator, lock-step), and its summary as ``--json`` gives it."""

from __future__ import annotations

import dataclasses
from pathlib import Path

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
