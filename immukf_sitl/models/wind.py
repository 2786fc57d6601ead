"""The air the aircraft flies in: steady wind and MIL-F-8785C turbulence levels.

A scenario's ``wind:`` block. The simulator hands it to JSBSim's own atmosphere (steady wind
``atmosphere/wind-{north,east,down}-fps``; Dryden turbulence ``atmosphere/turb-type`` 3 with
``turbulence/milspec/windspeed_at_20ft_AGL-fps`` and ``severity``); nothing here generates
turbulence.

MIL-F-8785C, low altitude (below 1000 ft AGL): the wind speed at 20 ft sets the intensities,
``sigma_w = 0.1 W20`` and ``sigma_u = sigma_v = sigma_w / (0.177 + 0.000823 h)^0.4`` (h in ft);
W20 is 15 kt for light, 30 kt for moderate and 45 kt for severe turbulence. Above 2000 ft the
probability-of-exceedance index sets them (light 3, moderate 4, severe 6).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["TURBULENCE_LEVELS", "TurbulenceLevel", "WindSpec", "milspec_low_altitude_sigmas"]

_KT_MPS = 0.514444
_FT_M = 0.3048


@dataclass(frozen=True)
class TurbulenceLevel:
    """One MIL-F-8785C turbulence level."""

    name: str
    w20_mps: float
    severity_index: int


#: ``none`` turns JSBSim's turbulence off.
TURBULENCE_LEVELS: dict[str, TurbulenceLevel] = {
    "none": TurbulenceLevel("none", 0.0, 0),
    "light": TurbulenceLevel("light", 15.0 * _KT_MPS, 3),
    "moderate": TurbulenceLevel("moderate", 30.0 * _KT_MPS, 4),
    "severe": TurbulenceLevel("severe", 45.0 * _KT_MPS, 6),
}


def milspec_low_altitude_sigmas(w20_mps: float, height_m: float) -> np.ndarray:
    """MIL-F-8785C low-altitude turbulence intensities ``(sigma_u, sigma_v, sigma_w)`` (m/s)."""
    h_ft = min(max(height_m / _FT_M, 10.0), 1000.0)
    sigma_w = 0.1 * w20_mps
    sigma_uv = sigma_w / (0.177 + 0.000823 * h_ft) ** 0.4
    return np.array([sigma_uv, sigma_uv, sigma_w])


@dataclass(frozen=True)
class WindSpec:
    """Steady wind and turbulence.

    Attributes
    ----------
    speed_mps : float
        Horizontal steady wind speed at the start height (m/s).
    from_deg : float
        Meteorological direction: where the wind blows from, true north, clockwise (deg).
    down_mps : float
        Steady vertical wind, positive down (m/s).
    turbulence : str
        ``none``, ``light``, ``moderate`` or ``severe``.
    """

    speed_mps: float = 0.0
    from_deg: float = 0.0
    down_mps: float = 0.0
    turbulence: str = "none"

    def __post_init__(self) -> None:
        if not (math.isfinite(self.speed_mps) and 0.0 <= self.speed_mps <= 30.0):
            raise ValueError(f"speed_mps: expected 0..30 m/s, got {self.speed_mps}")
        if not (math.isfinite(self.down_mps) and abs(self.down_mps) <= 5.0):
            raise ValueError(f"down_mps: expected -5..5 m/s, got {self.down_mps}")
        if self.turbulence not in TURBULENCE_LEVELS:
            raise ValueError(
                f"turbulence: expected one of {', '.join(TURBULENCE_LEVELS)}, "
                f"got {self.turbulence!r}"
            )

    @property
    def is_calm(self) -> bool:
        """Still air: no steady wind, no turbulence."""
        return self.speed_mps == 0.0 and self.down_mps == 0.0 and self.turbulence == "none"

    @property
    def level(self) -> TurbulenceLevel:
        """The turbulence level's MIL-F-8785C parameters."""
        return TURBULENCE_LEVELS[self.turbulence]

    def steady_ned_mps(self) -> np.ndarray:
        """The steady wind as a NED vector (m/s): blowing *towards* ``from_deg + 180``."""
        to_rad = math.radians(self.from_deg) + math.pi
        return np.array(
            [self.speed_mps * math.cos(to_rad), self.speed_mps * math.sin(to_rad), self.down_mps]
        )
