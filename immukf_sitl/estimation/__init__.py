"""Pure numerics: sigma points, UKF (eqs. 9-25), IMM (eqs. 6-8, 26-28) and fault modes.

One job: filter arrays. Imports numpy, scipy and numba only; nothing else of the project, no
I/O, no MAVLink, no aircraft (the models come in as functions, ``docs/conventions.md``).
"""

from immukf_sitl.estimation.diagnostics import FilterDiagnostics
from immukf_sitl.estimation.fault_modes import (
    FAULT_SIGNATURES,
    IMU_CHANNELS,
    ChannelOffset,
    DeadOrAnyEvidence,
    FaultMode,
    ObservabilityGate,
    all_fault_modes,
    bank_modes,
    failure_marginals,
    fault_mode_noise_var,
    fault_mode_output,
    single_fault_modes,
)
from immukf_sitl.estimation.imm import ImmEstimate, ImmEstimator, sticky_transition
from immukf_sitl.estimation.models import Measurement, MeasurementModel, ProcessModel, SampleGate
from immukf_sitl.estimation.sigma_points import (
    JulierSigmaPoints,
    ScaledSigmaPoints,
    sigma_points,
    unscented_transform,
)
from immukf_sitl.estimation.symmetry import StateSymmetry
from immukf_sitl.estimation.ukf import UkfEstimate, UnscentedKalmanFilter

__all__ = [
    "ObservabilityGate",
    "DeadOrAnyEvidence",
    "ChannelOffset",
    "IMU_CHANNELS",
    "FaultMode",
    "FilterDiagnostics",
    "ImmEstimate",
    "ImmEstimator",
    "JulierSigmaPoints",
    "Measurement",
    "MeasurementModel",
    "ProcessModel",
    "SampleGate",
    "StateSymmetry",
    "ScaledSigmaPoints",
    "UkfEstimate",
    "UnscentedKalmanFilter",
    "all_fault_modes",
    "bank_modes",
    "failure_marginals",
    "FAULT_SIGNATURES",
    "fault_mode_noise_var",
    "fault_mode_output",
    "single_fault_modes",
    "sticky_transition",
    "sigma_points",
    "unscented_transform",
]
