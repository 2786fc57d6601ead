"""A plain PID autopilot that flies the Aerosonde along a waypoint flight plan.

Loops (Beard & McLain, *Small Unmanned Aircraft*, 2012, ch. 6 and 10), all at the step rate:

- guidance: straight-line path following between consecutive waypoints (B&M eq. 10.8,
  ``chi_c = chi_q - chi_inf (2/pi) atan(k_path e_py)``); a waypoint is reached when the aircraft
  is within the acceptance radius or has crossed the plane through the waypoint perpendicular to
  the leg it flies;
- lateral: course -> roll command (PI, limited bank), roll -> aileron (PD on the roll rate),
  sideslip -> rudder (PI, the yaw damper: it keeps turns coordinated);
- longitudinal: the waypoint altitude, rate-limited to a climb rate, -> pitch command (PI,
  limited), pitch -> elevator (PID, the pitch rate as the derivative), airspeed -> throttle (PI).

Every integrator has conditional-integration anti-windup (it stops when the output saturates in
the direction of the error) and every output is limited; the roll command and the control
outputs are slew-rate limited (servo speed), so that a waypoint switch does not step the
surfaces. Surface commands are trim plus the
loop outputs, so the autopilot starts from the trim without a transient.

The autopilot sees the aircraft only through :class:`NavigationState`, built from the truth
(:meth:`NavigationState.from_truth`) or from any estimate of the 12-state of
``docs/conventions.md`` (:meth:`NavigationState.from_state_vector`), so that it can fly closed
loop on the estimator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from immukf_sitl.models.earth import body_to_ned
from immukf_sitl.scenario import FlightPlan
from sim.truth import TrimResult, TruthState

__all__ = [
    "Autopilot",
    "AutopilotGains",
    "AutopilotStatus",
    "NavigationState",
    "PidController",
    "wrap_angle_rad",
]


def wrap_angle_rad(angle_rad: float) -> float:
    """Wrap an angle to [-pi, pi] (rad)."""
    return math.remainder(angle_rad, 2.0 * math.pi)


@dataclass(frozen=True)
class NavigationState:
    """What the autopilot needs to know about the aircraft (truth or estimate).

    Attributes
    ----------
    time_s : float
        Time of the state (s).
    position_ned_m : numpy.ndarray
        ``(3,)`` NED position about the origin (m).
    alt_m : float
        Height above the WGS-84 ellipsoid (m).
    velocity_ned_mps : numpy.ndarray
        ``(3,)`` NED velocity over the ground (m/s).
    euler_rad : numpy.ndarray
        ``(3,)`` roll, pitch, yaw (rad).
    rates_body_radps : numpy.ndarray
        ``(3,)`` body rates p, q, r (rad/s).
    airspeed_mps : float
        Airspeed (m/s).
    beta_rad : float
        Sideslip angle (rad).
    """

    time_s: float
    position_ned_m: np.ndarray
    alt_m: float
    velocity_ned_mps: np.ndarray
    euler_rad: np.ndarray
    rates_body_radps: np.ndarray
    airspeed_mps: float
    beta_rad: float

    @classmethod
    def from_truth(cls, truth: TruthState) -> NavigationState:
        """The navigation state of a JSBSim truth record (flying "on truth")."""
        return cls(
            time_s=truth.time_s,
            position_ned_m=truth.position_ned_m,
            alt_m=truth.alt_m,
            velocity_ned_mps=truth.velocity_ned_mps,
            euler_rad=truth.euler_rad,
            rates_body_radps=truth.rates_body_radps,
            airspeed_mps=truth.airspeed_mps,
            beta_rad=truth.beta_rad,
        )

    @classmethod
    def from_navigation(
        cls,
        time_s: float,
        position_ned_m: np.ndarray,
        alt_m: float,
        velocity_ned_mps: np.ndarray,
        euler_rad: np.ndarray,
        rates_body_radps: np.ndarray,
        wind_ned_mps: np.ndarray | None = None,
    ) -> NavigationState:
        """The navigation state of an estimator's navigation solution (flying closed loop).

        Parameters
        ----------
        time_s : float
            Time of the estimate (s).
        position_ned_m : numpy.ndarray
            ``(3,)`` NED position about the flight's origin (m).
        alt_m : float
            Height above the WGS-84 ellipsoid (m).
        velocity_ned_mps : numpy.ndarray
            ``(3,)`` NED velocity over the ground (m/s).
        euler_rad : numpy.ndarray
            ``(3,)`` roll, pitch, yaw (rad).
        rates_body_radps : numpy.ndarray
            ``(3,)`` body rates p, q, r (rad/s).
        wind_ned_mps : numpy.ndarray, optional
            ``(3,)`` estimated wind (m/s, NED, where it blows to); default none.

        Returns
        -------
        NavigationState
            Airspeed and sideslip from the air-relative velocity in body axes.
        """
        euler = np.asarray(euler_rad, dtype=float)
        velocity = np.asarray(velocity_ned_mps, dtype=float)
        air = velocity if wind_ned_mps is None else velocity - np.asarray(wind_ned_mps, float)
        body = body_to_ned(euler).T @ air
        airspeed = float(np.linalg.norm(body))
        beta = math.asin(max(-1.0, min(1.0, body[1] / airspeed))) if airspeed > 0.0 else 0.0
        return cls(
            time_s=float(time_s),
            position_ned_m=np.array(position_ned_m, dtype=float),
            alt_m=float(alt_m),
            velocity_ned_mps=velocity.copy(),
            euler_rad=euler.copy(),
            rates_body_radps=np.array(rates_body_radps, dtype=float),
            airspeed_mps=airspeed,
            beta_rad=beta,
        )

    @classmethod
    def from_state_vector(
        cls, time_s: float, state: np.ndarray, origin_alt_m: float
    ) -> NavigationState:
        """The navigation state of a 12-state estimate (docs/conventions.md), no wind.

        Parameters
        ----------
        time_s : float
            Time of the estimate (s).
        state : numpy.ndarray
            ``(12,)`` ``[pN, pE, pD, u, v, w, phi, theta, psi, p, q, r]``.
        origin_alt_m : float
            Height of the NED origin above the WGS-84 ellipsoid (m); the altitude is
            ``origin_alt_m - pD`` (the earth's curvature, under 0.1 m within 1 km, is ignored).

        Returns
        -------
        NavigationState
            With airspeed ``|(u, v, w)|`` and sideslip ``asin(v / Va)`` (no wind).
        """
        x = np.asarray(state, dtype=float)
        if x.shape != (12,):
            raise ValueError(f"state: expected shape (12,), got {x.shape}")
        uvw = x[3:6]
        airspeed = float(np.linalg.norm(uvw))
        beta = math.asin(max(-1.0, min(1.0, x[4] / airspeed))) if airspeed > 0.0 else 0.0
        return cls(
            time_s=float(time_s),
            position_ned_m=x[0:3].copy(),
            alt_m=float(origin_alt_m - x[2]),
            velocity_ned_mps=body_to_ned(x[6:9]) @ uvw,
            euler_rad=x[6:9].copy(),
            rates_body_radps=x[9:12].copy(),
            airspeed_mps=airspeed,
            beta_rad=beta,
        )


@dataclass(frozen=True)
class AutopilotGains:
    """Gains and limits of the loops (SI units: rad, m, m/s, s).

    Designed from B&M ch. 6 transfer functions of the Aerosonde at 25 m/s and checked in
    flight (``tests/test_sim_flight.py``).
    """

    # lateral
    course_kp: float = 1.5  # rad roll per rad course error
    course_ki: float = 0.02
    roll_limit_rad: float = math.radians(30.0)
    roll_cmd_rate_radps: float = math.radians(45.0)  # slew limit of the roll command
    roll_kp: float = 0.8  # rad aileron per rad roll error
    roll_ki: float = 0.05
    roll_kd: float = 0.05  # rad aileron per rad/s roll rate
    sideslip_kp: float = 1.0  # rad rudder per rad sideslip
    sideslip_ki: float = 0.5
    path_k_per_m: float = 0.02  # B&M eq. 10.8 k_path
    path_chi_inf_rad: float = math.radians(60.0)
    # longitudinal
    climb_rate_mps: float = 2.5  # rate limit of the altitude reference
    altitude_kp: float = 0.03  # rad pitch per m
    altitude_ki: float = 0.006
    pitch_limit_rad: float = math.radians(15.0)
    pitch_kp: float = 1.2  # rad (nose-up) elevator per rad pitch error
    pitch_ki: float = 0.5
    pitch_kd: float = 0.15  # rad per rad/s pitch rate
    airspeed_kp: float = 0.08  # throttle per m/s
    airspeed_ki: float = 0.03
    # actuators
    surface_rate_radps: float = 3.0  # slew limit of the surface commands (servo speed)
    throttle_rate_ps: float = 1.0  # slew limit of the throttle command (1/s)


@dataclass(frozen=True)
class AutopilotStatus:
    """What the autopilot commanded at its last update (for logs and tests).

    Attributes
    ----------
    time_s : float
        Time of the navigation state used (s).
    waypoint_index : int
        Index of the waypoint being flown to.
    waypoints_reached : int
        How many waypoints were reached so far (counting repeats when looping).
    altitude_ref_m : float
        Rate-limited altitude reference (m).
    altitude_target_m : float
        Altitude of the active waypoint (m).
    airspeed_cmd_mps, course_cmd_rad, roll_cmd_rad, pitch_cmd_rad : float
        Inner-loop commands.
    cross_track_m : float
        Signed distance right of the active leg (m), of the navigation state flown on.
    leg_start_ne_m, leg_target_ne_m : tuple of float
        ``(north, east)`` of the active leg's start and end (m): the desired path, against
        which experiments measure the true aircraft (control error).
    """

    time_s: float
    waypoint_index: int
    waypoints_reached: int
    altitude_ref_m: float
    altitude_target_m: float
    airspeed_cmd_mps: float
    course_cmd_rad: float
    roll_cmd_rad: float
    pitch_cmd_rad: float
    cross_track_m: float
    leg_start_ne_m: tuple[float, float] = (math.nan, math.nan)
    leg_target_ne_m: tuple[float, float] = (math.nan, math.nan)


@dataclass
class PidController:
    """PID with output limits and conditional-integration anti-windup.

    ``output = kp e + ki integral(e) - kd measured_rate``, limited to ``[lower, upper]``; the
    derivative acts on a measured rate (no derivative kick). The integrator does not grow while
    the output is saturated in the direction the error would push it.

    Parameters
    ----------
    kp, ki, kd : float
        Gains.
    lower, upper : float
        Output limits.
    """

    kp: float
    ki: float
    kd: float
    lower: float
    upper: float
    integral: float = field(default=0.0)

    def update(self, error: float, dt_s: float, rate: float = 0.0) -> float:
        """One step; returns the limited output."""
        unclipped = self.kp * error + self.ki * self.integral - self.kd * rate
        candidate = self.integral + error * dt_s
        trial = self.kp * error + self.ki * candidate - self.kd * rate
        saturated_high = trial > self.upper and error * self.ki > 0.0
        saturated_low = trial < self.lower and error * self.ki < 0.0
        if not (saturated_high or saturated_low):
            self.integral = candidate
            unclipped = trial
        return min(max(unclipped, self.lower), self.upper)

    def reset(self) -> None:
        """Clear the integrator."""
        self.integral = 0.0


class Autopilot:
    """Waypoint-following PID autopilot.

    Parameters
    ----------
    plan : FlightPlan
        The waypoints.
    trim : TrimResult
        Trim of the aircraft: controls and pitch used as feed-forward.
    dt_s : float
        Update period (s), the simulation step.
    limits_lower, limits_upper : numpy.ndarray
        ``(4,)`` control limits ``[delta_e, delta_a, delta_r, delta_t]``
        (``AircraftParams.actuators.lower_limits`` / ``upper_limits``).
    gains : AutopilotGains, optional
        Loop gains and limits.
    """

    def __init__(
        self,
        plan: FlightPlan,
        trim: TrimResult,
        dt_s: float,
        limits_lower: np.ndarray,
        limits_upper: np.ndarray,
        gains: AutopilotGains | None = None,
    ) -> None:
        self.plan = plan
        self.trim = trim
        self.dt_s = float(dt_s)
        self.gains = gains if gains is not None else AutopilotGains()
        self._lower = np.asarray(limits_lower, dtype=float)
        self._upper = np.asarray(limits_upper, dtype=float)
        g, u0 = self.gains, trim.controls
        self._course = PidController(
            g.course_kp, g.course_ki, 0.0, -g.roll_limit_rad, g.roll_limit_rad
        )
        self._roll = PidController(
            g.roll_kp, g.roll_ki, g.roll_kd, self._lower[1] - u0[1], self._upper[1] - u0[1]
        )
        # The rudder opposes sideslip: positive beta needs a positive yawing moment, i.e. a
        # negative rudder (C_n_delta_r < 0); the controller's output is -delta_r.
        self._sideslip = PidController(
            g.sideslip_kp, g.sideslip_ki, 0.0, u0[2] - self._upper[2], u0[2] - self._lower[2]
        )
        self._altitude = PidController(
            g.altitude_kp, g.altitude_ki, 0.0, -g.pitch_limit_rad, g.pitch_limit_rad
        )
        # Nose-up elevator is negative delta_e (C_m_delta_e < 0): the output is -delta_e.
        self._pitch = PidController(
            g.pitch_kp, g.pitch_ki, g.pitch_kd, u0[0] - self._upper[0], u0[0] - self._lower[0]
        )
        self._airspeed = PidController(
            g.airspeed_kp, g.airspeed_ki, 0.0, self._lower[3] - u0[3], self._upper[3] - u0[3]
        )
        self._index = 0
        self._reached = 0
        self._finished = False
        self._leg_start: np.ndarray | None = None
        self._alt_ref: float | None = None
        self._roll_cmd = 0.0
        self._last_controls = np.array(trim.controls, dtype=float)
        self._status: AutopilotStatus | None = None

    @property
    def status(self) -> AutopilotStatus | None:
        """Commands of the last update (``None`` before the first)."""
        return self._status

    @property
    def waypoint_index(self) -> int:
        """Index of the waypoint being flown to."""
        return self._index

    def _advance(self, position_ne: np.ndarray) -> None:
        """Switch to the next waypoint when the active one is reached."""
        plan = self.plan
        count = len(plan.waypoints)
        for _ in range(count):
            if self._finished:
                return
            wp = plan.waypoints[self._index]
            target = np.array([wp.north_m, wp.east_m])
            assert self._leg_start is not None
            to_target = target - position_ne
            within = float(np.hypot(*to_target)) <= plan.acceptance_radius_m
            crossed = float(np.dot(target - self._leg_start, to_target)) < 0.0
            if not (within or crossed):
                return
            self._reached += 1
            if self._index == count - 1 and not plan.loop:
                # Hold the last leg's line beyond its waypoint.
                self._finished = True
                return
            self._leg_start = target
            self._index = (self._index + 1) % count

    def update(self, nav: NavigationState) -> np.ndarray:
        """Controls for the next step.

        Parameters
        ----------
        nav : NavigationState
            Current navigation state (truth or estimate).

        Returns
        -------
        numpy.ndarray
            ``(4,)`` ``[delta_e, delta_a, delta_r (rad), delta_t (0..1)]`` within the limits.
        """
        g, dt, u0 = self.gains, self.dt_s, self.trim.controls
        position_ne = np.asarray(nav.position_ned_m[:2], dtype=float)
        if self._leg_start is None:
            self._leg_start = position_ne.copy()
            self._alt_ref = float(nav.alt_m)
        self._advance(position_ne)
        wp = self.plan.waypoints[self._index]
        target = np.array([wp.north_m, wp.east_m])

        # Straight-line path following (B&M eq. 10.8).
        leg = target - self._leg_start
        if float(np.hypot(*leg)) < 1e-6:
            leg = target - position_ne
        chi_q = math.atan2(leg[1], leg[0])
        offset = position_ne - self._leg_start
        cross_track = -math.sin(chi_q) * offset[0] + math.cos(chi_q) * offset[1]
        vn, ve = float(nav.velocity_ned_mps[0]), float(nav.velocity_ned_mps[1])
        course = math.atan2(ve, vn) if math.hypot(vn, ve) > 1.0 else float(nav.euler_rad[2])
        chi_q = course + wrap_angle_rad(chi_q - course)
        course_cmd = chi_q - g.path_chi_inf_rad * (2.0 / math.pi) * math.atan(
            g.path_k_per_m * cross_track
        )

        # Lateral loops.
        phi, theta = float(nav.euler_rad[0]), float(nav.euler_rad[1])
        p, q = float(nav.rates_body_radps[0]), float(nav.rates_body_radps[1])
        roll_target = self._course.update(wrap_angle_rad(course_cmd - course), dt)
        roll_step = g.roll_cmd_rate_radps * dt
        self._roll_cmd += min(max(roll_target - self._roll_cmd, -roll_step), roll_step)
        roll_cmd = self._roll_cmd
        delta_a = u0[1] + self._roll.update(roll_cmd - phi, dt, rate=p)
        delta_r = u0[2] - self._sideslip.update(float(nav.beta_rad), dt)

        # Longitudinal loops.
        assert self._alt_ref is not None
        step = g.climb_rate_mps * dt
        self._alt_ref += min(max(wp.alt_m - self._alt_ref, -step), step)
        pitch_cmd = self.trim.theta_rad + self._altitude.update(self._alt_ref - nav.alt_m, dt)
        delta_e = u0[0] - self._pitch.update(pitch_cmd - theta, dt, rate=q)
        delta_t = u0[3] + self._airspeed.update(wp.airspeed_mps - nav.airspeed_mps, dt)

        self._status = AutopilotStatus(
            time_s=float(nav.time_s),
            waypoint_index=self._index,
            waypoints_reached=self._reached,
            altitude_ref_m=self._alt_ref,
            altitude_target_m=wp.alt_m,
            airspeed_cmd_mps=wp.airspeed_mps,
            course_cmd_rad=wrap_angle_rad(course_cmd),
            roll_cmd_rad=roll_cmd,
            pitch_cmd_rad=pitch_cmd,
            cross_track_m=cross_track,
            leg_start_ne_m=(float(self._leg_start[0]), float(self._leg_start[1])),
            leg_target_ne_m=(float(target[0]), float(target[1])),
        )
        controls = np.clip(np.array([delta_e, delta_a, delta_r, delta_t]), self._lower, self._upper)
        rate = np.array([g.surface_rate_radps] * 3 + [g.throttle_rate_ps]) * dt
        controls = self._last_controls + np.clip(controls - self._last_controls, -rate, rate)
        self._last_controls = controls
        return controls.copy()
