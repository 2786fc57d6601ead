"""The ``immukf-sitl`` command line: wires subcommands together, nothing else.

Each subcommand lives in its own module exposing ``register(subparsers)``; that function adds an
argparse parser whose ``handler`` default runs it. Output for people goes to stderr; ``--json``
prints exactly one JSON object on stdout.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from immukf_sitl.errors import UserError

#: Sub-commands in ``--help`` order: (name, module providing ``register``, one-line help).
#: A module is imported only when its sub-command runs, so that ``--help`` and ``replay`` stay
#: fast (the sim imports JSBSim, the estimator compiles numba kernels).
SUBCOMMANDS: tuple[tuple[str, str, str], ...] = (
    ("run", "immukf_sitl.experiments.run",
     "fly a scenario through sim -> proxy -> serve on loopback and summarise"),
    ("sim", "sim.emitter", "fly a scenario in JSBSim and send the sensor stream as MAVLink 2"),
    ("proxy", "sim.fault_proxy",
     "forward MAVLink from the sim to the estimator, injecting a scenario's IMU faults"),
    ("serve", "immukf_sitl.mavlink.serve", "run the IMM-UKF estimator service on a MAVLink stream"),
    ("replay", "immukf_sitl.experiments.replay",
     "run the estimator over a recorded flight tlog and summarise"),
    ("experiment", "immukf_sitl.experiments.experiment",
     "run a Monte Carlo campaign of the paper's variants and fault sets; tables and report"),
    ("validate-model", "immukf_sitl.experiments.validate_model",
     "score the filter's aerodynamic model against a JSBSim manoeuvring flight"),
    ("bench", "immukf_sitl.experiments.bench", "time one IMM-UKF step (medians, ratios)"),
)  # fmt: skip


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The argument parser; only the sub-command named in ``argv`` is imported and built."""
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = argparse.ArgumentParser(
        prog="immukf-sitl",
        description=(
            "IMM-UKF inertial-sensor fault detection for fixed-wing UAVs: a MAVLink "
            "software-in-the-loop estimator, its JSBSim truth simulator and experiments."
        ),
    )
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    subparsers.required = True
    chosen = next((a for a in argv if not a.startswith("-")), None)
    for name, module_name, help_text in SUBCOMMANDS:
        if name == chosen:
            importlib.import_module(module_name).register(subparsers)
        else:
            subparsers.add_parser(name, help=help_text)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the console script."""
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    try:
        return int(args.handler(args) or 0)
    except UserError as exc:
        print(f"immukf-sitl {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"immukf-sitl {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
