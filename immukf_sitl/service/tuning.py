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

    ``sigma_point_alpha``: None draws the paper's sigma points (Julier, ``kappa = 0``: at
    ``sqrt(n)`` sigma, 6 sigma for 33 augmented dimensions); a value draws scaled points at
    ``alpha sqrt(n)`` sigma (van der Merwe), which keeps them where the aerodynamics are smooth
    when a sigma is large (the real-air model's initial wind, 10 m/s: Julier points probe
    60 m/s of wind). ``consider_states`` names slow-state groups kept as Schmidt consider
    states (:class:`~immukf_sitl.estimation.models.ProcessModel`): their uncertainty is
    accounted for, their mean never estimated.

    ``slow_states`` chooses the model: False is the paper's (the 12 rigid-body states, still
    air, exact sensors and airframe), True the real-air model (18 more states: wind,
    gyro biases, force and moment corrections, GPS error; :mod:`immukf_sitl.models.augmented`),
    which also scores a failed channel only while it is observable
    (:class:`~immukf_sitl.estimation.fault_modes.ObservabilityGate`). :meth:`real_air` is that
    model with its chain, scaled sigma points (alpha 0.01) and the GPS error as consider
    states: the receiver's error and the position are told apart only by the dynamics, so an
    estimated error absorbed every vertical model error (the position drifted 100 m while the
    error state, 10 sigma off its own prior, held the difference).

    ``adaptive_turbulence`` (real-air model only): the design air is the roughest the filter
    holds in, not the air it flies in; the turbulence states' noise is scaled in flight to the
    air the innovations show, between ``turbulence_floor`` and 1 times the design's sigmas,
    averaged over ``turbulence_averaging_s`` (:mod:`immukf_sitl.service.turbulence`).

    ``initial_fault_probability``: each fault mode's probability when the bank starts; None
    takes the chain's stationary distribution (the paper's chain: 4e-4 per fault mode). The
    real-air chain is symmetric, so its stationary distribution is uniform: 1/7 per mode, a
    6-in-7 belief that some sensor is dead at power-on. While the filters converged from the
    alignment, one fault mode then led (the p mode at 1.0 for 2 s on a calm flight), the
    combined estimate was that mode's, and the post-settling re-seed took it: the IMM's
    attitude MSE was 1.37 times UKF-2's on the very same flight. The real-air preset starts
    every fault mode at its onset probability: a sensor dead at power-on is found the way one
    that dies in flight is.

    The paper model's chain is asymmetric on purpose. ``onset_probability`` is the chance per
    step that the fault-free system develops a given fault; ``recovery_probability`` the chance
    per step that a faulty mode hands back to fault-free. Whatever edge an unobservable fault
    mode keeps, a recovery probability above it bounds its posterior odds near
    ``onset / recovery``, while a fault that shows (a true value a few sigma from zero) wins
    within a few steps. Measured on the default flight (seed 3, 30 s of fault-free flight
    after settling): recovery 0.05 let the p mode reach 0.95 on the straight first leg, 0.15
    kept every fault mode below 0.26, 0.25 below 0.07, while zeroed x, y, z, p, q, r gyros were
    still declared within 0.13 s of becoming observable. The probabilities then measure the
    current excitation; what makes a declaration mean "failed" is the detector's latch
    (:mod:`immukf_sitl.service.detection`). The real-air chain is symmetric and sticky
    (1e-7 both ways): with the gate, a mode's odds move only with evidence.
    """

    process_noise_factor: float = 10.0
    onset_probability: float = 1e-4
    recovery_probability: float = 0.25
    probability_floor: float = 1e-6
    slow_states: bool = False
    design_turbulence: str = "moderate"
    design_height_m: float = 150.0
    design_airspeed_mps: float = 25.0
    model_uncertainty: AirframeUncertainty = field(
        default_factory=lambda: AirframeUncertainty(aero=0.10, mass=0.05, inertia=0.10)
    )
    correction_time_constant_s: float = 10.0
    initial_wind_sigma_mps: float = 10.0
    observability_sigmas: float = 3.0
    sigma_point_alpha: float | None = None
    consider_states: tuple[str, ...] = ()
    initial_fault_probability: float | None = None
    adaptive_turbulence: bool = True
    turbulence_floor: float = 0.1
    turbulence_averaging_s: float = 10.0

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
            "turbulence_averaging_s": self.turbulence_averaging_s,
        }
        for name, value in positive.items():
            if not value > 0.0:
                raise ValueError(f"{name}: expected > 0, got {value}")
        p0 = self.initial_fault_probability
        if p0 is not None and not 0.0 < p0 < 0.1:
            raise ValueError(f"initial_fault_probability: expected in (0, 0.1), got {p0}")
        if not 0.0 < self.turbulence_floor <= 1.0:
            raise ValueError(f"turbulence_floor: expected in (0, 1], got {self.turbulence_floor}")

    @classmethod
    def real_air(cls, **changes: object) -> FilterTuning:
        """The real-air model (slow states, observability gate) with its sticky chain."""
        preset: dict[str, object] = {
            "slow_states": True,
            "onset_probability": 1e-7,
            "recovery_probability": 1e-7,
            "probability_floor": 1e-9,
            "sigma_point_alpha": 0.01,
            "consider_states": ("gps_error",),
            "initial_fault_probability": 1e-7,
        }
        preset.update(changes)
        return cls(**preset)  # type: ignore[arg-type]

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
