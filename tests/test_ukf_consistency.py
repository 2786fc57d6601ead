"""Statistical consistency (NEES, NIS) of the UKF on range-bearing tracking, 60 seeded runs."""

import numpy as np
import pytest
import scipy.stats
from toy_systems import constant_velocity, range_bearing_model, simulate_target

from immukf_sitl.estimation import Measurement, UnscentedKalmanFilter

N_RUNS = 60
N_STEPS = 80


def _monte_carlo(noise_form):
    sys = constant_velocity()
    model = range_bearing_model()
    ukf = UnscentedKalmanFilter(sys.process(), noise_form=noise_form)
    rng = np.random.default_rng(20261123)
    x0_true_mean = np.array([2000.0, 1500.0, -10.0, 12.0])
    P0 = np.diag([30.0**2, 30.0**2, 3.0**2, 3.0**2])
    nees = np.empty((N_RUNS, N_STEPS))
    nis = np.empty((N_RUNS, N_STEPS))
    for run in range(N_RUNS):
        x_true0 = x0_true_mean + np.linalg.cholesky(P0) @ rng.standard_normal(4)
        xs, zs = simulate_target(rng, sys, x_true0, N_STEPS)
        est = ukf.initial_estimate(0.0, x0_true_mean, P0)
        for k in range(N_STEPS):
            est = ukf.step(est, 0.1 * (k + 1), np.zeros(0), Measurement(zs[k], model))
            x, P = est.mean, est.cov
            err = xs[k] - x[0]
            nees[run, k] = err @ np.linalg.solve(P[0], err)
            nis[run, k] = est.nis[0]
    return nees, nis


@pytest.mark.parametrize("noise_form", ["augmented", "additive"])
def test_average_nees_and_nis_lie_in_their_95_percent_bands(noise_form):
    nees, nis = _monte_carlo(noise_form)
    for values, dof in ((nees, 4), (nis, 2)):
        # per time step: N_RUNS * mean ~ chi2(N_RUNS * dof)
        lo, hi = scipy.stats.chi2.ppf([0.025, 0.975], N_RUNS * dof) / N_RUNS
        per_step = values.mean(axis=0)
        inside = np.mean((per_step >= lo) & (per_step <= hi))
        # 95 % expected; a biased or overconfident filter falls far below
        assert inside >= 0.88, (dof, inside, per_step.min(), per_step.max())
        # the time average too (steps are correlated, so it gets the single-step band)
        assert lo <= per_step.mean() <= hi, (dof, per_step.mean())
