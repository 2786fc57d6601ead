"""The paper's filter variants assembled from the aircraft models and the estimation core.

- UKF-1: aerodynamic model, one filter matched to the true fault mode (an oracle);
- UKF-2: aerodynamic model, one filter matched to the fault-free mode;
- UKF-3: strapdown INS equations (IMU as input, GPS as observation), fault-free;
- UKF-4 (``imm``): aerodynamic model, IMM over the 7 single fault modes.

Every variant is driven the same way: :meth:`AircraftEstimator.step` with the controls, the six
IMU channels and, when a fix arrived, the five GPS observables (see ``docs/conventions.md``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from immukf_sitl.estimation import (
    FaultMode,
    ImmEstimate,
    ImmEstimator,
    JulierSigmaPoints,
    Measurement,
    MeasurementModel,
    ProcessModel,
    UnscentedKalmanFilter,
    fault_masked_output,
    single_fault_modes,
)
from immukf_sitl.estimation.ukf import NoiseForm
from immukf_sitl.models.aero import AeroModel

Variant = Literal["ukf1", "ukf2", "ukf3", "imm"]
VARIANTS: tuple[str, ...] = ("ukf1", "ukf2", "ukf3", "imm")
GPS_COURSE_CHANNEL = 4


@dataclass(frozen=True)
class SensorNoise:
    """Standard deviations the filters assume (Beard & McLain ch. 7, DESIGN.md section 6)."""

    accel_mps2: float = 0.0245
    gyro_radps: float = 0.00227
    gps_horizontal_m: float = 0.21
    gps_vertical_m: float = 0.40
    gps_speed_mps: float = 0.05
    #: course sigma is 0.05 / Vg rad; the filter uses the value at a nominal ground speed
    gps_course_rad: float = 0.05 / 20.0

    def imu_cov(self) -> np.ndarray:
        """``R`` of the six IMU channels."""
        return np.diag([self.accel_mps2**2] * 3 + [self.gyro_radps**2] * 3)

    def gps_cov(self) -> np.ndarray:
        """``R`` of the five GPS observables."""
        return np.diag(
            [
                self.gps_horizontal_m**2,
                self.gps_horizontal_m**2,
                self.gps_vertical_m**2,
                self.gps_speed_mps**2,
                self.gps_course_rad**2,
            ]
        )


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
    fault that shows (a true value a few sigma from zero) wins within a few steps.
    """

    process_noise_factor: float = 10.0
    onset_probability: float = 1e-4
    recovery_probability: float = 0.05
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


def aero_process_model(
    model: AeroModel, noise: SensorNoise | None = None, tuning: FilterTuning | None = None
) -> ProcessModel:
    """``x(k+1) = f[x(k), u(k), v(k)]`` (eq. 1): RK4 of the 6-DOF aircraft model.

    ``v`` is additive on the body and angular accelerations, with standard deviations
    ``tuning.process_noise_factor`` times the accelerometer (m/s^2) and gyro (rad/s, read as
    rad/s^2) noise. The filter's control argument is the pair ``[u(k), u(k+1)]`` (shape (2, 4)):
    ``f`` flies the step on ``u(k)``, the output model predicts the IMU at ``k+1`` with
    ``u(k+1)`` (the specific force depends on the surfaces and throttle acting at the sample).
    """
    noise = noise if noise is not None else SensorNoise()
    tuning = tuning if tuning is not None else FilterTuning()
    sigma = tuning.process_noise_factor * np.array([noise.accel_mps2] * 3 + [noise.gyro_radps] * 3)
    q = np.diag(sigma**2)
    # additive form: v held over one step moves velocity and rates by v dt
    dt = model.dt_s
    additive = np.zeros((12, 12))
    vel_rates = [3, 4, 5, 9, 10, 11]
    additive[np.ix_(vel_rates, vel_rates)] = q * dt**2

    def f(t_s: float, x: np.ndarray, u: np.ndarray, v: np.ndarray | None) -> np.ndarray:
        return model.step(t_s, x, u[0], v)

    return ProcessModel(
        f=f,
        nx=12,
        noise_cov=q,
        additive_noise_cov=additive,
        angle_idx=model.angle_indices,
    )


def aero_measurement_models(
    model: AeroModel, modes: Sequence[FaultMode], noise: SensorNoise
) -> tuple[MeasurementModel, MeasurementModel]:
    """Mode-batched output models (eq. 2): IMU alone, and IMU followed by GPS."""

    def imu(t_s: float, x: np.ndarray, u: np.ndarray, w: np.ndarray | None) -> np.ndarray:
        return model.imu(t_s, x, u[1])

    def imu_gps(t_s: float, x: np.ndarray, u: np.ndarray, w: np.ndarray | None) -> np.ndarray:
        return np.concatenate([model.imu(t_s, x, u[1]), model.gps(t_s, x, u[1])])

    imu_only = MeasurementModel(fault_masked_output(imu, modes), noise.imu_cov(), name="imu")
    gps_cov = np.zeros((11, 11))
    gps_cov[:6, :6] = noise.imu_cov()
    gps_cov[6:, 6:] = noise.gps_cov()
    with_gps = MeasurementModel(
        fault_masked_output(imu_gps, modes, n_extra=5),
        gps_cov,
        angle_idx=(6 + GPS_COURSE_CHANNEL,),
        name="imu+gps",
    )
    return imu_only, with_gps


@dataclass
class AircraftEstimator:
    """A bank of mode-matched UKFs over the aerodynamic model (one mode for UKF-1/UKF-2).

    Use :func:`build_aero_estimator`; then :meth:`initialize` and :meth:`step` once per IMU
    sample.
    """

    variant: str
    modes: tuple[FaultMode, ...]
    imm: ImmEstimator
    imu_model: MeasurementModel
    imu_gps_model: MeasurementModel
    estimate: ImmEstimate | None = field(default=None)
    _controls: np.ndarray = field(default_factory=lambda: np.zeros(4), repr=False)

    def initialize(
        self, t_s: float, mean: np.ndarray, cov: np.ndarray, controls: np.ndarray
    ) -> ImmEstimate:
        """Start every mode-matched filter at ``mean``, ``cov``; ``controls`` act from ``t_s``."""
        self.estimate = self.imm.initial_estimate(t_s, mean, cov)
        self._controls = np.array(controls, dtype=float)
        return self.estimate

    def step(
        self, t_s: float, controls: np.ndarray, imu: np.ndarray, gps: np.ndarray | None
    ) -> ImmEstimate:
        """Advance to the sample at ``t_s``.

        Parameters
        ----------
        t_s : float
            Time of the IMU sample (s).
        controls : ndarray, shape (4,)
            ``[delta_e, delta_a, delta_r, delta_t]`` acting from ``t_s``; the step from the
            previous sample flies on the previous call's controls.
        imu : ndarray, shape (6,)
            ``[f_x, f_y, f_z, p, q, r]`` at ``t_s``.
        gps : ndarray, shape (5,), or None
            ``[pN, pE, pD, ground speed, course]`` when a fix is due at ``t_s``.
        """
        if self.estimate is None:
            raise RuntimeError("initialize() the estimator before step()")
        if gps is None:
            z = Measurement(imu, self.imu_model)
        else:
            z = Measurement(np.concatenate([imu, gps]), self.imu_gps_model)
        controls = np.asarray(controls, dtype=float)
        pair = np.stack([self._controls, controls])
        self.estimate = self.imm.step(self.estimate, self.estimate.t_s, pair, z)
        self.estimate = replace(self.estimate, t_s=t_s)
        self._controls = controls
        return self.estimate


def build_aero_estimator(
    variant: Variant,
    model: AeroModel,
    true_mode: FaultMode | None = None,
    noise: SensorNoise | None = None,
    tuning: FilterTuning | None = None,
    noise_form: NoiseForm = "augmented",
    kappa: float = 0.0,
) -> AircraftEstimator:
    """UKF-1 (``"ukf1"``, needs ``true_mode``), UKF-2 (``"ukf2"``) or UKF-4 (``"imm"``)."""
    noise = noise if noise is not None else SensorNoise()
    tuning = tuning if tuning is not None else FilterTuning()
    if variant == "imm":
        modes = single_fault_modes()
    elif variant == "ukf1":
        if true_mode is None:
            raise ValueError("UKF-1 is matched to the true mode: pass true_mode")
        modes = (true_mode,)
    elif variant == "ukf2":
        modes = (FaultMode(0),)
    else:
        raise ValueError(f"not an aerodynamic-model variant: {variant!r}")
    process = aero_process_model(model, noise, tuning)
    ukf = UnscentedKalmanFilter(process, JulierSigmaPoints(kappa), noise_form)
    transition = tuning.transition(modes)
    floor = tuning.probability_floor if len(modes) > 1 else 0.0
    imm = ImmEstimator(ukf, transition, floor)
    imu_model, imu_gps_model = aero_measurement_models(model, modes, noise)
    return AircraftEstimator(variant, tuple(modes), imm, imu_model, imu_gps_model)
