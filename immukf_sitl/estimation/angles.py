"""Angle-valued components: wrapped residuals and masks of the angle rows.

Filters treat the components listed in an ``angle_idx`` tuple as angles in radians: residuals
are wrapped to [-pi, pi) and means are taken on the circle (in the kernels of
:mod:`immukf_sitl.estimation.kernels`), so that a heading near +-pi does not average to zero.
"""

from __future__ import annotations

import numpy as np

from immukf_sitl.estimation import kernels

#: The kernel's formula; uncompiled, it runs on numpy arrays (``py_func`` is absent only when
#: numba's JIT is disabled, and then the kernel is the plain function already).
_wrap = getattr(kernels.wrap, "py_func", kernels.wrap)


def wrap_angle(angle_rad: np.ndarray | float) -> np.ndarray:
    """Wrap angles to [-pi, pi): ``(a + pi) mod 2 pi - pi``, elementwise."""
    return _wrap(np.asarray(angle_rad))


def angle_mask(n: int, angle_idx: tuple[int, ...]) -> np.ndarray:
    """Read-only boolean mask of length ``n``, True at ``angle_idx`` (the kernels' angle form)."""
    mask = np.zeros(n, dtype=np.bool_)
    mask[list(angle_idx)] = True
    mask.setflags(write=False)
    return mask
