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
from immukf_sitl.models.params import AircraftParamsError

#: Modules that provide subcommands, in ``--help`` order.
SUBCOMMAND_MODULES: tuple[str, ...] = (
    "immukf_sitl.experiments.run",
    "sim.emitter",
    "sim.fault_proxy",
    "immukf_sitl.mavlink.serve",
    "immukf_sitl.experiments.replay",
    "immukf_sitl.experiments.validate_model",
    "immukf_sitl.experiments.bench",
)


def build_parser() -> argparse.ArgumentParser:
    """The full argument parser."""
    parser = argparse.ArgumentParser(
        prog="immukf-sitl",
        description=(
            "IMM-UKF inertial-sensor fault detection for fixed-wing UAVs: a MAVLink "
            "software-in-the-loop estimator, its JSBSim truth simulator and experiments."
        ),
    )
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    subparsers.required = True
    for name in SUBCOMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name != name:
                raise
            continue  # a subcommand not built yet
        module.register(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the console script."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.handler(args) or 0)
    except (UserError, AircraftParamsError) as exc:
        print(f"immukf-sitl {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"immukf-sitl {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
