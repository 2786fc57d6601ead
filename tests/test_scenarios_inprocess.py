"""Full 90 s scenarios through the in-process chain (JSBSim -> fault injector -> pipeline)."""

from pathlib import Path

import pytest

from immukf_sitl.experiments.inprocess import run_inprocess
from immukf_sitl.scenario import load_scenario

# flies JSBSim or the estimator chain
pytestmark = pytest.mark.slow

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"


@pytest.mark.parametrize("name", ["p_gyro_zeroed", "y_accel_zeroed"])
def test_late_observable_faults_are_identified_and_no_fix_is_lost(name):
    # p and y are the channels that hide longest in this plan; 90 s lets the GPS error wander
    scenario = load_scenario(SCENARIOS / f"{name}.yaml")
    run = run_inprocess(scenario)
    summary = run.summary().to_json()
    assert summary["expectation"]["met"], summary["faults"]
    assert summary["false_alarms"] == 0
    counters = run.pipeline.counters
    assert counters.rejected_gps == 0 and counters.realignments == 0
