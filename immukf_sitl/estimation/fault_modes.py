"""Inertial-sensor fault modes: which of the six IMU channels read zero.

A fault mode is a subset of the IMU channels ``x, y, z`` (accelerometers) and ``p, q, r`` (rate
gyros), stored as a 6-bit mask (bit ``i`` = channel ``IMU_CHANNELS[i]``, the same order as
HIGHRES_IMU's ``fields_updated`` bits). The paper's fault model (section 3): a failed sensor
reads zero plus its noise, so the filter matched to mode ``M_j`` predicts zero on the failed
channels — they give the state no feedback but still score the mode's likelihood.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from immukf_sitl.estimation.models import MeasurementFn

IMU_CHANNELS: tuple[str, ...] = ("x", "y", "z", "p", "q", "r")
CHANNEL_DESCRIPTIONS: dict[str, str] = {
    "x": "x accel",
    "y": "y accel",
    "z": "z accel",
    "p": "p gyro",
    "q": "q gyro",
    "r": "r gyro",
}
N_IMU = len(IMU_CHANNELS)


@dataclass(frozen=True, order=True)
class FaultMode:
    """A set of zeroed IMU channels.

    Parameters
    ----------
    bits : int
        Bit ``i`` set when channel ``IMU_CHANNELS[i]`` has failed (0 = fault-free, 63 = all).
    """

    bits: int

    def __post_init__(self) -> None:
        if not isinstance(self.bits, int | np.integer) or not 0 <= int(self.bits) < 2**N_IMU:
            raise ValueError(f"fault mode bits must be an integer in [0, 63], got {self.bits!r}")

    @classmethod
    def from_channels(cls, channels: Iterable[str]) -> FaultMode:
        """The mode with the given channels failed (``[]`` is fault-free)."""
        bits = 0
        for channel in channels:
            if channel not in IMU_CHANNELS:
                raise ValueError(
                    f"unknown IMU channel {channel!r}: expected one of {', '.join(IMU_CHANNELS)}"
                )
            bits |= 1 << IMU_CHANNELS.index(channel)
        return cls(bits)

    @classmethod
    def from_name(cls, name: str) -> FaultMode:
        """Parse ``"none"`` or channel names joined by ``+`` (``"q"``, ``"x+q"``)."""
        name = name.strip().lower()
        if name in ("none", ""):
            return cls(0)
        return cls.from_channels(part.strip() for part in name.split("+"))

    @cached_property
    def channels(self) -> tuple[str, ...]:
        """Failed channels in IMU order."""
        return tuple(c for i, c in enumerate(IMU_CHANNELS) if self.bits >> i & 1)

    @property
    def name(self) -> str:
        """``"none"``, ``"q"``, ``"x+q"``..."""
        return "+".join(self.channels) if self.bits else "none"

    @property
    def description(self) -> str:
        """Human label: ``"fault-free"``, ``"q gyro"``, ``"x accel + q gyro"``."""
        if not self.bits:
            return "fault-free"
        return " + ".join(CHANNEL_DESCRIPTIONS[c] for c in self.channels)

    @cached_property
    def healthy_mask(self) -> np.ndarray:
        """Shape (6,): 1.0 on working channels, 0.0 on failed ones."""
        mask = np.array([0.0 if self.bits >> i & 1 else 1.0 for i in range(N_IMU)])
        mask.setflags(write=False)
        return mask

    @property
    def paper_index(self) -> int:
        """The paper's fault index I of Table 2 (1 = none, 2-7 single, ..., 64 = all six)."""
        return all_fault_modes().index(self) + 1

    def __str__(self) -> str:
        return self.name


def all_fault_modes() -> tuple[FaultMode, ...]:
    """The 64 subsets in the paper's Table 2 order: by number of faults, then lexicographic."""
    return _ALL_MODES


def single_fault_modes() -> tuple[FaultMode, ...]:
    """The 7 modes of the paper's IMM (UKF-4): fault-free, then x, y, z, p, q, r alone."""
    return _ALL_MODES[: N_IMU + 1]


def _generate_all() -> tuple[FaultMode, ...]:
    modes = []
    for count in range(N_IMU + 1):
        for combo in itertools.combinations(IMU_CHANNELS, count):
            modes.append(FaultMode.from_channels(combo))
    return tuple(modes)


_ALL_MODES = _generate_all()


def fault_masked_output(
    healthy_output: MeasurementFn,
    modes: Sequence[FaultMode],
    n_extra: int = 0,
) -> MeasurementFn:
    """Mode-batched output function ``g_j(x, u, w) = m_j * h(x, u) + w`` (eq. 2 per mode).

    Parameters
    ----------
    healthy_output : callable
        ``h(t_s, x, u, None)`` returning ``(6 + n_extra, *batch)``: the six IMU channels first,
        then ``n_extra`` channels (e.g. GPS) that no fault mode touches.
    modes : sequence of FaultMode
        One per filter of the bank, in the bank's batch order.
    n_extra : int
        Number of non-IMU output channels after the six IMU ones.

    Returns
    -------
    callable
        ``g(t_s, x, u, w)`` for ``x`` of shape ``(nx, len(modes), sigma)``.
    """
    mask = np.ones((N_IMU + n_extra, len(modes), 1))
    for j, mode in enumerate(modes):
        mask[:N_IMU, j, 0] = mode.healthy_mask

    def output(t_s: float, x: np.ndarray, u: np.ndarray, w: np.ndarray | None) -> np.ndarray:
        z = healthy_output(t_s, x, u, None) * mask
        return z if w is None else z + w

    return output
