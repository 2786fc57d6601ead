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
from dataclasses import dataclass, field
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
    sticky_transition,
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
class ImmSettings:
    """IMM tuning: Markov stay probability (eq. 3) and the mode-probability floor."""

    stay_probability: float = 0.99
    probability_floor: float = 1e-4


def aero_process_model(model: AeroModel, noise_cov: np.ndarray | None = None) -> ProcessModel:
    """``x(k+1) = f[x(k), u(k), v(k)]`` (eq. 1): RK4 of the 6-DOF aircraft model."""
    q = model.process_noise_cov() if noise_cov is None else np.asarray(noise_cov, dtype=float)
    # additive form: v held over one step moves velocity and rates by v dt
    dt = model.dt_s
    additive = np.zeros((12, 12))
    vel_rates = [3, 4, 5, 9, 10, 11]
    additive[np.ix_(vel_rates, vel_rates)] = q * dt**2
    return ProcessModel(
        f=model.step,
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
        return model.imu(t_s, x, u)

    def imu_gps(t_s: float, x: np.ndarray, u: np.ndarray, w: np.ndarray | None) -> np.ndarray:
        return np.concatenate([model.imu(t_s, x, u), model.gps(t_s, x, u)])

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

    def initialize(self, t_s: float, mean: np.ndarray, cov: np.ndarray) -> ImmEstimate:
        """Start every mode-matched filter at ``mean``, ``cov``."""
        self.estimate = self.imm.initial_estimate(t_s, mean, cov)
        return self.estimate

    def step(
        self, t_s: float, u: np.ndarray, imu: np.ndarray, gps: np.ndarray | None
    ) -> ImmEstimate:
        """One cycle: controls ``u`` held from the last sample, IMU (and GPS) at ``t_s``."""
        if self.estimate is None:
            raise RuntimeError("initialize() the estimator before step()")
        if gps is None:
            z = Measurement(imu, self.imu_model)
        else:
            z = Measurement(np.concatenate([imu, gps]), self.imu_gps_model)
        self.estimate = self.imm.step(self.estimate, t_s, u, z)
        return self.estimate


def build_aero_estimator(
    variant: Variant,
    model: AeroModel,
    true_mode: FaultMode | None = None,
    noise: SensorNoise | None = None,
    imm_settings: ImmSettings | None = None,
    noise_form: NoiseForm = "augmented",
    kappa: float = 0.0,
) -> AircraftEstimator:
    """UKF-1 (``"ukf1"``, needs ``true_mode``), UKF-2 (``"ukf2"``) or UKF-4 (``"imm"``)."""
    noise = noise if noise is not None else SensorNoise()
    settings = imm_settings if imm_settings is not None else ImmSettings()
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
    ukf = UnscentedKalmanFilter(aero_process_model(model), JulierSigmaPoints(kappa), noise_form)
    transition = sticky_transition(len(modes), settings.stay_probability)
    floor = settings.probability_floor if len(modes) > 1 else 0.0
    imm = ImmEstimator(ukf, transition, floor)
    imu_model, imu_gps_model = aero_measurement_models(model, modes, noise)
    return AircraftEstimator(variant, tuple(modes), imm, imu_model, imu_gps_model)
