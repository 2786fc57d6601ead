"""Small systems with known answers, shared by the estimation tests."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from immukf_sitl.estimation import MeasurementModel, ProcessModel

DT_S = 0.1


@dataclass(frozen=True)
class LinearGaussian:
    """``x(k+1) = F x + G v``, ``z = H x + w``: a 2-D constant-velocity target."""

    F: np.ndarray
    G: np.ndarray
    H: np.ndarray
    Q: np.ndarray
    R: np.ndarray

    def process(self) -> ProcessModel:
        def f(t_s, x, u, v):
            out = np.tensordot(self.F, x, axes=1)
            return out if v is None else out + np.tensordot(self.G, v, axes=1)

        return ProcessModel(f, 4, self.Q, additive_noise_cov=self.G @ self.Q @ self.G.T)

    def measurement(self) -> MeasurementModel:
        def g(t_s, x, u, w):
            out = np.tensordot(self.H, x, axes=1)
            return out if w is None else out + w

        return MeasurementModel(g, self.R, name="position")


def constant_velocity() -> LinearGaussian:
    """State [north_m, east_m, vn_mps, ve_mps]; white-acceleration noise; position measured."""
    F = np.eye(4)
    F[0, 2] = F[1, 3] = DT_S
    G = np.array([[0.5 * DT_S**2, 0], [0, 0.5 * DT_S**2], [DT_S, 0], [0, DT_S]])
    H = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0]])
    return LinearGaussian(F, G, H, np.diag([0.3**2, 0.2**2]), np.diag([2.0**2, 1.5**2]))


def kalman_filter(sys: LinearGaussian, x0, P0, zs):
    """Plain Kalman filter (the closed-form answer), returning every posterior."""
    x, P = x0.copy(), P0.copy()
    out = []
    Qd = sys.G @ sys.Q @ sys.G.T
    for z in zs:
        x = sys.F @ x
        P = sys.F @ P @ sys.F.T + Qd
        S = sys.H @ P @ sys.H.T + sys.R
        K = P @ sys.H.T @ np.linalg.inv(S)
        x = x + K @ (z - sys.H @ x)
        P = P - K @ S @ K.T
        out.append((x.copy(), P.copy()))
    return out


# -- range-bearing tracking: nonlinear measurement of a constant-velocity target ---------------

RANGE_SIGMA_M = 5.0
BEARING_SIGMA_RAD = np.deg2rad(0.5)


def range_bearing(x, u=None, w=None):
    """[range_m, bearing_rad] of the target seen from the origin; bearing = atan2(east, north)."""
    out = np.array([np.hypot(x[0], x[1]), np.arctan2(x[1], x[0])])
    return out if w is None else out + w


def range_bearing_model(angles: bool = True) -> MeasurementModel:
    return MeasurementModel(
        lambda t, x, u, w: range_bearing(x, u, w),
        np.diag([RANGE_SIGMA_M**2, BEARING_SIGMA_RAD**2]),
        angle_idx=(1,) if angles else (),
        name="range-bearing",
    )


def simulate_target(rng: np.random.Generator, sys: LinearGaussian, x0, n_steps):
    """True states and range-bearing measurements (bearing wrapped)."""
    xs, zs = [], []
    x = x0.copy()
    L_Q = np.linalg.cholesky(sys.Q)
    for _ in range(n_steps):
        x = sys.F @ x + sys.G @ (L_Q @ rng.standard_normal(2))
        z = range_bearing(x) + np.array([RANGE_SIGMA_M, BEARING_SIGMA_RAD]) * rng.standard_normal(2)
        z[1] = (z[1] + np.pi) % (2 * np.pi) - np.pi
        xs.append(x.copy())
        zs.append(z)
    return np.array(xs), np.array(zs)


# -- a six-channel "IMU" toy: three decoupled oscillators, every state component measured ------

OMEGA_RADPS = np.array([0.9, 1.3, 1.7])


def oscillator_bank() -> tuple[ProcessModel, np.ndarray]:
    """State [a1, a2, a3, b1, b2, b3]: rotations of three phasors (exact discretisation)."""
    A = np.zeros((6, 6))
    for i, om in enumerate(OMEGA_RADPS):
        c, s = np.cos(om * DT_S), np.sin(om * DT_S)
        A[i, i], A[i, i + 3], A[i + 3, i], A[i + 3, i + 3] = c, -s, s, c
    Q = np.eye(6) * 0.01**2

    def f(t, x, u, v):
        out = np.tensordot(A, x, axes=1)
        return out if v is None else out + v

    return ProcessModel(f, 6, Q, additive_noise_cov=Q), A


def identity_output(t, x, u, w):
    return x if w is None else x + w
