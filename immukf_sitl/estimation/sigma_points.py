"""Sigma-point schemes and the unscented transform (paper eqs. 11-12).

A scheme gives, for a dimension ``n``, the spread factor ``c`` (sigma points sit at the mean
plus and minus ``c`` times the columns of a square root of the covariance) and the mean and
covariance weights ``Wm``, ``Wc`` of the ``2 n + 1`` points, ordered
``[mean, mean + c L[:, 0..n-1], mean - c L[:, 0..n-1]]``.

References
----------
.. [1] S. J. Julier, J. K. Uhlmann, "A new extension of the Kalman filter to nonlinear
   systems", Proc. SPIE 3068, 1997 (the kappa form, the paper's eqs. 11-12).
.. [2] R. van der Merwe, "Sigma-point Kalman filters for probabilistic inference in dynamic
   state-space models", PhD thesis, OGI, 2004 (the scaled alpha/beta/kappa form).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from immukf_sitl.estimation.angles import weighted_mean, wrap_rows


@dataclass(frozen=True)
class SigmaWeights:
    """Spread factor and weights of one scheme at one dimension."""

    n: int
    spread: float
    mean_weights: np.ndarray
    cov_weights: np.ndarray


@dataclass(frozen=True)
class JulierSigmaPoints:
    """The paper's kappa scaling (eqs. 11-12): ``c = sqrt(n + kappa)``, ``W0 = kappa/(n+kappa)``.

    Mean and covariance weights are equal. ``kappa = 0`` (the default) puts no weight on the
    central point; ``kappa = 3 - n`` matches the fourth moment of a Gaussian but gives a negative
    central weight for large ``n``.
    """

    kappa: float = 0.0

    def weights(self, n: int) -> SigmaWeights:
        """Spread and weights for dimension ``n``."""
        return _julier_weights(n, float(self.kappa))


@dataclass(frozen=True)
class ScaledSigmaPoints:
    """Scaled sigma points: ``lambda = alpha^2 (n + kappa) - n``, ``c = sqrt(n + lambda)``.

    ``Wm0 = lambda/(n+lambda)``, ``Wc0 = Wm0 + 1 - alpha^2 + beta``, others ``1/(2(n+lambda))``.
    """

    alpha: float = 1.0
    beta: float = 2.0
    kappa: float = 0.0

    def weights(self, n: int) -> SigmaWeights:
        """Spread and weights for dimension ``n``."""
        return _scaled_weights(n, float(self.alpha), float(self.beta), float(self.kappa))


SigmaPointScheme = JulierSigmaPoints | ScaledSigmaPoints


@lru_cache(maxsize=256)
def _julier_weights(n: int, kappa: float) -> SigmaWeights:
    if n + kappa <= 0.0:
        raise ValueError(f"kappa={kappa} gives n + kappa <= 0 for n={n}")
    w = np.full(2 * n + 1, 0.5 / (n + kappa))  # eq. (12)
    w[0] = kappa / (n + kappa)
    w.setflags(write=False)
    return SigmaWeights(n, float(np.sqrt(n + kappa)), w, w)


@lru_cache(maxsize=256)
def _scaled_weights(n: int, alpha: float, beta: float, kappa: float) -> SigmaWeights:
    lam = alpha**2 * (n + kappa) - n
    if n + lam <= 0.0:
        raise ValueError(f"alpha={alpha}, kappa={kappa} give n + lambda <= 0 for n={n}")
    wm = np.full(2 * n + 1, 0.5 / (n + lam))
    wc = wm.copy()
    wm[0] = lam / (n + lam)
    wc[0] = lam / (n + lam) + 1.0 - alpha**2 + beta
    wm.setflags(write=False)
    wc.setflags(write=False)
    return SigmaWeights(n, float(np.sqrt(n + lam)), wm, wc)


def sigma_points(mean: np.ndarray, sqrt_cov: np.ndarray, spread: float) -> np.ndarray:
    """Sigma points of eq. (11), batched.

    Parameters
    ----------
    mean : ndarray, shape (B, n)
    sqrt_cov : ndarray, shape (B, n, n)
        Any square root ``L`` with ``L L' = P`` (lower Cholesky factor in this package).
    spread : float
        ``sqrt(n + kappa)`` or the scaled equivalent.

    Returns
    -------
    ndarray, shape (n, B, 2n + 1)
        Component axis first, the layout every model function takes.
    """
    batch, n = mean.shape
    points = np.empty((n, batch, 2 * n + 1))
    centre = mean.T[:, :, None]
    offsets = spread * sqrt_cov.transpose(1, 0, 2)
    points[:, :, :1] = centre
    np.add(centre, offsets, out=points[:, :, 1 : n + 1])
    np.subtract(centre, offsets, out=points[:, :, n + 1 :])
    return points


def unscented_transform(
    points: np.ndarray,
    weights: SigmaWeights,
    angle_idx: tuple[int, ...] = (),
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean, covariance and residuals of transformed sigma points (eqs. 16-18, 20).

    Parameters
    ----------
    points : ndarray, shape (m, B, s)
    weights : SigmaWeights
    angle_idx : tuple of int
        Rows that are angles: circular mean, wrapped residuals.

    Returns
    -------
    mean : ndarray, shape (B, m)
    cov : ndarray, shape (B, m, m)
    residuals : ndarray, shape (B, m, s)
    """
    mean = weighted_mean(points, weights.mean_weights, angle_idx)
    residuals = points - mean[:, :, None]
    wrap_rows(residuals, angle_idx)
    residuals = residuals.transpose(1, 0, 2)
    cov = (residuals * weights.cov_weights) @ residuals.transpose(0, 2, 1)
    return mean.T, cov, residuals
