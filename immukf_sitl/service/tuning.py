"""The filter's tuning: process noise of the aerodynamic model and the IMM's Markov chain."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from immukf_sitl.estimation import FaultMode


@dataclass(frozen=True)
class FilterTuning:
    """Process noise of the aerodynamic model and the IMM's Markov chain (eq. 3).

    ``process_noise_factor`` scales the IMU noise into the model's process noise ``v``: the
    paper (section 3) uses two orders of magnitude; this project's model reproduces the JSBSim
    aircraft far better than that (``immukf-sitl validate-model``), and an over-wide ``Q``
    makes the fault-free filter's predictions of near-zero channels (p, q, r, y in steady
    flight) more uncertain than a zeroed channel's, which hands the fault modes a likelihood
    edge every step. Ten times the IMU noise is the measured compromise (see README).

    The chain is asymmetric on purpose. ``onset_probability`` is the chance per step that the
    fault-free system develops a given fault; ``recovery_probability`` the chance per step that
    a faulty mode hands back to fault-free. Whatever edge an unobservable fault mode keeps, a
    recovery probability above it bounds its posterior odds near ``onset / recovery``, while a
    fault that shows (a true value a few sigma from zero) wins within a few steps. Measured on
    the default flight (seed 3, 30 s of fault-free flight after settling): recovery 0.05 let
    the p mode reach 0.95 on the straight first leg, 0.15 kept every fault mode below 0.26,
    0.25 below 0.07, while zeroed x, y, z, p, q, r gyros were still declared within 0.13 s of
    becoming observable.
    """

    process_noise_factor: float = 10.0
    onset_probability: float = 1e-4
    recovery_probability: float = 0.25
    probability_floor: float = 1e-6

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
