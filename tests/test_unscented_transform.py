"""The unscented transform against closed-form Gaussian moments."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from immukf_sitl.estimation import JulierSigmaPoints, ScaledSigmaPoints
from immukf_sitl.estimation.sigma_points import sigma_points, unscented_transform


def _transform(mean, cov, fn, scheme):
    n = mean.size
    weights = scheme.weights(n)
    points = sigma_points(mean[None], np.linalg.cholesky(cov)[None], weights.spread)
    y_mean, y_cov, _ = unscented_transform(fn(points), weights)
    return y_mean[0], y_cov[0]


def test_quadratic_map_of_scalar_gaussian_is_exact_in_mean_and_covariance():
    # y = [a + b x + c x^2, d x + e x^2] with x ~ N(m, s^2); kappa = 3 - n matches E[x^4]
    m, s = 0.7, 1.3
    a, b, c, d, e = 0.5, -1.2, 0.8, 2.0, -0.3

    def fn(x):
        return np.stack([a + b * x[0] + c * x[0] ** 2, d * x[0] + e * x[0] ** 2])

    # raw moments of N(m, s^2)
    m1, m2 = m, m**2 + s**2
    m3 = m**3 + 3 * m * s**2
    m4 = m**4 + 6 * m**2 * s**2 + 3 * s**4
    mean1 = a + b * m1 + c * m2
    mean2 = d * m1 + e * m2
    e11 = a**2 + 2 * a * b * m1 + (b**2 + 2 * a * c) * m2 + 2 * b * c * m3 + c**2 * m4
    e22 = d**2 * m2 + 2 * d * e * m3 + e**2 * m4
    e12 = a * d * m1 + (a * e + b * d) * m2 + (b * e + c * d) * m3 + c * e * m4
    expected_cov = np.array(
        [[e11 - mean1**2, e12 - mean1 * mean2], [e12 - mean1 * mean2, e22 - mean2**2]]
    )
    y_mean, y_cov = _transform(np.array([m]), np.array([[s**2]]), fn, JulierSigmaPoints(2.0))
    np.testing.assert_allclose(y_mean, [mean1, mean2], rtol=1e-12)
    np.testing.assert_allclose(y_cov, expected_cov, rtol=1e-12)


def test_scaled_form_with_beta_2_matches_the_same_quadratic_covariance():
    # alpha = 1, kappa = 3 - n, beta = 0 reduces to the kappa form; beta=2 adds (1-a^2+b) on W0c
    m, s = -0.4, 0.9

    def fn(x):
        return x**2

    y_mean, y_cov = _transform(
        np.array([m]), np.array([[s**2]]), fn, ScaledSigmaPoints(1.0, 0.0, 2.0)
    )
    assert y_mean[0] == pytest.approx(m**2 + s**2, rel=1e-12)
    assert y_cov[0, 0] == pytest.approx(4 * m**2 * s**2 + 2 * s**4, rel=1e-12)


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(1, 6),
    kappa=st.floats(0.0, 5.0),
)
def test_mean_of_any_quadratic_form_is_exact(seed, n, kappa):
    # E[x' C x + b' x] = m' C m + tr(C P) + b' m for every kappa (symmetric sigma sets)
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n))
    P = A @ A.T + 0.1 * np.eye(n)
    m = rng.normal(size=n)
    C = rng.normal(size=(n, n))
    b = rng.normal(size=n)

    def fn(x):
        flat = x.reshape(n, -1)
        return (np.einsum("is,ij,js->s", flat, C, flat) + b @ flat).reshape(1, *x.shape[1:])

    y_mean, _ = _transform(m, P, fn, JulierSigmaPoints(kappa))
    assert y_mean[0] == pytest.approx(m @ C @ m + np.trace(C @ P) + b @ m, rel=1e-9, abs=1e-9)


def test_linear_map_is_exact_for_every_scheme():
    rng = np.random.default_rng(3)
    n = 5
    A = rng.normal(size=(n, n))
    P = A @ A.T + np.eye(n)
    m = rng.normal(size=n)
    M = rng.normal(size=(3, n))
    for scheme in (JulierSigmaPoints(0.0), JulierSigmaPoints(2.0), ScaledSigmaPoints(0.3, 2, 1)):
        y_mean, y_cov = _transform(m, P, lambda x, M=M: np.tensordot(M, x, axes=1), scheme)
        np.testing.assert_allclose(y_mean, M @ m, rtol=1e-10)
        np.testing.assert_allclose(y_cov, M @ P @ M.T, rtol=1e-10)


def test_weights_sum_to_one_and_reject_degenerate_parameters():
    for scheme in (JulierSigmaPoints(0.0), JulierSigmaPoints(-2.0), ScaledSigmaPoints(1e-3)):
        w = scheme.weights(7)
        assert w.mean_weights.sum() == pytest.approx(1.0)
        assert len(w.mean_weights) == 15
    with pytest.raises(ValueError, match="n \\+ kappa <= 0"):
        JulierSigmaPoints(kappa=-3.0).weights(3)


def test_circular_mean_of_angles_across_pi():
    # sigma points of a heading near +pi straddle the cut; the mean must stay near pi
    weights = JulierSigmaPoints(1.0).weights(1)
    mean = np.array([[np.pi - 0.01]])
    points = sigma_points(mean, np.array([[[0.05]]]), weights.spread)
    points = (points + np.pi) % (2 * np.pi) - np.pi  # what a model returning wrapped angles gives
    y_mean, y_cov, _ = unscented_transform(points, weights, angle_idx=(0,))
    assert abs(((y_mean[0, 0] - (np.pi - 0.01)) + np.pi) % (2 * np.pi) - np.pi) < 1e-12
    assert y_cov[0, 0, 0] == pytest.approx(0.05**2, rel=1e-9)
