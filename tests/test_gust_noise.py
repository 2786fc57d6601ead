"""The rotational gusts of the design turbulence as states of the real-air model."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg

from immukf_sitl.models.aero import AeroModel
from immukf_sitl.models.augmented import GUST, N_AUGMENTED, N_RIGID, N_SLOW, AugmentedAeroModel
from immukf_sitl.models.params import load_aircraft_params
from immukf_sitl.models.sensors import SensorSpec
from immukf_sitl.models.wind import TURBULENCE_LEVELS, milspec_low_altitude_sigmas
from immukf_sitl.service.filter_models import RealAirModel
from immukf_sitl.service.noise_model import (
    milspec_scale_lengths_m,
    rotational_gust_sigmas,
    slow_state_noise,
)


@pytest.fixture(scope="module")
def model() -> AeroModel:
    return AeroModel(load_aircraft_params())


def _lyapunov_gradient_sigma(sigma: float, scale_m: float, speed: float, tau_s: float) -> float:
    """Std of ``(s/V)/(1 + tau s)`` applied to a Dryden ``v_g``/``w_g``, from a state-space model.

    Independent of the frequency-domain integral: the Dryden shaping filter
    ``sigma sqrt(L/V) (1 + sqrt(3) (L/V) s) / (1 + (L/V) s)^2`` driven by unit white noise,
    followed by the gradient filter, and the stationary covariance from the Lyapunov equation.
    """
    t = scale_m / speed
    k = sigma * math.sqrt(t)
    # shaping filter, controllable canonical form of k (1 + sqrt3 t s) / (t^2 s^2 + 2 t s + 1)
    a1 = np.array([[0.0, 1.0], [-1.0 / t**2, -2.0 / t]])
    b1 = np.array([[0.0], [1.0]])
    c1 = np.array([[k / t**2, k * math.sqrt(3.0) / t]])
    # gradient filter (s/V)/(1 + tau s) = (1/(V tau)) (1 - 1/(1 + tau s)): state z' = (y - z)/tau
    a = np.zeros((3, 3))
    a[:2, :2] = a1
    a[2, :2] = c1[0] / tau_s
    a[2, 2] = -1.0 / tau_s
    b = np.vstack([b1, [[0.0]]])
    c = np.concatenate([c1[0], [-1.0]]) / (speed * tau_s)
    x = scipy.linalg.solve_continuous_lyapunov(a, -b @ b.T)
    return float(math.sqrt(c @ x @ c))


@pytest.mark.parametrize("level", ["light", "moderate", "severe"])
def test_gust_rates_match_a_state_space_model_of_the_milspec_filters(model, level) -> None:
    tuning = RealAirModel(design_turbulence=level)
    span = model.params.geometry.b_m
    sigmas = rotational_gust_sigmas(tuning, span)
    gust = milspec_low_altitude_sigmas(TURBULENCE_LEVELS[level].w20_mps, tuning.design_height_m)
    lengths = milspec_scale_lengths_m(tuning.design_height_m)
    speed = tuning.design_airspeed_mps
    assert sigmas[0] == pytest.approx(1.9 * gust[2] / math.sqrt(lengths[2] * span))
    tau_q, tau_r = 4.0 * span / (math.pi * speed), 3.0 * span / (math.pi * speed)
    assert sigmas[1] == pytest.approx(
        _lyapunov_gradient_sigma(gust[2], lengths[2], speed, tau_q), rel=1e-6
    )
    assert sigmas[2] == pytest.approx(
        _lyapunov_gradient_sigma(gust[1], lengths[1], speed, tau_r), rel=1e-6
    )


def test_still_air_has_no_gusts(model) -> None:
    tuning = RealAirModel(design_turbulence="none")
    assert np.all(rotational_gust_sigmas(tuning, 2.9) == 0.0)
    noise = slow_state_noise(model.params, SensorSpec(), tuning)
    assert np.all(noise.initial_sigma[GUST] == 0.0) and np.all(noise.stationary_sigma[GUST] == 0.0)


def test_gust_states_are_the_milspec_processes(model) -> None:
    """Sigma of the MIL-F-8785C gust rates, time constants of JSBSim's generator (Yeager)."""
    tuning = RealAirModel(design_turbulence="moderate")
    span = model.params.geometry.b_m
    noise = slow_state_noise(model.params, SensorSpec(), tuning)
    sigmas = rotational_gust_sigmas(tuning, span)
    assert np.array_equal(noise.initial_sigma[GUST], sigmas)
    assert np.array_equal(noise.stationary_sigma[GUST], sigmas)
    l_w = milspec_scale_lengths_m(tuning.design_height_m)[2]
    speed = tuning.design_airspeed_mps
    tau = [
        math.sqrt(l_w * span) / 2.6 / speed,
        4 * span / (math.pi * speed),
        3 * span / (math.pi * speed),
    ]
    np.testing.assert_allclose(1.0 / noise.decay_per_s[GUST], tau, rtol=1e-12)
    assert 0.1 < min(tau) and max(tau) < 0.4  # fast: ten to forty 10 ms steps


def test_the_aerodynamics_see_the_rates_relative_to_the_turning_air(model) -> None:
    """A gust state omega_g gives the forces and moments of the body rates omega - omega_g."""
    aug = AugmentedAeroModel(model, np.zeros(N_SLOW))
    x0, u0 = model.trim(25.0)
    x0[9:12] = [0.2, -0.1, 0.05]
    gust = np.array([0.08, 0.03, -0.04])
    x = np.zeros(N_AUGMENTED)
    x[:N_RIGID] = x0
    x[N_RIGID + GUST.start : N_RIGID + GUST.stop] = gust
    turned = x0.copy()
    turned[9:12] -= gust
    fm_air = model.forces_moments(0.0, turned, u0)
    # the IMU's specific force is the aerodynamic force of the air-relative rates
    imu = aug.imu(0.0, x, u0)
    np.testing.assert_allclose(imu[:3], fm_air[:3] / model.params.mass.mass_kg, rtol=1e-12)
    np.testing.assert_allclose(imu[3:], x0[9:12])  # the gyros read the inertial rates
    # in still-turning air (no gust) the same state gives other forces
    still = aug.imu(0.0, np.concatenate([x0, np.zeros(N_SLOW)]), u0)
    assert np.max(np.abs(still[:3] - imu[:3])) > 1e-3


def test_the_turbulence_ceiling_is_the_roughest_airs_w20_over_the_designs() -> None:
    """MIL-F-8785C's low-altitude W20: severe 45 kt over moderate 30 kt."""
    assert RealAirModel(roughest_turbulence="severe").turbulence_ceiling == pytest.approx(1.5)
    assert RealAirModel().turbulence_ceiling == 1.0  # the design air, by default
    light = RealAirModel(design_turbulence="light", roughest_turbulence="severe")
    assert light.turbulence_ceiling == pytest.approx(3.0)
    with pytest.raises(ValueError, match="roughest_turbulence"):
        RealAirModel(roughest_turbulence="light")
    with pytest.raises(ValueError, match="roughest_turbulence"):
        RealAirModel(roughest_turbulence="hurricane")
    with pytest.raises(ValueError, match="still air"):
        RealAirModel(design_turbulence="none", roughest_turbulence="severe")
