"""The maintainers' naming tools: a recorded namer, replayed, names exactly as it did live."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np

from immukf_sitl.service.fault_naming import FaultNamer

TOOLS = Path(__file__).resolve().parent.parent / "tools"
SIGMAS = np.array([0.03, 0.03, 0.03, 0.00227, 0.00227, 0.00227])


def _tool(name: str):
    """Import ``tools/<name>.py`` (the tools are scripts, not a package)."""
    spec = importlib.util.spec_from_file_location(name, TOOLS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def _fly(namer: FaultNamer, rng: np.random.Generator, drift_radps2: float) -> list:
    """A namer fed as the pipeline feeds it: 11 s healthy, q declared, 16 s of a drifting q."""
    names = []
    t = 19.0 + 0.01 * np.arange(2700)
    swing = 0.1 * np.sin(2.0 * np.pi * 0.2 * t)
    nu, var = np.zeros((7, 6)), np.full((7, 6), SIGMAS**2 + 0.002**2)
    for k, tk in enumerate(t):
        truth = np.array([0.5, 0.0, -9.8, 0.0, 0.0, 0.0]) + np.r_[np.zeros(3), swing[k], 0.0, 0.0]
        imu = truth + SIGMAS * rng.standard_normal(6)
        if tk > 30.0:
            imu[4] += drift_radps2 * (tk - 30.0)
            nu[0] = imu - (truth + 0.002 * rng.standard_normal(6))
        namer.record(tk, imu)
        if namer.pending:
            names += namer.observe(tk, imu, nu, var)
        if k == 1100:
            namer.declared(0, 4, tk)
    return names


def test_a_recorded_namer_is_replayed_to_the_same_names(monkeypatch):
    # a q gyro drifting at 0.02 rad/s^2 from 30 s, declared at 30.0 s: the namer names it at
    # 1 s, 5 s and 15 s; replayed from its record by tools/rename.py, a fresh namer of the same
    # code gives the last of those names, kind and size to the last bit
    record_naming, rename = _tool("record_naming"), _tool("rename")
    for method in ("declared", "observe", "cancel"):  # restored after the test
        monkeypatch.setattr(FaultNamer, method, getattr(FaultNamer, method))
    log: list[tuple] = []
    record_naming._recording(log)
    live = _fly(FaultNamer(SIGMAS), np.random.default_rng(11), 0.02)
    monkeypatch.undo()
    assert [c for c, _ in live] == [4] * len(live) and len(live) >= 2
    replayed = rename.replay(log, FaultNamer(SIGMAS), 4)
    assert replayed == (live[-1][1].kind, live[-1][1].size)
    assert replayed[0] == "drift"
