"""The navigation solution every filter variant starts from and reports; coarse alignment.

:func:`align` produces the first one in flight, from one IMU sample and one GPS fix.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class NavSolution:
    """A navigation state every variant can start from and report (NED about the origin).

    Attributes
    ----------
    t_s : float
    position_ned_m, velocity_ned_mps : ndarray, shape (3,)
    euler_rad : ndarray, shape (3,)
        Roll, pitch, yaw (ZYX).
    rates_radps : ndarray, shape (3,)
        Body rates p, q, r.
    position_sigma_m, velocity_sigma_mps, euler_sigma_rad, rates_sigma_radps : ndarray
        One-sigma uncertainties of the same (diagonal of the covariance).
    wind_ned_mps : ndarray, shape (3,), or None
        The estimated wind (NED, where it blows to) of a variant that estimates it (the
        real-air model); None for one that assumes still air.
    """

    t_s: float
    position_ned_m: np.ndarray
    velocity_ned_mps: np.ndarray
    euler_rad: np.ndarray
    rates_radps: np.ndarray
    position_sigma_m: np.ndarray
    velocity_sigma_mps: np.ndarray
    euler_sigma_rad: np.ndarray
    rates_sigma_radps: np.ndarray
    wind_ned_mps: np.ndarray | None = None


#: Specific force of unaccelerated flight differs from gravity by less than this fraction; an
#: accelerometer triad further off has a dead channel (or the aircraft is manoeuvring hard).
GRAVITY_TOLERANCE = 0.3
#: Gravity used to rebuild a dead accelerometer channel (m/s^2).
STANDARD_GRAVITY_MPS2 = 9.80665


def dead_accelerometer(specific_force_mps2: np.ndarray) -> int | None:
    """The accelerometer channel that reads zero when the triad cannot be gravity, else None.

    In unaccelerated flight the accelerometers read ``-R_bn g``: a norm near ``g``. A zeroed
    channel whose true value is large (z in level flight reads -9.8) breaks that. Each channel
    is tried as the dead one, rebuilt (:func:`_rebuilt_gravity`), and the one giving the
    attitude nearest upright and level wins. A zeroed channel whose true value is small breaks
    nothing, and the full triad's attitude is still right.
    """
    f = np.asarray(specific_force_mps2, dtype=float)
    norm = float(np.linalg.norm(f))
    if abs(norm - STANDARD_GRAVITY_MPS2) <= GRAVITY_TOLERANCE * STANDARD_GRAVITY_MPS2:
        return None
    best, best_tilt = None, np.inf
    for channel in range(3):
        rebuilt = _rebuilt_gravity(f, channel)
        g = float(np.linalg.norm(rebuilt))
        if abs(g - STANDARD_GRAVITY_MPS2) > GRAVITY_TOLERANCE * STANDARD_GRAVITY_MPS2:
            continue  # this channel's true value cannot make up the missing gravity
        tilt = abs(np.arcsin(np.clip(rebuilt[0] / g, -1.0, 1.0))) + abs(
            np.arctan2(-rebuilt[1], -rebuilt[2])
        )
        if tilt < best_tilt:
            best, best_tilt = channel, tilt
    return best


def _rebuilt_gravity(f: np.ndarray, dead: int) -> np.ndarray:
    """``f`` with the dead channel rebuilt as unaccelerated, upright, coordinated flight reads it.

    ``f_y`` is 0 (coordinated flight: no side force); ``f_z`` and ``f_x`` take what makes
    ``|f| = g``, ``f_z`` negative (upright) and ``f_x`` positive (nose above the horizon by
    about the angle of attack: the pitch of level flight).
    """
    rebuilt = f.copy()
    if dead == 1:
        rebuilt[1] = 0.0
        return rebuilt
    rest = float(np.sum(np.delete(f, dead) ** 2))
    magnitude = float(np.sqrt(max(STANDARD_GRAVITY_MPS2**2 - rest, 0.0)))
    rebuilt[dead] = -magnitude if dead == 2 else magnitude
    return rebuilt


def align(
    t_s: float,
    imu: np.ndarray,
    gps: np.ndarray,
    failed_channels: tuple[str, ...] = (),
) -> NavSolution:
    """A coarse in-flight alignment from one IMU sample and one GPS fix.

    Roll and pitch from the specific force of unaccelerated flight (``f = -R_bn g``:
    ``theta = asin(f_x / |f|)``, ``phi = atan2(-f_y, -f_z)``), yaw from the GPS course (no wind,
    small sideslip), NED velocity from ground speed and course (vertical unknown: 0), rates from
    the gyros. The sigmas say how rough that is: roll and pitch at least the angle the
    centripetal acceleration ``V |omega|`` the gyros show makes with gravity.

    A channel in ``failed_channels`` (the IMM's declared fault, ``x``...``r``) is not trusted,
    and neither is an accelerometer triad that cannot be gravity (:func:`dead_accelerometer`,
    at start-up nothing is declared yet): a dead accelerometer is rebuilt from ``|f| = g`` on
    the upright branch, a dead gyro's rate starts at zero with a sigma of a manoeuvre's rate.
    """
    f = np.array(imu[:3], dtype=float)
    rates = np.array(imu[3:6], dtype=float)
    euler_sigma = np.radians([3.0, 3.0, 5.0])
    rates_sigma = np.full(3, 0.003)  # straight from the gyros
    dead = [i for i, c in enumerate("xyz") if c in failed_channels]
    detected = dead_accelerometer(f)
    if not dead and detected is not None:
        dead = [detected]
    for i in dead[:1]:  # the IMM's modes have one failed channel
        f = _rebuilt_gravity(f, i)
        euler_sigma = np.radians([10.0, 10.0, 5.0])  # the upright-and-level guess
    for i, c in enumerate("pqr"):
        if c in failed_channels:
            rates[i] = 0.0
            rates_sigma[i] = 0.2
    g = float(np.linalg.norm(f))
    theta = float(np.arcsin(np.clip(f[0] / g, -1.0, 1.0)))
    phi = float(np.arctan2(-f[1], -f[2]))
    course = float(gps[4])
    speed = float(gps[3])
    # in a turn or pull-up the specific force is not gravity: it is off by the centripetal
    # acceleration V |omega|, so roll and pitch are no better than atan(V |omega| / g)
    turning = float(np.arctan2(speed * np.linalg.norm(rates), STANDARD_GRAVITY_MPS2))
    euler_sigma[:2] = np.maximum(euler_sigma[:2], turning)
    return NavSolution(
        t_s,
        np.array(gps[:3], dtype=float),
        np.array([speed * np.cos(course), speed * np.sin(course), 0.0]),
        np.array([phi, theta, course]),
        rates,
        np.array([1.0, 1.0, 1.5]),
        np.array([1.0, 1.0, 1.0]),
        euler_sigma,
        rates_sigma,
    )
