"""A run of exactly repeated readings: called held only beyond the chance a healthy channel has.

The chance is checked against closed forms: a held run is called at the first length ``n``
with ``((repeats + 1) / (pairs + 2))^n`` below ``HELD_CHANCE``, and a quantised Gaussian
channel repeats its reading at the rate the normal distribution of two samples' difference
gives, and never long enough to be called held.
"""

import math

import numpy as np
from scipy.stats import norm

from immukf_sitl.estimation.failure_kernels import failure_terms
from immukf_sitl.estimation.held_readings import HELD_CHANCE, RepeatRuns

RANGES = np.array([160.0, 160.0, 160.0, 8.7, 8.7, 8.7])


def _fly(readings: np.ndarray) -> tuple[RepeatRuns, list[np.ndarray]]:
    runs, called = RepeatRuns.start(), []
    for reading in readings:
        runs = runs.after(reading, RANGES)
        called.append(runs.beyond_chance())
    return runs, called


def _first_length_beyond_chance(pairs: int) -> int:
    """The shortest run, after ``pairs`` distinct readings, whose chance is below the bound."""
    n = 1
    while ((n + 1) / (pairs + n + 2)) ** n >= HELD_CHANCE:
        n += 1
    return n


def test_a_held_channel_is_called_at_the_closed_form_length():
    rng = np.random.default_rng(7)
    healthy = rng.normal(0.0, 0.01, (1000, 6))
    held = np.repeat(healthy[-1:], 40, axis=0)
    held[:, :5] = rng.normal(0.0, 0.01, (40, 5))  # only the last channel (r) holds
    runs, called = _fly(np.vstack([healthy, held]))
    calls = np.array(called)[1000:]
    first = int(np.argmax(calls[:, 5] > 0.5)) + 1  # repeats in a row when first called
    assert first == _first_length_beyond_chance(999)
    assert 2 <= first <= 5  # a float channel: a few samples, not a second
    assert calls[:, :5].sum() == 0.0 and runs.run[5] == 40


def test_a_quantised_healthy_channel_repeats_at_its_rate_and_is_never_called():
    rng = np.random.default_rng(11)
    sigma, quantum = 0.0017, 0.001  # a gyro read in mrad/s, as RAW_IMU gives it
    readings = np.round(rng.normal(0.0, sigma, (100_000, 6)) / quantum) * quantum
    runs, called = _fly(readings)
    # two independent samples round to the same reading when both fall in one cell:
    # sum over cells of the cell's probability squared
    edges = (np.arange(-40, 41) + 0.5) * quantum
    cells = np.diff(norm.cdf(edges, 0.0, sigma))
    repeat = float(np.sum(cells**2))
    rates = runs.repeats / runs.pairs
    np.testing.assert_allclose(rates, repeat, rtol=0.05)
    assert np.array(called).sum() == 0.0
    assert runs.run.max() < 30


def test_a_reading_on_its_rail_is_not_a_held_register():
    rng = np.random.default_rng(3)
    readings = rng.normal(0.0, 0.01, (1500, 6))
    readings[1000:, 3] = RANGES[3]  # a healthy p gyro saturated for five seconds
    _, called = _fly(readings)
    assert np.array(called)[:, 3].sum() == 0.0


def test_a_missing_sample_neither_breaks_nor_extends_a_run():
    runs = RepeatRuns.start()
    for reading in np.random.default_rng(5).normal(0.0, 0.01, (500, 6)):
        runs = runs.after(reading, RANGES)
    held = runs.last.copy()
    runs = runs.after(held, RANGES)
    runs = runs.after(np.full(6, np.nan), RANGES)  # a predict-only step: no sample
    assert (runs.run == 1).all()
    runs = runs.after(held, RANGES)
    assert (runs.run == 2).all() and np.array_equal(runs.last, held)


def test_the_stuck_part_is_seen_on_a_run_beyond_chance_and_not_without_it():
    # one failed pair: mode 1 takes channel 4 (q) for failed, slot 0 trusts it; the held value
    # sits within a sigma of the prediction, so only the run can show it
    pairs = np.array([[1, 4, 0]])
    r = np.full(6, 0.01**2)
    limits = np.concatenate([r, [3.0, 0.1]])
    z = np.full(6, 0.02)
    innovation = np.zeros((2, 6))
    innovation[:, 4] = 0.005
    cov = np.tile(np.diag(np.full(6, 0.02**2)), (2, 1, 1))
    previous = z.copy()  # the reading repeats exactly
    offset = np.zeros(1)
    quiet = failure_terms(pairs, innovation, cov, z, previous, offset, limits, np.zeros(6))
    held = failure_terms(pairs, innovation, cov, z, previous, offset, limits, np.ones(6))
    assert quiet[0, 4] == 0.0 and held[0, 4] == 1.0
    reference = norm.logpdf(0.005, 0.0, 0.02)
    assert math.isclose(quiet[0, 2], reference, rel_tol=1e-12)  # unseen: the reference's
    assert math.isclose(held[0, 2], norm.logpdf(0.0, 0.0, 0.1 * 0.01), rel_tol=1e-12)
