"""The aircraft's equations, written once: plain functions, compiled by numba for the hot path.

Every equation of :class:`immukf_sitl.models.aero.AeroModel` (forces and moments, the rigid-body
derivatives, the RK4 step, the IMU and GPS outputs, the stall blend and the propeller) is here,
once, as a Python function of one column of the state, in the subset of Python that numba
compiles. The same code serves twice:

- **compiled**: each kernel is a ``numba.njit(inline="always")`` dispatcher, and the ``*_batch``
  loops (``numba.njit``) call them column by column over a flattened batch, ``x`` ``(12, N)``,
  with every kernel inlined;
- **uncompiled**: :data:`uncompiled` holds the kernels' Python functions (``.py_func``) bound to
  each other instead of to the dispatchers, so no numba is involved. Since the kernels index the
  state only along its first axis they accept whole rows as well: with ``x`` ``(12, *batch)``,
  ``x[3]`` is the row of ``u`` and numpy evaluates a kernel over the batch at once. That is
  ``AeroModel(compiled=False)``, the reference the compiled loops are tested against, and what
  the public coefficient helpers of :mod:`immukf_sitl.models.aero` run.

So that both uses agree, a kernel branches on constants only (the density switch, the lever
arm), never on a state value: ``np.sign``, ``np.maximum`` and a masked division stand in for
``if``, ``torque_on_roll`` is a factor 0 or 1, and every elementary function is a numpy ufunc
(numba compiles those for floats).

Cost notes (the IMM's 259-column RK4 batch is about half of a 200 us filter step):

- the kernels are inlined into the loops (as separate functions every call paid reference
  counting on its array arguments, as much as the aerodynamics cost);
- :func:`rk4_step` runs its four stages as a loop around one call site, so the inlined derivative
  is compiled once;
- no call of a kernel taking an array sits in a branch, and such kernels have one exit
  (:func:`air_density`, which returns from a branch, takes scalars): either defeats numba's
  reference-count pruning (an incref/decref pair per call, +20 % on the RK4 loop);
- ``cos(alpha)`` and ``sin(alpha)`` are ``u / sqrt(u^2 + w^2)`` and ``w / sqrt(u^2 + w^2)``,
  without two more transcendental calls. What remains per stage is libm: three ``sin``/``cos``
  pairs of the Euler angles, two ``atan2``, two ``exp`` of the stall blend and one ``pow`` of the
  ISA density;
- ``numba.extending.register_jitable`` would give plain functions without :data:`uncompiled`, but
  its inlining made the first compile of ``step_batch`` 15 times slower.

References: Beard & McLain, *Small Unmanned Aircraft*, 2012 (B&M), ch. 2-4 and the authors'
supplement (propeller, ch. 4); the model's assumptions are in :mod:`immukf_sitl.models.aero`.
"""

from __future__ import annotations

import dataclasses
import math
import types
from collections.abc import Callable
from typing import NamedTuple, TypeAlias

import numba
import numpy as np

from immukf_sitl.models import earth
from immukf_sitl.models.params import AircraftParams, Propulsion

__all__ = [
    "NAMES",
    "N_DYNAMIC_EXTRA",
    "N_EXTRA",
    "N_OUTPUT_EXTRA",
    "Rk4Work",
    "air_density",
    "air_relative",
    "angular_acceleration",
    "derivatives",
    "derivatives_batch",
    "drag_coefficient",
    "euler_trig",
    "forces_moments",
    "forces_moments_batch",
    "gps",
    "imu",
    "imu_batch",
    "lift_coefficient",
    "pack_constants",
    "pack_propulsion",
    "propeller",
    "rk4_step",
    "rotate_body_to_ned",
    "rotate_ned_to_body",
    "stall_blend_sigma",
    "step_batch",
    "uncompiled",
    "wrap_pi",
]


#: A float in the compiled loops, or a row of a batch when run uncompiled.
Value: TypeAlias = "float | np.ndarray"
_KERNELS: list[numba.core.dispatcher.Dispatcher] = []


def _kernel(fn: Callable) -> numba.core.dispatcher.Dispatcher:
    """``fn`` compiled for inlining into the batch loops; ``.py_func`` is ``fn`` itself."""
    dispatcher = numba.njit(inline="always", error_model="numpy")(fn)
    _KERNELS.append(dispatcher)
    return dispatcher


# The ISA troposphere of the earth module, compiled into the kernels (one formula for both).
isa_density = _kernel(earth.isa_density_unchecked)

# ---------------------------------------------------------------------------------------------
# the packed constant vector k

#: Names of the entries of ``k``, in order. The aerodynamic coefficients are named as the fields
#: of :class:`~immukf_sitl.models.params.AeroCoefficients`; :func:`_lateral` relies on the six of
#: each lateral axis following each other here as ``0, beta, p, r, delta_a, delta_r``.
NAMES = (
    "G1 G2 G3 G4 G5 G6 G7 G8 inv_Jy inv_mass g0 dg h0 rho S b c b_2 c_2 "
    "C_L_0 C_L_alpha C_L_q C_L_delta_e M alpha0_rad C_D_0 C_D_alpha C_D_q C_D_delta_e "
    "C_m_0 C_m_alpha C_m_q C_m_delta_e "
    "C_Y_0 C_Y_beta C_Y_p C_Y_r C_Y_delta_a C_Y_delta_r "
    "C_ell_0 C_ell_beta C_ell_p C_ell_r C_ell_delta_a C_ell_delta_r "
    "C_n_0 C_n_beta C_n_p C_n_r C_n_delta_a C_n_delta_r "
    "a_q b_q c_q b_motor c_volt c_i0 t_0 t_1 t_2 torque_on_roll "
    "imu_rx imu_ry imu_rz"
).split()
(
    G1, G2, G3, G4, G5, G6, G7, G8, INV_JY, INV_MASS, G0, DG, H0, RHO, S, B, C, B_2, C_2,
    CL0, CLA, CLQ, CLDE, M_BLEND, ALPHA0, CD0, CDA, CDQ, CDDE,
    CM0, CMA, CMQ, CMDE,
    CY0, CYB, CYP, CYR, CYDA, CYDR,
    CELL0, CELLB, CELLP, CELLR, CELLDA, CELLDR,
    CN0, CNB, CNP, CNR, CNDA, CNDR,
    A_Q, B_Q, C_Q, B_MOTOR, C_VOLT, C_I0, T_0, T_1, T_2, TORQUE_ON_ROLL,
    IMU_RX, IMU_RY, IMU_RZ,
) = range(len(NAMES))  # fmt: skip
_TWO_PI = 2.0 * math.pi

#: Layout of ``e``, the slowly varying states of the filter's model that follow the 12 rigid-body
#: states (:class:`immukf_sitl.models.augmented.AugmentedAeroModel`; zeros for the aircraft
#: itself): wind NED (m/s), specific-force corrections x, y, z (m/s^2), angular-acceleration
#: corrections p, q, r (rad/s^2), rotational gusts p, q, r (rad/s, the air's rotation about the
#: aircraft), gyro biases p, q, r (rad/s), GPS position errors NED (m).
WIND_N, WIND_E, WIND_D = 0, 1, 2
FORCE_X = 3
MOMENT_P = 6
GUST_P = 9
GYRO_BIAS_P = 12
GPS_ERROR_N = 15
N_EXTRA = 18
#: The entries of ``e`` that :func:`derivatives` reads: all before the gyro biases, which only
#: :func:`imu` reads, and the GPS errors, which only :func:`gps` reads. Those come last, so that
#: a sigma point that moves only them (a lower Cholesky factor's last columns touch no other
#: row) flies as its centre, and one that moves only the GPS errors reads the IMU as it.
N_DYNAMIC_EXTRA = GYRO_BIAS_P
#: The entries of ``e`` that :func:`imu` reads: all before the GPS errors.
N_OUTPUT_EXTRA = GPS_ERROR_N


def _pack(values: dict[str, float]) -> np.ndarray:
    """``k`` from a name -> value mapping; names not given are zero."""
    unknown = set(values) - set(NAMES)
    if unknown:
        raise KeyError(f"unknown kernel constants: {sorted(unknown)}")
    return np.array([float(values.get(name, 0.0)) for name in NAMES])


def _propulsion_values(prop: Propulsion) -> dict[str, float]:
    """Propeller coefficients with the powers of D folded in (per unit density)."""
    d = prop.prop_diameter_m
    kq = prop.K_Q_Nm_per_A
    return {
        "a_q": d**5 * prop.C_Q[0] / _TWO_PI**2,
        "b_q": d**4 * prop.C_Q[1] / _TWO_PI,
        "c_q": d**3 * prop.C_Q[2],
        "b_motor": kq * prop.K_V_Vs_per_rad / prop.R_motor_ohm,
        "c_volt": kq * prop.V_max_V / prop.R_motor_ohm,
        "c_i0": kq * prop.i0_A,
        "t_0": d**4 * prop.C_T[0] / _TWO_PI**2,
        "t_1": d**3 * prop.C_T[1] / _TWO_PI,
        "t_2": d**2 * prop.C_T[2],
        "torque_on_roll": float(prop.prop_torque_on_roll),
    }


def pack_propulsion(prop: Propulsion) -> np.ndarray:
    """A constant vector ``k`` holding only the propeller's entries (for :func:`propeller`)."""
    return _pack(_propulsion_values(prop))


def pack_constants(
    params: AircraftParams,
    *,
    gravity_mps2: float,
    gravity_gradient_ps2: float,
    origin_alt_m: float,
    density_kgpm3: float | None,
) -> np.ndarray:
    """The constant vector ``k`` of the kernels, entries named by :data:`NAMES`.

    Parameters
    ----------
    params : AircraftParams
        Mass, geometry, coefficients and propulsion.
    gravity_mps2, gravity_gradient_ps2 : float
        Gravity at ``pD = 0`` and its derivative ``d g / d pD``.
    origin_alt_m : float
        Altitude of ``pD = 0`` above mean sea level (the ISA density's reference).
    density_kgpm3 : float or None
        Constant air density, or None for ISA at the state's altitude (stored as -1).

    Returns
    -------
    numpy.ndarray
        ``(len(NAMES),)`` constants.
    """
    m, g = params.mass, params.geometry
    jx, jy, jz, jxz = m.Jx_kgm2, m.Jy_kgm2, m.Jz_kgm2, m.Jxz_kgm2
    gam = jx * jz - jxz**2  # B&M eq. (3.13): the Gamma terms of the inertia matrix
    lever = tuple(float(r) for r in g.imu_position_m)
    values = {
        "G1": jxz * (jx - jy + jz) / gam,
        "G2": (jz * (jz - jy) + jxz**2) / gam,
        "G3": jz / gam,
        "G4": jxz / gam,
        "G5": (jz - jx) / jy,
        "G6": jxz / jy,
        "G7": ((jx - jy) * jx + jxz**2) / gam,
        "G8": jx / gam,
        "inv_Jy": 1.0 / jy,
        "inv_mass": 1.0 / m.mass_kg,
        "g0": gravity_mps2,
        "dg": gravity_gradient_ps2,
        "h0": origin_alt_m,
        "rho": -1.0 if density_kgpm3 is None else density_kgpm3,
        "S": g.S_m2,
        "b": g.b_m,
        "c": g.c_m,
        "b_2": 0.5 * g.b_m,  # b / 2 multiplies p / Va and r / Va
        "c_2": 0.5 * g.c_m,  # c / 2 multiplies q / Va
        "imu_rx": lever[0],
        "imu_ry": lever[1],
        "imu_rz": lever[2],
    }
    aero = dataclasses.asdict(params.aero)
    values |= {name: aero[name] for name in NAMES if name in aero}
    values |= _propulsion_values(params.propulsion)
    return _pack(values)


# ---------------------------------------------------------------------------------------------
# aerodynamic and propeller laws


@_kernel
def stall_blend_sigma(alpha: Value, m: float, alpha0: float) -> Value:
    """Stall blending function sigma(alpha) in [0, 1], B&M eq. (4.10)."""
    e_minus = np.exp(-m * (alpha - alpha0))
    e_plus = np.exp(m * (alpha + alpha0))
    return (1.0 + e_minus + e_plus) / ((1.0 + e_minus) * (1.0 + e_plus))  # B&M eq. (4.10)


@_kernel
def lift_coefficient(
    alpha: Value,
    sin_alpha: Value,
    cos_alpha: Value,
    c_l_0: float,
    c_l_alpha: float,
    m: float,
    alpha0: float,
) -> Value:
    """Static lift coefficient blended into a flat plate beyond stall, B&M eq. (4.9)."""
    sigma = stall_blend_sigma(alpha, m, alpha0)
    flat_plate = 2.0 * np.sign(alpha) * sin_alpha * sin_alpha * cos_alpha
    return (1.0 - sigma) * (c_l_0 + c_l_alpha * alpha) + sigma * flat_plate  # B&M eq. (4.9)


@_kernel
def drag_coefficient(alpha: Value, c_d_0: float, c_d_alpha: float) -> Value:
    """Static drag coefficient, linear in alpha (the truth aircraft uses the same law)."""
    return c_d_0 + c_d_alpha * alpha


@_kernel
def propeller(va: Value, delta_t: Value, rho: Value, k: np.ndarray) -> tuple[Value, Value]:
    """Thrust (N) and torque (N m) of the DC motor + propeller, B&M supplement ch. 4.

    The propeller speed is the positive root of ``a Omega^2 + b Omega + c = 0`` (motor and
    propeller torques balance), in the cancellation-free form ``-2 c / (b + sqrt(b^2 - 4ac))``,
    finite at ``rho = 0``. ``T = rho n^2 D^4 C_T(J)`` and ``Q = rho n^2 D^5 C_Q(J)`` with
    ``n = Omega / 2 pi`` and ``J = Va / (n D)`` are expanded so that nothing divides by Omega.
    """
    a = rho * k[A_Q]
    b = rho * k[B_Q] * va + k[B_MOTOR]
    c = rho * k[C_Q] * va * va - k[C_VOLT] * delta_t + k[C_I0]
    disc = np.maximum(b * b - 4.0 * a * c, 0.0)  # >= 0 for physical inputs; guards sigma points
    omega = -2.0 * c / (b + np.sqrt(disc))
    omega2 = omega * omega
    omega_va = omega * va
    va2 = va * va
    thrust = rho * (k[T_0] * omega2 + k[T_1] * omega_va + k[T_2] * va2)
    torque = rho * (k[A_Q] * omega2 + k[B_Q] * omega_va + k[C_Q] * va2)
    return thrust, torque


@_kernel
def air_density(p_d: Value, rho_const: float, h0: float) -> Value:
    """Air density (kg/m^3): ``rho_const`` if >= 0, else ISA at the altitude ``h0 - pD``."""
    # scalar arguments only: see the cost notes of the module
    if rho_const >= 0.0:
        return rho_const
    return isa_density(h0 - p_d)


@_kernel
def _lateral(k: np.ndarray, i: int, flow: tuple) -> Value:
    """Bracket of B&M eqs. (4.14), (4.19) for the lateral axis whose ``C_0`` is ``k[i]``.

    ``flow`` is ``(qbar, qv, beta, b p / 2, b r / 2, delta_a, delta_r)``, the same for the side
    force, the rolling and the yawing moment.
    """
    qbar, qv, beta, bp, br, delta_a, delta_r = flow
    # k[i:i + 6]: C_0, C_beta, C_p, C_r, C_delta_a, C_delta_r
    static = k[i] + k[i + 1] * beta + k[i + 4] * delta_a + k[i + 5] * delta_r
    return qbar * static + qv * (k[i + 2] * bp + k[i + 3] * br)


@_kernel
def forces_moments(x: np.ndarray, u: np.ndarray, k: np.ndarray, out: np.ndarray) -> None:
    """Body forces (N) and moments (N m) about the CG, gravity excluded, into ``out[0:6]``.

    B&M ch. 4 without wind: lift and drag in stability axes rotated to body by alpha, side
    force and moments in body axes, the propeller's thrust along x and, if ``torque_on_roll``,
    the reaction ``-Q`` of its torque about x. The rate terms ``1/2 rho Va^2 C (c q / 2 Va)`` are
    written ``1/2 rho Va C (c/2) q``, finite at ``Va = 0``.
    """
    uu, vv, ww = x[3], x[4], x[5]
    p, q, r = x[9], x[10], x[11]
    delta_e, delta_a, delta_r, delta_t = u[0], u[1], u[2], u[3]
    rho = air_density(x[2], k[RHO], k[H0])
    va2 = uu * uu + vv * vv + ww * ww
    va = np.sqrt(va2)
    v_uw = np.sqrt(uu * uu + ww * ww)
    alpha = np.arctan2(ww, uu)  # B&M eq. (2.8)
    beta = np.arctan2(vv, v_uw)  # B&M eq. (2.8), = asin(v / Va)
    at_rest = v_uw == 0.0  # there alpha = atan2(0, 0) = 0: cos 1, sin 0
    cos_a = (uu + at_rest) / (v_uw + at_rest)
    sin_a = ww / (v_uw + at_rest)
    qbar = 0.5 * rho * va2
    qv = 0.5 * rho * va

    c_lift = lift_coefficient(alpha, sin_a, cos_a, k[CL0], k[CLA], k[M_BLEND], k[ALPHA0])
    c_drag = drag_coefficient(alpha, k[CD0], k[CDA])
    cq = k[C_2] * q
    s = k[S]
    lift = s * (qbar * (c_lift + k[CLDE] * delta_e) + qv * k[CLQ] * cq)  # B&M eq. (4.6)
    drag = s * (qbar * (c_drag + k[CDDE] * delta_e) + qv * k[CDQ] * cq)  # B&M eq. (4.7)
    thrust, torque = propeller(va, delta_t, rho, k)

    lateral = (qbar, qv, beta, k[B_2] * p, k[B_2] * r, delta_a, delta_r)
    out[0] = -cos_a * drag + sin_a * lift + thrust  # B&M eq. (4.18): stability -> body
    out[1] = s * _lateral(k, CY0, lateral)  # B&M eq. (4.14)
    out[2] = -sin_a * drag - cos_a * lift  # B&M eq. (4.18)
    # B&M eq. (4.19): moments in body axes; the propeller torque's reaction if switched on
    roll = s * k[B] * _lateral(k, CELL0, lateral)
    out[3] = roll - k[TORQUE_ON_ROLL] * torque
    pitch_static = k[CM0] + k[CMA] * alpha + k[CMDE] * delta_e
    out[4] = s * k[C] * (qbar * pitch_static + qv * k[CMQ] * cq)
    out[5] = s * k[B] * _lateral(k, CN0, lateral)


# ---------------------------------------------------------------------------------------------
# rigid-body equations, RK4 and outputs


@_kernel
def euler_trig(x: np.ndarray) -> tuple:
    """``(sin phi, cos phi, sin theta, cos theta, sin psi, cos psi)`` of the state ``x``."""
    return np.sin(x[6]), np.cos(x[6]), np.sin(x[7]), np.cos(x[7]), np.sin(x[8]), np.cos(x[8])


@_kernel
def rotate_body_to_ned(uu: Value, vv: Value, ww: Value, trig: tuple) -> tuple[Value, Value, Value]:
    """Body vector to NED, ``R_nb = Rz(psi) Ry(theta) Rx(phi)`` of B&M eq. (3.14).

    ``trig`` is :func:`euler_trig` of the attitude.
    """
    sph, cph, sth, cth, sps, cps = trig
    sph_sth = sph * sth
    cph_sth = cph * sth
    north = cth * cps * uu + (sph_sth * cps - cph * sps) * vv + (cph_sth * cps + sph * sps) * ww
    east = cth * sps * uu + (sph_sth * sps + cph * cps) * vv + (cph_sth * sps - sph * cps) * ww
    down = -sth * uu + sph * cth * vv + cph * cth * ww
    return north, east, down


@_kernel
def angular_acceleration(
    p: Value, q: Value, r: Value, ell: Value, em: Value, en: Value, k: np.ndarray
) -> tuple[Value, Value, Value]:
    """Body angular acceleration ``(p_dot, q_dot, r_dot)`` (rad/s^2), B&M eq. (3.17)."""
    p_dot = k[G1] * p * q - k[G2] * q * r + k[G3] * ell + k[G4] * en
    q_dot = k[G5] * p * r - k[G6] * (p * p - r * r) + k[INV_JY] * em
    r_dot = k[G7] * p * q - k[G1] * q * r + k[G4] * ell + k[G8] * en
    return p_dot, q_dot, r_dot


@_kernel
def rotate_ned_to_body(
    north: Value, east: Value, down: Value, trig: tuple
) -> tuple[Value, Value, Value]:
    """NED vector to body, ``R_bn = R_nb'`` (the transpose of :func:`rotate_body_to_ned`)."""
    sph, cph, sth, cth, sps, cps = trig
    sph_sth = sph * sth
    cph_sth = cph * sth
    x = cth * cps * north + cth * sps * east - sth * down
    y = (sph_sth * cps - cph * sps) * north + (sph_sth * sps + cph * cps) * east + sph * cth * down
    z = (cph_sth * cps + sph * sps) * north + (cph_sth * sps - sph * cps) * east + cph * cth * down
    return x, y, z


@_kernel
def air_relative(x: np.ndarray, e: np.ndarray, trig: tuple, xa: np.ndarray) -> None:
    """``x`` made relative to the air moving at ``e[0:3]`` (NED) and turning at ``e[9:12]``.

    The forces and moments depend on the velocity through the air, ``v_a = v_g - R_bn w``
    (B&M eq. 2.5), and on the rates relative to the air, ``omega - omega_g`` (the rotational
    gusts of MIL-F-8785C, applied so by JSBSim); the rigid-body equations keep the ground
    velocity and the inertial rates. ``trig`` is :func:`euler_trig` of ``x`` (the caller has
    it).
    """
    w_u, w_v, w_w = rotate_ned_to_body(e[WIND_N], e[WIND_E], e[WIND_D], trig)
    for i in range(12):
        xa[i] = x[i]
    xa[3] = x[3] - w_u
    xa[4] = x[4] - w_v
    xa[5] = x[5] - w_w
    xa[9] = x[9] - e[GUST_P]
    xa[10] = x[10] - e[GUST_P + 1]
    xa[11] = x[11] - e[GUST_P + 2]


@_kernel
def derivatives(
    x: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    e: np.ndarray,
    k: np.ndarray,
    fm: np.ndarray,
    xa: np.ndarray,
    out: np.ndarray,
) -> None:
    """State derivative into ``out[0:12]``, B&M eqs. (3.14)-(3.17); ``fm``, ``xa`` are scratch.

    ``v`` is the process noise added to ``u_dot, v_dot, w_dot`` and ``p_dot, q_dot, r_dot``;
    ``e`` the slowly varying states of the filter's model (:data:`N_EXTRA`; zeros for the
    aircraft itself): the wind sets the air-relative velocity the forces see, the corrections
    add a specific force (m/s^2) and an angular acceleration (rad/s^2). Gravity is the flat
    earth's normal gravity, corrected for height by its gradient.
    """
    uu, vv, ww = x[3], x[4], x[5]
    p, q, r = x[9], x[10], x[11]
    trig = euler_trig(x)
    sph, cph, sth, cth, _, _ = trig
    north, east, down = rotate_body_to_ned(uu, vv, ww, trig)
    out[0] = north  # B&M eq. (3.14)
    out[1] = east
    out[2] = down
    air_relative(x, e, trig, xa)
    forces_moments(xa, u, k, fm)
    grav = k[G0] + k[DG] * x[2]
    inv_m = k[INV_MASS]
    # B&M eq. (3.15), gravity in body axes (eq. 4.3)
    out[3] = r * vv - q * ww + fm[0] * inv_m + e[FORCE_X] - grav * sth + v[0]
    out[4] = p * ww - r * uu + fm[1] * inv_m + e[FORCE_X + 1] + grav * cth * sph + v[1]
    out[5] = q * uu - p * vv + fm[2] * inv_m + e[FORCE_X + 2] + grav * cth * cph + v[2]
    # B&M eq. (3.16): Euler angle rates
    out[6] = p + (q * sph + r * cph) * (sth / cth)
    out[7] = q * cph - r * sph
    out[8] = (q * sph + r * cph) / cth
    p_dot, q_dot, r_dot = angular_acceleration(p, q, r, fm[3], fm[4], fm[5], k)
    out[9] = p_dot + e[MOMENT_P] + v[3]
    out[10] = q_dot + e[MOMENT_P + 1] + v[4]
    out[11] = r_dot + e[MOMENT_P + 2] + v[5]


@_kernel
def wrap_pi(angle: Value) -> Value:
    """Angle wrapped to [-pi, pi)."""
    return (angle + np.pi) % (2.0 * np.pi) - np.pi


class Rk4Work(NamedTuple):
    """Scratch of :func:`rk4_step`.

    The stage state, derivative and sum and the air-relative state (12 rows each), the forces
    and moments (6 rows).
    """

    xt: np.ndarray
    kk: np.ndarray
    acc: np.ndarray
    xa: np.ndarray
    fm: np.ndarray


@_kernel
def rk4_step(
    x: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    e: np.ndarray,
    k: np.ndarray,
    dt: float,
    work: Rk4Work,
    out: np.ndarray,
) -> None:
    """Classical RK4 of ``x[0:12]`` over ``dt``, u, v and e held, into ``out``; phi, psi wrapped."""
    xt, kk, acc, xa, fm = work
    half = 0.5 * dt
    for i in range(12):
        xt[i] = x[i]
    # k1..k4 at x, x + dt/2 k1, x + dt/2 k2, x + dt k3 (one call site: inlined once)
    for stage in range(4):
        derivatives(xt, u, v, e, k, fm, xa, kk)
        if stage == 0:
            for i in range(12):
                acc[i] = kk[i]
                xt[i] = x[i] + half * kk[i]
        elif stage == 1:
            for i in range(12):
                acc[i] += 2.0 * kk[i]
                xt[i] = x[i] + half * kk[i]
        elif stage == 2:
            for i in range(12):
                acc[i] += 2.0 * kk[i]
                xt[i] = x[i] + dt * kk[i]
    for i in range(12):
        out[i] = x[i] + dt / 6.0 * (acc[i] + kk[i])
    out[6] = wrap_pi(out[6])
    out[8] = wrap_pi(out[8])


@_kernel
def imu(
    x: np.ndarray,
    u: np.ndarray,
    e: np.ndarray,
    k: np.ndarray,
    fm: np.ndarray,
    xa: np.ndarray,
    out: np.ndarray,
) -> None:
    """Noise-free IMU ``[f_x, f_y, f_z, p, q, r]`` into ``out[0:6]``; ``fm``, ``xa`` are scratch.

    Specific force (aerodynamic + thrust force over mass, from the air-relative velocity, plus
    the model's correction ``e``) at the CG, moved to the IMU at ``r`` by
    ``+ omega_dot x r + omega x (omega x r)`` when the lever arm is non-zero; the gyros read the
    body rates plus their biases.
    """
    air_relative(x, e, euler_trig(x), xa)
    forces_moments(xa, u, k, fm)
    p, q, r = x[9], x[10], x[11]
    inv_m = k[INV_MASS]
    out[0] = fm[0] * inv_m + e[FORCE_X]
    out[1] = fm[1] * inv_m + e[FORCE_X + 1]
    out[2] = fm[2] * inv_m + e[FORCE_X + 2]
    rx, ry, rz = k[IMU_RX], k[IMU_RY], k[IMU_RZ]
    p_dot, q_dot, r_dot = angular_acceleration(p, q, r, fm[3], fm[4], fm[5], k)
    p_dot += e[MOMENT_P]
    q_dot += e[MOMENT_P + 1]
    r_dot += e[MOMENT_P + 2]
    if rx != 0.0 or ry != 0.0 or rz != 0.0:
        wr_x = q * rz - r * ry  # omega x r
        wr_y = r * rx - p * rz
        wr_z = p * ry - q * rx
        out[0] += (q_dot * rz - r_dot * ry) + (q * wr_z - r * wr_y)
        out[1] += (r_dot * rx - p_dot * rz) + (r * wr_x - p * wr_z)
        out[2] += (p_dot * ry - q_dot * rx) + (p * wr_y - q * wr_x)
    out[3] = p + e[GYRO_BIAS_P]
    out[4] = q + e[GYRO_BIAS_P + 1]
    out[5] = r + e[GYRO_BIAS_P + 2]


@_kernel
def gps(x: np.ndarray, e: np.ndarray, out: np.ndarray) -> None:
    """Noise-free GPS ``[pN, pE, pD, Vg, chi]`` into ``out[0:5]``, and ``vD`` into ``out[5]``.

    Position plus the receiver's slowly wandering error ``e`` (B&M eq. 7.17); ground speed is
    horizontal, ``hypot(vN, vE)``, and course ``atan2(vE, vN)`` in (-pi, pi], both of the
    velocity over the ground (the state's velocity; the wind does not enter). The vertical
    velocity ``vD`` is written where ``out`` has a sixth row (a receiver that reports it).
    """
    v_n, v_e, v_d = rotate_body_to_ned(x[3], x[4], x[5], euler_trig(x))
    if out.shape[0] > 5:
        out[5] = v_d
    out[0] = x[0] + e[GPS_ERROR_N]
    out[1] = x[1] + e[GPS_ERROR_N + 1]
    out[2] = x[2] + e[GPS_ERROR_N + 2]
    out[3] = np.hypot(v_n, v_e)
    out[4] = np.arctan2(v_e, v_n)


# ---------------------------------------------------------------------------------------------
# compiled loops over the columns of a flattened batch


@_kernel
def _column(a: np.ndarray, j: int, col: np.ndarray) -> None:
    """Copy column ``j`` of ``a`` into ``col``."""
    for i in range(col.shape[0]):
        col[i] = a[i, j]


@_kernel
def _bitwise_equal(p: float, q: float) -> bool:
    """Whether ``p`` and ``q`` are the same double: equal, with equal sign bits.

    Only +0 and -0 compare equal with different bits; NaN equals nothing.
    """
    return p == q and math.copysign(1.0, p) == math.copysign(1.0, q)


@_kernel
def _column_repeats(a: np.ndarray, rows: int, j: int, first: int) -> bool:
    """Whether column ``j``'s first ``rows`` entries are bitwise column ``first``'s."""
    for i in range(rows):
        if not _bitwise_equal(a[i, j], a[i, first]):
            return False
    return True


@numba.njit(cache=True, error_model="numpy")
def step_batch(
    x: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    e: np.ndarray,
    k: np.ndarray,
    dt: float,
    period: int,
    out: np.ndarray,
) -> int:
    """:func:`rk4_step` of every column of x (12, N), u (4, N), v (6, N), e (15, N) into out.

    ``out`` is (12, N); ``e`` is not advanced (the caller owns the slow states' dynamics).
    Columns come in groups of ``period`` (a filter's sigma points, centre first): a column whose
    inputs (``x``, ``u``, ``v`` and the ``N_DYNAMIC_EXTRA`` entries of ``e`` the dynamics read)
    are bitwise those of its group's first column takes that column's result, the same numbers
    without the integration. The real-air filter's points that move only the gyro biases and
    the GPS errors (the last states: a lower Cholesky factor's last columns touch no other row)
    are such columns.
    ``period = 1`` compares nothing. Returns the number of columns that took their group's
    result.
    """
    xs, xo = np.empty(12), np.empty(12)
    us, vs, es = np.empty(4), np.empty(6), np.empty(N_EXTRA)
    work = Rk4Work(np.empty(12), np.empty(12), np.empty(12), np.empty(12), np.empty(6))
    n_reused = 0
    for j in range(x.shape[1]):
        first = j - j % period
        same = (
            first != j
            and _column_repeats(x, 12, j, first)
            and _column_repeats(e, N_DYNAMIC_EXTRA, j, first)
            and _column_repeats(v, 6, j, first)
            and _column_repeats(u, 4, j, first)
        )
        if same:
            for i in range(12):
                out[i, j] = out[i, first]
            n_reused += 1
            continue
        _column(x, j, xs)
        _column(u, j, us)
        _column(v, j, vs)
        _column(e, j, es)
        rk4_step(xs, us, vs, es, k, dt, work, xo)
        for i in range(12):
            out[i, j] = xo[i]
    return n_reused


@numba.njit(cache=True, error_model="numpy")
def derivatives_batch(
    x: np.ndarray, u: np.ndarray, v: np.ndarray, e: np.ndarray, k: np.ndarray, out: np.ndarray
) -> None:
    """:func:`derivatives` of every column of x (12, N), u (4, N), v (6, N), e (15, N) into out."""
    xs, kk, xa = np.empty(12), np.empty(12), np.empty(12)
    us, vs, es, fm = np.empty(4), np.empty(6), np.empty(N_EXTRA), np.empty(6)
    for j in range(x.shape[1]):
        _column(x, j, xs)
        _column(u, j, us)
        _column(v, j, vs)
        _column(e, j, es)
        derivatives(xs, us, vs, es, k, fm, xa, kk)
        for i in range(12):
            out[i, j] = kk[i]


@numba.njit(cache=True, error_model="numpy")
def forces_moments_batch(x: np.ndarray, u: np.ndarray, k: np.ndarray, out: np.ndarray) -> None:
    """:func:`forces_moments` of every column of x (12, N), u (4, N) into out (6, N)."""
    xs, us, fm = np.empty(12), np.empty(4), np.empty(6)
    for j in range(x.shape[1]):
        _column(x, j, xs)
        _column(u, j, us)
        forces_moments(xs, us, k, fm)
        for i in range(6):
            out[i, j] = fm[i]


@numba.njit(cache=True, error_model="numpy")
def imu_batch(
    x: np.ndarray, u: np.ndarray, e: np.ndarray, k: np.ndarray, period: int, out: np.ndarray
) -> int:
    """:func:`imu` of every column of x (12, N), u (4, N), e (15, N) into out (6, N).

    As in :func:`step_batch`, a column whose inputs (``x``, ``u`` and the ``N_OUTPUT_EXTRA``
    entries of ``e``) are bitwise those of the first column of its group of ``period`` takes
    that column's reading: in the augmented filter, the points that move only the measurement
    noise or the GPS errors. Returns the number of such columns.
    """
    xs, us, es, fm, zs, xa = (
        np.empty(12), np.empty(4), np.empty(N_EXTRA), np.empty(6), np.empty(6), np.empty(12)
    )  # fmt: skip
    n_reused = 0
    for j in range(x.shape[1]):
        first = j - j % period
        same = (
            first != j
            and _column_repeats(x, 12, j, first)
            and _column_repeats(e, N_OUTPUT_EXTRA, j, first)
            and _column_repeats(u, 4, j, first)
        )
        if same:
            for i in range(6):
                out[i, j] = out[i, first]
            n_reused += 1
            continue
        _column(x, j, xs)
        _column(u, j, us)
        _column(e, j, es)
        imu(xs, us, es, k, fm, xa, zs)
        for i in range(6):
            out[i, j] = zs[i]
    return n_reused


# ---------------------------------------------------------------------------------------------
# the same kernels, uncompiled


def _uncompiled() -> types.SimpleNamespace:
    """Every kernel of this module as a plain Python function calling the others plainly."""
    dispatchers = {name: obj for name, obj in globals().items() if any(obj is k for k in _KERNELS)}
    namespace = dict(globals())
    plain = {}
    for name, dispatcher in dispatchers.items():
        fn = dispatcher.py_func
        if fn.__globals__ is globals():  # rebind to the plain kernels; others (ISA) as they are
            fn = types.FunctionType(fn.__code__, namespace, fn.__name__, fn.__defaults__)
            fn.__doc__ = dispatcher.py_func.__doc__
            fn.__annotations__ = dispatcher.py_func.__annotations__
        plain[name] = fn
    namespace.update(plain)
    return types.SimpleNamespace(**plain)


#: The kernels as plain Python functions (no numba), e.g. ``uncompiled.forces_moments``.
uncompiled = _uncompiled()
