"""Closed loop: the autopilot holds the estimate's airspeed, through the estimated wind."""

from __future__ import annotations

import numpy as np
import pytest

from immukf_sitl.estimation import FaultMode
from immukf_sitl.experiments.inprocess import _navigation
from immukf_sitl.models.aero import AeroModel
from immukf_sitl.models.augmented import N_RIGID, WIND
from immukf_sitl.models.earth import body_to_ned
from immukf_sitl.models.params import load_aircraft_params
from immukf_sitl.service.filter_models import PaperModel, RealAirModel
from immukf_sitl.service.filters import build_aero_estimator
from immukf_sitl.service.pipeline import EstimateOutput


@pytest.fixture(scope="module")
def model() -> AeroModel:
    return AeroModel(load_aircraft_params())


def _output(nav) -> EstimateOutput:
    return EstimateOutput(0.0, nav, 0.0, 0.0, 0.0, (FaultMode(0),), np.ones(1), (), 0.0)


def test_real_air_navigation_flies_the_air_relative_speed(model) -> None:
    est = build_aero_estimator("ukf2", model, filter_model=RealAirModel())
    x0, u0 = model.trim(25.0)
    x0[8] = 0.3  # heading 17 deg
    wind = np.array([-8.0, 1.0, 0.5])  # a headwind
    mean, cov = est.augmented(x0, np.eye(12) * 1e-4)
    mean[N_RIGID + WIND.start : N_RIGID + WIND.stop] = wind
    nav = est.navigation(est.start(0.0, mean, cov, u0))
    assert np.array_equal(nav.wind_ned_mps, wind)
    state = _navigation(_output(nav), np.zeros(3), 100.0)
    air_body = body_to_ned(x0[6:9]).T @ (body_to_ned(x0[6:9]) @ x0[3:6] - wind)
    assert state.airspeed_mps == pytest.approx(float(np.linalg.norm(air_body)), rel=1e-12)
    # 8 m/s of headwind: a ground-speed autopilot would be 7 m/s slow
    assert abs(state.airspeed_mps - float(np.linalg.norm(x0[3:6]))) > 3.0


def test_still_air_navigation_flies_the_ground_speed(model) -> None:
    est = build_aero_estimator("ukf2", model, filter_model=PaperModel())
    x0, u0 = model.trim(25.0)
    nav = est.navigation(est.start(0.0, x0, np.eye(12) * 1e-4, u0))
    assert nav.wind_ned_mps is None
    state = _navigation(_output(nav), np.zeros(3), 100.0)
    assert state.airspeed_mps == pytest.approx(float(np.linalg.norm(x0[3:6])), rel=1e-12)
