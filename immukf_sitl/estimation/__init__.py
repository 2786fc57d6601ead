"""Pure numerics of the estimator: sigma points, UKF, IMM and fault modes. No I/O."""

from immukf_sitl.estimation.diagnostics import FilterDiagnostics
from immukf_sitl.estimation.fault_modes import (
    IMU_CHANNELS,
    FaultMode,
    all_fault_modes,
    fault_masked_output,
    single_fault_modes,
)
from immukf_sitl.estimation.imm import ImmEstimate, ImmEstimator, sticky_transition
from immukf_sitl.estimation.models import Measurement, MeasurementModel, ProcessModel
from immukf_sitl.estimation.sigma_points import (
    JulierSigmaPoints,
    ScaledSigmaPoints,
    sigma_points,
    unscented_transform,
)
from immukf_sitl.estimation.ukf import UkfEstimate, UnscentedKalmanFilter

__all__ = [
    "IMU_CHANNELS",
    "FaultMode",
    "FilterDiagnostics",
    "ImmEstimate",
    "ImmEstimator",
    "JulierSigmaPoints",
    "Measurement",
    "MeasurementModel",
    "ProcessModel",
    "ScaledSigmaPoints",
    "UkfEstimate",
    "UnscentedKalmanFilter",
    "all_fault_modes",
    "fault_masked_output",
    "single_fault_modes",
    "sticky_transition",
    "sigma_points",
    "unscented_transform",
]
