"""Detection delay and false declarations against IMU and servo rate, from recorded flights.

Each flight log (a ``run``'s flight.tlog, 100 Hz IMU and servo) is re-sampled the way a slower
or faster autopilot link would carry it: the IMU linearly interpolated to the rate (above
100 Hz) or decimated (below), then quantised as RAW_IMU (mG, mrad/s); the servo outputs
decimated to their rate; GPS as flown. Each version is replayed with the chosen filter and the
first detection of each fault, and every false declaration, are tabulated (markdown).

usage: python tools/rate_table.py FLIGHT.tlog [FLIGHT.tlog ...] [--filter-model real-air]
       [--fault-modes zero] [--imu-hz 20 50 100 250] [--servo-hz 5 10 25]
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from immukf_sitl.experiments.replay import replay, summary_of
from immukf_sitl.mavlink import codec
from immukf_sitl.mavlink.flightlog import FlightLog, read_flight_log
from immukf_sitl.options import FilterOptions
from immukf_sitl.samples import ActuatorSample, ImuSample


def resampled(log: FlightLog, imu_hz: float, servo_hz: float) -> FlightLog:
    """The flight at ``imu_hz`` (RAW_IMU-quantised) and ``servo_hz``; GPS and truth kept."""
    imu = [s for s in log.stream if isinstance(s, ImuSample)]
    times = np.array([s.time_s for s in imu])
    values = np.array([s.as_array() for s in imu])
    new_times = np.arange(times[0], times[-1] + 1e-9, 1.0 / imu_hz)
    if imu_hz <= 100.0:  # decimate: the samples the slower link would have carried
        new_times = times[np.searchsorted(times, new_times - 1e-7)]
    rows = np.column_stack([np.interp(new_times, times, values[:, c]) for c in range(6)])
    new_imu = []
    for t, row in zip(new_times, rows, strict=True):
        sample = ImuSample(float(t), row[:3], row[3:])
        new_imu.append(codec.decode_imu(codec.imu_message("RAW_IMU", sample)))
    kept, next_s = [], -1.0
    for s in log.stream:
        if isinstance(s, ActuatorSample):
            if s.time_s + 1e-6 < next_s:
                continue
            next_s = s.time_s + 1.0 / servo_hz
            kept.append(s)
        elif not isinstance(s, ImuSample):
            kept.append(s)
    merged = sorted(
        [(s.time_s, 0, i, s) for i, s in enumerate(kept)]
        + [(s.time_s, 1, i, s) for i, s in enumerate(new_imu)],
        key=lambda r: r[:3],
    )
    return FlightLog(
        stream=[r[3] for r in merged], truth=log.truth, faults=log.faults, scenario=log.scenario
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("flights", nargs="+")
    parser.add_argument("--imu-hz", type=float, nargs="+", default=[20.0, 50.0, 100.0, 250.0])
    parser.add_argument("--servo-hz", type=float, nargs="+", default=[5.0, 10.0, 25.0])
    FilterOptions.add_arguments(parser)
    args = parser.parse_args()
    options = FilterOptions.from_args(args)
    logs = [read_flight_log(path) for path in args.flights]
    hours = sum(log.stream[-1].time_s - log.stream[0].time_s for log in logs) / 3600.0
    print(f"{options.variant}; {len(logs)} flights, {hours * 60:.1f} min")
    print("| IMU Hz | servo Hz | identified (delay after observable, s) | false declarations |")
    print("|---|---|---|---|")
    for imu_hz in args.imu_hz:
        for servo_hz in args.servo_hz:
            delays, false = [], 0
            for log in logs:
                pipeline = options.pipeline()
                summary = summary_of(replay(resampled(log, imu_hz, servo_hz), pipeline), "x")
                data = summary.to_json()
                false += data["false_alarms"]
                for fault in data["faults"]:
                    delay = fault["detection_delay_s"]
                    delays.append("missed" if delay is None else f"{fault['mode']} {delay:.2f}")
            print(f"| {imu_hz:g} | {servo_hz:g} | {', '.join(delays) or '-'} | {false} |")
            sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
