"""Records of the truth simulation, free of JSBSim: initial conditions, trim, the true state.

The autopilot, the sensor models and the experiments read these; only :mod:`sim.driver` talks
to JSBSim. Frames and units follow ``docs/conventions.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from immukf_sitl.samples import TruthSample

__all__ = ["InitialConditions", "TrimResult", "TruthState"]


@dataclass(frozen=True)
class InitialConditions:
    """Where and how the flight starts (steady, wings-level, straight and level after trim).

    Attributes
    ----------
    lat_deg, lon_deg : float
        Geodetic latitude and longitude of the start (WGS-84, deg); also the NED origin.
    alt_m : float
        Height above the WGS-84 ellipsoid (m); the NED origin's height.
    airspeed_mps : float
        True airspeed (m/s).
    heading_rad : float
        True heading psi (rad, 0 = north, clockwise positive).
    """

    lat_deg: float = 47.3977
    lon_deg: float = 8.5456
    alt_m: float = 150.0
    airspeed_mps: float = 25.0
    heading_rad: float = 0.0

    def __post_init__(self) -> None:
        if not -85.0 <= self.lat_deg <= 85.0:
            raise ValueError(f"lat_deg: expected a latitude within +-85 deg, got {self.lat_deg}")
        if not 10.0 <= self.airspeed_mps <= 60.0:
            raise ValueError(
                f"airspeed_mps: expected 10..60 m/s for this airframe, got {self.airspeed_mps}"
            )
        if not -400.0 <= self.alt_m <= 10000.0:
            raise ValueError(f"alt_m: expected -400..10000 m, got {self.alt_m}")


@dataclass(frozen=True)
class TrimResult:
    """Steady, wings-level, straight and level flight found on the JSBSim aircraft.

    Attributes
    ----------
    controls : numpy.ndarray
        ``(4,)`` ``[delta_e, delta_a, delta_r (rad), delta_t (0..1)]`` (docs/conventions.md).
    alpha_rad, beta_rad, theta_rad : float
        Angle of attack, sideslip and pitch at trim (theta = alpha in level flight).
    residual_accel_mps2 : float
        Largest remaining body acceleration ``|(u, v, w)_dot|`` (m/s^2) at trim.
    residual_angular_accel_radps2 : float
        Largest remaining ``|(p, q, r)_dot|`` (rad/s^2) at trim.
    """

    controls: np.ndarray
    alpha_rad: float
    beta_rad: float
    theta_rad: float
    residual_accel_mps2: float
    residual_angular_accel_radps2: float


@dataclass(frozen=True)
class TruthState:
    """The true state of the aircraft at one step (read-only arrays).

    Attributes
    ----------
    time_s : float
        Simulation time (s) since the initial conditions.
    lat_deg, lon_deg : float
        Geodetic latitude and longitude (WGS-84, deg).
    alt_m : float
        Height above the WGS-84 ellipsoid (m).
    position_ned_m : numpy.ndarray
        ``(3,)`` position north, east, down (m) about the driver's origin.
    velocity_ned_mps : numpy.ndarray
        ``(3,)`` velocity relative to the earth in NED (m/s).
    velocity_body_mps : numpy.ndarray
        ``(3,)`` the same velocity in body FRD axes ``(u, v, w)`` (m/s).
    euler_rad : numpy.ndarray
        ``(3,)`` roll, pitch, yaw ``(phi, theta, psi)`` (rad, ZYX, psi in (-pi, pi]).
    rates_body_radps : numpy.ndarray
        ``(3,)`` INERTIAL body rates ``(p, q, r)`` (rad/s) — what a gyro measures
        (``velocities/{pi,qi,ri}-rad_sec``; the earth-relative rates differ by the earth rate).
    airspeed_mps, alpha_rad, beta_rad : float
        True airspeed (m/s), angle of attack and sideslip (rad).
    specific_force_body_mps2 : numpy.ndarray
        ``(3,)`` specific force at the IMU in body FRD (m/s^2), from this step's forces: about
        ``(0, 0, -9.8)`` in level flight.
    controls : numpy.ndarray
        ``(4,)`` ``[delta_e, delta_a, delta_r (rad), delta_t (0..1)]`` acting at this step
        (after JSBSim's clipping to the surface limits).
    wind_ned_mps : numpy.ndarray
        ``(3,)`` total wind the aircraft feels, steady plus turbulence, NED (m/s), from
        ``atmosphere/total-wind-{north,east,down}-fps``.
    """

    time_s: float
    lat_deg: float
    lon_deg: float
    alt_m: float
    position_ned_m: np.ndarray
    velocity_ned_mps: np.ndarray
    velocity_body_mps: np.ndarray
    euler_rad: np.ndarray
    rates_body_radps: np.ndarray
    airspeed_mps: float
    alpha_rad: float
    beta_rad: float
    specific_force_body_mps2: np.ndarray
    controls: np.ndarray
    wind_ned_mps: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def sample(self) -> TruthSample:
        """The state as a flight log holds it (:class:`immukf_sitl.samples.TruthSample`)."""
        return TruthSample(
            self.time_s,
            self.lat_deg,
            self.lon_deg,
            self.alt_m,
            np.asarray(self.euler_rad),
            np.asarray(self.rates_body_radps),
            np.asarray(self.velocity_ned_mps),
            np.asarray(self.specific_force_body_mps2),
            self.airspeed_mps,
            np.asarray(self.wind_ned_mps),
        )

    def state_vector(self) -> np.ndarray:
        """The 12-state of the aerodynamic-model filter (docs/conventions.md).

        Returns
        -------
        numpy.ndarray
            ``(12,)`` ``[pN, pE, pD, u, v, w, phi, theta, psi, p, q, r]``.
        """
        return np.concatenate(
            [self.position_ned_m, self.velocity_body_mps, self.euler_rad, self.rates_body_radps]
        )

    @property
    def ground_speed_mps(self) -> float:
        """Horizontal speed over the ground (m/s)."""
        return float(math.hypot(self.velocity_ned_mps[0], self.velocity_ned_mps[1]))

    @property
    def course_rad(self) -> float:
        """Course over the ground, ``atan2(vE, vN)`` (rad, in (-pi, pi])."""
        return float(math.atan2(self.velocity_ned_mps[1], self.velocity_ned_mps[0]))
