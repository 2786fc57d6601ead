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

from immukf_sitl.estimation import kernels
from immukf_sitl.estimation.angles import angle_mask


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
    """Sigma points of eq. (11), batched: ``[x, x + c L[:, k], x - c L[:, k]]``, ``k < n``.

    Runs the filter's kernel :func:`immukf_sitl.estimation.kernels.state_points`.

    Parameters
    ----------
    mean : ndarray, shape (B, n)
    sqrt_cov : ndarray, shape (B, n, n)
        Any square root ``L`` with ``L L' = P`` (lower Cholesky factor in this package).
    spread : float
        ``c = sqrt(n + kappa)`` or the scaled equivalent.

    Returns
    -------
    ndarray, shape (n, B, 2n + 1)
        Component axis first, the layout every model function takes.
    """
    mean = np.ascontiguousarray(mean, dtype=float)
    batch, n = mean.shape
    points = np.empty((n, batch, 2 * n + 1))
    kernels.state_points(mean, np.ascontiguousarray(sqrt_cov, dtype=float), float(spread), points)
    return points


def unscented_transform(
    points: np.ndarray,
    weights: SigmaWeights,
    angle_idx: tuple[int, ...] = (),
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean, covariance and residuals of transformed sigma points (eqs. 16-18, 20).

    ``x^ = sum_s Wm_s X_s``, ``P = sum_s Wc_s (X_s - x^)(X_s - x^)'``; runs the filter's kernel
    :func:`immukf_sitl.estimation.kernels.predict_moments`.

    Parameters
    ----------
    points : ndarray, shape (m, B, s)
    weights : SigmaWeights
    angle_idx : tuple of int
        Rows that are angles: circular mean ``atan2(sum Wm sin, sum Wm cos)``, wrapped
        residuals.

    Returns
    -------
    mean : ndarray, shape (B, m)
    cov : ndarray, shape (B, m, m)
    residuals : ndarray, shape (B, m, s)
    """
    points = np.ascontiguousarray(points, dtype=float)
    m, batch, s = points.shape
    mean = np.empty((batch, m))
    cov = np.empty((batch, m, m))
    residuals = np.empty((batch, m, s))
    kernels.predict_moments(
        points,
        np.arange(s),
        kernels.MomentWeights(weights.mean_weights, weights.cov_weights),
        angle_mask(m, angle_idx),
        np.zeros((m, m)),
        kernels.Moments(np.empty_like(points), mean, cov, residuals),
    )
    return mean, cov, residuals
