"""Score the one-sample alignment against JSBSim's truth at every GPS fix; one table row an air.

    python tools/alignment_check.py scenarios/campaigns/fault_kinds.yaml --seeds 1-6

Flies the campaign's (or a scenario's) flight in each of its airs on the given seeds (airframe,
sensor and turbulence draws), the autopilot on truth, aligns at every fix from 3 s and prints,
per air, the RMS errors of roll, pitch and yaw, the mean (error / sigma)^2 per axis and the share
of roll errors beyond 3 sigma. Yaw's sigma is widened as the real-air filter widens it, by the
crab of its initial wind sigma. docs/design/detection-and-tuning.md ("Alignment") holds the
table this printed. Progress goes to stderr.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import yaml

from immukf_sitl.errors import UserError
from immukf_sitl.experiments.alignment_check import alignment_errors
from immukf_sitl.scenario import Scenario, parse_scenario
from immukf_sitl.service.filter_models import RealAirModel


def _seeds(text: str) -> list[int]:
    """``1-6`` or ``1,2,5`` as a list of seeds."""
    if "-" in text:
        first, last = (int(v) for v in text.split("-", 1))
        return list(range(first, last + 1))
    return [int(v) for v in text.split(",")]


def _flights(path: Path, seeds: list[int], duration_s: float) -> dict[str, list[Scenario]]:
    """Per air, the scenario of each seed, validated before anything flies."""
    if not seeds or not duration_s > 0.0:
        raise ValueError("expected at least one seed and a duration > 0")
    spec = yaml.safe_load(path.read_text())
    if not isinstance(spec, dict):
        raise ValueError("expected a campaign or scenario mapping")
    base = spec.get("scenario", spec)
    airs = spec.get("air") or [{"name": "scenario", "wind": base.get("wind", {})}]
    flights: dict[str, list[Scenario]] = {}
    for air in airs:
        name = str(air.get("name", "air")) if isinstance(air, dict) else "air"
        wind = air.get("wind", {}) if isinstance(air, dict) else air
        flights[name] = [
            parse_scenario(
                {**base, "name": "alignment", "seed": seed, "duration_s": duration_s, "wind": wind},
                str(path),
            )  # fmt: skip
            for seed in seeds
        ]
    return flights


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("file", help="a campaign YAML (its scenario and air) or a scenario YAML")
    parser.add_argument("--seeds", default="1-6", help="seeds to fly, '1-6' or '1,2,5'")
    parser.add_argument("--duration", type=float, default=120.0, help="flight length (s)")
    args = parser.parse_args()
    try:
        flights = _flights(Path(args.file), _seeds(args.seeds), args.duration)
    except (OSError, ValueError, UserError, yaml.YAMLError) as exc:
        where = "" if str(exc).startswith(args.file) else f"{args.file}: "
        print(f"alignment_check: {where}{exc}", file=sys.stderr)
        return 2
    wind_sigma_mps = RealAirModel().initial_wind_sigma_mps
    print(
        "| air | fixes | RMS error, roll / pitch / yaw (deg) | mean (error / sigma)², roll / "
        "pitch / yaw | beyond 3 sigma, roll |\n|---|---|---|---|---|"
    )
    for air, scenarios in flights.items():
        errors, sigmas = [], []
        for scenario in scenarios:
            print(f"alignment_check: {air}, seed {scenario.seed}", file=sys.stderr)
            flown = alignment_errors(scenario)
            sigma = flown.sigma_rad.copy()
            speed = np.maximum(flown.ground_speed_mps, 1.0)
            sigma[:, 2] = np.hypot(sigma[:, 2], np.arctan2(wind_sigma_mps, speed))
            errors.append(flown.error_rad)
            sigmas.append(sigma)
        e, s = np.concatenate(errors), np.concatenate(sigmas)
        rms = np.degrees(np.sqrt(np.mean(e**2, axis=0)))
        mean_square = np.mean((e / s) ** 2, axis=0)
        beyond = np.mean(np.abs(e[:, 0] / s[:, 0]) > 3.0)
        print(
            f"| {air} | {len(e)} | {' / '.join(f'{v:.1f}' for v in rms)} | "
            f"{' / '.join(f'{v:.2f}' for v in mean_square)} | {100 * beyond:.1f} % |"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
