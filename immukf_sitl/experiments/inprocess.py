"""The sim -> fault proxy -> estimator chain in one process, without sockets; open or closed loop.

The same objects the three UDP processes wrap (docs/design/architecture.md): the JSBSim
:class:`~sim.flight.Flight`, the proxy's :class:`~sim.fault_proxy.FaultInjector` and the
:class:`~immukf_sitl.service.pipeline.EstimatorPipeline`, stepped together. Experiments and tuning
studies use it; the summary is the one ``run`` and ``replay`` print.

The stream differs from the wire only by what the wire quantises: the estimator here gets the
sensor values at full precision (HIGHRES_IMU carries float32, GPS_RAW_INT integers) and the
controls through the same PWM map.

**Closed loop** (``closed_loop=True``, the paper's set-up): the autopilot flies on the estimate.
Record ``k`` (truth, IMU and GPS at ``t_k``) goes through the fault injector into the pipeline,
and the pipeline's estimate at ``t_k`` is the navigation state from which the autopilot computes
the controls of record ``k+1``: the same one step of computation delay as flying on truth
(:mod:`sim.flight`). Before the filter's first estimate (it aligns on the first GPS fix) the
autopilot flies on truth, as if it had been engaged at alignment; when the pipeline publishes
nothing for a sample (a diverged estimate it drops, then re-aligns) the autopilot keeps the last
estimate it had. The estimate's NED frame has its origin at the pipeline's first GPS fix; it is
shifted once onto the flight's origin (the two are metres apart, so the frames' rotation, under
1e-6 rad, is ignored).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from immukf_sitl.experiments.report import EstimateHistory, Summary, summarize
from immukf_sitl.models.earth import NedOrigin, geodetic_to_ned
from immukf_sitl.models.params import AircraftParams, load_aircraft_params
from immukf_sitl.samples import ActuatorSample, TruthSample
from immukf_sitl.scenario import Scenario
from immukf_sitl.service.pipeline import EstimateOutput, EstimatorPipeline, PipelineConfig
from sim.autopilot import NavigationState
from sim.fault_proxy import FaultInjector
from sim.flight import FlightRecord
from sim.scenario_flight import flight_from_scenario

#: A per-step check of a flight: the record and the estimate (in the flight's NED frame, or
#: ``None`` before the first) in, a reason to stop the flight (or ``None``) out.
StopCheck = Callable[[FlightRecord, NavigationState | None], str | None]


@dataclass(frozen=True)
class InProcessRun:
    """Outputs of the estimator and the truth of one in-process flight.

    Attributes
    ----------
    scenario : Scenario
    history : EstimateHistory
        The pipeline's outputs (NED about the pipeline's own origin).
    truth : tuple of TruthSample
        One per step.
    pipeline : EstimatorPipeline
    airframe : dict
        Factors of the flown airframe against the book's.
    closed_loop : bool
        Whether the autopilot flew on the estimate.
    records : tuple of FlightRecord
        The sim's records, one per step (truth, autopilot commands).
    estimates : tuple of NavigationState or None
        Per step, the estimate in the flight's NED frame (``None`` before the first).
    stop_reason : str or None
        Why the flight ended before the scenario's duration (a :data:`StopCheck`'s answer).
    """

    scenario: Scenario
    history: EstimateHistory
    truth: tuple[TruthSample, ...]
    pipeline: EstimatorPipeline
    airframe: dict[str, float]
    closed_loop: bool = False
    records: tuple[FlightRecord, ...] = ()
    estimates: tuple[NavigationState | None, ...] = ()
    stop_reason: str | None = None

    def summary(self) -> Summary:
        """The run/replay summary."""
        summary = summarize(
            self.scenario.name,
            [f for f in self.scenario.faults if f.imu == 0],  # the IMU fed in is the first
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


def _navigation(out: EstimateOutput, offset_m: np.ndarray, origin_alt_m: float) -> NavigationState:
    """The pipeline's estimate as the autopilot's navigation state, in the flight's frame.

    The airspeed the autopilot holds is the estimate's: ground velocity less the estimated wind
    when the variant estimates it (the real-air model), else the ground speed (a variant that
    assumes still air flies as an autopilot without an airspeed sensor or wind estimate does).
    """
    nav = out.nav
    position = nav.position_ned_m + offset_m
    return NavigationState.from_navigation(
        out.t_s,
        position,
        origin_alt_m - float(position[2]),
        nav.velocity_ned_mps,
        nav.euler_rad,
        nav.rates_radps,
        nav.wind_ned_mps,
    )


def _feed(
    pipeline: EstimatorPipeline,
    injector: FaultInjector,
    record: FlightRecord,
    params: AircraftParams,
) -> EstimateOutput | None:
    """One step of the flight into the estimator, in the order the wire delivers it.

    The servo outputs first (as PWM, the way SERVO_OUTPUT_RAW carries them), then a GPS fix when
    one is due, then the IMU sample through the fault injector.
    """
    pwm = params.actuators.controls_to_pwm(record.controls)
    pipeline.on_actuators(ActuatorSample(record.time_s, tuple(pwm.get(c, 0) for c in range(1, 17))))
    if record.gps is not None:
        pipeline.on_gps(record.gps)
    return pipeline.on_imu(injector.apply(record.imu))


def run_inprocess(
    scenario: Scenario,
    config: PipelineConfig | None = None,
    duration_s: float | None = None,
    *,
    closed_loop: bool = False,
    stop: StopCheck | None = None,
) -> InProcessRun:
    """Fly ``scenario`` through the fault injector into the estimator, in one process.

    The filter keeps the book's aircraft and, unless ``config`` says otherwise, is told the
    scenario's sensor spec sheet (sigmas, not the true biases); the flight flies the scenario's
    airframe and air.

    Parameters
    ----------
    scenario : Scenario
        The flight, its sensors and faults.
    config : PipelineConfig, optional
        The estimator (variant, tuning, detection).
    duration_s : float, optional
        Simulated time (default the scenario's).
    closed_loop : bool, optional
        Fly the autopilot on the estimate (see the module docstring); default on truth.
    stop : StopCheck, optional
        Called after every step; the flight ends at the first reason it returns.

    Returns
    -------
    InProcessRun
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
    records: list[FlightRecord] = []
    estimates: list[NavigationState | None] = []
    nav: NavigationState | None = None
    offset_m: np.ndarray | None = None
    stop_reason = None
    record = flight.start()
    flight_origin = NedOrigin(*flight.origin)
    for k in range(steps + 1):
        if k:
            record = flight.step(nav if closed_loop else None)
        out = _feed(pipeline, injector, record, params)
        truth.append(record.truth.sample())
        records.append(record)
        if out is not None:
            outputs.append(out)
            if offset_m is None:
                assert pipeline.origin is not None
                o = pipeline.origin
                offset_m = geodetic_to_ned(o.lat_deg, o.lon_deg, o.alt_m, flight_origin)
            nav = _navigation(out, offset_m, flight_origin.alt_m)
        estimates.append(nav)
        if stop is not None:
            stop_reason = stop(record, nav)
            if stop_reason is not None:
                break
    return InProcessRun(
        scenario,
        EstimateHistory(tuple(outputs)),
        tuple(truth),
        pipeline,
        flight.airframe_factors,
        closed_loop=closed_loop,
        records=tuple(records),
        estimates=tuple(estimates),
        stop_reason=stop_reason,
    )
