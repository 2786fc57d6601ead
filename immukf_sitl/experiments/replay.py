"""``immukf-sitl replay LOG``: the estimator over a recorded flight log, as fast as it can.

Feeds the sensor stream of a flight log (a tlog, a DataFlash ``.bin`` or a ULog ``.ulg``, read by
:mod:`immukf_sitl.logs.reader`) through the same
pipeline ``serve`` runs, in recorded order, and prints the same summary as ``run``: faults (from
the fault proxy's annotations), detections, false alarms, and, when the log holds the sim's
truth, estimation errors.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from immukf_sitl.errors import UserError
from immukf_sitl.estimation.fault_modes import single_fault_modes
from immukf_sitl.experiments.report import (
    EstimateHistory,
    Summary,
    human_summary,
    plot_summary,
    summarize,
)
from immukf_sitl.logs.reader import check_replayable, imu_rate_hz, read_log
from immukf_sitl.mavlink.flightlog import FlightLog
from immukf_sitl.mavlink.publish import probability_name
from immukf_sitl.models.servo_map import (
    ControlMap,
    ServoMap,
    control_map_source,
    has_servo_functions,
)
from immukf_sitl.options import FilterOptions, add_json_argument
from immukf_sitl.samples import ActuatorSample, GpsSample, ImuSample
from immukf_sitl.service.pipeline import EstimateOutput, EstimatorPipeline


@dataclass(frozen=True)
class ReplayResult:
    """Everything a replay produced."""

    history: EstimateHistory
    log: FlightLog
    pipeline: EstimatorPipeline


def replay(log: FlightLog, pipeline: EstimatorPipeline, progress: bool = False) -> ReplayResult:
    """Run ``pipeline`` over the log's stream in recorded order."""
    outputs: list[EstimateOutput] = []
    n = len(log.stream)
    for i, sample in enumerate(log.stream):
        if isinstance(sample, ImuSample):
            out = pipeline.on_imu(sample)
            if out is not None:
                outputs.append(out)
        elif isinstance(sample, GpsSample):
            pipeline.on_gps(sample)
        elif isinstance(sample, ActuatorSample):
            pipeline.on_actuators(sample)
        if progress and i % 20000 == 0:
            print(f"replay: {100 * i / max(n, 1):.0f} %", file=sys.stderr, flush=True)
    return ReplayResult(EstimateHistory(tuple(outputs)), log, pipeline)


def summary_of(result: ReplayResult, scenario_name: str) -> Summary:
    """The run-style summary of a replay."""
    history = result.history
    return summarize(
        scenario_name,
        result.log.faults_seen(),
        result.log.truth,
        history.events(),
        history.track(),
        history.step_us(),
        settle_s=result.pipeline.config.detector.settle_s,
    )


def probability_series(result: ReplayResult) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """P(no failure) and P(each channel failed) over time, keyed by their MAVLink names."""
    return result.history.probability_series([probability_name(m) for m in single_fault_modes()])


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``replay`` subcommand."""
    parser = subparsers.add_parser(
        "replay",
        help="run the estimator over a recorded flight log and summarise",
        description=(
            "Feed a flight log through the estimator as fast as possible, then print the same "
            "summary as `run`: faults, detections with delays, false alarms and, when truth is "
            "in the log, estimation errors. The log is a MAVLink tlog (as `immukf-sitl run` "
            "writes it, with the sim's truth and the fault proxy's annotations, or any "
            "autopilot's or ground station's), an ArduPilot DataFlash .bin or a PX4 ULog .ulg, "
            "at its logged rate (at least 20 Hz of IMU). A log that is not of a fixed-wing "
            "aircraft, or lacks an IMU, servo or GPS stream, is refused in one line."
        ),
    )
    parser.add_argument(
        "tlog",
        metavar="LOG",
        help="flight log to replay: a MAVLink tlog, an ArduPilot DataFlash .bin or a PX4 ULog "
        ".ulg (told apart by their content)",
    )
    parser.add_argument(
        "--imu",
        type=int,
        default=None,
        metavar="N",
        help="IMU instance to use (0 first; default: the first IMU stream in the log)",
    )
    add_json_argument(parser)
    parser.add_argument("--plot", default=None, help="also write a PNG of the mode probabilities")
    FilterOptions.add_arguments(parser)
    parser.set_defaults(handler=_main)


def _main(args: argparse.Namespace) -> int:
    options = FilterOptions.from_args(args)
    pipeline = options.pipeline()
    if args.plot and not Path(args.plot).resolve().parent.is_dir():
        raise UserError(f"--plot {args.plot}: no such directory")
    if args.imu is not None and args.imu < 0:
        raise UserError(f"--imu: expected an instance >= 0, got {args.imu}")
    log = read_log(args.tlog, args.imu)
    check_replayable(log, args.tlog, pipeline.config.min_imu_rate_hz)
    pipeline.imu_label = log.imu_source or "IMU"
    if options.servo_map_path is None and has_servo_functions(log.params):
        pipeline.control_map = ControlMap(
            ServoMap.from_params(log.params, f"{args.tlog}'s SERVOn_* parameters"), pipeline.params
        )
    print(
        f"replay: {args.tlog}: {log.kind}, {len(log.stream)} samples, IMU {log.imu_source} "
        f"at {imu_rate_hz(log):.0f} Hz, servo map: {control_map_source(pipeline.control_map)}",
        file=sys.stderr,
    )
    result = replay(log, pipeline, progress=True)
    unused = pipeline.counters.gps_velocity_down_unused
    if unused:
        print(
            f"replay: {unused} fixes carried a vertical velocity, not fused (the spec sheet's "
            "receiver does not report one; --sensors with sensors.gps.reports_velocity_down: "
            "true fuses it)",
            file=sys.stderr,
        )
    name = log.scenario or Path(args.tlog).stem
    summary = dataclasses.replace(
        summary_of(result, name),
        tlog=str(args.tlog),
        variant=options.variant,
        note=None if log.truth else "no truth in the log: estimation errors unavailable",
    )
    print(human_summary(summary), file=sys.stderr)
    if args.plot:
        t, probs = probability_series(result)
        plot_summary(args.plot, summary, t, probs, log.truth, result.history.track())
        print(f"replay: plot {args.plot}", file=sys.stderr)
    if args.json:
        print(json.dumps(summary.to_json()))
    return 0
