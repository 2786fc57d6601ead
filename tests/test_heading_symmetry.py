"""Heading and wind seen together: the symmetry's tangent, its covariance transport, and a flight
whose heading uncertainty stays honest until the turns tell heading and wind apart."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.stats

from immukf_sitl.estimation import StateSymmetry
from immukf_sitl.models.aero import AeroModel
from immukf_sitl.models.augmented import (
    HEADING,
    N_RIGID,
    N_SLOW,
    WIND,
    AugmentedAeroModel,
    heading_tangent,
)
from immukf_sitl.models.earth import body_to_ned
from immukf_sitl.models.params import load_aircraft_params

REPO = Path(__file__).resolve().parents[1]
WIND_ROWS = slice(N_RIGID + WIND.start, N_RIGID + WIND.stop)


@pytest.fixture(scope="module")
def model_and_state():
    aero = AeroModel(load_aircraft_params())
    x0, u0 = aero.trim(25.0)
    x = np.concatenate([x0, np.zeros(N_SLOW)])
    x[6:9] = [0.15, 0.04, 0.7]  # banked a little, heading north-east
    wind = np.array([4.0, -7.0, 0.3])
    x[WIND_ROWS] = wind
    x[3:6] = x0[3:6] + body_to_ned(x[6:9]).T @ wind  # ground velocity in body axes
    return AugmentedAeroModel(aero, np.zeros(N_SLOW)), x, u0


def _turned(x: np.ndarray, s_rad: float) -> np.ndarray:
    """``x`` with its heading turned by ``s``, ground velocity and body air velocity kept."""
    v_n = body_to_ned(x[6:9]) @ x[3:6]
    air_b = x[3:6] - body_to_ned(x[6:9]).T @ x[WIND_ROWS]
    out = x.copy()
    out[HEADING] += s_rad
    r_nb = body_to_ned(out[6:9])
    out[3:6] = r_nb.T @ v_n
    out[WIND_ROWS] = v_n - r_nb @ air_b
    return out


def test_turning_heading_and_wind_together_changes_no_reading(model_and_state) -> None:
    """Exactly, not to first order: the IMU and the GPS velocity of the turned state are the
    same, whatever the turn; its position and the GPS position too (they are not turned)."""
    model, x, u = model_and_state
    for s in (-0.4, 0.05, 0.3):
        turned = _turned(x, s)
        np.testing.assert_allclose(model.imu(0.0, turned, u), model.imu(0.0, x, u), atol=1e-10)
        np.testing.assert_allclose(model.gps(0.0, turned, u), model.gps(0.0, x, u), atol=1e-10)


def test_the_tangent_is_the_turns_derivative(model_and_state) -> None:
    """Against central differences of the exact turn, at several means of one batch."""
    _, x, _ = model_and_state
    means = np.stack([x, _turned(x, 0.5), _turned(x, -1.2)])
    extra = np.zeros((3, 6))  # appended states (a bank's offsets) do not move
    h = 1e-6
    expected = np.stack([(_turned(m, h) - _turned(m, -h)) / (2 * h) for m in means])
    got = heading_tangent(np.hstack([means, extra]))
    np.testing.assert_allclose(got[:, : means.shape[1]], expected, atol=1e-6)
    assert np.all(got[:, means.shape[1] :] == 0.0)
    assert np.all(got[:, HEADING] == 1.0)


def test_the_transport_is_t_p_t_and_undoes_itself(model_and_state) -> None:
    """``carried`` against an explicit ``T P T'``; carried back, the covariance is the same."""
    _, x, _ = model_and_state
    rng = np.random.default_rng(7)
    n = x.size
    a = rng.standard_normal((2, n, n))
    cov = a @ np.swapaxes(a, 1, 2) / n
    before = np.stack([x, _turned(x, 0.2)])
    after = np.stack([_turned(x, 0.35), _turned(x, -0.1)])
    after[:, WIND_ROWS] += [[1.5, -2.0, 0.0], [-3.0, 0.5, 0.2]]  # the update moved the wind too
    symmetry = StateSymmetry(HEADING, heading_tangent)
    carried = symmetry.carried(before, after, cov)
    for b in range(2):
        t = np.eye(n)
        t[:, HEADING] += (
            heading_tangent(after[b : b + 1])[0] - heading_tangent(before[b : b + 1])[0]
        )
        np.testing.assert_allclose(carried[b], t @ cov[b] @ t.T, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(symmetry.carried(after, before, carried), cov, atol=1e-12)


@pytest.mark.slow
def test_the_heading_is_as_uncertain_as_it_is_wrong_before_the_first_turn() -> None:
    """scenarios/fault_free_windy.yaml (6 m/s across the first leg, light turbulence), 12 s on
    the real-air filter, aligned on the GPS course: the heading starts off by the wind's crab,
    which nothing in a straight leg observes. Its normalised error ``(e / sigma)^2`` stays
    within the 99.9 % chi-square bound of 1 d.o.f. (10.8) at every estimate; without the
    transport it reached 37."""
    from immukf_sitl.experiments.inprocess import run_inprocess
    from immukf_sitl.scenario import load_scenario
    from immukf_sitl.service.filter_models import RealAirModel
    from immukf_sitl.service.pipeline import PipelineConfig

    scenario = load_scenario(REPO / "scenarios" / "fault_free_windy.yaml")
    config = PipelineConfig(
        variant="imm", sensors=scenario.sensors.spec_sheet(), filter_model=RealAirModel()
    )
    run = run_inprocess(scenario, config, duration_s=12.0)
    truth = {round(t.t_s, 3): t for t in run.truth}
    nees = []
    for out in run.history.outputs:
        true_heading = truth[round(out.t_s, 3)].euler_rad[2]
        error = (out.nav.euler_rad[2] - true_heading + np.pi) % (2 * np.pi) - np.pi
        nees.append(float((error / out.nav.euler_sigma_rad[2]) ** 2))
    assert len(nees) > 1000
    assert max(nees) < scipy.stats.chi2.ppf(0.999, 1)
