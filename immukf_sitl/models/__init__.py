"""Aircraft parameters, the 6-DOF aerodynamic model, INS mechanisation and the WGS-84 earth.

Conventions (state, control, noise, array layout): ``docs/conventions.md``.
"""

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
    "AircraftParams",
    "AircraftParamsError",
    "Geometry",
    "MassProperties",
    "Propulsion",
    "ServoChannel",
    "ThrottleChannel",
    "default_params_path",
    "load_aircraft_params",
]
