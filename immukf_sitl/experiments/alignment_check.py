"""The one-sample alignment scored against JSBSim's truth at every GPS fix of a flight.

``serve`` aligns (:func:`~immukf_sitl.service.alignment.align`) at the first fix, or again
after a reset, wherever the aircraft is: level, in a turn, in turbulence. This flies a scenario
in JSBSim (the autopilot on truth, no estimator) and aligns at each fix, so that the sigmas the
alignment gives can be checked against the errors it makes (docs/design/detection-and-tuning.md,
"Alignment"; ``tools/alignment_check.py`` prints the table).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from immukf_sitl.scenario import Scenario
from immukf_sitl.service.alignment import align
from sim.scenario_flight import flight_from_scenario

__all__ = ["AlignmentErrors", "alignment_errors"]


@dataclass(frozen=True)
class AlignmentErrors:
    """Roll, pitch and yaw errors of the alignment at each fix, and the sigmas it gave.

    Attributes
    ----------
    t_s : ndarray, shape (n,)
        Times of the fixes aligned at (s).
    error_rad, sigma_rad : ndarray, shape (n, 3)
        Aligned minus true Euler angles, wrapped to (-pi, pi], and the alignment's sigmas.
    ground_speed_mps : ndarray, shape (n,)
        The fixes' ground speeds (m/s).
    """

    t_s: np.ndarray
    error_rad: np.ndarray
    sigma_rad: np.ndarray
    ground_speed_mps: np.ndarray

    def normalised(self) -> np.ndarray:
        """``(n, 3)``: each error over its sigma."""
        return self.error_rad / self.sigma_rad


def alignment_errors(scenario: Scenario, from_s: float = 3.0) -> AlignmentErrors:
    """Fly ``scenario`` for its duration and align at every fix from ``from_s`` on.

    The fix gives ground speed and course; position does not enter the attitude.
    """
    flight = flight_from_scenario(scenario)
    flight.start()
    times, errors, sigmas, speeds = [], [], [], []
    for _ in range(round(scenario.duration_s / flight.driver.dt_s)):
        record = flight.step()
        fix = record.gps
        if fix is None or record.time_s < from_s:
            continue
        gps = np.array([0.0, 0.0, 0.0, fix.ground_speed_mps, fix.course_rad])
        nav = align(record.time_s, record.imu.as_array(), gps)
        wrapped = np.remainder(nav.euler_rad - record.truth.euler_rad + math.pi, 2.0 * math.pi)
        times.append(record.time_s)
        errors.append(wrapped - math.pi)
        sigmas.append(np.asarray(nav.euler_sigma_rad, dtype=float))
        speeds.append(fix.ground_speed_mps)
    return AlignmentErrors(*(np.array(v) for v in (times, errors, sigmas, speeds)))
