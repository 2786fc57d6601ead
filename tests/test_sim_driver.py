"""JSBSim driver: trim, steady flight, truth record semantics, specific force timing, speed."""

from __future__ import annotations

import numpy as np
import pymap3d
import pytest

from immukf_sitl.models.params import load_aircraft_params
from sim.driver import JsbsimDriver
from sim.truth import InitialConditions, TruthState

# flies JSBSim or the estimator chain
pytestmark = pytest.mark.slow

FT = 0.3048


@pytest.fixture(scope="module")
def driver() -> JsbsimDriver:
    d = JsbsimDriver(InitialConditions(lat_deg=-33.9, lon_deg=151.2, alt_m=200.0, heading_rad=1.0))
    d.trim()
    return d


def test_trim_is_steady_level_flight_within_the_limits(driver):
    trim = driver.trim()
    params = load_aircraft_params()
    assert trim.residual_accel_mps2 < 1e-8
    assert trim.residual_angular_accel_radps2 < 1e-8
    assert np.all(trim.controls >= params.actuators.lower_limits)
    assert np.all(trim.controls <= params.actuators.upper_limits)
    # Thrust is negative below delta_t ~ 0.67 at 25 m/s (the supplement's propeller), so trim
    # throttle is high.
    assert 0.67 < trim.controls[3] < 0.95
    assert 0.0 < trim.alpha_rad < 0.15
    # The propeller's reaction torque is balanced by a small aileron deflection.
    assert abs(trim.controls[1]) < 0.05
    assert trim.theta_rad == trim.alpha_rad


def test_trim_holds_for_ten_seconds(driver):
    start = driver.reset()
    assert np.allclose(start.position_ned_m, 0.0, atol=1e-9)
    assert start.time_s == 0.0
    controls = driver.trim_result.controls
    worst_rate = 0.0
    for _ in range(1000):
        state = driver.step(controls)
        worst_rate = max(worst_rate, float(np.max(np.abs(state.rates_body_radps))))
    assert state.time_s == pytest.approx(10.0)
    print(
        f"trim held 10 s: max |rate| {worst_rate:.2e} rad/s, alt change "
        f"{state.alt_m - start.alt_m:+.3f} m, airspeed {state.airspeed_mps:.4f} m/s"
    )
    assert worst_rate < 2e-4  # earth rate (7.3e-5 rad/s) and rounding only
    assert abs(state.alt_m - start.alt_m) < 0.5
    assert state.airspeed_mps == pytest.approx(25.0, abs=0.02)
    assert abs(state.euler_rad[0]) < 1e-3
    # heading held (the earth's rotation turns the local frame a little)
    assert state.euler_rad[2] == pytest.approx(1.0, abs=2e-3)


def test_truth_record_is_consistent(driver):
    driver.reset()
    controls = driver.trim_result.controls + np.array([0.02, 0.05, -0.02, 0.05])
    for _ in range(200):
        state = driver.step(controls)
    assert isinstance(state, TruthState)
    lat0, lon0, alt0 = driver.origin
    ned = pymap3d.geodetic2ned(state.lat_deg, state.lon_deg, state.alt_m, lat0, lon0, alt0)
    assert np.allclose(state.position_ned_m, ned, atol=1e-6)
    phi, theta, psi = state.euler_rad
    # body velocity rotated by R_nb(phi, theta, psi) is the NED velocity
    cf, sf, ct, st, cp, sp = (
        np.cos(phi),
        np.sin(phi),
        np.cos(theta),
        np.sin(theta),
        np.cos(psi),
        np.sin(psi),
    )
    r_nb = np.array(
        [
            [ct * cp, sf * st * cp - cf * sp, cf * st * cp + sf * sp],
            [ct * sp, sf * st * sp + cf * cp, cf * st * sp - sf * cp],
            [-st, sf * ct, cf * ct],
        ]
    )
    assert np.allclose(r_nb @ state.velocity_body_mps, state.velocity_ned_mps, atol=1e-6)
    assert state.airspeed_mps == pytest.approx(np.linalg.norm(state.velocity_body_mps), rel=1e-9)
    assert state.alpha_rad == pytest.approx(
        np.arctan2(state.velocity_body_mps[2], state.velocity_body_mps[0]), abs=1e-9
    )
    assert np.allclose(state.controls, np.clip(controls, -0.4363, 1.0))
    x = state.state_vector()
    assert x.shape == (12,)
    assert np.array_equal(x[9:12], state.rates_body_radps)
    with pytest.raises(ValueError):
        state.position_ned_m[0] = 1.0  # read-only


def test_rates_are_inertial(driver):
    driver.reset()
    state = driver.step(driver.trim_result.controls)
    earth_relative = np.array([driver.get_property(f"velocities/{a}-rad_sec") for a in "pqr"])
    difference = np.linalg.norm(state.rates_body_radps - earth_relative)
    assert 5e-5 < difference < 8e-5  # the earth rate, 7.29e-5 rad/s


def test_specific_force_is_this_steps_and_a_pilot_lags_one_step(driver):
    """fb-total / mass excludes gravity and belongs to the current step (a-pilot lags one)."""
    driver.reset()
    trim = driver.trim_result.controls
    forces, pilots = [], []
    for k in range(300):
        wiggle = np.array([0.05 * np.sin(0.1 * k), 0.08 * np.sin(0.07 * k), 0.03, 0.0])
        state = driver.step(trim + wiggle)
        forces.append(state.specific_force_body_mps2)
        pilots.append(
            [driver.get_property(f"accelerations/a-pilot-{a}-ft_sec2") * FT for a in "xyz"]
        )
    forces, pilots = np.array(forces), np.array(pilots)
    lagged = np.max(np.abs(pilots[1:] - forces[:-1]))
    same_step = np.max(np.abs(pilots - forces))
    print(
        f"a-pilot vs specific force: same step {same_step:.3g}, shifted one step {lagged:.3g} m/s^2"
    )
    assert lagged < 1e-6
    assert same_step > 1e-3
    # level flight reads about -g on z: gravity is not in fb-total
    driver.reset()
    assert driver.truth().specific_force_body_mps2[2] == pytest.approx(-9.79, abs=0.05)


def test_step_rejects_bad_controls(driver):
    with pytest.raises(ValueError, match="4 finite values"):
        driver.step(np.array([0.0, 0.0, np.nan, 0.5]))
    with pytest.raises(ValueError, match="4 finite values"):
        driver.step(np.zeros(3))


@pytest.mark.parametrize("airspeed_mps", [18.0, 30.0])
def test_trim_across_the_envelope(airspeed_mps):
    trim = JsbsimDriver(InitialConditions(airspeed_mps=airspeed_mps)).trim()
    assert trim.residual_accel_mps2 < 1e-8


def test_trim_outside_the_envelope_raises():
    from sim.driver import JsbsimError

    # at 40 m/s full throttle cannot balance the drag
    with pytest.raises(JsbsimError, match="trim did not converge at 40.0 m/s"):
        JsbsimDriver(InitialConditions(airspeed_mps=40.0)).trim()


def test_initial_conditions_are_validated():
    with pytest.raises(ValueError, match="airspeed_mps"):
        InitialConditions(airspeed_mps=5.0)
    with pytest.raises(ValueError, match="lat_deg"):
        InitialConditions(lat_deg=89.0)


def test_same_inputs_same_trajectory():
    runs = []
    for _ in range(2):
        d = JsbsimDriver()
        d.trim()
        d.reset()
        for k in range(100):
            s = d.step(d.trim_result.controls + np.array([0.0, 0.01 * np.sin(k), 0.0, 0.0]))
        runs.append(s.state_vector())
    assert np.array_equal(runs[0], runs[1])
