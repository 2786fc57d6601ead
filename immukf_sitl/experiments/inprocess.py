"""The sim -> fault proxy -> estimator chain in one process, without sockets.

The same objects the three UDP processes wrap (DESIGN.md section 1): the JSBSim
:class:`~sim.flight.Flight`, the proxy's :class:`~sim.fault_proxy.FaultInjector` and the
:class:`~immukf_sitl.service.pipeline.EstimatorPipeline`, stepped together. Experiments and tuning
studies use it; the summary is the one ``run`` and ``replay`` print.

The stream differs from the wire only by what the wire quantises: the estimator here gets the
sensor values at full precision (HIGHRES_IMU carries float32, GPS_RAW_INT integers) and the
controls through the same PWM map.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from immukf_sitl.experiments.report import EstimateHistory, Summary, summarize
from immukf_sitl.models.params import load_aircraft_params
from immukf_sitl.samples import ActuatorSample, TruthSample
from immukf_sitl.scenario import Scenario
from immukf_sitl.service.pipeline import EstimateOutput, EstimatorPipeline, PipelineConfig
from sim.fault_proxy import FaultInjector
from sim.scenario_flight import flight_from_scenario


@dataclass(frozen=True)
class InProcessRun:
    """Outputs of the estimator and the truth of one in-process flight."""

    scenario: Scenario
    history: EstimateHistory
    truth: tuple[TruthSample, ...]
    pipeline: EstimatorPipeline
    airframe: dict[str, float]

    def summary(self) -> Summary:
        """The run/replay summary."""
        summary = summarize(
            self.scenario.name,
            self.scenario.faults,
            self.truth,
            self.history.events(),
            self.history.track(),
            self.history.step_us(),
            self.scenario.sensors.imu,
            self.scenario.expect,
            settle_s=self.pipeline.config.detector.settle_s,
        )
        return dataclasses.replace(
            summary, airframe=self.airframe, wind=dataclasses.asdict(self.scenario.wind)
        )


def run_inprocess(
    scenario: Scenario,
    config: PipelineConfig | None = None,
    duration_s: float | None = None,
) -> InProcessRun:
    """Fly ``scenario`` through the fault injector into the estimator, in one process.

    The filter keeps the book's aircraft and, unless ``config`` says otherwise, is told the
    scenario's sensor spec sheet (sigmas, not the true biases); the flight flies the scenario's
    airframe and air.
    """
    params = load_aircraft_params()
    if config is None:
        config = PipelineConfig(sensors=scenario.sensors.spec_sheet())
    pipeline = EstimatorPipeline(params, config)
    flight = flight_from_scenario(scenario, params)
    injector = FaultInjector.from_scenario(scenario)
    steps = int(round((duration_s or scenario.duration_s) / flight.driver.dt_s))
    outputs: list[EstimateOutput] = []
    truth: list[TruthSample] = []
    record = flight.start()
    for k in range(steps + 1):
        if k:
            record = flight.step()
        t = record.time_s
        pwm = params.actuators.controls_to_pwm(record.controls)
        pipeline.on_actuators(ActuatorSample(t, tuple(pwm.get(c, 0) for c in range(1, 17))))
        if record.gps is not None:
            pipeline.on_gps(record.gps)
        out = pipeline.on_imu(injector.apply(record.imu))
        truth.append(record.truth.sample())
        if out is not None:
            outputs.append(out)
    return InProcessRun(
        scenario, EstimateHistory(tuple(outputs)), tuple(truth), pipeline, flight.airframe_factors
    )
