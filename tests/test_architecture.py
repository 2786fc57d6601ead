"""The layering each package's docstring promises, checked on the import statements.

Every product module is parsed (not imported) and each ``import``/``from ... import`` is held to
the rules below, so that a new maintainer who reads a package's ``__init__`` docstring can trust
it: pure numerics stay free of I/O, MAVLink stays in its adapter, JSBSim stays in the driver.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PRODUCT = sorted(
    p for p in [*ROOT.glob("immukf_sitl/**/*.py"), *ROOT.glob("sim/**/*.py")] if p.is_file()
)

#: Project packages a module may import, by where the module lives (first matching prefix).
ALLOWED = (
    ("immukf_sitl/estimation/", {"immukf_sitl.estimation"}),
    ("immukf_sitl/models/", {"immukf_sitl.models", "immukf_sitl.errors"}),
    ("immukf_sitl/samples.py", set()),
    ("immukf_sitl/errors.py", set()),
    ("immukf_sitl/vehicle.py", {"immukf_sitl.errors"}),
    ("immukf_sitl/fault_kinds.py", set()),
    ("immukf_sitl/stream_profile.py", set()),
    (
        "immukf_sitl/scenario.py",
        {
            "immukf_sitl.errors",
            "immukf_sitl.estimation",
            "immukf_sitl.models",
            "immukf_sitl.yaml_fields",
            "immukf_sitl.fault_kinds",
            "immukf_sitl.stream_profile",
        },
    ),  # fmt: skip
    ("immukf_sitl/yaml_fields.py", {"immukf_sitl.errors"}),
    (
        "immukf_sitl/service/",
        {
            "immukf_sitl.service",
            "immukf_sitl.estimation",
            "immukf_sitl.models",
            "immukf_sitl.samples",
        },
    ),  # fmt: skip
    (
        "immukf_sitl/options.py",
        {
            "immukf_sitl.errors",
            "immukf_sitl.estimation",
            "immukf_sitl.models",
            "immukf_sitl.scenario",
            "immukf_sitl.service",
        },
    ),  # fmt: skip
    (
        "immukf_sitl/mavlink/",
        {
            "immukf_sitl.mavlink",
            "immukf_sitl.fault_kinds",
            "immukf_sitl.service",
            "immukf_sitl.estimation",
            "immukf_sitl.models",
            "immukf_sitl.samples",
            "immukf_sitl.scenario",
            "immukf_sitl.errors",
            "immukf_sitl.options",
            "immukf_sitl.vehicle",
        },
    ),  # fmt: skip
    # the autopilots' logs read into the MAVLink adapter's FlightLog
    (
        "immukf_sitl/logs/",
        {
            "immukf_sitl.logs",
            "immukf_sitl.mavlink",
            "immukf_sitl.samples",
            "immukf_sitl.errors",
            "immukf_sitl.vehicle",
        },
    ),  # fmt: skip
    ("immukf_sitl/experiments/", {"immukf_sitl", "sim"}),
    ("immukf_sitl/cli.py", {"immukf_sitl"}),
    ("immukf_sitl/__init__.py", set()),
    ("sim/emitter.py", {"immukf_sitl", "sim"}),
    ("sim/profile_stream.py", {"immukf_sitl", "sim"}),
    ("sim/fault_proxy.py", {"immukf_sitl", "sim"}),
    (
        "sim/",
        {
            "sim",
            "immukf_sitl.models",
            "immukf_sitl.samples",
            "immukf_sitl.scenario",
            "immukf_sitl.stream_profile",
            "immukf_sitl.errors",
        },
    ),  # fmt: skip
)
#: Third-party packages confined to a few modules.
CONFINED = {
    "pymavlink": ("immukf_sitl/mavlink/wire.py",),
    "jsbsim": ("sim/driver.py",),
    "pyulog": ("immukf_sitl/logs/ulog.py",),
    # campaigns run on a Dask cluster through one executor interface
    "dask": ("immukf_sitl/experiments/executor.py",),
    "distributed": ("immukf_sitl/experiments/executor.py",),
    "argparse": ("immukf_sitl/cli.py", "immukf_sitl/options.py", "immukf_sitl/mavlink/serve.py",
                 "immukf_sitl/experiments/", "sim/emitter.py", "sim/fault_proxy.py",
                 "sim/aircraft_xml.py"),
}  # fmt: skip
#: MAVLink 2 signing is pymavlink's (immukf_sitl/mavlink/signing.py drives it): nothing on the
#: wire side computes a digest or MAC of its own.
NO_OWN_MAC = {"hmac", "hashlib"}
#: What the MAVLink adapter hands out that is pymavlink itself (the module, its message class).
PYMAVLINK_NAMES = {"mavlink", "mavutil"}
ADAPTER_SHELLS = (
    "immukf_sitl/mavlink/",
    "sim/emitter.py",
    "sim/fault_proxy.py",
    "sim/profile_stream.py",
)


def _imports(path: Path) -> list[tuple[str, tuple[str, ...]]]:
    """``(module, names)`` of every import in the file (relative imports resolved)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.extend((alias.name, ()) for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            out.append((node.module, tuple(alias.name for alias in node.names)))
    return out


def _rel(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


def _allowed(rel: str) -> set[str]:
    return next(allowed for prefix, allowed in ALLOWED if rel.startswith(prefix))


def _within(module: str, packages: set[str]) -> bool:
    return any(module == p or module.startswith(p + ".") for p in packages)


@pytest.mark.parametrize("path", PRODUCT, ids=_rel)
def test_module_imports_only_what_its_layer_may(path: Path) -> None:
    rel = _rel(path)
    allowed = _allowed(rel)
    wrong = [
        module
        for module, _ in _imports(path)
        if module.split(".")[0] in ("immukf_sitl", "sim") and not _within(module, allowed)
    ]
    assert not wrong, f"{rel} imports {wrong}; its layer may import only {sorted(allowed)}"


@pytest.mark.parametrize("path", PRODUCT, ids=_rel)
def test_confined_libraries_stay_where_they_belong(path: Path) -> None:
    rel = _rel(path)
    for module, names in _imports(path):
        top = module.split(".")[0]
        if top in CONFINED:
            assert rel.startswith(CONFINED[top]), f"{rel} imports {top}"
        if module == "immukf_sitl.mavlink.wire" and PYMAVLINK_NAMES & set(names):
            assert rel.startswith(ADAPTER_SHELLS), (
                f"{rel} takes pymavlink ({sorted(PYMAVLINK_NAMES & set(names))}) from the "
                "adapter: convert messages in immukf_sitl.mavlink instead"
            )


@pytest.mark.parametrize(
    "path", [p for p in PRODUCT if _rel(p).startswith(ADAPTER_SHELLS)], ids=_rel
)
def test_signing_is_pymavlinks_own(path: Path) -> None:
    own = sorted({m.split(".")[0] for m, _ in _imports(path)} & NO_OWN_MAC)
    assert not own, f"{_rel(path)} imports {own}: sign and check with pymavlink's signing"


def test_the_rules_cover_every_module_and_catch_a_violation(tmp_path: Path) -> None:
    assert len(PRODUCT) > 40
    for path in PRODUCT:
        _allowed(_rel(path))  # raises StopIteration for a module no rule covers
    bad = tmp_path / "bad.py"
    bad.write_text("import pymavlink.mavutil\nfrom immukf_sitl.mavlink import codec\n")
    modules = [m for m, _ in _imports(bad)]
    assert modules == ["pymavlink.mavutil", "immukf_sitl.mavlink"]
    assert not "immukf_sitl/experiments/campaign_run.py".startswith(CONFINED["distributed"])
    assert not _within("immukf_sitl.mavlink", _allowed("immukf_sitl/estimation/x.py"))
