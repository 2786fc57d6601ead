"""What kind of vehicle a log or stream comes from, and the refusal of what is not fixed-wing.

The estimator's models are fixed-wing aircraft (6-DOF rigid body with wing aerodynamics): a
multicopter's IMU stream would fly through the same filter and every mode would be wrong at
once. A log says what flew in one of three ways, each read by its own reader into
:attr:`immukf_sitl.mavlink.flightlog.FlightLog.vehicle`: a MAVLink HEARTBEAT's ``type``
(MAV_TYPE), ArduPilot's firmware string (``ArduPlane V4.5.7``) and PX4's ``vehicle_status``.
"""

from __future__ import annotations

from immukf_sitl.errors import UserError

FIXED_WING = "fixed-wing"
MULTICOPTER = "multicopter"
HELICOPTER = "helicopter"

#: MAV_TYPE values (MAVLink common) of vehicles, by class; a type not here (a ground station,
#: a gimbal, an onboard computer, this estimator) says nothing about the vehicle
_MAV_TYPE_CLASSES: dict[int, str] = {
    1: FIXED_WING,  # FIXED_WING
    2: MULTICOPTER,  # QUADROTOR
    3: HELICOPTER,  # COAXIAL
    4: HELICOPTER,  # HELICOPTER
    7: "airship",
    8: "balloon",
    9: "rocket",
    10: "ground rover",
    11: "surface boat",
    12: "submarine",
    13: MULTICOPTER,  # HEXAROTOR
    14: MULTICOPTER,  # OCTOROTOR
    15: MULTICOPTER,  # TRICOPTER
    16: "flapping wing",
    17: "kite",
    19: FIXED_WING,  # VTOL_DUOROTOR (a VTOL plane flies its wings in cruise)
    20: FIXED_WING,  # VTOL_QUADROTOR
    21: FIXED_WING,  # VTOL_TILTROTOR
    22: FIXED_WING,  # VTOL_RESERVED2 (fixed rotor)
    23: FIXED_WING,  # VTOL_RESERVED3 (tailsitter)
    24: FIXED_WING,  # VTOL_RESERVED4 (tilt wing)
    25: FIXED_WING,  # VTOL_RESERVED5
    28: "parafoil",
    29: MULTICOPTER,  # DODECAROTOR
    35: MULTICOPTER,  # DECAROTOR
    43: MULTICOPTER,  # GENERIC_MULTIROTOR
    46: "ground quadruped",
    47: FIXED_WING,  # VTOL_GYRODYNE
}

#: ArduPilot's firmware names, as its logs and STATUSTEXT give them (``ArduPlane V4.5.7``)
_ARDUPILOT_FIRMWARE: dict[str, str] = {
    "arduplane": FIXED_WING,
    "arducopter": MULTICOPTER,
    "ardusub": "submarine",
    "ardurover": "ground rover",
    "rover": "ground rover",
    "antennatracker": "antenna tracker",
    "blimp": "airship",
    "heli": HELICOPTER,
}


def vehicle_of_mav_type(mav_type: int) -> str | None:
    """The vehicle class of a HEARTBEAT ``type``; None for a type that is not a vehicle."""
    return _MAV_TYPE_CLASSES.get(int(mav_type))


def vehicle_of_firmware(text: str) -> str | None:
    """The vehicle class named by an ArduPilot firmware string, or None if it names none.

    ``ArduCopter V4.5.1 (...)`` is a multicopter (a traditional-helicopter build says
    ``heli`` in its string), ``ArduPlane V4.5.7`` fixed-wing.
    """
    words = text.strip().lower().split()
    if not words:
        return None
    found = _ARDUPILOT_FIRMWARE.get(words[0])
    if found == MULTICOPTER and "heli" in text.lower():
        return HELICOPTER
    return found


def require_fixed_wing(source: str, vehicle: str | None, evidence: str) -> None:
    """Refuse, in one line, a log or stream that says it is not a fixed-wing aircraft.

    Parameters
    ----------
    source : str
        The log's path or the link, for the message.
    vehicle : str or None
        What the log says flew (None: it does not say, and it is taken as fixed-wing).
    evidence : str
        Where that came from, e.g. ``HEARTBEAT type QUADROTOR``.

    Raises
    ------
    UserError
        For any vehicle class but fixed-wing.
    """
    if vehicle is None or vehicle == FIXED_WING:
        return
    article = "an" if vehicle[0] in "aeiou" else "a"
    raise UserError(
        f"{source}: this is {article} {vehicle} log ({evidence}): this tool models fixed-wing "
        "aircraft"
    )
