"""The filter's tuning: process noise of the aerodynamic model and the IMM's Markov chain."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from immukf_sitl.estimation import FaultMode
from immukf_sitl.models.airframe import AirframeUncertainty
from immukf_sitl.models.wind import TURBULENCE_LEVELS


@dataclass(frozen=True)
class FilterTuning:
    """The filter's design: the air and airframe it is built for, and the IMM's Markov chain.

    Process noise of the aircraft model (every number below is a documented quantity, see
    :mod:`immukf_sitl.service.noise_model`):

    - ``process_noise_factor`` scales the IMU noise into the white part of the model's process
      noise ``v`` (accelerations and angular accelerations the slow states do not carry);
    - ``design_turbulence``, ``design_height_m``, ``design_airspeed_mps``: the MIL-F-8785C air
      the wind states are built for (the worst the filter is meant to hold in);
    - ``model_uncertainty``: how far the flown airframe may be from the parameter file (1-sigma
      relative), which sizes the force and moment corrections; ``correction_time_constant_s``
      how fast their error changes with the flight condition;
    - ``initial_wind_sigma_mps``: what is known of the wind at start-up (nothing much).

    The chain (eq. 3) is symmetric and sticky: ``onset_probability`` per step that a sensor
    fails, ``recovery_probability`` per step that a failed one recovers. A mode's posterior odds
    then move only with evidence, and the filter counts a failed channel's evidence only while
    the channel is observable (:class:`~immukf_sitl.estimation.fault_modes.ObservabilityGate`):
    a declared sensor that stays dead keeps its probability through a straight leg, and a sensor
    that recovers is cleared as soon as it reads a value away from zero. From the floor at about
    ``onset``, a fault mode needs ``log(0.9 / onset)`` (16 nats at 1e-7) of evidence to reach the
    detector's threshold; an observable zeroed gyro gives hundreds per step. README, "Detection
    and tuning", has the arithmetic.
    """

    process_noise_factor: float = 10.0
    onset_probability: float = 1e-7
    recovery_probability: float = 1e-7
    probability_floor: float = 1e-9
    design_turbulence: str = "moderate"
    design_height_m: float = 150.0
    design_airspeed_mps: float = 25.0
    model_uncertainty: AirframeUncertainty = field(
        default_factory=lambda: AirframeUncertainty(aero=0.10, mass=0.05, inertia=0.10)
    )
    correction_time_constant_s: float = 10.0
    initial_wind_sigma_mps: float = 10.0
    observability_sigmas: float = 3.0

    def __post_init__(self) -> None:
        if self.design_turbulence not in TURBULENCE_LEVELS:
            raise ValueError(
                f"design_turbulence: expected one of {', '.join(TURBULENCE_LEVELS)}, "
                f"got {self.design_turbulence!r}"
            )
        positive = {
            "process_noise_factor": self.process_noise_factor,
            "design_airspeed_mps": self.design_airspeed_mps,
            "correction_time_constant_s": self.correction_time_constant_s,
            "initial_wind_sigma_mps": self.initial_wind_sigma_mps,
        }
        for name, value in positive.items():
            if not value > 0.0:
                raise ValueError(f"{name}: expected > 0, got {value}")

    def transition(self, modes: Sequence[FaultMode]) -> np.ndarray:
        """``T[i, j] = P(M(k+1)=j | M(k)=i)`` (eq. 3) over ``modes`` (fault-free first)."""
        r = len(modes)
        if r == 1:
            return np.ones((1, 1))
        eps, delta = self.onset_probability, self.recovery_probability
        if not (0 < eps * (r - 1) < 1 and 0 < delta + eps * (r - 2) < 1):
            raise ValueError("onset/recovery probabilities leave no mass to stay in a mode")
        matrix = np.full((r, r), eps)
        healthy = [j for j, m in enumerate(modes) if m.bits == 0]
        for i, mode in enumerate(modes):
            if mode.bits != 0 and healthy:
                matrix[i, healthy[0]] = delta
            matrix[i, i] = 0.0
            matrix[i, i] = 1.0 - matrix[i].sum()
        return matrix
