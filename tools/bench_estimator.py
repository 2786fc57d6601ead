#!/usr/bin/env python3
"""Benchmark of the 7-mode IMM-UKF step; the same as ``immukf-sitl bench``.

Usage: python tools/bench_estimator.py [--json] [--steps N] [--filterpy-steps N]
"""

import sys

from immukf_sitl.cli import main

if __name__ == "__main__":
    sys.exit(main(["bench", *sys.argv[1:]]))
