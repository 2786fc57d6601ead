"""The bank about a declared set: its modes, chain, references, offsets and failure weights,
each against a direct computation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq
from scipy.stats import norm

from immukf_sitl.estimation import (
    ChannelOffset,
    DeadOrAnyEvidence,
    FaultMode,
    bank_modes,
    failure_marginals,
    fault_mode_noise_var,
    single_fault_modes,
)
from immukf_sitl.estimation.fault_modes import (
    DRIFT_PRIOR_VAR,
    FAILURE_PRIOR,
    FAILURE_WAYS,
    FAILURE_WEIGHT_FLOOR,
    GAIN_PRIOR_VAR,
    NOISE_FACTORS,
    NOISE_WAY,
    OFFSET_PRIOR_VAR,
    OUTLIER_SHARE,
    STUCK_SIGMAS,
    reference_slots,
)
from immukf_sitl.models.earth import NedOrigin
from immukf_sitl.models.params import load_aircraft_params
from immukf_sitl.models.sensors import ImuSpec
from immukf_sitl.service.filter_models import PaperModel, RealAirModel
from immukf_sitl.service.filters import build_estimator

P = FaultMode.from_name("p")


def test_the_bank_about_nothing_is_the_papers():
    assert bank_modes() == single_fault_modes()
    assert bank_modes(FaultMode(0)) == single_fault_modes()


def test_the_bank_about_a_declared_set_changes_one_channel_a_slot():
    modes = bank_modes(P)
    assert [m.name for m in modes] == ["p", "x+p", "y+p", "z+p", "none", "p+q", "p+r"]
    # each slot trusts its changed channel in its reference: the slot without that channel
    ref = reference_slots(modes)
    pairs = [(j, i) for j, m in enumerate(modes) for i in range(6) if m.bits >> i & 1]
    for (j, i), k in zip(pairs, ref, strict=True):
        assert not modes[k].bits >> i & 1
        target = modes[j].bits & ~(1 << i)
        if target in [m.bits for m in modes]:
            assert modes[k].bits == target
    np.testing.assert_array_equal(reference_slots(single_fault_modes()), np.zeros(6))


def test_failure_marginals_sum_the_modes_that_hold_each_channel():
    modes = bank_modes(P)
    probs = np.array([0.6, 0.05, 0.05, 0.05, 0.1, 0.1, 0.05])
    got = failure_marginals(modes, probs)
    assert got[0] == pytest.approx(0.1)  # only "none" has no failure
    assert got[4] == pytest.approx(0.9)  # p: every slot but "none"
    assert got[5] == pytest.approx(0.1)  # q: "p+q"
    single = np.array([0.4, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1])
    np.testing.assert_allclose(failure_marginals(single_fault_modes(), single), single)


@pytest.mark.parametrize("model", [PaperModel(), RealAirModel()])
@pytest.mark.parametrize("declared", [None, P, FaultMode.from_name("x+q")])
def test_the_chain_hubs_on_the_base_slot(model, declared):
    modes = bank_modes(declared)
    t = model.transition(modes)
    np.testing.assert_allclose(t.sum(axis=1), 1.0)
    eps, delta = model.onset_probability, model.recovery_probability
    np.testing.assert_allclose(t[0, 1:], eps)
    np.testing.assert_allclose(t[1:, 0], delta)
    prior = model.prior_probabilities(modes, t)
    assert np.argmax(prior) == 0 and prior.sum() == pytest.approx(1.0)


def test_an_offset_is_read_on_failed_channels_only_and_trusted_ones_rest_at_prior():
    modes = bank_modes(P)
    ranges = ImuSpec().ranges
    offset = ChannelOffset(modes, ranges, index=3, walk_var=1e-9)
    rng = np.random.default_rng(1)
    x = rng.normal(0.0, 0.1, (9, 7, 5))
    added = offset.output(x)
    for j, mode in enumerate(modes):
        for i in range(6):
            expected = ranges[i] * x[3 + i, j] if mode.bits >> i & 1 else 0.0
            np.testing.assert_allclose(added[i, j], expected)
    means = rng.normal(0.0, 0.1, (7, 9))
    covs = np.tile(np.eye(9) * 0.01, (7, 1, 1))
    m2, c2 = offset.reset(means, covs)
    for j, mode in enumerate(modes):
        for i in range(6):
            row = 3 + i
            if mode.bits >> i & 1:
                assert m2[j, row] == means[j, row] and c2[j, row, row] == 0.01
            else:
                assert m2[j, row] == 0.0 and c2[j, row, row] == OFFSET_PRIOR_VAR
                assert not np.any(c2[j, row, :row]) and not np.any(c2[j, :row, row])


def test_a_declared_channel_reads_its_gain_and_its_offset_moves_at_its_drift_rate():
    """The declared p (bank about p): every slot that distrusts p reads ``(1 + g) h + range e``
    on it, its offset moves by ``dt d`` a step, and the slot that trusts p again ("none") holds
    ``d`` and ``g`` at their prior; the other channels are read as before."""
    modes = bank_modes(P)
    ranges = ImuSpec().ranges
    p = 3
    offset = ChannelOffset(modes, ranges, index=3, walk_var=1e-9, tracked=(p,))
    assert offset.n_states == 8 and offset.tracked_rows(0) == (9, 10)
    rng = np.random.default_rng(2)
    x = rng.normal(0.0, 0.1, (11, 7, 5))
    healthy = rng.normal(0.0, 1.0, (6, 7, 5))
    added = offset.output(x, healthy)
    for j, mode in enumerate(modes):
        for i in range(6):
            expected = ranges[i] * x[3 + i, j] if mode.bits >> i & 1 else 0.0
            if i == p and mode.bits >> p & 1:
                expected = expected + x[10, j] * healthy[p, j]
            np.testing.assert_allclose(added[i, j], expected)
    # an accelerometer's gain is its bias in flight: a declared z reads its offset alone
    z_offset = ChannelOffset(bank_modes(FaultMode.from_name("z")), ranges, 3, 1e-9, tracked=(2,))
    plain = ChannelOffset(bank_modes(FaultMode.from_name("z")), ranges, 3, 1e-9)
    np.testing.assert_array_equal(z_offset.output(x, healthy), plain.output(x[:9]))
    out = np.full(x.shape, np.nan)
    offset.fly(x, out, 0.01)
    expected = x[3:11].copy()
    expected[p] += 0.01 * x[9]
    np.testing.assert_allclose(out[3:11], expected)
    assert np.isnan(out[:3]).all()  # the model's own states are the model's to fly
    walk = offset.walk(0.01)
    np.testing.assert_allclose(walk[:6], 1e-9)
    assert walk[6] / DRIFT_PRIOR_VAR == pytest.approx(walk[7] / GAIN_PRIOR_VAR)
    means = rng.normal(0.0, 0.1, (7, 11))
    covs = np.tile(np.eye(11) * 0.01, (7, 1, 1))
    m2, c2 = offset.reset(means, covs)
    trusting = modes.index(FaultMode(0))
    for j in range(7):
        for row, prior in ((9, DRIFT_PRIOR_VAR), (10, GAIN_PRIOR_VAR)):
            if j == trusting:
                assert m2[j, row] == 0.0 and c2[j, row, row] == prior
                assert not np.any(c2[j, row, :row])
            else:
                assert m2[j, row] == means[j, row] and c2[j, row, row] == 0.01


def test_a_named_channels_drift_rate_and_gain_are_read_as_the_values_its_name_knows():
    """p declared, its drift rate known to be 0.002 and its gain -1: the offsets read those
    values whatever the states hold (a slot that distrusts p predicts ``range e`` whatever the
    state's rate, and its offset moves by ``dt 0.002``), and every slot keeps the two states
    at those values and their prior variance, unread and uncorrelated; let go, they are
    learnt from there."""
    modes = bank_modes(P)
    ranges = ImuSpec().ranges
    p = 3
    learnt = ChannelOffset(modes, ranges, index=3, walk_var=1e-9, tracked=(p,))
    known = learnt.holding({p: (0.002, -1.0), 0: (0.0, 0.0)})  # x is not tracked: not held
    assert known.held == ((9, 0.002), (10, -1.0))
    np.testing.assert_array_equal(known.walk(0.01), learnt.walk(0.01))
    rng = np.random.default_rng(5)
    x = rng.normal(0.0, 0.1, (11, 7, 4))
    healthy = rng.normal(0.0, 1.0, (6, 7, 4))
    predicted = healthy + known.output(x, healthy)
    for j, mode in enumerate(modes):
        if mode.bits >> p & 1:  # the offset alone, none of the state's rate
            np.testing.assert_allclose(predicted[p, j], ranges[p] * x[3 + p, j], atol=1e-12)
        else:
            np.testing.assert_array_equal(predicted[p, j], healthy[p, j])
    out = np.full(x.shape, np.nan)
    known.fly(x, out, 0.01)
    np.testing.assert_allclose(out[3 + p], x[3 + p] + 0.01 * 0.002)
    np.testing.assert_array_equal(out[9:11], x[9:11])
    means = rng.normal(0.0, 0.1, (7, 11))
    covs = np.tile(np.eye(11) * 0.01 + 0.001, (7, 1, 1))
    m2, c2 = known.reset(means, covs)
    np.testing.assert_array_equal(m2[:, 9:11], np.tile([0.002, -1.0], (7, 1)))
    for row, prior in ((9, DRIFT_PRIOR_VAR), (10, GAIN_PRIOR_VAR)):
        expected = np.zeros((7, 11))
        expected[:, row] = prior
        np.testing.assert_array_equal(c2[:, row, :], expected)
        np.testing.assert_array_equal(c2[:, :, row], expected)
    drift = learnt.holding({p: (None, -1.0)})  # the rate let go: read from the state again
    assert drift.held == ((10, -1.0),)
    drift.fly(x, out, 0.01)
    np.testing.assert_allclose(out[3 + p], x[3 + p] + 0.01 * x[9])
    m3, _ = drift.reset(m2, c2)
    assert m3[0, 9] == 0.002  # learnt from the value it was known at


@pytest.mark.parametrize("name", ["paper", "real-air"])
def test_a_declaration_adds_the_channels_drift_rate_and_gain_and_a_release_drops_them(name):
    """nx grows by two per declared channel; the states both layouts hold move with their
    covariances, a newly declared channel's two start at their prior."""
    import dataclasses

    from immukf_sitl.service.filters import VariantEstimate

    model = (PaperModel if name == "paper" else RealAirModel)(fault_signature="untrusted")
    bank = build_estimator(
        "imm", load_aircraft_params(), NedOrigin(47.4, 8.5, 150.0), filter_model=model
    )
    n = bank.imm.ukf.process.nx
    rng = np.random.default_rng(9)
    q = FaultMode.from_name("p+q")

    def estimate(b, seed_means):
        m = b.imm.ukf.process.nx
        a = rng.normal(0.0, 0.1, (m, m))
        cov = a @ a.T + np.eye(m)
        start = b.imm.initial_estimate(0.0, seed_means[0], cov, b.prior_probabilities())
        filt = dataclasses.replace(start, mode_means=seed_means, mode_covs=np.tile(cov, (7, 1, 1)))
        return VariantEstimate(0.0, filt, np.zeros(4), np.zeros(6))

    est = estimate(bank, rng.normal(0.0, 0.01, (7, n)))
    on_p = bank.rebased(P)
    assert on_p.imm.ukf.process.nx == n + 2
    moved = on_p.carried_over(est, bank).filter
    assert moved.mode_means.shape == (7, n + 2) and moved.mean.shape == (n + 2,)
    kept = [*range(n - 6), n - 6 + 3]  # the model's states and p's offset
    np.testing.assert_allclose(
        moved.mode_covs[0][np.ix_(kept, kept)], est.filter.mode_covs[4][np.ix_(kept, kept)]
    )
    np.testing.assert_allclose(
        moved.mode_covs[0, n:, n:], np.diag([DRIFT_PRIOR_VAR, GAIN_PRIOR_VAR])
    )
    assert not np.any(moved.mode_covs[0, n:, :n])
    # a second channel: p's two keep what they learnt, q's start at the prior
    est2 = estimate(on_p, rng.normal(0.0, 0.01, (7, n + 2)))
    on_pq = on_p.rebased(q)
    assert on_pq.dynamics.offset.tracked == (3, 4) and on_pq.imm.ukf.process.nx == n + 4
    pq_slot = on_p.modes.index(q)
    moved2 = on_pq.carried_over(est2, on_p).filter
    kept += [n - 6 + 4, n, n + 1]  # and q's offset, p's drift rate and gain
    np.testing.assert_allclose(moved2.mode_means[0, kept], est2.filter.mode_means[pq_slot, kept])
    np.testing.assert_allclose(
        moved2.mode_covs[0][np.ix_(kept, kept)], est2.filter.mode_covs[pq_slot][np.ix_(kept, kept)]
    )
    np.testing.assert_allclose(moved2.mode_means[0, n + 2 :], 0.0)
    np.testing.assert_allclose(
        np.diagonal(moved2.mode_covs[0])[n + 2 :], [DRIFT_PRIOR_VAR, GAIN_PRIOR_VAR]
    )
    # released again: the state is the model's and six offsets, as before any declaration
    back = on_p.rebased(None)
    assert back.imm.ukf.process.nx == n
    released = back.carried_over(est2, on_p).filter
    source = est2.filter.mode_means[on_p.modes.index(FaultMode(0))]
    np.testing.assert_allclose(released.mode_means[0, : n - 6], source[: n - 6])
    np.testing.assert_allclose(released.mode_means[0, n - 6 :], 0.0)  # all trusted: at prior
    assert back.imm.ukf.diagnostics is bank.imm.ukf.diagnostics


def _evidence(modes):
    imu = ImuSpec()
    offset = ChannelOffset(modes, imu.ranges, index=0, walk_var=1e-9)
    width = fault_mode_noise_var(modes, "untrusted", imu.ranges)
    return DeadOrAnyEvidence(modes, imu.sigmas**2, width, offset=offset), imu


def test_failure_weights_are_the_bayes_posterior_of_the_ways_to_fail():
    """One step against a direct computation: the channel's factor is the predictive mixture
    of the four ways to fail at the mode's weights, and the weights become its posterior."""
    modes = single_fault_modes()
    evidence, imu = _evidence(modes)
    q, slot = 4, 5
    z = np.array([0.0, 0.0, -9.8, 0.0, 0.0, 0.0])
    z[q] = 0.03  # the q reading
    previous = z.copy()
    previous[q] = 0.03 + 0.1 * imu.sigmas[q]  # it moved a tenth of a sigma: stuck-like
    nu = np.zeros((7, 6))
    cov = np.tile(np.diag(imu.sigmas**2 * 4.0), (7, 1, 1))
    nu[0, q] = z[q] - 0.2  # the fault-free mode predicts 0.2 rad/s
    nu[slot, q] = 0.01  # the q mode's offset explains the reading to 0.01
    mean = np.zeros((7, 6))  # offsets (the evidence's index 0): the q mode's learnt one
    mean[slot, q] = -0.17 / imu.ranges[q]
    prior = [0.2, 0.3, 0.4, 0.1]
    weights = np.tile(np.array(prior), (7, 6, 1))
    base = np.zeros(7)
    got, updated = evidence.score(0.0, mean, nu, cov, z, None, base, weights, previous, None)
    r = imu.sigmas[q] ** 2
    s = cov[slot, q, q]
    dead = norm.logpdf(z[q], 0.0, math.sqrt(r))  # seen: the prediction is far from zero
    stuck = norm.logpdf(z[q] - previous[q], 0.0, STUCK_SIGMAS * math.sqrt(r))
    factor = norm.logpdf(nu[slot, q], 0.0, math.sqrt(s))  # the UKF's, swapped for the mixture
    anything = norm.logpdf(nu[slot, q], 0.0, math.sqrt(s + imu.ranges[q] ** 2 / 3.0))
    off = np.logaddexp(math.log1p(-OUTLIER_SHARE) + factor, math.log(OUTLIER_SHARE) + anything)
    joint = np.log(prior) + [dead, stuck, off, anything]
    predictive = np.logaddexp.reduce(joint)
    assert got[slot] == pytest.approx(predictive - factor, abs=1e-9)
    posterior = np.maximum(np.exp(joint - predictive), FAILURE_WEIGHT_FLOOR)
    np.testing.assert_allclose(updated[slot, q], posterior / posterior.sum(), atol=1e-12)
    assert updated[slot, q, 1] > 0.98  # a reading that held still where it should have moved
    np.testing.assert_array_equal(updated[0], weights[0])  # the fault-free mode: untouched


def test_a_noisy_channel_is_scored_at_its_noise_factor_and_its_weights_find_the_factor():
    """One step against a direct computation of all eight ways (the noise ways
    ``N(nu; 0, S + (k^2 - 1) R)``), then a channel whose noise is 8 times the sensor's: its
    weights settle on the factor of 8 and the mode gains on it what the normals say."""
    modes = single_fault_modes()
    evidence, imu = _evidence(modes)
    q, slot = 4, 5
    r = imu.sigmas[q] ** 2
    cov = np.tile(np.diag(imu.sigmas**2 * 4.0), (7, 1, 1))  # a prediction 2 noise sigmas wide
    s = cov[slot, q, q]
    rng = np.random.default_rng(11)
    weights = np.tile(FAILURE_PRIOR, (7, 6, 1))
    z = np.array([0.3, 0.1, -9.8, 0.2, 0.3, 0.1])
    gained = 0.0
    for step in range(300):
        nu = rng.normal(0.0, 1.0, (7, 6)) * np.sqrt(np.diagonal(cov, axis1=1, axis2=2))
        nu[slot, q] = rng.normal(0.0, math.sqrt(s + (8.0**2 - 1.0) * r))
        z = z + rng.normal(0.0, 0.2, 6)  # far from zero and moving: dead and stuck seen
        previous = z + 0.5
        got, updated = evidence.score(
            0.0, np.zeros((7, 6)), nu, cov, z, None, np.zeros(7), weights, previous, None
        )
        if step == 0:
            dead = norm.logpdf(z[q], 0.0, math.sqrt(r))
            stuck = norm.logpdf(z[q] - previous[q], 0.0, STUCK_SIGMAS * math.sqrt(r))
            factor = norm.logpdf(nu[slot, q], 0.0, math.sqrt(s))
            anything = norm.logpdf(nu[slot, q], 0.0, math.sqrt(s + imu.ranges[q] ** 2 / 3.0))
            off = np.logaddexp(
                math.log1p(-OUTLIER_SHARE) + factor, math.log(OUTLIER_SHARE) + anything
            )
            noisy = [  # the offset way at the noise of each factor, its outliers and all
                np.logaddexp(
                    math.log1p(-OUTLIER_SHARE)
                    + norm.logpdf(nu[slot, q], 0.0, math.sqrt(s + (k**2 - 1.0) * r)),
                    math.log(OUTLIER_SHARE) + anything,
                )
                for k in NOISE_FACTORS
            ]
            joint = np.log(FAILURE_PRIOR) + np.array([dead, stuck, off, anything, *noisy])
            predictive = np.logaddexp.reduce(joint)
            assert got[slot] == pytest.approx(predictive - factor, abs=1e-9)
            posterior = np.maximum(np.exp(joint - predictive), FAILURE_WEIGHT_FLOOR)
            np.testing.assert_allclose(updated[slot, q], posterior / posterior.sum(), atol=1e-12)
        weights = updated
        gained += got[slot]  # the mixture over the UKF's healthy factor N(nu; 0, S)
    assert FAILURE_WAYS[int(np.argmax(weights[slot, q]))] == "noise x8"
    assert weights[slot, q, FAILURE_WAYS.index("noise x8")] > 0.9
    # 300 samples of a factor-8 noise over a prediction 2 sigmas wide: the x8 way against the
    # healthy one, E[ln N(nu; 0, 67 R) - ln N(nu; 0, 4 R)] = (67 / 4 - 1 - ln(67 / 4)) / 2
    # = 6.46 nats a sample; the ways' learning costs a few nats of it, once
    per_sample = (67.0 / 4.0 - 1.0 - math.log(67.0 / 4.0)) / 2.0
    assert 0.9 * 300 * per_sample < gained < 1.1 * 300 * per_sample


def test_settled_weights_cost_a_mode_its_outlier_share_where_a_fresh_mixture_costs_ln_2():
    modes = single_fault_modes()
    evidence, imu = _evidence(modes)
    rng = np.random.default_rng(3)
    cov = np.tile(np.diag(imu.sigmas**2 * 4.0), (7, 1, 1))
    weights = np.tile(FAILURE_PRIOR, (7, 6, 1))
    z = np.array([0.3, 0.1, -9.8, 0.2, 0.3, 0.1])
    costs, first = [], None
    for _ in range(400):  # an offset-like channel: readings the offset explains, far from 0
        z = z + rng.normal(0.0, 0.2, 6)
        nu = rng.normal(0.0, 1.0, (7, 6)) * np.sqrt(np.diagonal(cov, axis1=1, axis2=2))
        first = nu[5, 4] if first is None else first
        previous = z + 0.5  # it moves
        got, weights = evidence.score(
            0.0, np.zeros((7, 6)), nu, cov, z, None, np.zeros(7), weights, previous, None
        )
        costs.append(got[5])
    # the prior's price, once: the offset way's share, and the noise ways' densities beside it
    s_q, r_q = cov[5, 4, 4], imu.sigmas[4] ** 2
    noisy = [
        norm.pdf(first, scale=math.sqrt(s_q + (k**2 - 1) * r_q))
        / norm.pdf(first, scale=math.sqrt(s_q))
        for k in NOISE_FACTORS
    ]
    prior = (1 - OUTLIER_SHARE) * (FAILURE_PRIOR[2] + FAILURE_PRIOR[NOISE_WAY] * sum(noisy))
    assert costs[0] == pytest.approx(math.log(prior), abs=0.01)
    # then, once the noise ways have lost to the healthy spread (0.065 nats a sample at the
    # factor of 2), only the samples kept for outliers: ln(1 - share) a step, 0.01 nats
    # (each way at its floor adds its floor times a density ratio of about one)
    floors = 2 * len(FAILURE_WAYS) * FAILURE_WEIGHT_FLOOR
    assert costs[-1] == pytest.approx(math.log1p(-OUTLIER_SHARE), abs=floors)
    assert weights[5, 4, 2] > 0.999
    static = evidence(0.0, np.zeros((7, 6)), nu, cov, z, None, np.zeros(7))
    assert static[5] == pytest.approx(math.log(0.5), abs=1e-3)  # drawn anew: ln 2 a step


@pytest.mark.parametrize("name", ["paper", "real-air"])
def test_a_rebased_bank_carries_each_held_mode_over(name):
    model = (PaperModel if name == "paper" else RealAirModel)(fault_signature="untrusted")
    params = load_aircraft_params()
    origin = NedOrigin(47.4, 8.5, 150.0)
    bank = build_estimator("imm", params, origin, filter_model=model)
    assert bank.modes == single_fault_modes()
    n = bank.imm.ukf.process.nx
    rng = np.random.default_rng(5)
    means = rng.normal(0.0, 0.01, (7, n))
    covs = np.tile(np.eye(n) * 1e-4, (7, 1, 1))
    probs = np.array([0.04, 0.01, 0.01, 0.01, 0.9, 0.02, 0.01])
    start = bank.imm.initial_estimate(0.0, means[0], covs[0], probs)
    import dataclasses

    from immukf_sitl.service.filters import VariantEstimate

    filt = dataclasses.replace(start, mode_means=means, mode_covs=covs)
    est = VariantEstimate(0.0, filt, np.zeros(4), np.zeros(6))
    rebased = bank.rebased(P)
    moved = rebased.carried_over(est, bank).filter
    assert rebased.modes == bank_modes(P)
    # "p" was slot 4 and is now the base; "none" was the base and is now slot 4
    np.testing.assert_allclose(moved.mode_means[0, :12], means[4, :12])
    np.testing.assert_allclose(moved.mode_means[4, :12], means[0, :12])
    assert moved.mode_probabilities[0] / moved.mode_probabilities[4] == pytest.approx(0.9 / 0.04)
    # the modes new to the bank start from the base's filter, at the prior
    np.testing.assert_allclose(moved.mode_means[5, :12], means[4, :12])
    offset = rebased.dynamics.offset
    for j, mode in enumerate(rebased.modes):
        for i in range(6):
            if not mode.bits >> i & 1:
                assert moved.mode_means[j, offset.index + i] == 0.0
                assert moved.mode_covs[j, offset.index + i, offset.index + i] == OFFSET_PRIOR_VAR


class _Scored(Exception):
    """Raised by the recording bank below once it has seen what the modes are scored with."""


def test_the_unexplained_spread_scores_the_modes_before_and_after_a_declaration():
    """The spread the base's innovations show scores every bank's modes; a declared channel's
    is forgotten when the bank re-bases (its innovations measured the failure, not the air)."""
    from immukf_sitl.service.turbulence import TurbulenceEstimate

    model = RealAirModel(fault_signature="untrusted")
    bank = build_estimator(
        "imm", load_aircraft_params(), NedOrigin(47.4, 8.5, 150.0), filter_model=model
    )
    air = TurbulenceEstimate(beyond=np.full(6, 1e-3), beyond_weight=np.ones(6))
    seen = []

    class Recorder:
        def step(
            self, previous, t_next_s, u, z, process=None, previous_z=None, score_var=None,
            held_beyond_chance=None,
        ):  # fmt: skip
            seen.append(score_var)
            raise _Scored

    rebased = bank.rebased(P)
    for estimator, carried in ((bank, air), (rebased, air.forget_unexplained(P.healthy_mask == 0))):
        with pytest.raises(_Scored):
            estimator.dynamics.step(Recorder(), None, carried, 0.01, np.zeros((2, 4)), None)
    np.testing.assert_allclose(seen[0], np.full(6, 1e-3))
    np.testing.assert_allclose(seen[1], [1e-3, 1e-3, 1e-3, 0.0, 1e-3, 1e-3])
    # the paper's zero modes are scored as the paper scores them
    zero = build_estimator(
        "imm", load_aircraft_params(), NedOrigin(47.4, 8.5, 150.0),
        filter_model=RealAirModel(fault_signature="zero"),
    )  # fmt: skip
    with pytest.raises(_Scored):
        zero.dynamics.step(Recorder(), None, air, 0.01, np.zeros((2, 4)), None)
    assert seen[2] is None


def test_the_outlier_gate_keeps_out_what_the_offset_way_calls_an_outlier():
    """Against a direct computation: a sample of a channel read through its offset is kept out
    (width ``V``) where the offset way's outlier part ``s N(nu; 0, S + V)`` beats its inlier part
    ``(1 - s) N(nu; 0, S)``, about 5 sigmas of ``S`` for the gyro; only where the offset way
    leads the weights, and only on the mode's failed channel."""
    modes = single_fault_modes()
    evidence, imu = _evidence(modes)
    q, slot = 4, 5
    weights = np.tile(np.array([0.01, 0.01, 0.01, 0.97]), (7, 6, 1))  # "anything" leads
    assert evidence.outlier_gate(weights) is None
    weights[slot, q] = [0.01, 0.01, 0.97, 0.01]
    gate = evidence.outlier_gate(weights)
    s, wide = imu.sigmas[q] ** 2 * 4.0, imu.ranges[q] ** 2 / 3.0

    def outlier_odds(k: float) -> float:
        nu = k * math.sqrt(s)
        outlier = math.log(OUTLIER_SHARE) + norm.logpdf(nu, 0.0, math.sqrt(s + wide))
        return outlier - (math.log1p(-OUTLIER_SHARE) + norm.logpdf(nu, 0.0, math.sqrt(s)))

    assert (gate.filters.tolist(), gate.outputs.tolist()) == ([slot], [q])  # the rest: anything
    for k in np.linspace(-8.0, 8.0, 161):
        got = gate.widths(np.array([k * math.sqrt(s)]), np.array([s]))
        assert got.tolist() == [wide if outlier_odds(k) > 0.0 else 0.0]
    assert 4.5 < brentq(outlier_odds, 0.0, 20.0) < 5.5
    # a channel believed noisy is gated alike (its update's S is already the noisy reading's)
    ways = np.full((7, 6, len(FAILURE_WAYS)), 0.01)
    ways[:, :, 3] = 1.0 - 0.01 * (len(FAILURE_WAYS) - 1)
    assert evidence.outlier_gate(ways) is None
    ways[slot, q] = 0.01
    ways[slot, q, FAILURE_WAYS.index("noise x8")] = 1.0 - 0.01 * (len(FAILURE_WAYS) - 1)
    gate = evidence.outlier_gate(ways)
    assert (gate.filters.tolist(), gate.outputs.tolist()) == ([slot], [q])
    noisy_s = s + (8.0**2 - 1.0) * imu.sigmas[q] ** 2  # its inlier part: the reading at x8

    def noisy_odds(k: float) -> float:
        nu = k * math.sqrt(noisy_s)
        outlier = math.log(OUTLIER_SHARE) + norm.logpdf(nu, 0.0, math.sqrt(noisy_s + wide))
        return outlier - (math.log1p(-OUTLIER_SHARE) + norm.logpdf(nu, 0.0, math.sqrt(noisy_s)))

    for k in np.linspace(-8.0, 8.0, 161):
        got = gate.widths(np.array([k * math.sqrt(noisy_s)]), np.array([s]))
        assert got.tolist() == [wide if noisy_odds(k) > 0.0 else 0.0]


def test_a_declared_channel_reading_anything_is_read_with_its_weight_a_new_one_fully():
    """Against a direct computation of the update's widths: ``(w_dead + w_stuck) V`` on a newly
    failed channel, and on the declared set's channels the width that scales the channel's
    information ``1 / R`` by its offset way's weight ``1 - w`` (``R w / (1 - w)``, ``w`` that
    of dead, stuck and anything): the offset of a declared
    channel was learnt before its declaration, so "anything" there is a reading the offset
    cannot follow, while on a newly failed channel it is an offset still to learn."""
    modes = bank_modes(FaultMode.from_name("p"))
    evidence, imu = _evidence(modes)
    rng = np.random.default_rng(7)
    weights = rng.dirichlet(np.ones(len(FAILURE_WAYS)), (7, 6))
    got = evidence.widths(weights)
    wide, noise = imu.ranges**2 / 3.0, imu.sigmas**2
    floor = FAILURE_WEIGHT_FLOOR
    factors2 = np.array(NOISE_FACTORS) ** 2
    for j, mode in enumerate(modes):
        for i in range(6):
            if not mode.bits >> i & 1:
                assert got[j, i] == 0.0
                continue
            noisy = np.maximum(weights[j, i, NOISE_WAY:] - floor, 0.0)
            if i == 3:  # p: declared, in every slot that holds it
                w = weights[j, i, 0] + weights[j, i, 1] + weights[j, i, 3] - 3.0 * floor
                # the information form: 1 / (R + width) = (w_offset + sum w_k / k^2) / R
                read = 1.0 - w - noisy.sum() + np.sum(noisy / factors2)
                assert 1.0 / (noise[i] + got[j, i]) == pytest.approx(read / noise[i])
            else:  # dead and stuck unread; noise widens the likelihood only
                want = max(weights[j, i, 0] + weights[j, i, 1] - 2.0 * floor, 0.0) * wide[i]
                assert got[j, i] == pytest.approx(want, rel=1e-12)
    # a settled offset (the floors elsewhere) is read at R alone, declared or not
    settled = np.full((7, 6, len(FAILURE_WAYS)), floor)
    settled[:, :, 2] = 1.0 - (len(FAILURE_WAYS) - 1) * floor
    assert np.all(np.abs(evidence.widths(settled)) <= 1e-12 * noise.max())
    # a declared channel that reads anything for sure keeps the floors' share of its information
    anything = np.zeros((7, 6, len(FAILURE_WAYS)))
    anything[:, :, 3] = 1.0
    unread = 1.0 - 3.0 * floor
    assert evidence.widths(anything)[0, 3] == pytest.approx(noise[3] * unread / (1.0 - unread))
    # with nothing declared, "anything" widens nothing: the paper's bank learns its offsets
    fresh, _ = _evidence(single_fault_modes())
    assert np.all(fresh.widths(anything) <= 0.0)


@pytest.mark.parametrize("name", ["paper", "real-air"])
def test_a_channel_named_noisy_is_read_at_its_noise_by_the_modes_that_take_it_for_failed(name):
    """The innovation variance of p (declared, named noisy by a factor of 8) grows by exactly
    ``(8^2 - 1) R_p`` in every slot that takes p for failed, from the same prior, and not at all
    in the slot that trusts it again or on any other channel."""
    from immukf_sitl.experiments.bench import ORIGIN, initial_cov, make_flight
    from immukf_sitl.models.aero import AeroModel
    from immukf_sitl.service.filters import Observation, build_aero_estimator

    params = load_aircraft_params()
    model = AeroModel(params, ORIGIN, compiled=False)
    data = make_flight(model, 3, seed=4)
    kind = PaperModel if name == "paper" else RealAirModel
    bank = build_aero_estimator("imm", model, filter_model=kind(fault_signature="untrusted"))
    on_p = bank.rebased(P)
    start = on_p.start(0.0, *on_p.augmented(data.x0, initial_cov()), data.controls[0])
    scales = np.ones(6)
    scales[3] = 8.0**2
    plain = on_p.step(start, model.dt_s, data.controls[1], Observation(data.imu[1]))
    noisy = on_p.step(
        start, model.dt_s, data.controls[1], Observation(data.imu[1], failed_var_scale=scales)
    )
    grown = noisy.filter.innovation_var - plain.filter.innovation_var
    expected = np.zeros_like(grown)
    r_p = ImuSpec().sigmas[3] ** 2
    for j, mode in enumerate(on_p.modes):
        if mode.bits >> 3 & 1:
            expected[j, 3] = 63.0 * r_p
    assert on_p.modes[4] == FaultMode(0)  # the recovery: reads p at R
    np.testing.assert_allclose(grown, expected, rtol=1e-9, atol=1e-12 * r_p)


def test_a_rebased_bank_tests_a_further_failure_with_a_history_and_a_recovery_as_the_textbook():
    # the bank about p: the five slots that add a channel mix their history rows with floored
    # weights (eqs. 6-8, hand-computed), the recovery slot ("none") and the base as the textbook
    import dataclasses

    bank = build_estimator(
        "imm", load_aircraft_params(), NedOrigin(47.4, 8.5, 150.0),
        filter_model=RealAirModel(fault_signature="untrusted"),
    ).rebased(P)  # fmt: skip
    imm, n = bank.imm, bank.imm.ukf.process.nx
    rng = np.random.default_rng(11)
    means = rng.normal(0.0, 0.01, (7, n))
    covs = np.tile(np.eye(n) * 1e-4, (7, 1, 1))
    mu = np.array([1.0 - 6e-7, *[1e-7] * 6])  # every slot but the base far below the floor
    start = imm.initial_estimate(0.0, means[0], covs[0], mu)
    previous = dataclasses.replace(start, mode_means=means, mode_covs=covs)
    mu = np.exp(previous.log_mode_probabilities)
    _, mixed, _ = imm._mix(previous)
    rows = bank.dynamics.history_states()
    T = imm.transition
    added = np.array([bool(m.bits & ~P.bits) for m in bank.modes])
    floored = np.where(added, np.maximum(mu, bank.filter_model.history_floor), mu)
    for j, further in enumerate(added):
        seen = floored if further else mu
        weights = T[:, j] * seen / (T[:, j] @ seen)  # eq. (7)'s mu_{i|j}
        np.testing.assert_allclose(mixed[j, rows], weights @ means[:, rows], rtol=1e-6, atol=1e-7)
        assert (weights[j] > 0.5) == (further or j == 0)  # a further slot keeps its own history


def test_only_the_recovery_of_a_channel_declared_on_the_fixes_is_scored_on_them():
    # the bank about p+q, p declared on the fixes: the slot that trusts p again is scored on
    # the GPS outputs alone, the one that trusts q again and the further failures on all; a
    # named error held keeps it so
    bank = build_estimator(
        "imm", load_aircraft_params(), NedOrigin(47.4, 8.5, 150.0),
        filter_model=RealAirModel(fault_signature="untrusted"),
    ).rebased(FaultMode.from_channels(["p", "q"]), fix_scored=P)  # fmt: skip
    beyond = bank.imm._scored_beyond
    scored = [mode.name for mode, row in zip(bank.modes, beyond, strict=True) if row.any()]
    assert scored == ["q"] and beyond.shape == (7, 6)  # p+q less p
    held = bank.holding({3: (0.0, 0.0)})  # p named a bias
    assert held is not bank and held.fix_scored == P
    assert np.array_equal(held.imm._scored_beyond, beyond)
    assert bank.rebased(P).imm._scored_beyond is None
