"""Strapdown INS: analytic trajectories, agreement with the aero model, batching."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from immukf_sitl.models.aero import AeroModel
from immukf_sitl.models.earth import NedOrigin, normal_gravity_mps2
from immukf_sitl.models.ins import InsModel
from immukf_sitl.models.params import load_aircraft_params

G = 9.81


def uniform_gravity_ins(dt_s: float = 0.01) -> InsModel:
    return InsModel(dt_s=dt_s, gravity_mps2=G, gravity_gradient_ps2=0.0)


def test_straight_climb_with_constant_inputs() -> None:
    ins = uniform_gravity_ins()
    phi, theta, psi = 0.0, 0.08, 0.7
    v_ned = np.array([20.0 * np.cos(psi), 20.0 * np.sin(psi), -1.5])
    # unaccelerated: the accelerometer reads minus gravity in body axes
    f_body = Rotation.from_euler("ZYX", [psi, theta, phi]).inv().apply([0.0, 0.0, -G])
    u = np.concatenate([f_body, np.zeros(3)])
    x = np.concatenate([[10.0, -5.0, -100.0], v_ned, [phi, theta, psi]])
    x0 = x.copy()
    for k in range(500):
        x = ins.step(k * ins.dt_s, x, u)
    t = 500 * ins.dt_s
    np.testing.assert_allclose(x[0:3], x0[0:3] + v_ned * t, atol=1e-9)
    np.testing.assert_allclose(x[3:9], x0[3:9], atol=1e-12)


def test_coordinated_turn_is_a_circle() -> None:
    ins = uniform_gravity_ins()
    speed, turn_rate = 22.0, 0.15  # m/s, rad/s
    phi = np.arctan(speed * turn_rate / G)  # coordinated bank angle
    # level turn: psi_dot = turn_rate, phi and theta constant -> Euler kinematics, eq. (3.16)
    p, q, r = 0.0, turn_rate * np.sin(phi), turn_rate * np.cos(phi)
    # specific force: centripetal acceleration minus gravity, in body axes
    f_body = np.array([0.0, 0.0, -np.hypot(G, speed * turn_rate)])
    u = np.concatenate([f_body, [p, q, r]])
    x = np.array([0.0, 0.0, -200.0, speed, 0.0, 0.0, phi, 0.0, 0.0])
    n = 2000  # 20 s, most of a full circle
    for k in range(n):
        x = ins.step(k * ins.dt_s, x, u)
    t = n * ins.dt_s
    radius = speed / turn_rate
    psi = turn_rate * t
    expected_pos = [radius * np.sin(psi), radius * (1.0 - np.cos(psi)), -200.0]
    np.testing.assert_allclose(x[0:3], expected_pos, atol=1e-6)
    np.testing.assert_allclose(x[3:6], [speed * np.cos(psi), speed * np.sin(psi), 0.0], atol=1e-8)
    wrapped = (psi + np.pi) % (2 * np.pi) - np.pi
    np.testing.assert_allclose(x[6:9], [phi, 0.0, wrapped], atol=1e-10)
    gps = ins.gps(t, x, u)
    assert gps[3] == pytest.approx(speed, rel=1e-9)
    assert gps[4] == pytest.approx(wrapped, abs=1e-9)
    with_vd = ins.gps(t, x, u, velocity_down=True)
    np.testing.assert_array_equal(with_vd[:5], gps)
    assert with_vd[5] == pytest.approx(0.0, abs=1e-8)  # a level turn: no vertical velocity


def test_ins_fed_by_the_aero_model_imu_follows_the_aero_model() -> None:
    origin = NedOrigin(47.0, 8.0, 400.0)
    aero = AeroModel(load_aircraft_params(), origin=origin, compiled=False)
    ins = InsModel(origin=origin)
    xa, ua = aero.trim(25.0, 0.03)
    rot = Rotation.from_euler("ZYX", xa[8:5:-1])
    xi = np.concatenate([xa[0:3], rot.apply(xa[3:6]), xa[6:9]])
    for k in range(300):
        imu = aero.imu(k * aero.dt_s, xa, ua)
        xa = aero.step(k * aero.dt_s, xa, ua)
        xi = ins.step(k * ins.dt_s, xi, imu)
    v_ned = Rotation.from_euler("ZYX", xa[8:5:-1]).apply(xa[3:6])
    # the IMU is sampled at the start of each step (zero-order hold) while the climb slowly
    # changes the ISA density: a small, bounded drift
    np.testing.assert_allclose(xi[0:3], xa[0:3], rtol=0.0, atol=5e-5)
    np.testing.assert_allclose(xi[3:6], v_ned, rtol=0.0, atol=1e-5)
    np.testing.assert_allclose(xi[6:9], xa[6:9], rtol=0.0, atol=1e-6)
    assert xa[2] < -2.0  # it did climb: 3 s at 0.75 m/s


def test_noise_adds_to_the_input_and_batches() -> None:
    ins = InsModel(origin=NedOrigin(-33.9, 151.2, 50.0))
    rng = np.random.default_rng(7)
    x = np.empty((9, 7, 13))
    x[0:3] = rng.uniform(-100.0, 100.0, (3, 7, 13))
    x[3:6] = rng.uniform(-25.0, 25.0, (3, 7, 13))
    x[6:9] = rng.uniform(-0.5, 0.5, (3, 7, 13))
    u = np.array([0.5, 0.1, -9.7, 0.02, -0.01, 0.05])
    v = rng.standard_normal((6, 7, 13))
    stepped = ins.step(0.0, x, u, v)
    assert stepped.shape == (9, 7, 13)
    for i, j in [(0, 0), (3, 5), (6, 12)]:
        np.testing.assert_allclose(
            stepped[:, i, j], ins.step(0.0, x[:, i, j], u + v[:, i, j], None)
        )
        np.testing.assert_allclose(
            ins.derivatives(0.0, x, u[:, None, None] + v)[:, i, j],
            ins.derivatives(0.0, x[:, i, j], u, v[:, i, j]),
        )
    np.testing.assert_allclose(
        ins.step(0.0, x, u, v[:, 0, 0]), ins.step(0.0, x, u + v[:, 0, 0], None)
    )
    gps = ins.gps(0.0, x, u)
    assert gps.shape == (5, 7, 13)
    np.testing.assert_allclose(gps[3], np.hypot(x[3], x[4]))


def test_defaults_gravity_and_noise() -> None:
    ins = InsModel(origin=NedOrigin(45.0, 0.0, 1000.0))
    np.testing.assert_allclose(np.diag(ins.process_noise_cov()), [0.0245**2] * 3 + [0.00227**2] * 3)
    x = np.zeros(9)
    xd = ins.derivatives(0.0, x, np.zeros(6))
    assert xd[5] == pytest.approx(normal_gravity_mps2(45.0, 1000.0), abs=1e-12)
    x[2] = -500.0  # 500 m above the origin: weaker gravity
    assert ins.derivatives(0.0, x, np.zeros(6))[5] == pytest.approx(
        normal_gravity_mps2(45.0, 1500.0),
        abs=3e-7,  # linear gradient: 1.8e-7 curvature
    )
    assert ins.nx == 9 and ins.nu == 6 and ins.nv == 6 and len(ins.state_labels) == 9
    with pytest.raises(ValueError, match="dt_s: expected > 0"):
        InsModel(dt_s=-0.01)
