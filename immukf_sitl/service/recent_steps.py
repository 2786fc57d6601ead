"""The last half second of filter steps, so that a re-based bank is re-run from its failure.

A declaration re-bases the bank on the new declared set
(:mod:`immukf_sitl.service.declared_set`) 0.2 s, the dwell, after the failing slot took the
lead. Over that dwell the slot that becomes the new base read every other channel as healthy.
A second channel that failed in the same instant (two biases at once) has been followed by
that slot's rate and gust states, so the re-based slot that leaves it out pays for its
unknown offset at every sample and never leads: on the pairs campaign's calm x+r biases the
r gyro was never declared and the pitch drifted by 7 deg. Re-run over the same inputs from
the step at which the declared failure took the lead, the re-based bank sees the second
channel fail as a first bank sees a first failure. Not from further back, before the
declared channel failed: re-run from 0.5 s back, the pairs campaign's second biases 10 s
after the first were flown with the attitude lost more often after the first declaration
(median MSE 0.48 -> 4.2 deg^2; not traced). And the re-run is kept only where it shows a
second failure (the service's ``_rebase``): kept at every declaration, the same runs that
declared the same channels at the same times, four of 33 more than doubled their attitude
MSE after the first declaration (a calm p+q 0.29 -> 5.2 deg^2; a moderate z+r 2.1 -> 388,
lost; not traced either).

``REPLAY_S`` (0.5 s) bounds the re-run: the dwell, and the wait of a lead whose channel's
failure tests pass later; about 20 of the real-air bank's steps are re-run at a declaration.
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from immukf_sitl.models.sensors import IMU_PERIOD_S
from immukf_sitl.service.filters import AircraftEstimator, Observation, VariantEstimate

#: how far back a declaration may re-run the re-based bank (s)
REPLAY_S = 0.5
#: sample times closer than this are one instant (sums of steps, off by ~1e-12 s)
_EDGE_S = 1e-6


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

    def taken_by(self, estimator: object, since_s: float = -math.inf) -> list[Step]:
        """The latest steps from ``since_s`` on, taken without a break by ``estimator``."""
        out: list[Step] = []
        for step in reversed(self._steps):
            if step.estimator is not estimator or step.t_s < since_s - _EDGE_S:
                break
            out.append(step)
        return out[::-1]


def rerun(
    bank: AircraftEstimator, estimate: VariantEstimate, steps: list[Step]
) -> tuple[VariantEstimate, np.ndarray]:
    """``estimate`` of ``bank`` stepped again over ``steps``' inputs, and each slot's evidence.

    The evidence is each slot's log-likelihoods (eq. 25) summed over the re-run's updated
    steps, less the base's: ``(r,)``. A step's controls' sensitivity is of the state of the
    bank that took it: kept where ``bank``'s state has the same layout (a re-run on the same
    bank is the flight again), taken anew about ``estimate``, once, where it grew (two states
    per declared channel), as the service takes it once per servo sample.
    """
    n_states = estimate.filter.mean.shape[0]
    evidence = np.zeros(len(bank.modes))
    fresh = None
    for step in steps:
        observation = step.observation
        sensitivity = observation.control_sensitivity
        if sensitivity is not None and sensitivity.state.shape[0] != n_states:
            if fresh is None:
                fresh = bank.control_sensitivity(estimate)
            observation = dataclasses.replace(observation, control_sensitivity=fresh)
        estimate = bank.step(estimate, step.t_s, step.controls, observation)
        if estimate.filter.updated:
            evidence += estimate.filter.log_likelihoods - estimate.filter.log_likelihoods[0]
    return estimate, evidence
