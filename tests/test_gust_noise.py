"""Issue 9: the rotational gusts of the design turbulence in the real-air process noise."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import scipy.linalg

from immukf_sitl.models.aero import AeroModel
from immukf_sitl.models.earth import isa_density_kgpm3
from immukf_sitl.models.params import load_aircraft_params
from immukf_sitl.models.wind import TURBULENCE_LEVELS, milspec_low_altitude_sigmas
from immukf_sitl.service.filters import build_aero_estimator
from immukf_sitl.service.noise_model import (
    gust_acceleration_cov,
    milspec_scale_lengths_m,
    rotational_gust_sigmas,
)
from immukf_sitl.service.tuning import FilterTuning


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
    tuning = FilterTuning.real_air(design_turbulence=level)
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
    tuning = FilterTuning.real_air(design_turbulence="none")
    assert np.all(rotational_gust_sigmas(tuning, 2.9) == 0.0)
    assert np.all(gust_acceleration_cov(model, tuning) == 0.0)


def test_gust_acceleration_is_the_damping_derivatives_times_the_gust_rates(model) -> None:
    """The roll, pitch and yaw rows against the textbook damping terms (B&M eqs. 4.6, 5.x)."""
    tuning = FilterTuning.real_air(design_turbulence="moderate")
    params = model.params
    cov = gust_acceleration_cov(model, tuning)
    assert np.allclose(cov, cov.T) and np.all(np.linalg.eigvalsh(cov) > -1e-12)
    sigmas = rotational_gust_sigmas(tuning, params.geometry.b_m)
    x_trim, _ = model.trim(tuning.design_airspeed_mps)
    speed = float(np.linalg.norm(x_trim[3:6]))
    rho = isa_density_kgpm3(model.origin.alt_m)  # the model's ISA at the trim's height
    g, c, m = params.geometry, params.aero, params.mass
    qbar_s = 0.5 * rho * speed**2 * g.S_m2
    jx, jz, jxz = m.Jx_kgm2, m.Jz_kgm2, m.Jxz_kgm2
    gamma = jx * jz - jxz**2
    # roll acceleration per unit roll rate: (Jz dL/dp + Jxz dN/dp) / Gamma
    d_ell = qbar_s * g.b_m * c.C_ell_p * g.b_m / (2.0 * speed)
    d_n = qbar_s * g.b_m * c.C_n_p * g.b_m / (2.0 * speed)
    roll_from_p = (jz * d_ell + jxz * d_n) / gamma
    pitch_from_q = qbar_s * g.c_m * c.C_m_q * g.c_m / (2.0 * speed) / m.Jy_kgm2
    # each diagonal entry sums the three gust axes; roll is dominated by p_g, pitch is q_g alone
    assert math.sqrt(cov[4, 4]) == pytest.approx(abs(pitch_from_q) * sigmas[1], rel=0.02)
    assert math.sqrt(cov[3, 3]) >= abs(roll_from_p) * sigmas[0] * 0.98
    assert math.sqrt(cov[3, 3]) == pytest.approx(abs(roll_from_p) * sigmas[0], rel=0.1)
    # four times the variance from light to moderate (W20 doubles)
    light = gust_acceleration_cov(model, dataclasses.replace(tuning, design_turbulence="light"))
    assert np.allclose(cov, 4.0 * light, rtol=1e-6, atol=1e-12)


def test_gusts_reach_the_real_air_filters_process_noise_only(model) -> None:
    paper = build_aero_estimator("ukf2", model, tuning=FilterTuning())
    real = build_aero_estimator("ukf2", model, tuning=FilterTuning.real_air())
    gusts = gust_acceleration_cov(model, FilterTuning.real_air())
    assert np.allclose(real.imm.ukf.process.noise_cov - paper.imm.ukf.process.noise_cov, gusts)
