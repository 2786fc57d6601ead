"""A flown airframe that differs from the book: named parameters scaled, or drawn at random.

A real aircraft never matches its parameter file. A scenario's ``airframe:`` block makes the
simulated aircraft differ from ``params.yaml`` while the filter keeps ``params.yaml``:

- ``scale``: multiply named numeric parameters (``mass_kg``, ``Jx_kgm2``, ``C_m_alpha``, ...);
- ``uncertainty``: 1-sigma relative errors drawn per run from the scenario's seed, for every
  aerodynamic coefficient (``C_*``), the mass, and the inertias, each parameter with its own
  factor ``1 + sigma * N(0, 1)``. The inertias are drawn as a body, not as three numbers: a
  fixed wing is nearly flat (``Jz`` is about ``Jx + Jy``; the Aerosonde's principal moments
  miss the triangle inequality's limit by 10 %), so independent 10 % errors would often give
  a body that cannot exist. ``Jx``, ``Jy`` and ``Jxz`` get their own factors and ``Jz`` is
  ``Jx' + Jy' - d'``, where ``d = Jx + Jy - Jz`` (the thickness term) gets its own factor too.

The factors actually used are reported (the run summary's ``airframe`` key), so a flight can be
rebuilt from its summary.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from immukf_sitl.models.params import AircraftParams

__all__ = [
    "AIRFRAME_STREAM_INDEX",
    "AirframeSpec",
    "AirframeUncertainty",
    "airframe_factors",
    "scalable_parameters",
    "scaled_params",
]

#: Child of ``numpy.random.SeedSequence(seed)`` that draws the airframe (the sim's IMU and GPS
#: use children 0 and 1, the fault proxy 2).
AIRFRAME_STREAM_INDEX = 3
#: Parameter groups of :class:`AircraftParams` whose numeric fields may be scaled.
_GROUPS = ("mass", "geometry", "aero", "propulsion")
_INERTIAS = ("Jx_kgm2", "Jy_kgm2", "Jz_kgm2", "Jxz_kgm2")


@dataclass(frozen=True)
class AirframeUncertainty:
    """1-sigma relative errors of the drawn airframe (0: that group exact)."""

    aero: float = 0.0
    mass: float = 0.0
    inertia: float = 0.0

    def __post_init__(self) -> None:
        for name in ("aero", "mass", "inertia"):
            value = getattr(self, name)
            if not 0.0 <= value <= 0.5:
                raise ValueError(f"uncertainty.{name}: expected 0..0.5, got {value}")


@dataclass(frozen=True)
class AirframeSpec:
    """How the flown aircraft differs from the parameter file (a scenario's ``airframe:``)."""

    scale: Mapping[str, float] = field(default_factory=dict)
    uncertainty: AirframeUncertainty = field(default_factory=AirframeUncertainty)

    @property
    def is_exact(self) -> bool:
        """Whether the flown aircraft is the parameter file's (an identical twin)."""
        return not self.scale and self.uncertainty == AirframeUncertainty()


def scalable_parameters(params: AircraftParams) -> dict[str, tuple[str, str]]:
    """``{name: (group, field)}`` of every scalar numeric parameter, e.g. ``C_m_alpha``."""
    out: dict[str, tuple[str, str]] = {}
    for group in _GROUPS:
        record = getattr(params, group)
        for f in dataclasses.fields(record):
            value = getattr(record, f.name)
            if isinstance(value, float | int) and not isinstance(value, bool):
                out[f.name] = (group, f.name)
    return out


def airframe_factors(params: AircraftParams, spec: AirframeSpec, seed: int) -> dict[str, float]:
    """The factor of every parameter that differs, drawn reproducibly from ``seed``.

    Raises
    ------
    ValueError
        When ``spec.scale`` names a parameter that does not exist.
    """
    names = scalable_parameters(params)
    unknown = sorted(set(spec.scale) - set(names))
    if unknown:
        raise ValueError(f"scale.{unknown[0]}: not a numeric parameter of {params.source}")
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(AIRFRAME_STREAM_INDEX,)))
    sigma = spec.uncertainty
    factors: dict[str, float] = {}
    # one draw per parameter in a fixed order, whether or not its group is uncertain, so that
    # the factor of C_m_alpha does not change when, say, the mass sigma is switched on
    for name in sorted(names):
        draw = float(rng.standard_normal())
        if name.startswith("C_") and names[name][0] == "aero":
            relative = sigma.aero
        elif name == "mass_kg":
            relative = sigma.mass
        elif name in _INERTIAS:
            relative = sigma.inertia
        else:
            relative = 0.0
        factors[name] = 1.0 + relative * draw
    if sigma.inertia > 0.0:
        mass = params.mass
        jx, jy = mass.Jx_kgm2 * factors["Jx_kgm2"], mass.Jy_kgm2 * factors["Jy_kgm2"]
        thickness = (mass.Jx_kgm2 + mass.Jy_kgm2 - mass.Jz_kgm2) * max(factors["Jz_kgm2"], 0.0)
        factors["Jz_kgm2"] = (jx + jy - thickness) / mass.Jz_kgm2
    out = {}
    for name, drawn in factors.items():
        factor = float(spec.scale.get(name, 1.0)) * drawn
        if factor != 1.0:
            out[name] = factor
    return out


def scaled_params(params: AircraftParams, factors: Mapping[str, float]) -> AircraftParams:
    """``params`` with each named parameter multiplied by its factor (validated again)."""
    names = scalable_parameters(params)
    changes: dict[str, dict[str, float]] = {}
    for name, factor in factors.items():
        group, attribute = names[name]
        value = getattr(getattr(params, group), attribute)
        changes.setdefault(group, {})[attribute] = value * factor
    groups = {g: dataclasses.replace(getattr(params, g), **c) for g, c in changes.items()}
    source = f"{params.source} (scaled: {len(factors)} parameters)" if factors else params.source
    return dataclasses.replace(params, source=source, **groups)
