"""Guarded Cholesky factorisation for batched covariance matrices: the filter's repairs."""

from __future__ import annotations

import numpy as np

from immukf_sitl.estimation.diagnostics import FilterDiagnostics

#: Relative size of the first diagonal jitter (times the mean diagonal); grows by 100x per try.
JITTER_START = 1e-12
JITTER_TRIES = 4
#: Eigenvalue floor, relative to the largest eigenvalue, for the last-resort repair.
EIGEN_FLOOR_REL = 1e-12
EIGEN_FLOOR_ABS = 1e-300


def robust_cholesky(cov: np.ndarray, diag: FilterDiagnostics) -> np.ndarray:
    """Lower Cholesky factors of a stack ``(B, n, n)`` of symmetric matrices; never raises.

    A matrix that is not numerically positive definite is repaired: first by adding a growing
    diagonal jitter (counted in ``diag.cholesky_jitter``), then by flooring its eigenvalues
    (``diag.cholesky_eigen_floor``). Non-finite entries are replaced by the eigen floor's result
    of a diagonal matrix holding the finite diagonal entries, so the filter keeps running.
    """
    try:
        factor = np.linalg.cholesky(cov)
        if np.isfinite(factor).all():  # LAPACK passes NaN through without raising
            return factor
    except np.linalg.LinAlgError:
        pass
    out = np.empty_like(cov)
    for b in range(cov.shape[0]):
        out[b] = _repair_one(cov[b], diag)
    return out


def _repair_one(cov: np.ndarray, diag: FilterDiagnostics) -> np.ndarray:
    n = cov.shape[0]
    if np.all(np.isfinite(cov)):
        try:
            return np.linalg.cholesky(cov)
        except np.linalg.LinAlgError:
            pass
        scale = max(float(np.mean(np.abs(np.diag(cov)))), EIGEN_FLOOR_ABS)
        jitter = JITTER_START * scale
        for _ in range(JITTER_TRIES):
            try:
                factor = np.linalg.cholesky(cov + jitter * np.eye(n))
            except np.linalg.LinAlgError:
                jitter *= 100.0
                continue
            diag.cholesky_jitter += 1
            return factor
        sym = 0.5 * (cov + cov.T)
    else:
        finite_diag = np.where(np.isfinite(np.diag(cov)), np.abs(np.diag(cov)), 1.0)
        sym = np.diag(finite_diag)
    diag.cholesky_eigen_floor += 1
    eigval, eigvec = np.linalg.eigh(sym)
    floor = max(EIGEN_FLOOR_REL * float(np.max(np.abs(eigval))), EIGEN_FLOOR_ABS)
    eigval = np.maximum(eigval, floor)
    repaired = (eigvec * eigval) @ eigvec.T
    return np.linalg.cholesky(0.5 * (repaired + repaired.T))
