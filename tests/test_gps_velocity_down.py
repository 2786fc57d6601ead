"""A receiver's vertical velocity fused by the estimator: its innovations consistent in flight.

The fault-free windy flight (drawn airframe, 6 m/s light turbulence, MEMS biases) flown with a
receiver that reports ``vD``, on the real-air model: every fix after alignment is fused with its
``vD`` (the stream counter), and the base slot's normalised ``vD`` innovations over the flight
have the chi-square mean of one degree of freedom (two-sided 99.9 % bounds).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy import stats
from udp_tools import REPO

from immukf_sitl.models.params import load_aircraft_params
from immukf_sitl.samples import ActuatorSample
from immukf_sitl.scenario import load_scenario
from immukf_sitl.service.filter_models import RealAirModel
from immukf_sitl.service.pipeline import EstimatorPipeline, PipelineConfig
from sim.scenario_flight import flight_from_scenario

# flies JSBSim and the estimator
pytestmark = pytest.mark.slow

#: the filter's settling (10 s on the real-air model) and a few fixes more
FROM_S = 15.0
DURATION_S = 90.0


def _vertical_nis() -> tuple[np.ndarray, int, int]:
    """Base-slot NIS of ``vD`` at each fix after :data:`FROM_S`; fixes fused with it; fixes."""
    scenario = load_scenario(REPO / "scenarios" / "fault_free_windy.yaml")
    gps = dataclasses.replace(scenario.sensors.gps, reports_velocity_down=True)
    scenario = dataclasses.replace(scenario, sensors=dataclasses.replace(scenario.sensors, gps=gps))
    params = load_aircraft_params()
    config = PipelineConfig(
        filter_model=RealAirModel(fault_signature="untrusted"),
        sensors=scenario.sensors.spec_sheet(),
    )
    pipeline = EstimatorPipeline(params, config)
    flight = flight_from_scenario(scenario, params)
    record, nis = flight.start(), []
    for k in range(int(round(DURATION_S / flight.driver.dt_s)) + 1):
        if k:
            record = flight.step()
        pwm = params.actuators.controls_to_pwm(record.controls)
        pwm_us = tuple(pwm.get(c, 0) for c in range(1, 17))
        pipeline.on_actuators(ActuatorSample(record.time_s, pwm_us))
        if record.gps is not None:
            assert record.gps.velocity_down_mps is not None
            pipeline.on_gps(record.gps)
        pipeline.on_imu(record.imu)
        bank = None if pipeline.estimate is None else pipeline.estimate.filter
        fused = bank is not None and bank.innovations is not None and record.gps is not None
        if fused and record.time_s > FROM_S and bank.innovations.shape[1] == 12:
            nis.append(bank.innovations[0, 11] ** 2 / bank.innovation_var[0, 11])
    counters = pipeline.counters
    return np.array(nis), counters.gps_velocity_down, counters.gps_fixes


def test_the_vertical_velocity_is_fused_at_every_fix_with_consistent_innovations() -> None:
    nis, fused, fixes = _vertical_nis()
    assert fixes == int(DURATION_S) + 1
    assert fused >= fixes - 2  # the first fix aligns, before the filter runs
    n = len(nis)
    assert n >= DURATION_S - FROM_S - 2
    lo, hi = stats.chi2.ppf([0.0005, 0.9995], n) / n
    assert lo < nis.mean() < hi, (nis.mean(), lo, hi)
