"""Angle-valued components: wrapped residuals and weighted circular means.

Filters treat the components listed in an ``angle_idx`` tuple as angles in radians: residuals
are wrapped to [-pi, pi) and means are taken on the circle, so that a heading near +-pi does not
average to zero.
"""

from __future__ import annotations

import numpy as np

TWO_PI = 2.0 * np.pi


def wrap_angle(angle_rad: np.ndarray | float) -> np.ndarray:
    """Wrap angles to [-pi, pi)."""
    return (np.asarray(angle_rad) + np.pi) % TWO_PI - np.pi


def wrap_rows(values: np.ndarray, angle_idx: tuple[int, ...]) -> np.ndarray:
    """Wrap, in place, the rows ``angle_idx`` of an array whose first axis is the component axis."""
    if angle_idx:
        values[list(angle_idx)] = wrap_angle(values[list(angle_idx)])
    return values


def weighted_mean(
    points: np.ndarray, weights: np.ndarray, angle_idx: tuple[int, ...] = ()
) -> np.ndarray:
    """Weighted mean over the last axis; circular mean for the rows in ``angle_idx``.

    Parameters
    ----------
    points : ndarray, shape (n, ..., s)
        Component axis first, samples on the last axis.
    weights : ndarray, shape (s,)
        Sample weights (they may be negative, as with small kappa).
    angle_idx : tuple of int
        Components that are angles in radians.

    Returns
    -------
    ndarray, shape (n, ...)
    """
    mean = points @ weights
    if angle_idx:
        idx = list(angle_idx)
        angles = points[idx]
        mean[idx] = np.arctan2(np.sin(angles) @ weights, np.cos(angles) @ weights)
    return mean
