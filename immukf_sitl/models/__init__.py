"""Aircraft parameters, the 6-DOF aerodynamic model, INS mechanisation and the WGS-84 earth.

Conventions (state, control, noise, array layout): ``docs/conventions.md``.
"""

from immukf_sitl.models.aero import (
    AeroModel,
    drag_coefficient,
    lift_coefficient,
    propeller_thrust_torque,
    stall_blend_sigma,
)
from immukf_sitl.models.earth import (
    NedOrigin,
    geodetic_to_ned,
    isa_density_kgpm3,
    ned_to_geodetic,
    normal_gravity_mps2,
)
from immukf_sitl.models.ins import InsModel
from immukf_sitl.models.params import (
    Actuators,
    AeroCoefficients,
    AircraftParams,
    AircraftParamsError,
    Geometry,
    MassProperties,
    Propulsion,
    ServoChannel,
    ThrottleChannel,
    default_params_path,
    load_aircraft_params,
)

__all__ = [
    "Actuators",
    "AeroCoefficients",
    "AeroModel",
    "AircraftParams",
    "AircraftParamsError",
    "Geometry",
    "InsModel",
    "MassProperties",
    "NedOrigin",
    "Propulsion",
    "ServoChannel",
    "ThrottleChannel",
    "default_params_path",
    "drag_coefficient",
    "geodetic_to_ned",
    "isa_density_kgpm3",
    "lift_coefficient",
    "load_aircraft_params",
    "ned_to_geodetic",
    "normal_gravity_mps2",
    "propeller_thrust_torque",
    "stall_blend_sigma",
]
