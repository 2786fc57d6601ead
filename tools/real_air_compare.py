"""Fly scenarios in process with the paper's or the real-air filter model; one JSON line each.

    python tools/real_air_compare.py real-air:scenarios/fault_free_windy.yaml \
        paper:scenarios/q_gyro_zeroed_windy.yaml

Each argument is MODEL:SCENARIO (MODEL: paper or real-air). The IMM runs on the scenario's
sensor spec sheet; the line holds detection, false declarations, errors and the step median.
"""

from __future__ import annotations

import json
import sys
import time

from immukf_sitl.experiments.inprocess import run_inprocess
from immukf_sitl.scenario import load_scenario
from immukf_sitl.service.filter_models import filter_model
from immukf_sitl.service.pipeline import PipelineConfig


def main(specs: list[str]) -> None:
    for spec in specs:
        model, _, path = spec.partition(":")
        if model not in ("paper", "real-air") or not path:
            sys.exit(f"expected MODEL:SCENARIO with MODEL paper or real-air, got {spec!r}")
        scenario = load_scenario(path)
        config = PipelineConfig(
            variant="imm", sensors=scenario.sensors.spec_sheet(), filter_model=filter_model(model)
        )
        start = time.time()
        summary = run_inprocess(scenario, config).summary().to_json()
        fault = summary["faults"][0] if summary["faults"] else {}
        error = summary["est_error"]
        line = {
            "model": model,
            "scenario": summary["scenario"],
            "observable_t_s": fault.get("observable_t_s"),
            "detected_t_s": fault.get("detected_t_s"),
            "delay_s": fault.get("detection_delay_s"),
            "false_alarms": summary["false_alarms"],
            "att_max_deg": round(error["att_max_deg"], 2),
            "att_mse_deg2": round(error["att_mse_deg2"], 3),
            "pos_max_m": round(error["pos_max_m"], 1),
            "step_median_us": round(summary["step_us"]["median"]),
            "wall_s": round(time.time() - start, 1),
        }
        print(json.dumps(line), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
