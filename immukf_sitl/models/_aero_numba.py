"""Optional numba kernels of :class:`immukf_sitl.models.aero.AeroModel` (same equations).

The numpy methods of ``AeroModel`` are the reference; these compiled loops evaluate the same
equations element by element over a flattened batch, which avoids numpy's per-operation
overhead on small arrays (a (12, 7, 49) sigma-point batch). ``tests/test_aero.py`` checks that
both agree. Imported only when numba is installed.

Cost notes (measured on the IMM's 259-column RK4 batch): the per-element helpers are inlined
into their callers (``inline="always"``); as separate functions every call paid reference
counting on its array arguments, which cost as much as the aerodynamics. ``step_batch`` runs
its four RK4 stages as a loop around one call site, so the inlined derivative is compiled once.
The angle of attack enters through ``cos(alpha) = u / sqrt(u^2 + w^2)`` and
``sin(alpha) = w / sqrt(u^2 + w^2)`` (the same values to rounding, without two transcendental
calls); what remains per stage is dominated by libm: three ``sincos`` of the Euler angles, two
``atan2``, two ``exp`` of the stall blend and one ``pow`` of the ISA density.
"""

import math

import numba
import numpy as np

# Indices into the packed constant vector (see ``pack_constants``).
NAMES = (
    "G1 G2 G3 G4 G5 G6 G7 G8 inv_jy inv_mass g0 dg h0 rho_const S b c c_2 b_2 "
    "C_L_0 C_L_alpha C_L_q C_L_delta_e M alpha0 C_D_0 C_D_alpha C_D_q C_D_delta_e "
    "C_m_0 C_m_alpha C_m_q C_m_delta_e C_Y_0 C_Y_beta C_Y_p C_Y_r C_Y_delta_a C_Y_delta_r "
    "C_ell_0 C_ell_beta C_ell_p C_ell_r C_ell_delta_a C_ell_delta_r "
    "C_n_0 C_n_beta C_n_p C_n_r C_n_delta_a C_n_delta_r "
    "a_q b_q c_q b_motor c_volt c_i0 t_0 t_1 t_2 torque_on_roll "
    "isa_r0 isa_lapse_t0 isa_rho0 isa_exp imu_rx imu_ry imu_rz has_lever"
).split()
(
    G1, G2, G3, G4, G5, G6, G7, G8, INV_JY, INV_MASS, G0, DG, H0, RHO_CONST, S, B, C, C_2, B_2,
    CL0, CLA, CLQ, CLDE, M_BLEND, ALPHA0, CD0, CDA, CDQ, CDDE,
    CM0, CMA, CMQ, CMDE, CY0, CYB, CYP, CYR, CYDA, CYDR,
    CL_0, CL_B, CL_P, CL_R, CL_DA, CL_DR,
    CN0, CNB, CNP, CNR, CNDA, CNDR,
    A_Q, B_Q, C_Q, B_MOTOR, C_VOLT, C_I0, T_0, T_1, T_2, TORQUE_ON_ROLL,
    ISA_R0, ISA_LAPSE_T0, ISA_RHO0, ISA_EXP, IMU_RX, IMU_RY, IMU_RZ, HAS_LEVER,
) = range(len(NAMES))  # fmt: skip


def pack_constants(values: dict) -> np.ndarray:
    """Pack a name -> float mapping into the kernel's constant vector (every name required)."""
    missing = [n for n in NAMES if n not in values]
    if missing:
        raise KeyError(f"missing kernel constants: {missing}")
    return np.array([float(values[n]) for n in NAMES])


@numba.njit(cache=True, inline="always", error_model="numpy")
def _sign(a: float) -> float:
    if a > 0.0:
        return 1.0
    if a < 0.0:
        return -1.0
    return 0.0


@numba.njit(cache=True, inline="always", error_model="numpy")
def _forces_moments(x, u, k, out):
    """Body forces (N) and moments (N m) about the CG into out[0:6] (see AeroModel)."""
    uu, vv, ww = x[3], x[4], x[5]
    p, q, r = x[9], x[10], x[11]
    de, da, dr, dt = u[0], u[1], u[2], u[3]
    if k[RHO_CONST] >= 0.0:
        rho = k[RHO_CONST]
    else:
        h = k[H0] - x[2]
        hgp = k[ISA_R0] * h / (k[ISA_R0] + h)
        rho = k[ISA_RHO0] * (1.0 - k[ISA_LAPSE_T0] * hgp) ** k[ISA_EXP]
    va2 = uu * uu + vv * vv + ww * ww
    va = math.sqrt(va2)
    alpha = math.atan2(ww, uu)
    v_uw = math.sqrt(uu * uu + ww * ww)
    beta = math.atan2(vv, v_uw)
    if 0.0 < v_uw < math.inf:  # cos and sin of alpha = atan2(w, u), without calling them
        ca = uu / v_uw
        sa = ww / v_uw
    else:
        ca = math.cos(alpha)
        sa = math.sin(alpha)
    qbar = 0.5 * rho * va2
    qv = 0.5 * rho * va
    e_minus = math.exp(-k[M_BLEND] * (alpha - k[ALPHA0]))
    e_plus = math.exp(k[M_BLEND] * (alpha + k[ALPHA0]))
    sigma = (1.0 + e_minus + e_plus) / ((1.0 + e_minus) * (1.0 + e_plus))
    c_lift = (1.0 - sigma) * (k[CL0] + k[CLA] * alpha) + sigma * (2.0 * _sign(alpha) * sa * sa * ca)
    c_drag = k[CD0] + k[CDA] * alpha
    cq = k[C_2] * q
    s = k[S]
    lift = s * (qbar * (c_lift + k[CLDE] * de) + qv * k[CLQ] * cq)
    drag = s * (qbar * (c_drag + k[CDDE] * de) + qv * k[CDQ] * cq)
    bp = k[B_2] * p
    br = k[B_2] * r

    # propeller (supplement ch. 4)
    a_ = rho * k[A_Q]
    b_ = rho * k[B_Q] * va + k[B_MOTOR]
    c_ = rho * k[C_Q] * va2 - k[C_VOLT] * dt + k[C_I0]
    disc = b_ * b_ - 4.0 * a_ * c_
    if disc < 0.0:
        disc = 0.0
    omega = -2.0 * c_ / (b_ + math.sqrt(disc))
    omega2 = omega * omega
    omega_va = omega * va
    thrust = rho * (k[T_0] * omega2 + k[T_1] * omega_va + k[T_2] * va2)
    torque = rho * (k[A_Q] * omega2 + k[B_Q] * omega_va + k[C_Q] * va2)

    out[0] = -ca * drag + sa * lift + thrust
    out[1] = s * (
        qbar * (k[CY0] + k[CYB] * beta + k[CYDA] * da + k[CYDR] * dr)
        + qv * (k[CYP] * bp + k[CYR] * br)
    )
    out[2] = -sa * drag - ca * lift
    roll = (
        s
        * k[B]
        * (
            qbar * (k[CL_0] + k[CL_B] * beta + k[CL_DA] * da + k[CL_DR] * dr)
            + qv * (k[CL_P] * bp + k[CL_R] * br)
        )
    )
    if k[TORQUE_ON_ROLL] != 0.0:
        roll = roll - torque
    out[3] = roll
    out[4] = s * k[C] * (qbar * (k[CM0] + k[CMA] * alpha + k[CMDE] * de) + qv * k[CMQ] * cq)
    out[5] = (
        s
        * k[B]
        * (
            qbar * (k[CN0] + k[CNB] * beta + k[CNDA] * da + k[CNDR] * dr)
            + qv * (k[CNP] * bp + k[CNR] * br)
        )
    )


@numba.njit(cache=True, inline="always", error_model="numpy")
def _derivatives(x, u, v, k, fm, out):
    """State derivative of one element into out (12,); fm is (6,) scratch."""
    uu, vv, ww = x[3], x[4], x[5]
    phi, theta, psi = x[6], x[7], x[8]
    p, q, r = x[9], x[10], x[11]
    sph, cph = math.sin(phi), math.cos(phi)
    sth, cth = math.sin(theta), math.cos(theta)
    sps, cps = math.sin(psi), math.cos(psi)
    sph_sth = sph * sth
    cph_sth = cph * sth
    out[0] = cth * cps * uu + (sph_sth * cps - cph * sps) * vv + (cph_sth * cps + sph * sps) * ww
    out[1] = cth * sps * uu + (sph_sth * sps + cph * cps) * vv + (cph_sth * sps - sph * cps) * ww
    out[2] = -sth * uu + sph * cth * vv + cph * cth * ww
    _forces_moments(x, u, k, fm)
    grav = k[G0] + k[DG] * x[2]
    inv_m = k[INV_MASS]
    out[3] = r * vv - q * ww + fm[0] * inv_m - grav * sth + v[0]
    out[4] = p * ww - r * uu + fm[1] * inv_m + grav * cth * sph + v[1]
    out[5] = q * uu - p * vv + fm[2] * inv_m + grav * cth * cph + v[2]
    tth = sth / cth
    out[6] = p + (q * sph + r * cph) * tth
    out[7] = q * cph - r * sph
    out[8] = (q * sph + r * cph) / cth
    ell, em, en = fm[3], fm[4], fm[5]
    out[9] = k[G1] * p * q - k[G2] * q * r + k[G3] * ell + k[G4] * en + v[3]
    out[10] = k[G5] * p * r - k[G6] * (p * p - r * r) + k[INV_JY] * em + v[4]
    out[11] = k[G7] * p * q - k[G1] * q * r + k[G4] * ell + k[G8] * en + v[5]


@numba.njit(cache=True, error_model="numpy")
def _wrap(a: float) -> float:
    w = (a + math.pi) % (2.0 * math.pi) - math.pi
    return w


@numba.njit(cache=True, error_model="numpy")
def step_batch(x, u, v, k, dt, out):
    """RK4 over dt for every column of x (12, N), u (4, N), v (6, N) into out (12, N)."""
    n = x.shape[1]
    xs = np.empty(12)
    xt = np.empty(12)
    us = np.empty(4)
    vs = np.empty(6)
    kk = np.empty(12)
    acc = np.empty(12)
    fm = np.empty(6)
    half = 0.5 * dt
    for j in range(n):
        for i in range(12):
            xs[i] = x[i, j]
            xt[i] = x[i, j]
        for i in range(4):
            us[i] = u[i, j]
        for i in range(6):
            vs[i] = v[i, j]
        # k1..k4 at xs, xs + dt/2 k1, xs + dt/2 k2, xs + dt k3 (one call site: inlined once)
        for stage in range(4):
            _derivatives(xt, us, vs, k, fm, kk)
            if stage == 0:
                for i in range(12):
                    acc[i] = kk[i]
                    xt[i] = xs[i] + half * kk[i]
            elif stage == 1:
                for i in range(12):
                    acc[i] += 2.0 * kk[i]
                    xt[i] = xs[i] + half * kk[i]
            elif stage == 2:
                for i in range(12):
                    acc[i] += 2.0 * kk[i]
                    xt[i] = xs[i] + dt * kk[i]
        for i in range(12):
            out[i, j] = xs[i] + dt / 6.0 * (acc[i] + kk[i])
        out[6, j] = _wrap(out[6, j])
        out[8, j] = _wrap(out[8, j])


@numba.njit(cache=True, error_model="numpy")
def derivatives_batch(x, u, v, k, out):
    """State derivative of every column of x (12, N) into out (12, N)."""
    n = x.shape[1]
    xs = np.empty(12)
    us = np.empty(4)
    vs = np.empty(6)
    kk = np.empty(12)
    fm = np.empty(6)
    for j in range(n):
        for i in range(12):
            xs[i] = x[i, j]
        for i in range(4):
            us[i] = u[i, j]
        for i in range(6):
            vs[i] = v[i, j]
        _derivatives(xs, us, vs, k, fm, kk)
        for i in range(12):
            out[i, j] = kk[i]


@numba.njit(cache=True, error_model="numpy")
def forces_moments_batch(x, u, k, out):
    """Body forces and moments of every column of x (12, N) into out (6, N)."""
    n = x.shape[1]
    xs = np.empty(12)
    us = np.empty(4)
    fm = np.empty(6)
    for j in range(n):
        for i in range(12):
            xs[i] = x[i, j]
        for i in range(4):
            us[i] = u[i, j]
        _forces_moments(xs, us, k, fm)
        for i in range(6):
            out[i, j] = fm[i]


@numba.njit(cache=True, error_model="numpy")
def imu_batch(x, u, k, out):
    """IMU reading ``[f_x, f_y, f_z, p, q, r]`` of every column of x (12, N) into out (6, N).

    Specific force at the CG, moved to the IMU by ``omega_dot x r + omega x (omega x r)`` when
    the lever arm is non-zero (see ``AeroModel.imu``).
    """
    n = x.shape[1]
    xs = np.empty(12)
    us = np.empty(4)
    fm = np.empty(6)
    inv_m = k[INV_MASS]
    rx, ry, rz = k[IMU_RX], k[IMU_RY], k[IMU_RZ]
    for j in range(n):
        for i in range(12):
            xs[i] = x[i, j]
        for i in range(4):
            us[i] = u[i, j]
        _forces_moments(xs, us, k, fm)
        p, q, r = xs[9], xs[10], xs[11]
        f_x = fm[0] * inv_m
        f_y = fm[1] * inv_m
        f_z = fm[2] * inv_m
        if k[HAS_LEVER] != 0.0:
            ell, em, en = fm[3], fm[4], fm[5]
            p_dot = k[G1] * p * q - k[G2] * q * r + k[G3] * ell + k[G4] * en
            q_dot = k[G5] * p * r - k[G6] * (p * p - r * r) + k[INV_JY] * em
            r_dot = k[G7] * p * q - k[G1] * q * r + k[G4] * ell + k[G8] * en
            wr_x = q * rz - r * ry
            wr_y = r * rx - p * rz
            wr_z = p * ry - q * rx
            f_x += (q_dot * rz - r_dot * ry) + (q * wr_z - r * wr_y)
            f_y += (r_dot * rx - p_dot * rz) + (r * wr_x - p * wr_z)
            f_z += (p_dot * ry - q_dot * rx) + (p * wr_y - q * wr_x)
        out[0, j] = f_x
        out[1, j] = f_y
        out[2, j] = f_z
        out[3, j] = p
        out[4, j] = q
        out[5, j] = r
