"""The steps a declaration re-runs: what is kept, and that a re-run is the flight again."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from flights import thinned

from immukf_sitl.experiments.replay import replay
from immukf_sitl.mavlink.flightlog import read_flight_log
from immukf_sitl.models.params import load_aircraft_params
from immukf_sitl.samples import ActuatorSample, ImuSample
from immukf_sitl.service.filter_models import RealAirModel
from immukf_sitl.service.pipeline import EstimatorPipeline, PipelineConfig
from immukf_sitl.service.recent_steps import RecentSteps, Step, rerun

DATA = Path(__file__).parent / "data"


def _step(estimator: object, t_s: float) -> Step:
    return Step(estimator, None, t_s, np.zeros(4), None)  # type: ignore[arg-type]


def test_the_steps_kept_are_the_last_half_second_of_the_current_estimator():
    first, second = object(), object()
    recent = RecentSteps(span_s=0.5)
    for k in range(30):
        recent.record(_step(first, k * 0.01))
    for k in range(30, 80):
        recent.record(_step(second, k * 0.01))
    kept = [s.t_s for s in recent.taken_by(second)]
    assert kept == pytest.approx([k * 0.01 for k in range(30, 80)])
    assert recent.taken_by(first) == []  # not the latest: another estimator stepped since
    recent.record(_step(second, 0.80))
    assert len(recent.taken_by(second)) == 50  # the oldest fell out
    recent.clear()
    assert recent.taken_by(second) == []


@pytest.mark.slow
@pytest.mark.parametrize(("imu_hz", "servo_hz"), [(None, None), (50.0, 20.0)])
def test_a_rerun_over_the_recorded_steps_is_the_flight_again(imu_hz, servo_hz):
    """The recorded fault-free flight on the real-air bank of untrusted modes, as recorded and
    thinned to an autopilot's telemetry rates (every other filter step bridged without an
    update, the servo outputs held between samples): the last half second re-run from its
    first estimate gives, bit for bit, the estimate the service has. Every input a step reads
    is recorded, the bridged steps too, and nothing is changed in place."""
    log = read_flight_log(DATA / "fault_free.tlog")
    if imu_hz is not None:
        stream = thinned(log.stream, ImuSample, 1.0 / imu_hz)
        log = dataclasses.replace(log, stream=thinned(stream, ActuatorSample, 1.0 / servo_hz))
    config = PipelineConfig(filter_model=RealAirModel(fault_signature="untrusted"))
    pipeline = EstimatorPipeline(load_aircraft_params(), config)
    replay(log, pipeline)
    steps = pipeline._recent.taken_by(pipeline.estimator)
    assert len(steps) == 50
    assert np.diff([s.t_s for s in steps]) == pytest.approx(np.full(49, 0.01))
    if imu_hz is not None:
        assert any(s.observation.control_sensitivity is not None for s in steps)
        assert sum(not np.isfinite(s.observation.imu).any() for s in steps) == 25
    again, evidence = rerun(pipeline.estimator, steps[0].estimate, steps)
    # nothing failed: no slot that adds a failure out-scores the base (the re-run a
    # declaration keeps only where one does by ln(0.999 / 0.001) = 6.9 nats)
    assert evidence[0] == 0.0 and np.max(evidence[1:]) < math.log(0.999 / 0.001)
    np.testing.assert_array_equal(again.filter.mode_means, pipeline.estimate.filter.mode_means)
    np.testing.assert_array_equal(again.filter.mode_covs, pipeline.estimate.filter.mode_covs)
    np.testing.assert_array_equal(
        again.filter.mode_probabilities, pipeline.estimate.filter.mode_probabilities
    )
