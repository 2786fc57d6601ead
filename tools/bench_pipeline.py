#!/usr/bin/env python3
"""Benchmark of serve's per-sample path without sockets: pipeline step plus publication.

    python tools/bench_pipeline.py [--tlog tests/data/fault_free.tlog] [--passes 3] [--json]
                                   [--filter-model paper|real-air] [--tree DIR]

Replays a recorded flight's stream (SERVO_OUTPUT_RAW, GPS_RAW_INT, HIGHRES_IMU) through a fresh
:class:`EstimatorPipeline` and a :class:`Publisher` per pass, and times each IMU sample from
``on_imu`` to the list of messages due (ATTITUDE, ATTITUDE_QUATERNION, GLOBAL_POSITION_INT,
probabilities). ``filter`` is the pipeline's own step time (the estimator's step), ``outside``
is the rest: what ``on_imu`` and the publisher add around the filter (gating, navigation
solution, geodetic position, detection, message building). Steps that consumed a GPS fix are
reported apart. The first pass after start-up is not timed (numba's kernels load or compile).

``--tree DIR`` imports ``immukf_sitl`` from another checkout (e.g. ``git archive HEAD~1 | tar -x
-C /tmp/before``) so that a change can be measured before and after on the same machine; run
the two alternately and compare medians.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _percentiles(values: list[float]) -> dict:
    import numpy as np

    a = np.asarray(values)
    if a.size == 0:
        return {"n": 0}
    return {
        "n": int(a.size),
        "median_us": round(float(np.median(a)), 1),
        "p99_us": round(float(np.percentile(a, 99)), 1),
        "mean_us": round(float(a.mean()), 1),
    }


def one_pass(stream: list, config: object, params: object) -> dict[str, list[float]]:
    from immukf_sitl.mavlink.publish import Publisher
    from immukf_sitl.samples import ActuatorSample, GpsSample, ImuSample
    from immukf_sitl.service.pipeline import EstimatorPipeline

    pipeline = EstimatorPipeline(params, config)
    publisher = Publisher()
    times: dict[str, list[float]] = {"total": [], "filter": [], "outside": [], "gps_total": []}
    fix_pending = False
    clock = time.perf_counter
    for sample in stream:
        if isinstance(sample, ImuSample):
            start = clock()
            out = pipeline.on_imu(sample)
            if out is not None:
                publisher.messages(out)
                total_us = (clock() - start) * 1e6
                times["gps_total" if fix_pending else "total"].append(total_us)
                if not fix_pending:
                    times["filter"].append(out.step_us)
                    times["outside"].append(total_us - out.step_us)
            fix_pending = False
        elif isinstance(sample, GpsSample):
            pipeline.on_gps(sample)
            fix_pending = True
        elif isinstance(sample, ActuatorSample):
            pipeline.on_actuators(sample)
    return times


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tlog", default=str(REPO / "tests" / "data" / "fault_free.tlog"))
    parser.add_argument("--passes", type=int, default=3, help="timed passes (default 3)")
    parser.add_argument("--filter-model", choices=("paper", "real-air"), default="paper")
    parser.add_argument("--tree", default=str(REPO), help="checkout to import immukf_sitl from")
    parser.add_argument("--json", action="store_true", help="one JSON object on stdout")
    args = parser.parse_args()
    sys.path.insert(0, str(Path(args.tree).resolve()))

    import immukf_sitl
    from immukf_sitl.mavlink.flightlog import read_flight_log
    from immukf_sitl.models.params import load_aircraft_params
    from immukf_sitl.service.filter_models import filter_model
    from immukf_sitl.service.pipeline import PipelineConfig

    config = PipelineConfig(filter_model=filter_model(args.filter_model))
    params = load_aircraft_params()
    stream = list(read_flight_log(args.tlog).stream)
    one_pass(stream, config, params)  # kernels compiled or loaded, caches warm
    merged: dict[str, list[float]] = {}
    for _ in range(args.passes):
        for key, values in one_pass(stream, config, params).items():
            merged.setdefault(key, []).extend(values)
    result = {
        "tree": str(Path(immukf_sitl.__file__).resolve().parents[1]),
        "tlog": args.tlog,
        "filter_model": args.filter_model,
        "passes": args.passes,
        "cpus": os.cpu_count(),
        "load_average": [round(x, 2) for x in os.getloadavg()],
        "python": platform.python_version(),
        **{key: _percentiles(values) for key, values in merged.items()},
    }
    if args.json:
        print(json.dumps(result))
    else:
        print(f"tree {result['tree']}  load {result['load_average']}")
        for key in ("total", "filter", "outside", "gps_total"):
            r = result[key]
            print(
                f"  {key:9s} median {r['median_us']:8.1f} us  p99 {r['p99_us']:8.1f} us"
                f"  mean {r['mean_us']:8.1f} us  (n={r['n']})"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
