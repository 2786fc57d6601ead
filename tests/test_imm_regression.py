"""Regression fixture: the 7-mode aircraft IMM's outputs on a fixed flight do not drift.

``tests/data/imm_regression.npz`` holds what the former numpy reference filter (with the
numpy aerodynamic model) produced on 250 steps of ``immukf_sitl.experiments.bench.make_flight``
(seed 1: control doublets from trim, default sensor noise, GPS fixes at steps 100 and 200), in
both noise forms: at every fifth step (the GPS steps among them) the combined mean and
covariance diagonal, the mode probabilities, every mode's log-likelihood and NIS; the final
mode-matched estimates; the safeguard counters. The filter's compiled kernels, over either
aerodynamic model compiled or not, must reproduce it to 1e-9 relative (the
kernels sum in another order than the numpy filter did, so bitwise equality is not asked for),
and the counters exactly. (The filter's interpreted kernels, ``compiled=False``, are held to
the compiled ones by ``tests/test_compiled_kernels.py``; a run of this length interpreted
would take minutes.)

Regenerate (only when a change of results is intended) with
``python tests/test_imm_regression.py``.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from immukf_sitl.experiments.bench import ORIGIN, initial_cov, make_flight
from immukf_sitl.models.aero import AeroModel
from immukf_sitl.models.params import load_aircraft_params
from immukf_sitl.service.filter_models import PaperModel
from immukf_sitl.service.filters import Observation, build_aero_estimator

FIXTURE = Path(__file__).parent / "data" / "imm_regression.npz"
N_STEPS = 250
RECORD_EVERY = 5
FORMS = ("augmented", "additive")
#: Relative agreement asked of every array, measured against the array's largest entry per step.
RTOL = 1e-9
HAS_NUMBA = importlib.util.find_spec("numba") is not None
#: The aerodynamic model uncompiled and compiled; the filter always runs its compiled kernels.
MODEL_COMPILED = [
    pytest.param(False, id="uncompiled"),
    pytest.param(True, id="compiled", marks=pytest.mark.skipif(not HAS_NUMBA, reason="no numba")),
]


def run_bank(form: str, model_compiled: bool) -> dict[str, np.ndarray]:
    """Every recorded output of the 7-mode bank over the fixture flight."""
    params = load_aircraft_params()
    data = make_flight(AeroModel(params, ORIGIN, compiled=False), N_STEPS, seed=1)
    model = AeroModel(params, ORIGIN, compiled=model_compiled)
    # the recording is of the paper's zero modes
    est = build_aero_estimator(
        "imm", model, filter_model=PaperModel(fault_signature="zero"), noise_form=form
    )
    assert est.imm.ukf.compiled
    estimate = est.start(0.0, *est.augmented(data.x0, initial_cov()), data.controls[0])
    rows: dict[str, list[np.ndarray]] = {
        "mean": [], "cov_diag": [], "mode_probabilities": [], "log_likelihoods": [], "nis": []
    }  # fmt: skip
    for k in range(1, N_STEPS):
        estimate = est.step(
            estimate, k * model.dt_s, data.controls[k], Observation(data.imu[k], data.gps[k])
        )
        e = estimate.filter
        if k % RECORD_EVERY:
            continue
        rows["mean"].append(e.mean)
        rows["cov_diag"].append(np.diagonal(e.cov))
        rows["mode_probabilities"].append(e.mode_probabilities)
        rows["log_likelihoods"].append(e.log_likelihoods)
        rows["nis"].append(e.nis)
    out = {name: np.array(values) for name, values in rows.items()}
    out["final_mode_means"] = e.mode_means
    out["final_mode_covs"] = e.mode_covs
    out["final_cov"] = e.cov
    out["diagnostics"] = np.array(list(est.imm.diagnostics.as_dict().values()))
    return out


def _relative_error(actual: np.ndarray, expected: np.ndarray) -> float:
    """Largest |actual - expected| over the largest |expected| of the same step (leading axis)."""
    axes = tuple(range(1, expected.ndim))
    scale = np.max(np.abs(expected), axis=axes, keepdims=True) if axes else np.abs(expected)
    return float(np.max(np.abs(actual - expected) / np.maximum(scale, 1e-300)))


@pytest.mark.parametrize("model_compiled", MODEL_COMPILED)
@pytest.mark.parametrize("form", FORMS)
def test_bank_reproduces_the_recorded_run(form: str, model_compiled: bool) -> None:
    expected = np.load(FIXTURE)
    actual = run_bank(form, model_compiled)
    for name, values in actual.items():
        reference = expected[f"{form}/{name}"]
        if name == "diagnostics":
            # the counters recorded, then those added since (none of which may fire here)
            recorded, added = values[: len(reference)], values[len(reference) :]
            assert np.array_equal(recorded, reference), (values, reference)
            assert not added.any(), values
            continue
        assert values.shape == reference.shape, name
        assert np.all(np.isfinite(values)), name
        assert _relative_error(values, reference) < RTOL, name


if __name__ == "__main__":
    arrays = {
        f"{form}/{name}": values
        for form in FORMS
        for name, values in run_bank(form, "numpy").items()
    }
    np.savez_compressed(FIXTURE, **arrays)
    print(f"wrote {FIXTURE} ({FIXTURE.stat().st_size} bytes)")
