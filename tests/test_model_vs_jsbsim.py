"""The filter's AeroModel against the JSBSim truth aircraft: same equations, same numbers."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from immukf_sitl.models.aero import AeroModel
from immukf_sitl.models.earth import NedOrigin
from immukf_sitl.models.params import load_aircraft_params
from immukf_sitl.models.sensors import ImuSpec
from sim.driver import JsbsimDriver
from sim.flight import fly
from sim.flight_plans import default_flight_plan

# flies JSBSim or the estimator chain
pytestmark = pytest.mark.slow

LBF_N = 4.4482216152605
FT = 0.3048
SLUG_FT3_KG_M3 = 515.378818


@pytest.fixture(scope="module")
def params():
    return load_aircraft_params()


@pytest.fixture(scope="module")
def manoeuvre(params):
    """A state in a rolling, yawing, pitching manoeuvre, with JSBSim's forces and moments."""
    driver = JsbsimDriver(params=params)
    trim = driver.trim()
    driver.reset()
    for k in range(150):
        controls = trim.controls + np.array([0.06 * np.sin(0.05 * k), 0.12, 0.06, 0.1])
        state = driver.step(controls)
    forces = np.array([driver.get_property(f"forces/fb{a}-total-lbs") for a in "xyz"]) * LBF_N
    moments = np.array([driver.get_property(f"moments/{a}-total-lbsft") for a in "lmn"])
    omega_dot = np.array([driver.get_property(f"accelerations/{a}idot-rad_sec2") for a in "pqr"])
    rho = driver.get_property("atmosphere/rho-slugs_ft3") * SLUG_FT3_KG_M3
    # JSBSim's aerodynamics use the rates relative to the air (the rotating earth's), the truth
    # record holds the inertial rates (what a gyro reads); they differ by the earth rate.
    aero_state = state.state_vector()
    aero_state[9:12] = [driver.get_property(f"velocities/{a}-aero-rad_sec") for a in "pqr"]
    return state, aero_state, forces, moments * LBF_N * FT, omega_dot, rho, driver.origin


def test_forces_and_moments_equal_the_aero_model(params, manoeuvre):
    state, aero_state, forces, moments, _, rho, origin = manoeuvre
    assert abs(state.euler_rad[0]) > 0.2 and abs(state.beta_rad) > 0.005  # a real manoeuvre
    model = AeroModel(params, origin=NedOrigin(*origin), density_kgpm3=rho, compiled=False)
    predicted = model.forces_moments(0.0, aero_state, state.controls)
    print("JSBSim forces/moments", forces, moments)
    print("AeroModel            ", predicted[:3], predicted[3:])
    # Equal up to the unit conversions' rounding (JSBSim works in slugs, feet and pounds).
    assert np.allclose(predicted[:3], forces, rtol=1e-6, atol=1e-6)
    assert np.allclose(predicted[3:], moments, rtol=1e-6, atol=1e-6)


def test_angular_accelerations_have_the_book_inertia_signs(params, manoeuvre):
    """Catches the Ixz sign trap: with the wrong sign roll and yaw accelerations differ a lot."""
    state, _, _, _, omega_dot, rho, origin = manoeuvre
    model = AeroModel(params, origin=NedOrigin(*origin), density_kgpm3=rho, compiled=False)
    xdot = model.derivatives(0.0, state.state_vector(), state.controls)
    flipped = dataclasses.replace(
        params, mass=dataclasses.replace(params.mass, Jxz_kgm2=-params.mass.Jxz_kgm2)
    )
    wrong = AeroModel(flipped, origin=NedOrigin(*origin), density_kgpm3=rho, compiled=False)
    xdot_wrong = wrong.derivatives(0.0, state.state_vector(), state.controls)
    print("JSBSim omega_dot", omega_dot, "AeroModel", xdot[9:12], "Ixz flipped", xdot_wrong[9:12])
    # The model damps with inertial rates, JSBSim with air-relative ones (the earth rate
    # apart): about 2e-3 rad/s^2 on p. The wrong Ixz sign is off by far more.
    assert np.allclose(xdot[9:12], omega_dot, atol=5e-3)
    assert np.max(np.abs(xdot_wrong[9:12] - omega_dot)) > 0.02


def test_specific_force_rms_error_over_a_manoeuvring_flight(params):
    records = list(fly(default_flight_plan(), seed=0, duration_s=60.0, params=params))
    origin = records[0].truth
    model = AeroModel(params, origin=NedOrigin(origin.lat_deg, origin.lon_deg, origin.alt_m))
    x = np.array([r.truth.state_vector() for r in records]).T
    u = np.array([r.controls for r in records]).T
    truth = np.array([r.truth.specific_force_body_mps2 for r in records]).T
    error = model.imu(0.0, x, u)[:3] - truth
    rms_error = float(np.sqrt(np.mean(np.sum(error**2, axis=0))))
    rms_signal = float(np.sqrt(np.mean(np.sum(truth**2, axis=0))))
    dynamic = truth - truth.mean(axis=1, keepdims=True)
    rms_dynamic = float(np.sqrt(np.mean(np.sum(dynamic**2, axis=0))))
    print(
        f"specific force over 60 s: RMS error {rms_error:.3g} m/s^2, signal RMS "
        f"{rms_signal:.3g} m/s^2 ({100 * rms_error / rms_signal:.4f} %), RMS about the mean "
        f"{rms_dynamic:.3g} m/s^2"
    )
    assert rms_dynamic > 0.3  # the flight manoeuvres
    assert rms_error < 0.1 * rms_signal
    assert rms_error < 0.1 * rms_dynamic


@pytest.mark.parametrize("start_s", [0.0, 15.0, 28.0])
def test_ins_model_on_noise_free_jsbsim_imu_follows_the_truth_for_10_s(start_s):
    """Strapdown INS (UKF-3's process model) on JSBSim's ideal IMU stays on the trajectory.

    Segments: straight flight, the turn onto the climbing leg, the climb with its pull-out.
    """
    from immukf_sitl.models.ins import InsModel

    ideal = ImuSpec(accel_sigma_mps2=0.0, gyro_sigma_radps=0.0)
    records = list(fly(default_flight_plan(), seed=0, duration_s=start_s + 10.0, imu_spec=ideal))
    origin = records[0].truth
    ins = InsModel(origin=NedOrigin(origin.lat_deg, origin.lon_deg, origin.alt_m))
    k0 = int(round(start_s / 0.01))
    t = records[k0].truth
    x = np.concatenate([t.position_ned_m, t.velocity_ned_mps, t.euler_rad])
    worst_position, worst_velocity = 0.0, 0.0
    for k in range(k0, k0 + 1000):
        x = ins.step(0.0, x, records[k].imu.as_array())
        truth = records[k + 1].truth
        worst_position = max(worst_position, float(np.linalg.norm(x[:3] - truth.position_ned_m)))
        worst_velocity = max(worst_velocity, float(np.linalg.norm(x[3:6] - truth.velocity_ned_mps)))
    print(
        f"INS from t = {start_s} s over 10 s: max position error {worst_position:.3f} m, "
        f"max velocity error {worst_velocity:.4f} m/s"
    )
    # Remaining error: JSBSim's earth rotates (Coriolis, ~4e-3 m/s^2 at 25 m/s), the INS's not.
    assert worst_position < 1.0
    assert worst_velocity < 0.1
