"""Nonlinear 6-DOF aerodynamic model of the aircraft: the process model f and outputs g.

Rigid-body equations of motion of Beard & McLain, *Small Unmanned Aircraft*, 2012, ch. 3
(eqs. 3.14-3.17), with the forces and moments of ch. 4 (no wind) and the DC-motor + propeller
of the authors' supplement (ch. 4). It is the same aerodynamic law the JSBSim truth aircraft
flies (``sim/aircraft_xml.py`` renders it from the same parameter file):

- lift with the stall blending of eq. 4.9: ``C_L = (1 - sigma) (C_L_0 + C_L_alpha alpha)
  + sigma 2 sign(alpha) sin^2(alpha) cos(alpha)``, ``sigma`` of eq. 4.10 with ``M`` and
  ``alpha0``;
- **linear** drag ``C_D = C_D_0 + C_D_alpha alpha`` (DESIGN.md section 6: with this coefficient
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

State, controls, noise and array layout: ``docs/conventions.md`` (state axis first).
"""

import dataclasses
import math
from dataclasses import dataclass, field
from typing import ClassVar, Literal

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import least_squares

from immukf_sitl.models.earth import (
    ISA_DENSITY_EXPONENT,
    ISA_EARTH_RADIUS_M,
    ISA_LAPSE_OVER_T0_PM,
    ISA_RHO0_KGPM3,
    NedOrigin,
    isa_density_kgpm3,
    isa_density_unchecked,
    normal_gravity_mps2,
)
from immukf_sitl.models.params import AeroCoefficients, AircraftParams, Propulsion

__all__ = [
    "ACCEL_NOISE_MPS2",
    "GYRO_NOISE_RADPS",
    "AeroModel",
    "drag_coefficient",
    "lift_coefficient",
    "propeller_thrust_torque",
    "stall_blend_sigma",
]

#: Accelerometer white-noise sigma (Beard & McLain ch. 7: 0.0025 g).
ACCEL_NOISE_MPS2 = 0.0245
#: Rate-gyro white-noise sigma (Beard & McLain ch. 7: 0.13 deg/s).
GYRO_NOISE_RADPS = 0.00227
#: Process noise is this many times the IMU noise (paper, section 3).
PROCESS_NOISE_FACTOR = 100.0

_TWO_PI = 2.0 * math.pi


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
    alpha = np.asarray(alpha_rad, dtype=float)
    e_minus = np.exp(-M * (alpha - alpha0_rad))
    e_plus = np.exp(M * (alpha + alpha0_rad))
    # eq. (4.10)
    return (1.0 + e_minus + e_plus) / ((1.0 + e_minus) * (1.0 + e_plus))


def lift_coefficient(alpha_rad: ArrayLike, aero: AeroCoefficients) -> np.ndarray:
    """Static lift coefficient C_L(alpha) with stall blending (Beard & McLain eq. 4.9)."""
    alpha = np.asarray(alpha_rad, dtype=float)
    sigma = stall_blend_sigma(alpha, aero.M, aero.alpha0_rad)
    sin_a = np.sin(alpha)
    flat_plate = 2.0 * np.sign(alpha) * sin_a * sin_a * np.cos(alpha)
    # eq. (4.9)
    return (1.0 - sigma) * (aero.C_L_0 + aero.C_L_alpha * alpha) + sigma * flat_plate


def drag_coefficient(alpha_rad: ArrayLike, aero: AeroCoefficients) -> np.ndarray:
    """Static drag coefficient, the linear law C_D = C_D_0 + C_D_alpha alpha (DESIGN.md s. 6)."""
    return aero.C_D_0 + aero.C_D_alpha * np.asarray(alpha_rad, dtype=float)


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
    Omega occurs.

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
    return _prop_thrust_torque(
        np.asarray(Va_mps, dtype=float),
        np.asarray(delta_t, dtype=float),
        np.asarray(rho_kgpm3, dtype=float),
        _PropConstants.of(prop),
    )


@dataclass(frozen=True)
class _PropConstants:
    """Propeller coefficients with the powers of D folded in (per unit density)."""

    a_q: float  # D^5 C_Q0 / (2 pi)^2
    b_q: float  # D^4 C_Q1 / (2 pi)
    c_q: float  # D^3 C_Q2
    b_motor: float  # K_Q K_V / R
    c_volt: float  # K_Q V_max / R
    c_i0: float  # K_Q i0
    t_0: float  # D^4 C_T0 / (2 pi)^2
    t_1: float  # D^3 C_T1 / (2 pi)
    t_2: float  # D^2 C_T2

    @classmethod
    def of(cls, prop: Propulsion) -> "_PropConstants":
        d = prop.prop_diameter_m
        kq = prop.K_Q_Nm_per_A
        kv = prop.K_V_Vs_per_rad
        return cls(
            a_q=d**5 * prop.C_Q[0] / _TWO_PI**2,
            b_q=d**4 * prop.C_Q[1] / _TWO_PI,
            c_q=d**3 * prop.C_Q[2],
            b_motor=kq * kv / prop.R_motor_ohm,
            c_volt=kq * prop.V_max_V / prop.R_motor_ohm,
            c_i0=kq * prop.i0_A,
            t_0=d**4 * prop.C_T[0] / _TWO_PI**2,
            t_1=d**3 * prop.C_T[1] / _TWO_PI,
            t_2=d**2 * prop.C_T[2],
        )


def _prop_thrust_torque(
    va: np.ndarray, delta_t: np.ndarray, rho: np.ndarray, k: _PropConstants
) -> tuple[np.ndarray, np.ndarray]:
    # Supplement ch. 4: motor-propeller torque balance, positive root for Omega.
    a = rho * k.a_q
    b = rho * k.b_q * va + k.b_motor
    c = rho * k.c_q * va * va - k.c_volt * delta_t + k.c_i0
    disc = np.maximum(b * b - 4.0 * a * c, 0.0)  # >= 0 for every physical input; guards sigmas
    omega = -2.0 * c / (b + np.sqrt(disc))
    omega_va = omega * va
    omega2 = omega * omega
    va2 = va * va
    # T = rho n^2 D^4 C_T(J), Q = rho n^2 D^5 C_Q(J), expanded in Omega and Va
    thrust = rho * (k.t_0 * omega2 + k.t_1 * omega_va + k.t_2 * va2)
    torque = rho * (k.a_q * omega2 + k.b_q * omega_va + k.c_q * va2)
    return thrust, torque


def _writeable_contiguous(a: np.ndarray) -> np.ndarray:
    """``a`` as a C-contiguous float array the kernels accept (a copy only when needed)."""
    a = np.ascontiguousarray(a, dtype=float)
    return a if a.flags.writeable else a.copy()


def _wrap_pi(angle: np.ndarray) -> np.ndarray:
    """Wrap angles to [-pi, pi)."""
    return (angle + math.pi) % _TWO_PI - math.pi


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
    backend : {"auto", "numpy", "numba"}
        Implementation of :meth:`step`, :meth:`derivatives` and :meth:`imu`: the numpy code is
        the reference; "numba" runs compiled loops of the same equations (about 20 times
        faster on a (12, 7, 49) batch); "auto" takes numba when it is installed.

    Notes
    -----
    Every vectorised method takes the state axis first and any batch axes after it:
    ``x`` ``(12, *batch)``, ``u`` ``(4,)`` or ``(4, *batch)``, ``v`` ``(6, *batch)``, ``(6,)``
    or None. Euler angles have a singularity at ``|theta| = 90 deg``, outside a fixed-wing
    envelope and not handled.
    """

    params: AircraftParams
    origin: NedOrigin = NedOrigin(0.0, 0.0, 0.0)
    dt_s: float = 0.01
    density_kgpm3: float | None = None
    gravity_mps2: float | None = None
    gravity_gradient_ps2: float | None = None
    backend: Literal["auto", "numpy", "numba"] = "auto"

    nx: ClassVar[int] = 12
    nu: ClassVar[int] = 4
    nv: ClassVar[int] = 6
    state_labels: ClassVar[tuple[str, ...]] = (
        "pN_m",
        "pE_m",
        "pD_m",
        "u_mps",
        "v_mps",
        "w_mps",
        "phi_rad",
        "theta_rad",
        "psi_rad",
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

    _c: dict = field(init=False, repr=False, compare=False)
    _kernel: object = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not self.dt_s > 0.0:
            raise ValueError(f"AeroModel.dt_s: expected > 0, got {self.dt_s}")
        p = self.params
        m, g = p.mass, p.geometry
        jx, jy, jz, jxz = m.Jx_kgm2, m.Jy_kgm2, m.Jz_kgm2, m.Jxz_kgm2
        gam = jx * jz - jxz**2  # eq. (3.13)
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
        r_imu = np.asarray(g.imu_position_m, dtype=float)
        c = {
            # eq. (3.13): Gamma terms of the inertia matrix
            "G1": jxz * (jx - jy + jz) / gam,
            "G2": (jz * (jz - jy) + jxz**2) / gam,
            "G3": jz / gam,
            "G4": jxz / gam,
            "G5": (jz - jx) / jy,
            "G6": jxz / jy,
            "G7": ((jx - jy) * jx + jxz**2) / gam,
            "G8": jx / gam,
            "inv_jy": 1.0 / jy,
            "inv_mass": 1.0 / m.mass_kg,
            "g0": g0,
            "dg": dg,
            "h0": h0,
            "rho": self.density_kgpm3,
            "c_2": 0.5 * g.c_m,  # c / 2 multiplies q / Va
            "b_2": 0.5 * g.b_m,  # b / 2 multiplies p / Va, r / Va
            "prop": _PropConstants.of(p.propulsion),
            "torque_on_roll": p.propulsion.prop_torque_on_roll,
            "imu_lever": r_imu if np.any(r_imu != 0.0) else None,
        }
        object.__setattr__(self, "_c", c)
        object.__setattr__(self, "_kernel", self._make_kernel())

    def _make_kernel(self) -> "tuple[object, np.ndarray] | None":
        """The numba module and its packed constants, or None for the numpy reference."""
        if self.backend == "numpy":
            return None
        try:
            from immukf_sitl.models import _aero_numba
        except ImportError:
            if self.backend == "numba":
                raise
            return None
        c = self._c
        a = self.params.aero
        g = self.params.geometry
        values = {name: c[name] for name in ("G1", "G2", "G3", "G4", "G5", "G6", "G7", "G8")}
        values |= {name: c[name] for name in ("inv_jy", "inv_mass", "g0", "dg", "h0")}
        values |= {
            "rho_const": -1.0 if c["rho"] is None else c["rho"],
            "S": g.S_m2,
            "b": g.b_m,
            "c": g.c_m,
            "c_2": c["c_2"],
            "b_2": c["b_2"],
            "alpha0": a.alpha0_rad,
            "torque_on_roll": 1.0 if c["torque_on_roll"] else 0.0,
            "isa_r0": ISA_EARTH_RADIUS_M,
            "isa_lapse_t0": ISA_LAPSE_OVER_T0_PM,
            "isa_rho0": ISA_RHO0_KGPM3,
            "isa_exp": ISA_DENSITY_EXPONENT,
        }
        lever = c["imu_lever"]
        values |= dict(zip(("imu_rx", "imu_ry", "imu_rz"), (0.0, 0.0, 0.0) if lever is None
                           else lever, strict=True))  # fmt: skip
        values["has_lever"] = 0.0 if lever is None else 1.0
        values |= {f.name: getattr(a, f.name) for f in dataclasses.fields(a)}
        values |= dataclasses.asdict(c["prop"])
        return _aero_numba, _aero_numba.pack_constants(values)

    @property
    def uses_numba(self) -> bool:
        """True when the compiled kernels are in use."""
        return self._kernel is not None

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

    # -----------------------------------------------------------------------------------------
    # constructors and noise

    @classmethod
    def at_origin(
        cls, params: AircraftParams, origin: NedOrigin, dt_s: float = 0.01
    ) -> "AeroModel":
        """Model about ``origin`` with normal gravity and ISA density there (the defaults)."""
        return cls(params=params, origin=origin, dt_s=dt_s)

    @staticmethod
    def process_noise_cov() -> np.ndarray:
        """Default process noise covariance Q (6x6) of ``v``.

        Diagonal: ``(100 * 0.0245 m/s^2)^2`` on u_dot, v_dot, w_dot and
        ``(100 * 0.00227 rad/s^2)^2`` on p_dot, q_dot, r_dot (paper, section 3: model
        uncertainty two orders of magnitude above the IMU noise, Beard & McLain ch. 7).
        """
        sig = PROCESS_NOISE_FACTOR * np.array([ACCEL_NOISE_MPS2] * 3 + [GYRO_NOISE_RADPS] * 3)
        return np.diag(sig**2)

    # -----------------------------------------------------------------------------------------
    # forces and moments

    def density(self, x: np.ndarray) -> np.ndarray | float:
        """Air density (kg/m^3) at the state's altitude (ISA) or the constant override."""
        rho = self._c["rho"]
        if rho is not None:
            return rho
        return isa_density_kgpm3(self._c["h0"] - np.asarray(x)[2])

    def forces_moments(self, t_s: float, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Aerodynamic + propulsive forces and moments in body axes, gravity excluded.

        Returns
        -------
        numpy.ndarray
            ``(6, *batch)`` ``[f_x, f_y, f_z (N), l, m, n (N m)]`` about the CG.
        """
        x = np.asarray(x, dtype=float)
        out = np.empty((6, *x.shape[1:]), dtype=float)
        self._forces_moments_into(x, np.asarray(u, dtype=float), out)
        return out

    def _forces_moments_into(self, x: np.ndarray, u: np.ndarray, out: np.ndarray) -> None:
        """Forces and moments into ``out`` (6, *batch) with the selected backend."""
        if self._kernel is not None:
            module, consts = self._kernel
            n = x[0].size
            x2, u2 = self._flat_xu(x, u, n)
            module.forces_moments_batch(x2, u2, consts, out.reshape(6, n))
            return
        self._forces_moments(x, u, out)

    def _forces_moments(self, x: np.ndarray, u: np.ndarray, out: np.ndarray) -> None:
        """Fill ``out[0:6]`` with body forces (N) and moments (N m) about the CG."""
        c = self._c
        a = self.params.aero
        uu, vv, ww = x[3], x[4], x[5]
        p, q, r = x[9], x[10], x[11]
        de, da, dr, dt = u[0], u[1], u[2], u[3]
        rho = c["rho"] if c["rho"] is not None else isa_density_unchecked(c["h0"] - x[2])

        va2 = uu * uu + vv * vv + ww * ww
        va = np.sqrt(va2)
        alpha = np.arctan2(ww, uu)  # eq. (2.8)
        beta = np.arctan2(vv, np.sqrt(uu * uu + ww * ww))  # eq. (2.8), = asin(v / Va)
        ca = np.cos(alpha)
        sa = np.sin(alpha)
        # dynamic pressure; the rate terms 1/2 rho Va^2 C (c q / (2 Va)) are written as
        # 1/2 rho Va C (c/2) q, which stays finite at Va = 0
        qbar = 0.5 * rho * va2
        qv = 0.5 * rho * va

        # lift and drag coefficients, eqs. (4.9), (4.10); linear drag (DESIGN.md s. 6)
        e_minus = np.exp(-a.M * (alpha - a.alpha0_rad))
        e_plus = np.exp(a.M * (alpha + a.alpha0_rad))
        sigma = (1.0 + e_minus + e_plus) / ((1.0 + e_minus) * (1.0 + e_plus))
        c_lift = (1.0 - sigma) * (a.C_L_0 + a.C_L_alpha * alpha) + sigma * (
            2.0 * np.sign(alpha) * sa * sa * ca
        )
        c_drag = a.C_D_0 + a.C_D_alpha * alpha
        cq = c["c_2"] * q
        s = self.params.geometry.S_m2
        # eq. (4.6), (4.7): stability-axis lift and drag (N)
        lift = s * (qbar * (c_lift + a.C_L_delta_e * de) + qv * a.C_L_q * cq)
        drag = s * (qbar * (c_drag + a.C_D_delta_e * de) + qv * a.C_D_q * cq)

        bp = c["b_2"] * p
        br = c["b_2"] * r
        thrust, torque = _prop_thrust_torque(va, dt, rho, c["prop"])

        # eq. (4.18): stability -> body; side force eq. (4.14)
        out[0] = -ca * drag + sa * lift + thrust
        out[1] = s * (
            qbar * (a.C_Y_0 + a.C_Y_beta * beta + a.C_Y_delta_a * da + a.C_Y_delta_r * dr)
            + qv * (a.C_Y_p * bp + a.C_Y_r * br)
        )
        out[2] = -sa * drag - ca * lift
        # eq. (4.19): moments in body axes
        b_m = self.params.geometry.b_m
        roll = (
            s
            * b_m
            * (
                qbar
                * (a.C_ell_0 + a.C_ell_beta * beta + a.C_ell_delta_a * da + a.C_ell_delta_r * dr)
                + qv * (a.C_ell_p * bp + a.C_ell_r * br)
            )
        )
        if c["torque_on_roll"]:
            roll = roll - torque  # reaction of the propeller torque (supplement ch. 4)
        out[3] = roll
        out[4] = (
            s
            * self.params.geometry.c_m
            * (qbar * (a.C_m_0 + a.C_m_alpha * alpha + a.C_m_delta_e * de) + qv * a.C_m_q * cq)
        )
        out[5] = (
            s
            * b_m
            * (
                qbar * (a.C_n_0 + a.C_n_beta * beta + a.C_n_delta_a * da + a.C_n_delta_r * dr)
                + qv * (a.C_n_p * bp + a.C_n_r * br)
            )
        )

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
        if self._kernel is not None:
            module, consts = self._kernel
            n = x[0].size
            x2, u2, v2 = self._flat(x, u, v, n)
            module.derivatives_batch(x2, u2, v2, consts, out.reshape(x.shape[0], n))
            return out
        self._derivatives(x, u, v, out)
        return out

    def _derivatives(
        self, x: np.ndarray, u: np.ndarray, v: np.ndarray | None, out: np.ndarray
    ) -> None:
        c = self._c
        uu, vv, ww = x[3], x[4], x[5]
        phi, theta, psi = x[6], x[7], x[8]
        p, q, r = x[9], x[10], x[11]
        sph, cph = np.sin(phi), np.cos(phi)
        sth, cth = np.sin(theta), np.cos(theta)
        sps, cps = np.sin(psi), np.cos(psi)

        # eq. (3.14): NED position rates, R_nb = Rz(psi) Ry(theta) Rx(phi) times body velocity
        sph_sth = sph * sth
        cph_sth = cph * sth
        out[0] = (
            cth * cps * uu + (sph_sth * cps - cph * sps) * vv + (cph_sth * cps + sph * sps) * ww
        )
        out[1] = (
            cth * sps * uu + (sph_sth * sps + cph * cps) * vv + (cph_sth * sps - sph * cps) * ww
        )
        out[2] = -sth * uu + sph * cth * vv + cph * cth * ww

        # forces and moments into rows 3..8 of out, used as scratch before being overwritten
        fm = out[3:9]
        self._forces_moments(x, u, fm)
        fx, fy, fz, ell, em, en = fm[0], fm[1], fm[2], fm[3], fm[4], fm[5]

        # eq. (3.15) with gravity in body axes (eq. 4.3); flat earth, normal gravity at height
        grav = c["g0"] + c["dg"] * x[2]
        inv_m = c["inv_mass"]
        u_dot = r * vv - q * ww + fx * inv_m - grav * sth
        v_dot = p * ww - r * uu + fy * inv_m + grav * cth * sph
        w_dot = q * uu - p * vv + fz * inv_m + grav * cth * cph
        # eq. (3.17)
        p_dot = c["G1"] * p * q - c["G2"] * q * r + c["G3"] * ell + c["G4"] * en
        q_dot = c["G5"] * p * r - c["G6"] * (p * p - r * r) + c["inv_jy"] * em
        r_dot = c["G7"] * p * q - c["G1"] * q * r + c["G4"] * ell + c["G8"] * en

        out[3] = u_dot
        out[4] = v_dot
        out[5] = w_dot
        # eq. (3.16): Euler angle rates
        tth = sth / cth
        out[6] = p + (q * sph + r * cph) * tth
        out[7] = q * cph - r * sph
        out[8] = (q * sph + r * cph) / cth
        out[9] = p_dot
        out[10] = q_dot
        out[11] = r_dot
        if v is not None:
            v = np.asarray(v, dtype=float)
            if v.ndim == 1 and x.ndim > 1:
                v = v.reshape((6,) + (1,) * (x.ndim - 1))
            out[3:6] += v[0:3]
            out[9:12] += v[3:6]

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
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        if self._kernel is not None:
            module, consts = self._kernel
            n = x[0].size
            x2, u2, v2 = self._flat(x, u, v, n)
            out = np.empty(x.shape, dtype=float)
            module.step_batch(x2, u2, v2, consts, self.dt_s, out.reshape(x.shape[0], n))
            return out
        h = self.dt_s
        k = np.empty(x.shape, dtype=float)
        acc = np.empty(x.shape, dtype=float)
        xt = np.empty(x.shape, dtype=float)
        self._derivatives(x, u, v, k)  # k1
        acc[...] = k
        np.multiply(k, 0.5 * h, out=xt)
        xt += x
        self._derivatives(xt, u, v, k)  # k2
        acc += 2.0 * k
        np.multiply(k, 0.5 * h, out=xt)
        xt += x
        self._derivatives(xt, u, v, k)  # k3
        acc += 2.0 * k
        np.multiply(k, h, out=xt)
        xt += x
        self._derivatives(xt, u, v, k)  # k4
        acc += k
        acc *= h / 6.0
        acc += x
        acc[6] = _wrap_pi(acc[6])
        acc[8] = _wrap_pi(acc[8])
        return acc

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
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        c = self._c
        out = np.empty((6, *x.shape[1:]), dtype=float)
        if self._kernel is not None:
            module, consts = self._kernel
            n = x[0].size
            x2, u2 = self._flat_xu(x, u, n)
            module.imu_batch(x2, u2, consts, out.reshape(6, n))
            return out
        self._forces_moments(x, u, out)
        lever = c["imu_lever"]
        p, q, r = x[9], x[10], x[11]
        if lever is not None:
            ell, em, en = out[3].copy(), out[4].copy(), out[5].copy()
            p_dot = c["G1"] * p * q - c["G2"] * q * r + c["G3"] * ell + c["G4"] * en
            q_dot = c["G5"] * p * r - c["G6"] * (p * p - r * r) + c["inv_jy"] * em
            r_dot = c["G7"] * p * q - c["G1"] * q * r + c["G4"] * ell + c["G8"] * en
        out[0:3] *= c["inv_mass"]
        if lever is not None:
            rx, ry, rz = lever
            # omega x r and omega_dot x r
            wr_x = q * rz - r * ry
            wr_y = r * rx - p * rz
            wr_z = p * ry - q * rx
            out[0] += (q_dot * rz - r_dot * ry) + (q * wr_z - r * wr_y)
            out[1] += (r_dot * rx - p_dot * rz) + (r * wr_x - p * wr_z)
            out[2] += (p_dot * ry - q_dot * rx) + (p * wr_y - q * wr_x)
        out[3] = p
        out[4] = q
        out[5] = r
        return out

    def gps(self, t_s: float, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Predicted noise-free GPS ``[pN, pE, pD (m), ground speed (m/s), course (rad)]``.

        Ground speed is horizontal, ``sqrt(vN^2 + vE^2)``, and course ``atan2(vE, vN)`` in
        ``(-pi, pi]`` (no wind, so the ground velocity is the air velocity rotated to NED).
        """
        x = np.asarray(x, dtype=float)
        uu, vv, ww = x[3], x[4], x[5]
        sph, cph = np.sin(x[6]), np.cos(x[6])
        sth, cth = np.sin(x[7]), np.cos(x[7])
        sps, cps = np.sin(x[8]), np.cos(x[8])
        # eq. (3.14)
        v_n = (
            cth * cps * uu + (sph * sth * cps - cph * sps) * vv + (cph * sth * cps + sph * sps) * ww
        )
        v_e = (
            cth * sps * uu + (sph * sth * sps + cph * cps) * vv + (cph * sth * sps - sph * cps) * ww
        )
        out = np.empty((5, *x.shape[1:]), dtype=float)
        out[0:3] = x[0:3]
        out[3] = np.hypot(v_n, v_e)
        out[4] = np.arctan2(v_e, v_n)
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
