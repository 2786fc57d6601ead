"""6-DOF aerodynamic model: trim, analytic motions, frames, batching, compiled = plain kernels.

The analytic motions (free fall, torque-free rotation, Newton-Euler, trim) are the independent
checks of the equations; the kernel test only shows that numba compiles them faithfully.
"""

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from immukf_sitl.models import aero_kernels
from immukf_sitl.models.aero import (
    AeroModel,
    drag_coefficient,
    lift_coefficient,
    propeller_thrust_torque,
    stall_blend_sigma,
)
from immukf_sitl.models.earth import NedOrigin, isa_density_kgpm3, normal_gravity_mps2
from immukf_sitl.models.params import load_aircraft_params

COMPILED = [False, True]


@pytest.fixture(scope="module")
def params():
    return load_aircraft_params()


@pytest.fixture(scope="module")
def model(params) -> AeroModel:
    return AeroModel(params, origin=NedOrigin(47.0, 8.0, 400.0), compiled=False)


def random_states(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """Plausible flight states: 18-32 m/s, moderate angles and rates."""
    x = np.empty((12, *shape))
    x[0:3] = rng.uniform(-500.0, 500.0, (3, *shape))
    x[3] = rng.uniform(18.0, 32.0, shape)
    x[4] = rng.uniform(-2.0, 2.0, shape)
    x[5] = rng.uniform(-1.0, 3.0, shape)
    x[6] = rng.uniform(-0.8, 0.8, shape)
    x[7] = rng.uniform(-0.4, 0.4, shape)
    x[8] = rng.uniform(-np.pi, np.pi, shape)
    x[9:12] = rng.uniform(-0.5, 0.5, (3, *shape))
    return x


def random_controls(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    u = rng.uniform(-0.3, 0.3, (4, *shape))
    u[3] = rng.uniform(0.4, 1.0, shape)
    return u


def vacuum_model(params, gravity_mps2: float) -> AeroModel:
    """No air (no aerodynamic or propeller force), uniform gravity."""
    return AeroModel(params, density_kgpm3=0.0, gravity_mps2=gravity_mps2, gravity_gradient_ps2=0.0)


# ---------------------------------------------------------------------------------------------
# trim


@pytest.mark.parametrize(("va_mps", "gamma_rad"), [(25.0, 0.0), (20.0, 0.0), (25.0, 0.05)])
def test_trim_is_a_fixed_point(model: AeroModel, va_mps: float, gamma_rad: float) -> None:
    x0, u0 = model.trim(va_mps, gamma_rad)
    xd = model.derivatives(0.0, x0, u0)
    np.testing.assert_allclose(xd[3:12], 0.0, atol=1e-8)
    assert np.linalg.norm(x0[3:6]) == pytest.approx(va_mps, rel=1e-12)
    assert -xd[2] == pytest.approx(va_mps * np.sin(gamma_rad), abs=1e-8)
    assert x0[6] == 0.0  # wings level
    # the supplement's propeller needs a high trim throttle
    assert 0.55 < u0[3] < 1.0
    assert u0[0] < 0.0  # trailing edge up to hold the nose up
    # one RK4 step keeps it (up to the ISA density change with the climb)
    x1 = model.step(0.0, x0, u0)
    np.testing.assert_allclose(x1[3:12], x0[3:12], atol=1e-8)
    # the accelerometer reads the reaction to gravity in steady flight
    g = normal_gravity_mps2(47.0, 400.0)
    theta = x0[7]
    np.testing.assert_allclose(
        model.imu(0.0, x0, u0), [g * np.sin(theta), 0.0, -g * np.cos(theta), 0, 0, 0], atol=1e-7
    )


def test_trim_outside_the_envelope_raises(model: AeroModel) -> None:
    with pytest.raises(RuntimeError, match="no steady flight at Va = 12.0 m/s"):
        model.trim(12.0)
    with pytest.raises(ValueError, match="Va_mps > 0"):
        model.trim(0.0)


# ---------------------------------------------------------------------------------------------
# analytic motions


def test_free_fall_is_a_parabola(params) -> None:
    g = 9.79
    m = vacuum_model(params, g)
    x = np.zeros(12)
    x[3:6] = [20.0, -3.0, 1.0]
    x[6:9] = [0.3, -0.2, 2.0]
    v_ned0 = Rotation.from_euler("ZYX", x[8:5:-1]).apply(x[3:6])
    u = np.array([0.1, -0.1, 0.05, 0.9])  # controls do nothing without air
    n_steps = 300
    for k in range(n_steps):
        x = m.step(k * m.dt_s, x, u)
    t = n_steps * m.dt_s
    expected_pos = v_ned0 * t + 0.5 * np.array([0.0, 0.0, g]) * t**2
    np.testing.assert_allclose(x[0:3], expected_pos, rtol=0.0, atol=1e-9)
    np.testing.assert_allclose(x[6:12], [0.3, -0.2, 2.0, 0.0, 0.0, 0.0], atol=1e-12)
    v_ned = Rotation.from_euler("ZYX", x[8:5:-1]).apply(x[3:6])
    np.testing.assert_allclose(v_ned, v_ned0 + [0.0, 0.0, g * t], atol=1e-9)
    # and an accelerometer in free fall reads nothing
    np.testing.assert_allclose(m.imu(0.0, x, u)[0:3], 0.0, atol=1e-12)


@pytest.mark.parametrize("compiled", COMPILED)
def test_torque_free_rotation_conserves_momentum_and_energy(params, compiled: bool) -> None:
    m = dataclasses.replace(vacuum_model(params, 0.0), compiled=compiled)
    inertia = params.mass.inertia_kgm2
    x = np.zeros(12)
    x[3] = 1.0
    x[6:9] = [0.1, 0.2, 0.3]
    x[9:12] = [1.5, -0.7, 0.9]  # rad/s: tumbling, couples through Jxz

    def invariants(state: np.ndarray) -> tuple[np.ndarray, float]:
        w = state[9:12]
        h_body = inertia @ w
        h_ned = Rotation.from_euler("ZYX", state[8:5:-1]).apply(h_body)
        return h_ned, 0.5 * w @ h_body

    h0, e0 = invariants(x)
    for k in range(400):  # 4 s
        x = m.step(k * m.dt_s, x, np.zeros(4))
    h1, e1 = invariants(x)
    assert abs(np.linalg.norm(h1) - np.linalg.norm(h0)) < 1e-8 * np.linalg.norm(h0)
    assert abs(e1 - e0) < 1e-8 * e0
    # the inertial angular momentum vector is constant too (Euler angles integrated by RK4)
    np.testing.assert_allclose(h1, h0, atol=1e-6 * np.linalg.norm(h0))
    assert not np.allclose(x[9:12], [1.5, -0.7, 0.9], atol=1e-2)  # the rates did change


def test_newton_euler_equations_hold(params, model: AeroModel) -> None:
    """m (v_dot + w x v) = F + m g_body and J w_dot + w x (J w) = M, for random states."""
    rng = np.random.default_rng(5)
    inertia = params.mass.inertia_kgm2
    mass = params.mass.mass_kg
    x = random_states(rng, (20,))
    u = random_controls(rng, (20,))
    xd = model.derivatives(0.0, x, u)
    fm = model.forces_moments(0.0, x, u)
    g = normal_gravity_mps2(47.0, 400.0 - x[2])
    for j in range(20):
        w, vel = x[9:12, j], x[3:6, j]
        rot = Rotation.from_euler("ZYX", x[8:5:-1, j])
        g_body = rot.inv().apply([0.0, 0.0, g[j]])
        np.testing.assert_allclose(
            mass * (xd[3:6, j] + np.cross(w, vel)), fm[0:3, j] + mass * g_body, atol=1e-6
        )
        np.testing.assert_allclose(
            inertia @ xd[9:12, j] + np.cross(w, inertia @ w), fm[3:6, j], atol=1e-9
        )
        # Euler angle rates: w = [phi_dot, 0, 0] + Rx' [0, theta_dot, 0] + (Ry Rx)' [0, 0, psi_dot]
        phi, theta = x[6, j], x[7, j]
        rx = Rotation.from_euler("X", phi)
        ry = Rotation.from_euler("Y", theta)
        rates = (
            [xd[6, j], 0.0, 0.0]
            + rx.inv().apply([0.0, xd[7, j], 0.0])
            + (ry * rx).inv().apply([0.0, 0.0, xd[8, j]])
        )
        np.testing.assert_allclose(rates, w, atol=1e-12)


def test_body_velocity_rotates_into_ned_like_scipy(model: AeroModel) -> None:
    rng = np.random.default_rng(1)
    x = random_states(rng, (50,))
    xd = model.derivatives(0.0, x, np.array([0.0, 0.0, 0.0, 0.7]))
    gps = model.gps(0.0, x, np.zeros(4))
    with_vd = model.gps(0.0, x, np.zeros(4), velocity_down=True)
    assert gps.shape == (5, 50) and with_vd.shape == (6, 50)
    np.testing.assert_array_equal(with_vd[:5], gps)
    for j in range(50):
        rot = Rotation.from_euler("ZYX", [x[8, j], x[7, j], x[6, j]])
        v_ned = rot.apply(x[3:6, j])
        np.testing.assert_allclose(xd[0:3, j], v_ned, rtol=0.0, atol=1e-12)
        np.testing.assert_allclose(gps[0:3, j], x[0:3, j])
        assert gps[3, j] == pytest.approx(np.hypot(v_ned[0], v_ned[1]), rel=1e-13)
        assert gps[4, j] == pytest.approx(np.arctan2(v_ned[1], v_ned[0]), abs=1e-13)
        assert with_vd[5, j] == pytest.approx(v_ned[2], abs=1e-12)


def test_specific_force_is_what_an_accelerometer_measures(params) -> None:
    """f = R_nb' (a_ned - g_ned), with a_ned differenced from the IMU point's NED velocity."""
    for imu_position in [(0.0, 0.0, 0.0), (0.4, -0.2, 0.15)]:
        p = dataclasses.replace(
            params, geometry=dataclasses.replace(params.geometry, imu_position_m=imu_position)
        )
        m = AeroModel(p, dt_s=2e-5, gravity_mps2=9.8, gravity_gradient_ps2=0.0, compiled=False)
        x0, u0 = m.trim(25.0)
        x0[9:12] = [0.4, 0.2, -0.3]  # manoeuvring: rates and angular accelerations
        u0 = u0 + [0.05, 0.1, -0.05, 0.0]
        r = np.asarray(imu_position)

        def imu_velocity_ned(x: np.ndarray, r: np.ndarray = r) -> np.ndarray:
            # velocity of the IMU point: R_nb (v_body + omega x r)
            return Rotation.from_euler("ZYX", x[8:5:-1]).apply(x[3:6] + np.cross(x[9:12], r))

        x1 = m.step(0.0, x0, u0)
        x2 = m.step(m.dt_s, x1, u0)
        v0, v1, v2 = (imu_velocity_ned(x) for x in (x0, x1, x2))
        a_ned = (-3.0 * v0 + 4.0 * v1 - v2) / (2.0 * m.dt_s)  # second-order forward difference
        f_expected = Rotation.from_euler("ZYX", x0[8:5:-1]).inv().apply(a_ned - [0, 0, 9.8])
        f_model = m.imu(0.0, x0, u0)
        np.testing.assert_allclose(f_model[0:3], f_expected, rtol=0.0, atol=2e-7)
        np.testing.assert_allclose(f_model[3:6], x0[9:12])
        if any(imu_position):
            # the lever arm matters at these rates: the CG's specific force differs
            f_cg = AeroModel(params, gravity_mps2=9.8, compiled=False).imu(0.0, x0, u0)
            assert np.max(np.abs(f_cg[0:3] - f_model[0:3])) > 0.05


# ---------------------------------------------------------------------------------------------
# aerodynamic and propeller laws


def test_stall_blending_lift_and_linear_drag(params) -> None:
    a = params.aero
    assert stall_blend_sigma(0.0, a.M, a.alpha0_rad) < 1e-9
    assert stall_blend_sigma(1.2, a.M, a.alpha0_rad) > 1.0 - 1e-9
    assert stall_blend_sigma(-1.2, a.M, a.alpha0_rad) > 1.0 - 1e-9
    assert stall_blend_sigma(a.alpha0_rad, a.M, a.alpha0_rad) == pytest.approx(0.5, abs=1e-9)
    assert lift_coefficient(0.1, a) == pytest.approx(a.C_L_0 + a.C_L_alpha * 0.1, rel=1e-7)
    alpha = 1.2
    assert lift_coefficient(alpha, a) == pytest.approx(
        2.0 * np.sin(alpha) ** 2 * np.cos(alpha), rel=1e-6
    )
    assert drag_coefficient(-0.1, a) == pytest.approx(a.C_D_0 - 0.1 * a.C_D_alpha)
    # the model's lift and drag in stability axes are these laws
    m = AeroModel(params, density_kgpm3=1.2, compiled=False)
    va, alpha = 24.0, 0.08
    x = np.zeros(12)
    x[3], x[5] = va * np.cos(alpha), va * np.sin(alpha)
    u = np.array([0.0, 0.0, 0.0, 0.0])
    fm = m.forces_moments(0.0, x, u)
    thrust, _ = propeller_thrust_torque(va, 0.0, 1.2, params)
    qs = 0.5 * 1.2 * va**2 * params.geometry.S_m2
    rot = np.array([[np.cos(alpha), -np.sin(alpha)], [np.sin(alpha), np.cos(alpha)]])
    drag, lift = -(rot.T @ (fm[[0, 2]] - [thrust, 0.0]))
    assert lift == pytest.approx(qs * lift_coefficient(alpha, a), rel=1e-12)
    assert drag == pytest.approx(qs * drag_coefficient(alpha, a), rel=1e-12)
    pitch = qs * params.geometry.c_m * (a.C_m_0 + a.C_m_alpha * alpha)
    assert fm[4] == pytest.approx(pitch, rel=1e-12)


def test_propeller_matches_the_advance_ratio_form(params) -> None:
    prop = params.propulsion
    d = prop.prop_diameter_m
    kq = prop.K_Q_Nm_per_A
    for va, dt, rho in [(25.0, 0.8, 1.225), (18.0, 1.0, 1.1), (30.0, 0.5, 1.2), (5.0, 0.3, 1.0)]:
        # torque balance of the supplement, solved with numpy's polynomial roots
        a = rho * d**5 * prop.C_Q[0] / (2 * np.pi) ** 2
        b = rho * d**4 * prop.C_Q[1] * va / (2 * np.pi) + kq**2 / prop.R_motor_ohm
        c = (
            rho * d**3 * prop.C_Q[2] * va**2
            - kq * prop.V_max_V * dt / prop.R_motor_ohm
            + kq * prop.i0_A
        )
        omega = max(np.roots([a, b, c]).real)
        n = omega / (2 * np.pi)
        j = va / (n * d)
        c_t = np.polynomial.polynomial.polyval(j, prop.C_T)
        c_q = np.polynomial.polynomial.polyval(j, prop.C_Q)
        thrust, torque = propeller_thrust_torque(va, dt, rho, params)
        assert thrust == pytest.approx(rho * n**2 * d**4 * c_t, rel=1e-9)
        assert torque == pytest.approx(rho * n**2 * d**5 * c_q, rel=1e-9)
    # the supplement's propeller: thrust changes sign near delta_t = 0.67 at 25 m/s
    thrust, _ = propeller_thrust_torque(25.0, np.array([0.6, 0.74]), 1.225, prop)
    assert thrust[0] < 0.0 < thrust[1]


def test_prop_torque_rolls_the_airframe_negatively(params) -> None:
    x = np.zeros(12)
    x[3] = 25.0
    on = AeroModel(params, compiled=False).forces_moments(0.0, x, np.array([0, 0, 0, 1.0]))
    no_torque = dataclasses.replace(
        params, propulsion=dataclasses.replace(params.propulsion, prop_torque_on_roll=False)
    )
    off = AeroModel(no_torque, compiled=False).forces_moments(0.0, x, np.array([0, 0, 0, 1.0]))
    _, torque = propeller_thrust_torque(25.0, 1.0, isa_density_kgpm3(0.0), params)
    assert torque > 0.0
    assert on[3] == pytest.approx(off[3] - torque, rel=1e-12)
    np.testing.assert_array_equal(np.delete(on, 3), np.delete(off, 3))


def test_control_signs_follow_the_conventions(model: AeroModel) -> None:
    x0, u0 = model.trim(25.0)
    base = model.derivatives(0.0, x0, u0)
    for idx, row, sign in [(0, 10, -1.0), (1, 9, 1.0), (2, 11, -1.0)]:
        du = np.zeros(4)
        du[idx] = 0.05
        change = model.derivatives(0.0, x0, u0 + du)[row] - base[row]
        assert np.sign(change) == sign, (idx, change)


def test_isa_density_at_altitude_is_used(params) -> None:
    m = AeroModel(params, origin=NedOrigin(0.0, 0.0, 100.0), compiled=False)
    x = np.zeros((12, 2))
    x[3] = 25.0
    x[2] = [0.0, -1000.0]  # 100 m and 1100 m
    fm = m.forces_moments(0.0, x, np.zeros(4))
    const = AeroModel(params, density_kgpm3=1.0, compiled=False).forces_moments(0.0, x, np.zeros(4))
    ratio = fm[2] / const[2]  # lift is proportional to density
    np.testing.assert_allclose(ratio, isa_density_kgpm3([100.0, 1100.0]), rtol=1e-12)


# ---------------------------------------------------------------------------------------------
# noise, batching, backends


def test_process_noise_enters_the_acceleration_states(model: AeroModel) -> None:
    rng = np.random.default_rng(2)
    x = random_states(rng, (5,))
    u = random_controls(rng, (5,))
    v = rng.standard_normal((6, 5))
    diff = model.derivatives(0.0, x, u, v) - model.derivatives(0.0, x, u, None)
    np.testing.assert_allclose(diff[3:6], v[0:3], atol=1e-12)
    np.testing.assert_allclose(diff[9:12], v[3:6], atol=1e-12)
    np.testing.assert_allclose(diff[[0, 1, 2, 6, 7, 8]], 0.0, atol=0.0)
    assert model.nx == 12 and model.nu == 4 and model.nv == 6
    assert len(model.state_labels) == 12


@pytest.mark.parametrize("compiled", COMPILED)
def test_batch_equals_column_by_column(params, compiled: bool) -> None:
    m = AeroModel(params, origin=NedOrigin(47.0, 8.0, 400.0), compiled=compiled)
    rng = np.random.default_rng(3)
    x = random_states(rng, (7, 49))
    v = rng.standard_normal((6, 7, 49))
    for u in (random_controls(rng, ()), random_controls(rng, (7, 49))):
        step = m.step(0.0, x, u, v)
        xd = m.derivatives(0.0, x, u, v)
        imu = m.imu(0.0, x, u)
        gps = m.gps(0.0, x, u)
        assert step.shape == xd.shape == (12, 7, 49)
        assert imu.shape == (6, 7, 49) and gps.shape == (5, 7, 49)
        for i, j in [(0, 0), (3, 17), (6, 48)]:
            uij = u if u.ndim == 1 else u[:, i, j]
            np.testing.assert_allclose(step[:, i, j], m.step(0.0, x[:, i, j], uij, v[:, i, j]))
            np.testing.assert_allclose(xd[:, i, j], m.derivatives(0.0, x[:, i, j], uij, v[:, i, j]))
            np.testing.assert_allclose(imu[:, i, j], m.imu(0.0, x[:, i, j], uij))
            np.testing.assert_allclose(gps[:, i, j], m.gps(0.0, x[:, i, j], uij))
    # a (6,) noise broadcasts over the batch
    v1 = rng.standard_normal(6)
    np.testing.assert_allclose(
        m.step(0.0, x, u, v1), m.step(0.0, x, u, np.broadcast_to(v1[:, None, None], (6, 7, 49)))
    )


def test_step_wraps_roll_and_yaw(model: AeroModel) -> None:
    x0, u0 = model.trim(25.0)
    x0[8] = np.pi - 1e-4
    x0[11] = 0.1  # yawing right through +pi
    x1 = model.step(0.0, x0, u0)
    assert -np.pi <= x1[8] < -np.pi + 1e-2


@pytest.mark.parametrize("imu_position", [(0.0, 0.0, 0.0), (0.3, 0.05, -0.1)])
@pytest.mark.parametrize("density_kgpm3", [None, 1.2682])
def test_compiled_kernels_equal_the_plain_functions(params, imu_position, density_kgpm3) -> None:
    """numba's loops against the same functions run by Python, over rows and on one column."""
    geometry = dataclasses.replace(params.geometry, imu_position_m=imu_position)
    p = dataclasses.replace(params, geometry=geometry)
    plain = AeroModel(p, NedOrigin(47.0, 8.0, 400.0), density_kgpm3=density_kgpm3, compiled=False)
    fast = dataclasses.replace(plain, compiled=True)
    assert fast.uses_numba and not plain.uses_numba
    rng = np.random.default_rng(4)
    x = random_states(rng, (7, 49))
    u = random_controls(rng, (7, 49))
    v = rng.standard_normal((6, 7, 49))
    tol = {"rtol": 1e-13, "atol": 1e-12}
    np.testing.assert_allclose(fast.step(0.0, x, u, v), plain.step(0.0, x, u, v), **tol)
    np.testing.assert_allclose(fast.step(0.0, x, u[:, 0, 0]), plain.step(0.0, x, u[:, 0, 0]), **tol)
    np.testing.assert_allclose(
        fast.derivatives(0.0, x, u, v[:, 0, 0]), plain.derivatives(0.0, x, u, v[:, 0, 0]), **tol
    )
    np.testing.assert_allclose(fast.imu(0.0, x, u), plain.imu(0.0, x, u), **tol)
    np.testing.assert_allclose(
        fast.forces_moments(0.0, x, u), plain.forces_moments(0.0, x, u), rtol=1e-13, atol=1e-10
    )
    # the scalar form numba compiles, run by Python on one column (numpy float64 scalars)
    k = fast._k
    xs, us, vs = x[:, 2, 5].copy(), u[:, 2, 5].copy(), v[:, 2, 5].copy()
    work = aero_kernels.Rk4Work(*(np.empty(12) for _ in range(4)), np.empty(6))
    es = np.zeros(aero_kernels.N_EXTRA)
    stepped = np.empty(12)
    aero_kernels.uncompiled.rk4_step(xs, us, vs, es, k, fast.dt_s, work, stepped)
    np.testing.assert_allclose(stepped, fast.step(0.0, xs, us, vs), **tol)
    imu = np.empty(6)
    aero_kernels.uncompiled.imu(xs, us, es, k, np.empty(6), np.empty(12), imu)
    np.testing.assert_allclose(imu, fast.imu(0.0, xs, us), **tol)


def test_public_laws_are_the_model_kernels(params) -> None:
    """The coefficient and propeller helpers evaluate the kernels the model integrates."""
    a = params.aero
    alpha = np.linspace(-0.6, 0.6, 13)
    expected = aero_kernels.uncompiled.lift_coefficient(
        alpha, np.sin(alpha), np.cos(alpha), a.C_L_0, a.C_L_alpha, a.M, a.alpha0_rad
    )
    np.testing.assert_array_equal(lift_coefficient(alpha, a), expected)
    k = AeroModel(params, compiled=False)._k
    thrust, torque = aero_kernels.uncompiled.propeller(25.0, np.array([0.5, 0.9]), 1.1, k)
    np.testing.assert_array_equal(
        propeller_thrust_torque(25.0, np.array([0.5, 0.9]), 1.1, params), (thrust, torque)
    )
    assert stall_blend_sigma(alpha, a.M, a.alpha0_rad).shape == alpha.shape


def test_invalid_model_settings(params) -> None:
    with pytest.raises(ValueError, match="dt_s: expected > 0"):
        AeroModel(params, dt_s=0.0)
    with pytest.raises(ValueError, match="density_kgpm3: expected >= 0"):
        AeroModel(params, density_kgpm3=-1.0)
    with pytest.raises(ValueError, match="compiled: expected True or False"):
        AeroModel(params, compiled="numpy")
