"""How much faster than real time the JSBSim truth simulator steps (medians and ratios).

    python tools/bench_sim.py [--steps 3000] [--repeats 5]

Prints the median steps per second of the trimmed Aerosonde over ``--repeats`` runs and its ratio
to real time (100 steps per second). The simulator must never be the chain's bottleneck: the
estimator's 7-mode step is about 0.2 ms, a JSBSim step about 0.03 ms.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

from sim.driver import JsbsimDriver


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=3000, help="steps per run (default 3000)")
    parser.add_argument("--repeats", type=int, default=5, help="runs (default 5)")
    args = parser.parse_args()
    if args.steps < 100 or args.repeats < 1:
        print("bench_sim: error: --steps >= 100 and --repeats >= 1", file=sys.stderr)
        return 2
    driver = JsbsimDriver()
    trim = driver.trim()
    rates = []
    for _ in range(args.repeats):
        driver.reset()
        start = time.perf_counter()
        for _ in range(args.steps):
            driver.step(trim.controls)
        rates.append(args.steps / (time.perf_counter() - start))
    median = statistics.median(rates)
    print(
        f"JSBSim driver: median {median:.0f} steps/s over {args.repeats} x {args.steps} steps "
        f"({median * driver.dt_s:.0f} x real time; min {min(rates):.0f}, max {max(rates):.0f})"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
