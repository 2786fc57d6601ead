"""The one-sample alignment against JSBSim's truth: the sigmas it gives hold in flight.

``serve`` aligns at the first GPS fix, or again after a reset, wherever the aircraft is: level,
in a turn, in turbulence. At every fix of a JSBSim flight (the autopilot on truth, the shipped
windy scenario's plan and airframe; :func:`~immukf_sitl.experiments.alignment_check.
alignment_errors`), the alignment's roll and pitch errors are compared with the sigmas it
gives: a statistical consistency test, the mean of ``(error / sigma)^2`` at most 1 per axis (1
for consistent sigmas, below for conservative ones) and no error beyond 5 sigma (one Gaussian
sample in 1.7 million). Without the centripetal term ``atan(V |omega| / g)``, a turn's bank
(the specific force of a coordinated turn lies along the body's z axis, so the sample reads
level) puts the mean ``(error / sigma)^2`` of roll at 37-42 and its largest error at 11-13
sigmas (0.47-0.63 and 1.3-2.6 with it). Yaw is the GPS course, checked in still air, where
heading and course differ only by the sideslip; in wind the filter widens it by the crab of an
unknown wind (``RealAirModel.initial_state``).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from immukf_sitl.experiments.alignment_check import alignment_errors
from immukf_sitl.models.wind import WindSpec
from immukf_sitl.scenario import load_scenario
from tests.flights import SCENARIOS


@pytest.mark.slow
@pytest.mark.parametrize(
    ("wind", "axes"),
    [
        (WindSpec(), 3),  # still air: the course is the heading, to the sideslip
        (WindSpec(speed_mps=10.0, from_deg=270.0, turbulence="moderate"), 2),
    ],
    ids=["calm", "moderate"],
)
def test_alignment_sigmas_hold_at_every_fix(wind: WindSpec, axes: int) -> None:
    base = load_scenario(SCENARIOS / "fault_free_windy.yaml")
    scenario = dataclasses.replace(base, wind=wind, duration_s=60.0)  # the first turns
    z = alignment_errors(scenario).normalised()[:, :axes]
    assert len(z) >= 50
    mean_square = np.mean(z**2, axis=0)
    assert np.all(mean_square <= 1.0), mean_square
    assert np.max(np.abs(z)) < 5.0, np.max(np.abs(z), axis=0)
