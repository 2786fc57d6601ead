"""The last half second of filter steps, so that a re-based bank is re-run from before a failure.

A declaration re-bases the bank on the new declared set
(:mod:`immukf_sitl.service.declared_set`) 0.2 s, the dwell, after the failing slot took the
lead. Over that dwell the slot that becomes the new base read every other channel as healthy.
A second channel that failed in the same instant (two biases at once) has been followed by
that slot's rate and gust states, so the re-based slot that leaves it out pays for its
unknown offset at every sample and never leads: on the pairs campaign's calm x+r biases the
r gyro was never declared and the pitch drifted by 7 deg. Re-run from a step before the
failure over the same inputs, the re-based bank sees the second channel fail as a first bank
sees a first failure, and its base never reads the channels it no longer trusts.

``REPLAY_S`` (0.5 s) reaches back over the dwell and the rise to the threshold of 83 of the
90 failures the tuning draw's first airframe found within 1 s; the re-run costs about 50 of
the real-air bank's steps (about 55 ms, once per declaration). Not swept.
"""

from __future__ import annotations

import dataclasses
from collections import deque
from dataclasses import dataclass

import numpy as np

from immukf_sitl.models.sensors import IMU_PERIOD_S
from immukf_sitl.service.filters import AircraftEstimator, Observation, VariantEstimate

#: how far back a declaration re-runs the re-based bank (s)
REPLAY_S = 0.5


@dataclass(frozen=True)
class Step:
    """One filter step's inputs, and the estimator and estimate it stepped from."""

    estimator: object
    estimate: VariantEstimate
    t_s: float
    controls: np.ndarray
    observation: Observation


class RecentSteps:
    """The filter steps of the last :data:`REPLAY_S`, oldest first."""

    def __init__(self, span_s: float = REPLAY_S) -> None:
        self._steps: deque[Step] = deque(maxlen=max(round(span_s / IMU_PERIOD_S), 1))

    def record(self, step: Step) -> None:
        """Keep ``step`` (the oldest kept falls out)."""
        self._steps.append(step)

    def clear(self) -> None:
        """Forget every step (the estimate was restarted: no step leads to it)."""
        self._steps.clear()

    def taken_by(self, estimator: object) -> list[Step]:
        """The latest steps taken, without a break, by ``estimator`` (oldest first)."""
        out: list[Step] = []
        for step in reversed(self._steps):
            if step.estimator is not estimator:
                break
            out.append(step)
        return out[::-1]


def rerun(bank: AircraftEstimator, estimate: VariantEstimate, steps: list[Step]) -> VariantEstimate:
    """``estimate`` of ``bank`` stepped again over ``steps``' inputs.

    A step's controls' sensitivity is of the state of the bank that took it: kept where
    ``bank``'s state has the same layout (a re-run on the same bank is the flight again),
    taken anew about ``estimate``, once, where it grew (two states per declared channel), as
    the service takes it once per servo sample.
    """
    n_states = estimate.filter.mean.shape[0]
    fresh = None
    for step in steps:
        observation = step.observation
        sensitivity = observation.control_sensitivity
        if sensitivity is not None and sensitivity.state.shape[0] != n_states:
            if fresh is None:
                fresh = bank.control_sensitivity(estimate)
            observation = dataclasses.replace(observation, control_sensitivity=fresh)
        estimate = bank.step(estimate, step.t_s, step.controls, observation)
    return estimate
