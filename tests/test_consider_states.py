"""Consider states (Schmidt-Kalman): the UKF equals an independent linear Schmidt filter.

A receiver's position bias ``b`` beside the position ``p``: ``z = p + b + w``. The data cannot
tell ``b`` from ``p`` except through the dynamics, so a filter that estimates ``b`` lets a
model error of the velocity drift into it; as a consider state its mean stays at zero and its
variance is never reduced, while every other gain and covariance accounts for it. The
reference below is written from the textbook form (gain rows of ``b`` zeroed, Joseph update,
valid for any gain), not from the filter's code.
"""

import numpy as np
import pytest

from immukf_sitl.estimation import (
    JulierSigmaPoints,
    Measurement,
    MeasurementModel,
    ProcessModel,
    ScaledSigmaPoints,
    UnscentedKalmanFilter,
)

DT_S = 0.1
F = np.array([[1.0, DT_S, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, np.exp(-DT_S / 50.0)]])
G = np.array([[0.5 * DT_S**2], [DT_S], [0.0]])
Q = np.array([[0.2**2]])
Q_BIAS = 4.0**2 * (1.0 - np.exp(-2.0 * DT_S / 50.0))  # Gauss-Markov, 4 m stationary
H = np.array([[1.0, 0.0, 1.0]])
R = np.array([[0.5**2]])


def _models(consider: tuple[int, ...]) -> tuple[ProcessModel, MeasurementModel]:
    state_noise = np.zeros((3, 3))
    state_noise[2, 2] = Q_BIAS  # referred to the step's end (additive form)
    at_start = np.zeros((3, 3))
    at_start[2, 2] = Q_BIAS / F[2, 2] ** 2  # before the decay (augmented form)

    def f(t_s, x, u, v):
        out = np.tensordot(F, x, axes=1)
        return out if v is None else out + np.tensordot(G, v, axes=1)

    def g(t_s, x, u, w):
        out = np.tensordot(H, x, axes=1)
        return out if w is None else out + w

    process = ProcessModel(
        f, 3, Q, additive_noise_cov=G @ Q @ G.T + state_noise, state_noise_cov=at_start,
        consider_idx=consider,
    )  # fmt: skip
    return process, MeasurementModel(g, R, name="position")


def _schmidt_reference(x0, P0, zs, consider: bool):
    x, P = x0.copy(), P0.copy()
    Qd = G @ Q @ G.T + np.diag([0.0, 0.0, Q_BIAS])
    out = []
    for z in zs:
        x = F @ x
        P = F @ P @ F.T + Qd
        S = H @ P @ H.T + R
        K = P @ H.T @ np.linalg.inv(S)
        if consider:
            K[2, :] = 0.0
        x = x + K @ (z - H @ x)
        A = np.eye(3) - K @ H
        P = A @ P @ A.T + K @ R @ K.T
        out.append((x.copy(), P.copy()))
    return out


@pytest.mark.parametrize("noise_form", ["augmented", "additive"])
@pytest.mark.parametrize(
    "scheme", [JulierSigmaPoints(0.0), ScaledSigmaPoints(0.01, 2.0, 0.0)], ids=["julier", "scaled"]
)
def test_consider_state_ukf_equals_the_schmidt_kalman_filter(noise_form, scheme) -> None:
    rng = np.random.default_rng(7)
    truth_v = 3.0
    zs = [np.array([truth_v * DT_S * (k + 1) + 2.0 + rng.normal(0.0, 0.5)]) for k in range(80)]
    x0 = np.array([0.0, 2.0, 0.0])
    P0 = np.diag([1.0, 4.0, 16.0])
    P0[0, 2] = P0[2, 0] = -0.5
    reference = _schmidt_reference(x0, P0, zs, consider=True)
    process, model = _models((2,))
    ukf = UnscentedKalmanFilter(process, scheme, noise_form)
    est = ukf.initial_estimate(0.0, x0, P0)
    for k, z in enumerate(zs):
        est = ukf.step(est, DT_S * (k + 1), np.zeros(0), Measurement(z, model))
        x_ref, P_ref = reference[k]
        np.testing.assert_allclose(est.mean[0], x_ref, rtol=1e-8, atol=1e-9)
        np.testing.assert_allclose(est.cov[0], P_ref, rtol=1e-8, atol=1e-9)
    assert abs(est.mean[0][2]) < 1e-12  # never moved by a measurement
    # its variance is the Gauss-Markov process's own, as if nothing were measured
    var_b = 16.0
    for _ in zs:
        var_b = F[2, 2] ** 2 * var_b + Q_BIAS
    assert est.cov[0][2, 2] == pytest.approx(var_b, rel=1e-12)


def test_consider_differs_from_estimating_the_state() -> None:
    """The optimal filter moves the bias and shrinks its variance; the Schmidt one does not."""
    rng = np.random.default_rng(3)
    zs = [np.array([0.3 * (k + 1) + rng.normal(0.0, 0.5)]) for k in range(40)]
    x0, P0 = np.zeros(3), np.diag([1.0, 4.0, 16.0])
    optimal = _schmidt_reference(x0, P0, zs, consider=False)[-1]
    process, model = _models(())
    ukf = UnscentedKalmanFilter(process, JulierSigmaPoints(0.0))
    est = ukf.initial_estimate(0.0, x0, P0)
    for k, z in enumerate(zs):
        est = ukf.step(est, DT_S * (k + 1), np.zeros(0), Measurement(z, model))
    np.testing.assert_allclose(est.mean[0], optimal[0], rtol=1e-8, atol=1e-9)
    assert est.mean[0][2] != 0.0
    consider = _schmidt_reference(x0, P0, zs, consider=True)[-1]
    assert consider[1][2, 2] > optimal[1][2, 2]
    # the Schmidt filter's position variance is larger: it never learns the bias away
    assert consider[1][0, 0] > optimal[1][0, 0]


def test_consider_indices_are_checked() -> None:
    process, _ = _models(())
    with pytest.raises(ValueError, match="consider_idx"):
        ProcessModel(process.f, 3, Q, consider_idx=(3,))
    with pytest.raises(ValueError, match="consider_idx"):
        ProcessModel(process.f, 3, Q, consider_idx=(1, 1))
