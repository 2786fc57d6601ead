"""Nonlinear 6-DOF aerodynamic model of the aircraft: the process model f and outputs g.

Rigid-body equations of motion of Beard & McLain, *Small Unmanned Aircraft*, 2012, ch. 3
(eqs. 3.14-3.17), with the forces and moments of ch. 4 (no wind) and the DC-motor + propeller
of the authors' supplement (ch. 4). It is the same aerodynamic law the JSBSim truth aircraft
flies (``sim/aircraft_xml.py`` renders it from the same parameter file):

- lift with the stall blending of eq. 4.9: ``C_L = (1 - sigma) (C_L_0 + C_L_alpha alpha)
  + sigma 2 sign(alpha) sin^2(alpha) cos(alpha)``, ``sigma`` of eq. 4.10 with ``M`` and
  ``alpha0``;
- **linear** drag ``C_D = C_D_0 + C_D_alpha alpha`` (with this coefficient
  set the parabolic ``C_D_p + C_L^2 / (pi e AR)`` would leave only induced drag);
- lift and drag in stability axes rotated to body by alpha (eq. 4.18); side force and moments
  in body axes (eqs. 4.14, 4.15, 4.19);
- thrust of the supplement's propeller along body x and, if ``prop_torque_on_roll``, the
  propeller reaction torque ``-Q_p`` about body x.

Assumptions of the paper (section 3): rigid body, constant mass and inertia, no wind. The earth
is a **flat, non-rotating NED tangent plane** at the origin with WGS-84 normal gravity at the
origin's latitude, corrected for height by the free-air gradient. The paper's model uses an
oblate earth; over a 2 km flight the direction of gravity tilts by only 2 km / 6371 km =
3e-4 rad against the tangent plane, far below the filter's process noise, and the filter's
position is converted to latitude/longitude with the full WGS-84 ellipsoid at the edges
(:mod:`immukf_sitl.models.earth`). Air density is ISA at the state's altitude, as in JSBSim.

The equations are written once, in :mod:`immukf_sitl.models.aero_kernels`, which numba compiles
for the hot path; this module packs the constants, shapes the arrays and solves the trim.

State, controls, noise and array layout: ``docs/conventions.md`` (state axis first).
"""

import math
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import least_squares

from immukf_sitl.models import aero_kernels as kernels
from immukf_sitl.models.earth import (
    EULER_LABELS,
    POSITION_NED_LABELS,
    NedOrigin,
    isa_density_kgpm3,
    normal_gravity_mps2,
)
from immukf_sitl.models.params import AeroCoefficients, AircraftParams, Propulsion
from immukf_sitl.models.sensors import IMU_PERIOD_S

__all__ = [
    "AeroModel",
    "drag_coefficient",
    "lift_coefficient",
    "propeller_thrust_torque",
    "stall_blend_sigma",
]


def stall_blend_sigma(alpha_rad: ArrayLike, M: float, alpha0_rad: float) -> np.ndarray:
    """Stall blending function sigma(alpha) of Beard & McLain eq. 4.10.

    Parameters
    ----------
    alpha_rad : array_like
        Angle of attack (rad).
    M : float
        Transition rate.
    alpha0_rad : float
        Cut-off angle of attack (rad).

    Returns
    -------
    numpy.ndarray
        sigma in [0, 1]: 0 in the linear range, 1 beyond stall.
    """
    return kernels.uncompiled.stall_blend_sigma(np.asarray(alpha_rad, dtype=float), M, alpha0_rad)


def lift_coefficient(alpha_rad: ArrayLike, aero: AeroCoefficients) -> np.ndarray:
    """Static lift coefficient C_L(alpha) with stall blending (Beard & McLain eq. 4.9)."""
    alpha = np.asarray(alpha_rad, dtype=float)
    return kernels.uncompiled.lift_coefficient(
        alpha, np.sin(alpha), np.cos(alpha), aero.C_L_0, aero.C_L_alpha, aero.M, aero.alpha0_rad
    )


def drag_coefficient(alpha_rad: ArrayLike, aero: AeroCoefficients) -> np.ndarray:
    """Static drag coefficient, the linear law C_D = C_D_0 + C_D_alpha alpha."""
    return kernels.uncompiled.drag_coefficient(
        np.asarray(alpha_rad, dtype=float), aero.C_D_0, aero.C_D_alpha
    )


def propeller_thrust_torque(
    Va_mps: ArrayLike,
    delta_t: ArrayLike,
    rho_kgpm3: ArrayLike,
    params: AircraftParams | Propulsion,
) -> tuple[np.ndarray, np.ndarray]:
    """Thrust and torque of the DC motor + propeller (Beard & McLain supplement, ch. 4).

    The propeller speed Omega is the positive root of the torque balance of motor and
    propeller, ``a Omega^2 + b Omega + c = 0`` with
    ``a = rho D^5 C_Q0 / (2 pi)^2``,
    ``b = rho D^4 C_Q1 Va / (2 pi) + K_Q K_V / R``,
    ``c = rho D^3 C_Q2 Va^2 - K_Q V_in / R + K_Q i0``, ``V_in = V_max delta_t``,
    evaluated in the cancellation-free form ``Omega = -2 c / (b + sqrt(b^2 - 4 a c))`` (which
    stays finite at ``rho = 0``). Then, with ``n = Omega / (2 pi)`` and ``J = Va / (n D)``,
    ``T = rho n^2 D^4 C_T(J)`` and ``Q = rho n^2 D^5 C_Q(J)``, expanded so that no division by
    Omega occurs (the model's kernel :func:`immukf_sitl.models.aero_kernels.propeller`).

    Parameters
    ----------
    Va_mps : array_like
        Airspeed (m/s), the propeller inflow speed.
    delta_t : array_like
        Throttle in [0, 1] (not clipped here).
    rho_kgpm3 : array_like
        Air density (kg/m^3).
    params : AircraftParams or Propulsion
        Propulsion parameters.

    Returns
    -------
    thrust_N : numpy.ndarray
        Thrust along body x (N); negative (windmilling drag) at low throttle and high speed.
    torque_Nm : numpy.ndarray
        Aerodynamic torque on the propeller (N m); the airframe feels ``-torque_Nm`` about x.
    """
    prop = params.propulsion if isinstance(params, AircraftParams) else params
    return kernels.uncompiled.propeller(
        np.asarray(Va_mps, dtype=float),
        np.asarray(delta_t, dtype=float),
        np.asarray(rho_kgpm3, dtype=float),
        kernels.pack_propulsion(prop),
    )


def _zero_extra(n: int) -> np.ndarray:
    """Zeros for the filter model's slow states of ``n`` columns: the aircraft itself."""
    return np.zeros((kernels.N_EXTRA, n))


def _writeable_contiguous(a: np.ndarray) -> np.ndarray:
    """``a`` as a C-contiguous float array the kernels accept (a copy only when needed)."""
    a = np.ascontiguousarray(a, dtype=float)
    return a if a.flags.writeable else a.copy()


@dataclass(frozen=True)
class AeroModel:
    """6-DOF aircraft model: ``x = [pN, pE, pD, u, v, w, phi, theta, psi, p, q, r]``.

    Parameters
    ----------
    params : AircraftParams
        Aircraft parameters (mass, geometry, coefficients, propulsion).
    origin : NedOrigin
        Origin of the flat NED frame. Its latitude and height set the normal gravity; its
        height (taken as altitude above mean sea level: the geoid undulation, at most about
        100 m, is neglected) sets the ISA density at ``pD = 0``.
    dt_s : float
        Integration step of :meth:`step` (s), the IMU period (100 Hz).
    density_kgpm3 : float, optional
        Constant air density instead of ISA at the state's altitude (e.g. the book's 1.2682;
        0 removes all aerodynamic and propeller forces).
    gravity_mps2 : float, optional
        Gravity at the origin; default WGS-84 normal gravity at the origin.
    gravity_gradient_ps2 : float, optional
        ``d g / d pD`` (1/s^2); default the free-air gradient at the origin (about 3.1e-6).
    compiled : bool
        How :meth:`step`, :meth:`derivatives`, :meth:`forces_moments` and :meth:`imu` run the
        equations of :mod:`immukf_sitl.models.aero_kernels`: True (the default) in compiled
        loops over the batch's columns, False the same functions uncompiled over whole rows of
        the batch (the reference; about 7 times slower on a (12, 7, 49) batch).

    Notes
    -----
    Every vectorised method takes the state axis first and any batch axes after it:
    ``x`` ``(12, *batch)``, ``u`` ``(4,)`` or ``(4, *batch)``, ``v`` ``(6, *batch)``, ``(6,)``
    or None. Euler angles have a singularity at ``|theta| = 90 deg``, outside a fixed-wing
    envelope and not handled.
    """

    params: AircraftParams
    origin: NedOrigin = NedOrigin(0.0, 0.0, 0.0)
    dt_s: float = IMU_PERIOD_S
    density_kgpm3: float | None = None
    gravity_mps2: float | None = None
    gravity_gradient_ps2: float | None = None
    compiled: bool = True

    nx: ClassVar[int] = 12
    nu: ClassVar[int] = 4
    nv: ClassVar[int] = 6
    state_labels: ClassVar[tuple[str, ...]] = (
        *POSITION_NED_LABELS,
        "u_mps",
        "v_mps",
        "w_mps",
        *EULER_LABELS,
        "p_radps",
        "q_radps",
        "r_radps",
    )
    control_labels: ClassVar[tuple[str, ...]] = (
        "delta_e_rad",
        "delta_a_rad",
        "delta_r_rad",
        "delta_t",
    )
    imu_labels: ClassVar[tuple[str, ...]] = ("x", "y", "z", "p", "q", "r")
    gps_labels: ClassVar[tuple[str, ...]] = ("pN_m", "pE_m", "pD_m", "Vg_mps", "chi_rad")
    #: State indices that are wrapped angles (phi, psi; theta never nears +-pi).
    angle_indices: ClassVar[tuple[int, ...]] = (6, 8)

    _k: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not self.dt_s > 0.0:
            raise ValueError(f"AeroModel.dt_s: expected > 0, got {self.dt_s}")
        if not isinstance(self.compiled, bool):
            raise ValueError(f"AeroModel.compiled: expected True or False, got {self.compiled!r}")
        lat, h0 = self.origin.lat_deg, self.origin.alt_m
        g0 = float(normal_gravity_mps2(lat, h0)) if self.gravity_mps2 is None else self.gravity_mps2
        if self.gravity_gradient_ps2 is None:
            # exact derivative of the (quadratic in h) free-air formula at the origin
            dg = float(normal_gravity_mps2(lat, h0 - 0.5) - normal_gravity_mps2(lat, h0 + 0.5))
        else:
            dg = self.gravity_gradient_ps2
        if self.density_kgpm3 is None:
            isa_density_kgpm3(h0)  # validates the origin altitude
        elif not self.density_kgpm3 >= 0.0:
            raise ValueError(f"AeroModel.density_kgpm3: expected >= 0, got {self.density_kgpm3}")
        k = kernels.pack_constants(
            self.params,
            gravity_mps2=g0,
            gravity_gradient_ps2=dg,
            origin_alt_m=h0,
            density_kgpm3=self.density_kgpm3,
        )
        object.__setattr__(self, "_k", k)

    @property
    def uses_numba(self) -> bool:
        """True when the compiled kernels are in use."""
        return self.compiled

    @staticmethod
    def _flat(x: np.ndarray, u: np.ndarray, v: np.ndarray | None, n: int):
        """Batch flattened to columns for the kernels: x (12, N), u (4, N), v (6, N).

        Each comes out C-contiguous and writeable, whatever the caller passes: numba compiles
        one signature per layout and read-only flag, and a read-only broadcast view (a single
        state, a (6,) noise) would cost a second compile of every kernel.
        """
        x2, u2 = AeroModel._flat_xu(x, u, n)
        if v is None:
            v2 = np.zeros((6, n))
        else:
            v = np.asarray(v, dtype=float)
            if v.ndim == 1:
                v2 = np.broadcast_to(v[:, None], (6, n))
            elif v.shape[1:] == x.shape[1:]:
                v2 = v.reshape(6, n)
            else:
                v2 = np.broadcast_to(v, (6, *x.shape[1:])).reshape(6, n)
        return x2, u2, _writeable_contiguous(v2)

    @staticmethod
    def _flat_xu(x: np.ndarray, u: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
        """The state and control parts of :meth:`_flat`."""
        x2 = _writeable_contiguous(x.reshape(x.shape[0], n))
        if u.ndim == 1:
            u2 = np.empty((u.shape[0], n))
            u2[...] = u[:, None]
        else:
            u2 = np.broadcast_to(u, (u.shape[0], *x.shape[1:])).reshape(u.shape[0], n)
        return x2, _writeable_contiguous(u2)

    @staticmethod
    def _rows(x: np.ndarray, v: np.ndarray | None) -> np.ndarray:
        """Process noise for the uncompiled kernels: rows that broadcast against x's."""
        if v is None:
            return np.zeros(6)
        v = np.asarray(v, dtype=float)
        if v.ndim == 1 and x.ndim > 1:
            return v.reshape((6,) + (1,) * (x.ndim - 1))
        return v

    # -----------------------------------------------------------------------------------------
    # forces and moments

    def density(self, x: np.ndarray) -> np.ndarray | float:
        """Air density (kg/m^3) at the state's altitude (ISA) or the constant override."""
        if self.density_kgpm3 is not None:
            return self.density_kgpm3
        return isa_density_kgpm3(self.origin.alt_m - np.asarray(x)[2])

    def forces_moments(self, t_s: float, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Aerodynamic + propulsive forces and moments in body axes, gravity excluded.

        Returns
        -------
        numpy.ndarray
            ``(6, *batch)`` ``[f_x, f_y, f_z (N), l, m, n (N m)]`` about the CG.
        """
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        out = np.empty((6, *x.shape[1:]), dtype=float)
        if self.uses_numba:
            n = x[0].size
            x2, u2 = self._flat_xu(x, u, n)
            kernels.forces_moments_batch(x2, u2, self._k, out.reshape(6, n))
        else:
            kernels.uncompiled.forces_moments(x, u, self._k, out)
        return out

    # -----------------------------------------------------------------------------------------
    # process model

    def derivatives(
        self, t_s: float, x: np.ndarray, u: np.ndarray, v: np.ndarray | None = None
    ) -> np.ndarray:
        """Time derivative of the state, Beard & McLain eqs. 3.14-3.17.

        Parameters
        ----------
        t_s : float
            Time (s); the model is time invariant.
        x : numpy.ndarray
            ``(12, *batch)`` state.
        u : numpy.ndarray
            ``(4,)`` or ``(4, *batch)`` controls ``[delta_e, delta_a, delta_r, delta_t]``.
        v : numpy.ndarray, optional
            ``(6, *batch)`` or ``(6,)`` process noise added to u_dot, v_dot, w_dot (m/s^2) and
            p_dot, q_dot, r_dot (rad/s^2); None means zero.

        Returns
        -------
        numpy.ndarray
            ``(12, *batch)`` state derivative.
        """
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        out = np.empty(x.shape, dtype=float)
        if self.uses_numba:
            n = x[0].size
            x2, u2, v2 = self._flat(x, u, v, n)
            e2 = _zero_extra(n)
            kernels.derivatives_batch(x2, u2, v2, e2, self._k, out.reshape(x.shape[0], n))
        else:
            fm, xa = np.empty((6, *x.shape[1:])), np.empty(x.shape)
            e = np.zeros(kernels.N_EXTRA)
            kernels.uncompiled.derivatives(x, u, self._rows(x, v), e, self._k, fm, xa, out)
        return out

    def step(
        self, t_s: float, x: np.ndarray, u: np.ndarray, v: np.ndarray | None = None
    ) -> np.ndarray:
        """State after one step ``dt_s``: classical RK4 with u and v held (paper eq. 1).

        Parameters
        ----------
        t_s : float
            Time at the start of the step (s).
        x : numpy.ndarray
            ``(12, *batch)`` state.
        u : numpy.ndarray
            ``(4,)`` or ``(4, *batch)`` controls.
        v : numpy.ndarray, optional
            ``(6, *batch)`` or ``(6,)`` process noise (see :meth:`derivatives`).

        Returns
        -------
        numpy.ndarray
            ``(12, *batch)`` state at ``t_s + dt_s``, with phi and psi wrapped to [-pi, pi).
        """
        return self.step_with(x, u, v, None)

    def step_with(
        self, x: np.ndarray, u: np.ndarray, v: np.ndarray | None, e: np.ndarray | None
    ) -> np.ndarray:
        """:meth:`step` of ``x`` ``(12, *batch)`` in air moving, and with corrections, as ``e``.

        ``e`` ``(N_EXTRA, *batch)`` holds the filter model's slow states, held over the step
        (layout :data:`immukf_sitl.models.aero_kernels.N_EXTRA`); None means zeros.
        """
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        out = np.empty(x.shape, dtype=float)
        if self.uses_numba:
            n = x[0].size
            x2, u2, v2 = self._flat(x, u, v, n)
            e2 = _zero_extra(n) if e is None else _writeable_contiguous(e.reshape(-1, n))
            # columns repeating the first of their row (a filter's centre) reuse its result
            period = x.shape[-1] if x.ndim > 1 else 1
            kernels.step_batch(
                x2, u2, v2, e2, self._k, self.dt_s, period, out.reshape(x.shape[0], n)
            )
        else:
            work = kernels.Rk4Work(
                *(np.empty(x.shape) for _ in range(4)), np.empty((6, *x.shape[1:]))
            )
            e = np.zeros(kernels.N_EXTRA) if e is None else e
            kernels.uncompiled.rk4_step(x, u, self._rows(x, v), e, self._k, self.dt_s, work, out)
        return out

    # -----------------------------------------------------------------------------------------
    # outputs

    def imu(self, t_s: float, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Predicted noise-free IMU reading ``[f_x, f_y, f_z, p, q, r]`` (body FRD).

        Specific force is (aerodynamic + thrust force) / mass, what an accelerometer reads
        (about ``[0, 0, -9.8]`` m/s^2 in level flight), moved from the CG to the IMU position
        ``r`` by ``+ omega_dot x r + omega x (omega x r)`` when ``imu_position_m`` is non-zero.

        Returns
        -------
        numpy.ndarray
            ``(6, *batch)``: specific force (m/s^2) and body rates (rad/s).
        """
        return self.imu_with(x, u, None)

    def imu_with(self, x: np.ndarray, u: np.ndarray, e: np.ndarray | None) -> np.ndarray:
        """:meth:`imu` of ``x`` ``(12, *batch)`` with the filter model's slow states ``e``.

        ``e`` ``(N_EXTRA, *batch)``: the wind sets the air-relative velocity, the corrections add
        to the specific force and angular acceleration, the gyro biases to the rates; None
        means zeros.
        """
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        out = np.empty((6, *x.shape[1:]), dtype=float)
        if self.uses_numba:
            n = x[0].size
            x2, u2 = self._flat_xu(x, u, n)
            e2 = _zero_extra(n) if e is None else _writeable_contiguous(e.reshape(-1, n))
            period = x.shape[-1] if x.ndim > 1 else 1  # as in step_with
            kernels.imu_batch(x2, u2, e2, self._k, period, out.reshape(6, n))
        else:
            e = np.zeros(kernels.N_EXTRA) if e is None else e
            scratch = np.empty((6, *x.shape[1:])), np.empty(x.shape)
            kernels.uncompiled.imu(x, u, e, self._k, *scratch, out)
        return out

    def gps(
        self, t_s: float, x: np.ndarray, u: np.ndarray, velocity_down: bool = False
    ) -> np.ndarray:
        """Predicted noise-free GPS ``[pN, pE, pD (m), ground speed (m/s), course (rad)]``.

        Ground speed is horizontal, ``sqrt(vN^2 + vE^2)``, and course ``atan2(vE, vN)`` in
        ``(-pi, pi]`` (no wind, so the ground velocity is the air velocity rotated to NED).
        ``velocity_down``: followed by the vertical velocity ``vD`` (m/s, NED down).
        """
        return self.gps_with(x, None, velocity_down)

    def gps_with(
        self, x: np.ndarray, e: np.ndarray | None, velocity_down: bool = False
    ) -> np.ndarray:
        """:meth:`gps` of ``x`` ``(12, *batch)`` plus the receiver errors held in ``e``."""
        x = np.asarray(x, dtype=float)
        out = np.empty((6 if velocity_down else 5, *x.shape[1:]), dtype=float)
        e = np.zeros(kernels.N_EXTRA) if e is None else e
        kernels.uncompiled.gps(x, e, out)  # uncompiled, over whole rows: off the hot path
        return out

    # -----------------------------------------------------------------------------------------
    # trim

    def trim(
        self, Va_mps: float, gamma_rad: float = 0.0, alt_m: float | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Wings-level steady trim (Beard & McLain ch. 5.3, straight flight, R = inf).

        Solves for alpha, beta, theta and the four controls with ``phi = 0``, ``p = q = r = 0``
        such that the body accelerations vanish and the climb rate is ``Va sin(gamma)``
        (scipy ``least_squares``, controls bounded by their limits).

        Parameters
        ----------
        Va_mps : float
            Airspeed (m/s).
        gamma_rad : float
            Flight-path angle (rad), positive climbing.
        alt_m : float, optional
            Altitude above mean sea level; default the origin's (``pD = 0``).

        Returns
        -------
        x0 : numpy.ndarray
            ``(12,)`` trimmed state at ``pN = pE = 0``, heading 0.
        u0 : numpy.ndarray
            ``(4,)`` trim controls.

        Raises
        ------
        RuntimeError
            If no trim within the control limits makes the derivatives vanish.
        """
        if not Va_mps > 0.0:
            raise ValueError(f"trim: expected Va_mps > 0, got {Va_mps}")
        p_d = 0.0 if alt_m is None else self.origin.alt_m - alt_m
        lower = self.params.actuators.lower_limits
        upper = self.params.actuators.upper_limits

        def state_of(z: np.ndarray) -> np.ndarray:
            alpha, beta, theta = z[0], z[1], z[2]
            x = np.zeros(12)
            x[2] = p_d
            x[3] = Va_mps * math.cos(alpha) * math.cos(beta)  # eq. (2.7)
            x[4] = Va_mps * math.sin(beta)
            x[5] = Va_mps * math.sin(alpha) * math.cos(beta)
            x[7] = theta
            return x

        def residual(z: np.ndarray) -> np.ndarray:
            x = state_of(z)
            xd = self.derivatives(0.0, x, z[3:7])
            climb = -xd[2] - Va_mps * math.sin(gamma_rad)
            return np.concatenate([xd[3:6], xd[9:12], [climb]])

        z0 = np.array([0.05, 0.0, 0.05 + gamma_rad, -0.1, 0.0, 0.0, 0.8])
        lo = np.concatenate([[-0.5, -0.5, -1.5], lower])
        hi = np.concatenate([[0.5, 0.5, 1.5], upper])
        sol = least_squares(residual, np.clip(z0, lo, hi), bounds=(lo, hi), xtol=1e-14, ftol=1e-14)
        worst = float(np.max(np.abs(sol.fun)))
        if worst > 1e-6:
            raise RuntimeError(
                f"trim: no steady flight at Va = {Va_mps} m/s, gamma = {gamma_rad} rad "
                f"within the control limits (largest residual {worst:.3g})"
            )
        return state_of(sol.x), sol.x[3:7].copy()
