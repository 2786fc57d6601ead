"""``immukf-sitl validate-model``: how well the filter's aerodynamic model predicts JSBSim.

Flies the default manoeuvring plan (:func:`sim.flight_plans.default_flight_plan`) in JSBSim under
the autopilot on truth, then evaluates :class:`~immukf_sitl.models.aero.AeroModel` on the true
states and controls of every step:

- specific force: the model's noise-free IMU prediction against the true specific force
  (m/s^2);
- angular acceleration: the model's ``(p, q, r)_dot`` against the central finite difference of
  the true (inertial) body rates (rad/s^2);
- one-step prediction: ``AeroModel.step`` from the true state of step ``k`` against the true
  state of step ``k + 1`` — position (m, NED), body velocity (m/s), attitude (rad, wrapped) and
  body rates (rad/s).

Each quantity is reported per axis as RMS error, max |error| and the signal's RMS (for the
one-step prediction also the RMS of the true one-step change, what a model that predicts "no
change" would miss by). The truth aircraft always flies the packaged parameters (the committed
JSBSim XML); ``--params`` changes only the model under test, to measure a parameter mismatch.
The mismatches that remain with the same parameters are the realistic ones: JSBSim's rotating,
curved earth and its Adams-Bashforth integration against the model's flat, non-rotating earth
and RK4.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from immukf_sitl.models.aero import AeroModel
from immukf_sitl.models.earth import NedOrigin
from immukf_sitl.models.params import AircraftParams, load_aircraft_params
from immukf_sitl.options import add_json_argument
from sim.flight import Flight, FlightRecord
from sim.flight_plans import default_flight_plan

__all__ = ["register", "validate_model"]

_AXES = ("x", "y", "z")


def _errors(error: np.ndarray, signal: np.ndarray, labels: tuple[str, ...]) -> dict[str, Any]:
    """RMS and max error per axis (rows) next to the signal's RMS, plus vector norms."""
    rms_error = np.sqrt(np.mean(error**2, axis=1))
    signal_rms = np.sqrt(np.mean(signal**2, axis=1))
    norm_error = float(np.sqrt(np.mean(np.sum(error**2, axis=0))))
    norm_signal = float(np.sqrt(np.mean(np.sum(signal**2, axis=0))))
    return {
        "axes": list(labels),
        "rms_error": rms_error.tolist(),
        "max_error": np.max(np.abs(error), axis=1).tolist(),
        "signal_rms": signal_rms.tolist(),
        "rms_error_norm": norm_error,
        "signal_rms_norm": norm_signal,
        "relative_rms_error": norm_error / norm_signal if norm_signal > 0.0 else None,
    }


def _wrap(angle: np.ndarray) -> np.ndarray:
    return np.remainder(angle + np.pi, 2.0 * np.pi) - np.pi


def _fly(
    duration_s: float, seed: int, params: AircraftParams
) -> tuple[Flight, list[FlightRecord], float]:
    """The manoeuvring plan in JSBSim: the flight, its records and the wall time it took."""
    flight = Flight(default_flight_plan(), seed, params=params)
    wall = time.perf_counter()
    records = [flight.start()]
    for _ in range(int(round(duration_s / flight.driver.dt_s))):
        records.append(flight.step())
    return flight, records, time.perf_counter() - wall


def _one_step_prediction(x: np.ndarray, x_next_model: np.ndarray) -> dict[str, Any]:
    """Errors of the model's one-step prediction ``x_next_model`` against the flown ``x``.

    Per state group, with the RMS of the state's own change in one step beside it: a
    prediction is only useful while its error is well below that change.
    """
    x_next = x[:, 1:]
    err = x_next_model - x_next
    err[6:9] = _wrap(err[6:9])
    change = x_next - x[:, :-1]
    change[6:9] = _wrap(change[6:9])

    def one_step(rows: slice, labels: tuple[str, ...]) -> dict[str, Any]:
        result = _errors(err[rows], x_next[rows], labels)
        result["step_change_rms"] = np.sqrt(np.mean(change[rows] ** 2, axis=1)).tolist()
        return result

    return {
        "position_m": one_step(slice(0, 3), ("north", "east", "down")),
        "velocity_mps": one_step(slice(3, 6), ("u", "v", "w")),
        "attitude_rad": one_step(slice(6, 9), ("phi", "theta", "psi")),
        "rates_radps": one_step(slice(9, 12), ("p", "q", "r")),
    }


def validate_model(
    duration_s: float = 60.0,
    seed: int = 0,
    params_path: str | Path | None = None,
) -> dict[str, Any]:
    """Fly the manoeuvring plan in JSBSim and score the aerodynamic model's predictions.

    Parameters
    ----------
    duration_s : float, optional
        Simulated flight time (s); at least 1 s.
    seed : int, optional
        Seed of the flight's sensor noise (the scores use the noise-free truth, so it only
        matters for reproducibility of the records).
    params_path : str or pathlib.Path, optional
        Parameter file of the model under test (default: the packaged Aerosonde, which the
        JSBSim aircraft is rendered from).

    Returns
    -------
    dict
        JSON-ready: ``specific_force_mps2``, ``angular_acceleration_radps2`` and
        ``one_step_prediction`` (``position_m``, ``velocity_mps``, ``attitude_rad``,
        ``rates_radps``), each with ``rms_error``, ``max_error``, ``signal_rms`` per axis and
        their norms; plus the run's settings, step count and JSBSim speed.

    Raises
    ------
    ValueError
        If ``duration_s`` is below 1 s.
    """
    if not duration_s >= 1.0:
        raise ValueError(f"duration_s: expected at least 1 s, got {duration_s}")
    truth_params = load_aircraft_params()
    model_params = truth_params if params_path is None else load_aircraft_params(params_path)
    flight, records, flight_wall_s = _fly(duration_s, seed, truth_params)
    steps = len(records) - 1
    dt = flight.driver.dt_s
    lat0, lon0, alt0 = flight.origin
    model = AeroModel(model_params, origin=NedOrigin(lat0, lon0, alt0), dt_s=dt)
    x = np.array([r.truth.state_vector() for r in records]).T  # (12, N)
    u = np.array([r.controls for r in records]).T  # (4, N)
    f_true = np.array([r.truth.specific_force_body_mps2 for r in records]).T

    wall = time.perf_counter()
    f_model = model.imu(0.0, x, u)[:3]
    xdot_model = model.derivatives(0.0, x, u)
    x_next_model = model.step(0.0, x[:, :-1], u[:, :-1])
    model_wall_s = time.perf_counter() - wall

    rates = x[9:12]
    omega_dot_true = (rates[:, 2:] - rates[:, :-2]) / (2.0 * dt)  # central difference
    omega_dot_model = xdot_model[9:12, 1:-1]

    return {
        "duration_s": float(steps * dt),
        "seed": int(seed),
        "params": str(model_params.source),
        "truth_params": str(truth_params.source),
        "steps": len(records),
        "dt_s": dt,
        "jsbsim_flight_steps_per_s": steps / flight_wall_s,
        "model_eval_s": model_wall_s,
        "specific_force_mps2": _errors(f_model - f_true, f_true, _AXES),
        "angular_acceleration_radps2": _errors(
            omega_dot_model - omega_dot_true, omega_dot_true, ("p", "q", "r")
        ),
        "one_step_prediction": _one_step_prediction(x, x_next_model),
    }


def format_report(result: dict[str, Any]) -> str:
    """The human-readable report of :func:`validate_model`."""
    lines = [
        f"AeroModel vs JSBSim, {result['duration_s']:.1f} s manoeuvring flight "
        f"({result['steps']} steps, JSBSim flight loop {result['jsbsim_flight_steps_per_s']:.0f} "
        "steps/s)",
        f"  model parameters: {result['params']}",
    ]

    def block(title: str, unit: str, entry: dict[str, Any]) -> None:
        lines.append(
            f"  {title} ({unit}): relative RMS error {entry['relative_rms_error']:.3g} "
            f"(|error| RMS {entry['rms_error_norm']:.3g} of signal RMS "
            f"{entry['signal_rms_norm']:.3g})"
        )
        for i, axis in enumerate(entry["axes"]):
            extra = ""
            if "step_change_rms" in entry:
                extra = f", one-step change RMS {entry['step_change_rms'][i]:.3g}"
            lines.append(
                f"    {axis:>5}: RMS error {entry['rms_error'][i]:.3g}, max "
                f"{entry['max_error'][i]:.3g}, signal RMS {entry['signal_rms'][i]:.3g}{extra}"
            )

    block("specific force", "m/s^2", result["specific_force_mps2"])
    block("angular acceleration", "rad/s^2", result["angular_acceleration_radps2"])
    one = result["one_step_prediction"]
    block("one-step position", "m", one["position_m"])
    block("one-step body velocity", "m/s", one["velocity_mps"])
    block("one-step attitude", "rad", one["attitude_rad"])
    block("one-step body rates", "rad/s", one["rates_radps"])
    return "\n".join(lines)


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``validate-model`` subcommand."""
    parser = subparsers.add_parser(
        "validate-model",
        help="score the filter's aerodynamic model against a JSBSim manoeuvring flight",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_json_argument(parser, "the results")
    parser.add_argument(
        "--duration", type=float, default=60.0, help="simulated seconds (default 60)"
    )
    parser.add_argument("--seed", type=int, default=0, help="sensor-noise seed (default 0)")
    parser.add_argument(
        "--params",
        type=Path,
        default=None,
        metavar="PATH",
        help="aircraft parameter YAML of the model under test (default: packaged Aerosonde)",
    )
    parser.set_defaults(handler=_main)


def _main(args: argparse.Namespace) -> int:
    from immukf_sitl.errors import UserError

    if not args.duration >= 1.0:
        raise UserError(f"--duration must be at least 1 s, got {args.duration}")
    print(f"flying {args.duration:g} s in JSBSim...", file=sys.stderr)
    result = validate_model(duration_s=args.duration, seed=args.seed, params_path=args.params)
    print(format_report(result), file=sys.stderr)
    if args.json:
        print(json.dumps(result))
    return 0
