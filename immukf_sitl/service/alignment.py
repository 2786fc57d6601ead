"""The navigation solution every filter variant starts from and reports; coarse alignment.

:func:`align` produces the first one in flight, from one IMU sample and one GPS fix.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation


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


def body_to_ned(euler_rad: np.ndarray) -> np.ndarray:
    """``R_nb`` for ZYX Euler angles (docs/conventions.md), via scipy."""
    return Rotation.from_euler("ZYX", np.asarray(euler_rad)[::-1]).as_matrix()


def align(t_s: float, imu: np.ndarray, gps: np.ndarray) -> NavSolution:
    """A coarse in-flight alignment from one IMU sample and one GPS fix.

    Roll and pitch from the specific force of unaccelerated flight (``f = -R_bn g``:
    ``theta = asin(f_x / |f|)``, ``phi = atan2(-f_y, -f_z)``), yaw from the GPS course (no wind,
    small sideslip), NED velocity from ground speed and course (vertical unknown: 0), rates from
    the gyros. The sigmas say how rough that is.
    """
    f = imu[:3]
    g = float(np.linalg.norm(f))
    theta = float(np.arcsin(np.clip(f[0] / g, -1.0, 1.0)))
    phi = float(np.arctan2(-f[1], -f[2]))
    course = float(gps[4])
    speed = float(gps[3])
    return NavSolution(
        t_s,
        np.array(gps[:3], dtype=float),
        np.array([speed * np.cos(course), speed * np.sin(course), 0.0]),
        np.array([phi, theta, course]),
        np.array(imu[3:6], dtype=float),
        np.array([1.0, 1.0, 1.5]),
        np.array([1.0, 1.0, 1.0]),
        np.radians([3.0, 3.0, 5.0]),
        np.full(3, 0.003),  # straight from the gyros
    )
