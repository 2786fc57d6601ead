"""``immukf-sitl bench``: microseconds per IMM step of the 7-mode aircraft bank.

Measures the product's hot path — one IMM-UKF cycle over the 6-DOF aerodynamic model at the IMU
rate, one GPS fix per 100 steps — in the paper's augmented form and in the additive-noise form,
and the same bank built from filterpy's ``IMMEstimator`` of ``UnscentedKalmanFilter`` objects as
a reference. Data come from the aerodynamic model itself flying control doublets from trim, with
the default sensor noise (seeded). Results: medians and 99th percentiles, and the ratio; the
first step of each form is reported apart (it includes numba's compilation, or its loading from
the cache, of the kernels that form uses).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from dataclasses import dataclass

import numpy as np

from immukf_sitl.estimation.fault_modes import FAULT_SIGNATURES
from immukf_sitl.models.aero import AeroModel
from immukf_sitl.models.earth import NedOrigin
from immukf_sitl.models.params import load_aircraft_params
from immukf_sitl.models.sensors import SensorSpec
from immukf_sitl.options import add_json_argument
from immukf_sitl.service.filter_models import FILTER_MODELS as MODEL_TYPES
from immukf_sitl.service.filter_models import filter_model as make_filter_model
from immukf_sitl.service.filters import Observation, build_aero_estimator

GPS_EVERY_STEPS = 100
ORIGIN = NedOrigin(-33.87, 151.21, 100.0)


@dataclass(frozen=True)
class BenchData:
    """Controls, IMU and GPS samples of a flight of the aerodynamic model."""

    x0: np.ndarray
    controls: np.ndarray
    imu: np.ndarray
    gps: list[np.ndarray | None]


def make_flight(model: AeroModel, n_steps: int, seed: int) -> BenchData:
    """Fly the model from trim at 25 m/s with elevator/aileron/rudder doublets."""
    rng = np.random.default_rng(seed)
    sensors = SensorSpec()
    x0, u0 = model.trim(25.0)
    x = x0.copy()
    controls, imu, gps = [], [], []
    imu_sigma = sensors.imu.sigmas
    gps_sigma = np.sqrt(np.diag(sensors.gps.noise_cov()))
    for k in range(n_steps):
        t = k * model.dt_s
        u = u0 + np.array(
            [0.02 * np.sin(0.7 * t), 0.03 * np.sin(0.5 * t), 0.01 * np.sin(0.3 * t), 0.0]
        )
        # sample k: controls acting from t_k, IMU and GPS of the state at t_k
        controls.append(u)
        imu.append(model.imu(t, x, u) + imu_sigma * rng.standard_normal(6))
        gps.append(
            model.gps(t, x, u) + gps_sigma * rng.standard_normal(5)
            if k % GPS_EVERY_STEPS == 0 and k > 0
            else None
        )
        x = model.step(t, x, u)
    return BenchData(x0, np.array(controls), np.array(imu), gps)


def initial_cov() -> np.ndarray:
    """A converged-looking covariance to start the bench from."""
    return np.diag([1.0, 1.0, 1.0, 0.1, 0.1, 0.1, 1e-3, 1e-3, 1e-3, 1e-4, 1e-4, 1e-4])


FILTER_MODELS = tuple(MODEL_TYPES)


def time_ours(
    model: AeroModel, data: BenchData, form: str, warmup: int, filter_model: str = "paper"
) -> dict:
    """Per-step times of our 7-mode IMM in one noise form with the paper or real-air model."""
    return time_interleaved(model, data, form, warmup, (filter_model,))[0]


def time_interleaved(
    model: AeroModel,
    data: BenchData,
    form: str,
    warmup: int,
    filter_models: tuple[str, ...],
    fault_modes: str = "zero",
) -> list[dict]:
    """Per-step times of our 7-mode IMM in one noise form, one bank per filter model.

    The banks take turns step by step on the same data, so that a change of the machine's
    load (another process, a frequency change) hits every model alike: their ratio holds on a
    shared machine where the medians of separate runs do not.
    """
    banks = []
    for filter_model in filter_models:
        est = build_aero_estimator(
            "imm",
            model,
            filter_model=make_filter_model(filter_model, fault_signature=fault_modes),
            noise_form=form,
        )
        estimate = est.start(0.0, *est.augmented(data.x0, initial_cov()), data.controls[0])
        banks.append({"est": est, "estimate": estimate, "imu": [], "gps": [], "first": 0})
    for k in range(1, len(data.controls)):
        observation = Observation(data.imu[k], data.gps[k])
        for bank in banks:
            start = time.perf_counter_ns()
            bank["estimate"] = bank["est"].step(
                bank["estimate"], k * model.dt_s, data.controls[k], observation
            )
            elapsed = time.perf_counter_ns() - start
            if k == 1:
                bank["first"] = elapsed
            if k >= warmup:
                bank["gps" if data.gps[k] is not None else "imu"].append(elapsed)
    results = []
    for filter_model, bank in zip(filter_models, banks, strict=True):
        est, times_ns, gps_times_ns = bank["est"], bank["imu"], bank["gps"]
        all_ns = np.array(times_ns + gps_times_ns)
        results.append(
            {
                "form": form,
                "filter_model": filter_model,
                "fault_modes": fault_modes,
                "states": est.imm.ukf.process.nx,
                "modes": len(est.modes),
                "steps": int(all_ns.size),
                "median_us": float(np.median(all_ns) / 1e3),
                "p99_us": float(np.percentile(all_ns, 99) / 1e3),
                "imu_only_median_us": float(np.median(times_ns) / 1e3),
                "gps_step_median_us": (
                    float(np.median(gps_times_ns) / 1e3) if gps_times_ns else None
                ),
                "first_step_ms": bank["first"] / 1e6,
                "filter_compiled": est.imm.ukf.compiled,
                "diagnostics": est.diagnostics.as_dict(),
            }
        )
    return results


def time_filterpy(model: AeroModel, data: BenchData, n_steps: int) -> dict:
    """The same 7-mode bank built from filterpy objects (a Python call per sigma point)."""
    from filterpy.kalman import IMMEstimator, MerweScaledSigmaPoints, UnscentedKalmanFilter

    from immukf_sitl.estimation import single_fault_modes, sticky_transition

    ours = build_aero_estimator("imm", model, noise_form="additive")
    process = ours.imm.ukf.process
    imu_model = ours.imu_model
    x0, cov0 = ours.augmented(data.x0, initial_cov())
    current = {"u_prev": data.controls[0], "u": data.controls[0]}
    filters = []
    for j, _mode in enumerate(single_fault_modes()):

        def hx(x: np.ndarray, j: int = j) -> np.ndarray:
            batch = np.repeat(x[:, None, None], len(ours.modes), axis=1)
            pair = np.array([current["u_prev"], current["u"]])
            return imu_model.g(0.0, batch, pair, None)[:, j, 0]

        def fx(x: np.ndarray, dt: float) -> np.ndarray:
            return process.f(0.0, x, np.array([current["u_prev"], current["u"]]), None)

        ukf = UnscentedKalmanFilter(
            dim_x=process.nx,
            dim_z=6,
            dt=model.dt_s,
            hx=hx,
            fx=fx,
            points=MerweScaledSigmaPoints(process.nx, alpha=1.0, beta=0.0, kappa=0.0),
        )
        ukf.x = x0.copy()
        ukf.P = cov0.copy()
        ukf.Q = process.additive_noise_cov.copy()
        ukf.R = SensorSpec().imu.noise_cov()
        filters.append(ukf)
    bank = IMMEstimator(filters, np.full(7, 1 / 7), sticky_transition(7, 0.99))
    times_ns = []
    for k in range(1, n_steps + 1):
        current["u_prev"], current["u"] = data.controls[k - 1], data.controls[k]
        start = time.perf_counter_ns()
        bank.predict()
        bank.update(data.imu[k])
        times_ns.append(time.perf_counter_ns() - start)
    arr = np.array(times_ns[2:])
    return {
        "form": "filterpy-additive",
        "modes": 7,
        "steps": int(arr.size),
        "median_us": float(np.median(arr) / 1e3),
        "p99_us": float(np.percentile(arr, 99) / 1e3),
    }


def run_bench(
    steps: int,
    filterpy_steps: int,
    seed: int = 1,
    filter_models: tuple[str, ...] = ("paper",),
    fault_modes: str = "zero",
) -> dict:
    """Run every measurement; returns the JSON-ready result.

    With both filter models, their banks take turns step by step (:func:`time_interleaved`) so
    that a change of the machine's load hits both, and ``real_air_ratio`` is the real-air
    model's augmented median over the paper's.
    """
    model = AeroModel(load_aircraft_params(), ORIGIN)
    data = make_flight(model, steps, seed)
    warmup = min(50, steps // 10)
    results = [
        row
        for form in ("augmented", "additive")
        for row in time_interleaved(model, data, form, warmup, tuple(filter_models), fault_modes)
    ]
    result: dict = {
        "benchmark": "7-mode IMM-UKF step over the 6-DOF Aerosonde model, 100 Hz IMU, 1 Hz GPS",
        "machine": {"python": platform.python_version(), "cpu_count": _cpu_count()},
        "model_compiled": model.uses_numba,
        "results": results,
    }
    medians = {
        row["filter_model"]: row["median_us"] for row in results if row["form"] == "augmented"
    }
    if len(medians) == 2:
        result["real_air_ratio"] = medians["real-air"] / medians["paper"]
    if filterpy_steps > 0:
        reference = time_filterpy(model, data, filterpy_steps)
        result["filterpy"] = reference
        ours_imu = next(
            r["imu_only_median_us"]
            for r in results
            if r["form"] == "additive" and r["filter_model"] == "paper"
        )
        result["filterpy_ratio"] = reference["median_us"] / ours_imu
        result["filterpy_ratio_note"] = (
            "filterpy median / our additive-form IMU-only median (same sigma-point count)"
        )
    return result


def _cpu_count() -> int:
    import os

    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()


def print_human(result: dict) -> None:
    """Table for people, on stderr."""
    out = sys.stderr
    compiled = {True: "compiled", False: "uncompiled"}
    kernels = f"model {compiled[result['model_compiled']]}"
    kernels += f", filter {compiled[result['results'][0]['filter_compiled']]}"
    print(f"{result['benchmark']} ({kernels})", file=out)
    header = f"{'form':<20}{'model':>9}{'states':>7}{'modes':>6}{'steps':>7}"
    header += f"{'median us':>11}{'p99 us':>10}"
    print(f"{header}{'GPS-step us':>13}{'first step ms':>15}", file=out)
    rows = list(result["results"])
    if "filterpy" in result:
        rows.append(result["filterpy"])
    for row in rows:
        line = (
            f"{row['form']:<20}{row.get('filter_model', ''):>9}{row.get('states', ''):>7}"
            f"{row['modes']:>6}{row['steps']:>7}"
            f"{row['median_us']:>11.1f}{row['p99_us']:>10.1f}"
        )
        if row.get("gps_step_median_us") is not None:
            line += f"{row['gps_step_median_us']:>13.1f}{row['first_step_ms']:>15.1f}"
        print(line, file=out)
    if "real_air_ratio" in result:
        print(
            f"real-air model / paper model (augmented medians): {result['real_air_ratio']:.2f}x",
            file=out,
        )
    if "filterpy_ratio" in result:
        print(f"filterpy is {result['filterpy_ratio']:.1f}x slower per step", file=out)
    budget_us = 10_000.0
    aug = result["results"][0]["median_us"]
    print(f"real-time margin at 100 Hz (augmented): {budget_us / aug:.1f}x", file=out)


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``bench`` subcommand."""
    parser = subparsers.add_parser(
        "bench",
        help="time the 7-mode IMM-UKF step (augmented, additive, filterpy reference)",
        description=(
            "Time one IMM-UKF step of the 7-mode bank over the Aerosonde model (100 Hz IMU, a "
            "GPS fix per 100 steps) in the augmented and additive forms, with the paper's "
            "12-state model and the real-air 30-state one, and the same bank "
            "built from filterpy's IMMEstimator for comparison. Prints medians and 99th "
            "percentiles in microseconds and the real-time margin at 100 Hz."
        ),
    )
    add_json_argument(parser, "the results")
    parser.add_argument(
        "--steps", type=int, default=2000, help="IMM steps to time per form (default 2000)"
    )
    parser.add_argument(
        "--filterpy-steps",
        type=int,
        default=30,
        help="steps of the (slow) filterpy reference; 0 skips it (default 30)",
    )
    parser.add_argument("--seed", type=int, default=1, help="noise seed (default 1)")
    parser.add_argument(
        "--filter-model",
        choices=(*FILTER_MODELS, "both"),
        default="both",
        help=(
            "the filter's model: the paper's 12 states, the real-air 30 states, or both, "
            "alternating, with their ratio (default both)"
        ),
    )
    parser.add_argument(
        "--fault-modes",
        choices=FAULT_SIGNATURES,
        default="zero",
        help="what the fault modes predict on their failed channel (as serve's; default zero)",
    )
    parser.set_defaults(handler=_main)


def _main(args: argparse.Namespace) -> int:
    from immukf_sitl.errors import UserError

    if args.steps < 20:
        raise UserError(f"--steps must be at least 20, got {args.steps}")
    if args.filterpy_steps < 0 or 0 < args.filterpy_steps < 5:
        raise UserError(f"--filterpy-steps must be 0 or at least 5, got {args.filterpy_steps}")
    if args.filterpy_steps:
        try:
            import filterpy  # noqa: F401
        except ImportError:
            raise UserError(
                "filterpy is not installed (pip install -e '.[dev]'), or pass --filterpy-steps 0"
            ) from None
    print(f"timing {args.steps} steps per form...", file=sys.stderr)
    models = FILTER_MODELS if args.filter_model == "both" else (args.filter_model,)
    result = run_bench(args.steps, args.filterpy_steps, args.seed, models, args.fault_modes)
    print_human(result)
    if args.json:
        print(json.dumps(result))
    return 0
