"""The IMM: reduction to one UKF, mode switching, and zeroed-channel fault identification."""

from dataclasses import replace

import numpy as np
import pytest
from toy_systems import (
    constant_velocity,
    identity_output,
    oscillator_bank,
    range_bearing_model,
    simulate_target,
)

from immukf_sitl.estimation import (
    FaultMode,
    ImmEstimator,
    Measurement,
    MeasurementModel,
    ProcessModel,
    UnscentedKalmanFilter,
    fault_mode_output,
    single_fault_modes,
    sticky_transition,
)

SENSOR_SIGMA = 0.05
#: Steps after a switch by which the true mode's probability must exceed 0.9 (documented bound).
SWITCH_DETECTION_STEPS = 5


def test_one_mode_imm_is_exactly_the_ukf():
    sys = constant_velocity()
    model = range_bearing_model()
    rng = np.random.default_rng(11)
    _, zs = simulate_target(rng, sys, np.array([1500.0, 400.0, -5.0, 8.0]), 50)
    x0 = np.array([1490.0, 410.0, -4.0, 7.0])
    P0 = np.diag([400.0, 400.0, 4.0, 4.0])

    ukf = UnscentedKalmanFilter(sys.process())
    imm = ImmEstimator(UnscentedKalmanFilter(sys.process()), np.ones((1, 1)))
    est = imm.initial_estimate(0.0, x0, P0)
    single = ukf.initial_estimate(0.0, x0, P0)
    for k, z in enumerate(zs):
        single = ukf.step(single, 0.1 * (k + 1), np.zeros(0), Measurement(z, model))
        est = imm.step(est, 0.1 * (k + 1), np.zeros(0), Measurement(z, model))
        assert np.array_equal(est.mean, single.mean[0])
        assert np.array_equal(est.cov, single.cov[0])
        assert est.mode_probabilities[0] == 1.0
        assert est.t_s == single.t_s == 0.1 * (k + 1)


def _simulate_oscillators(rng, A, n_steps, fault_at):
    """True oscillator states and six-channel readings; ``fault_at(k)`` gives the FaultMode."""
    x = np.array([1.0, 0.3, -0.8, 0.2, 1.0, 0.6])
    zs = []
    for k in range(n_steps):
        x = A @ x + 0.01 * rng.standard_normal(6)
        reading = x * fault_at(k).healthy_mask + SENSOR_SIGMA * rng.standard_normal(6)
        zs.append(reading)
    return np.array(zs)


def _bank(modes, stay=0.99, floor=1e-4):
    process, A = oscillator_bank()
    measurement = MeasurementModel(
        fault_mode_output(identity_output, modes, "zero"), np.eye(6) * SENSOR_SIGMA**2, name="imu"
    )
    imm = ImmEstimator(UnscentedKalmanFilter(process), sticky_transition(len(modes), stay), floor)
    return imm, measurement, A


def _run(imm, measurement, zs):
    est = imm.initial_estimate(0.0, np.zeros(6), np.eye(6))
    probs = []
    for k, z in enumerate(zs):
        est = imm.step(est, 0.1 * (k + 1), np.zeros(0), Measurement(z, measurement))
        probs.append(est.mode_probabilities)
    return np.array(probs), est


def test_true_mode_probability_exceeds_0_9_within_bound_after_each_switch():
    modes = [FaultMode(0), FaultMode.from_name("q")]
    imm, measurement, A = _bank(modes)
    switches = [0, 120, 260]  # none -> q at 120 -> none at 260

    def truth(k):
        return modes[1] if 120 <= k < 260 else modes[0]

    zs = _simulate_oscillators(np.random.default_rng(5), A, 400, truth)
    probs, _ = _run(imm, measurement, zs)
    true_index = np.array([modes.index(truth(k)) for k in range(400)])
    p_true = probs[np.arange(400), true_index]
    bounds = switches[1:] + [400]
    for start, end in zip(switches, bounds, strict=False):
        segment = p_true[start:end]
        delay = int(np.argmax(segment > 0.9))
        assert segment[delay] > 0.9 and delay <= SWITCH_DETECTION_STEPS, (start, segment[:10])
        # a channel crossing zero briefly favours the zeroed mode (physics, not a bug): allow 3 %
        assert np.mean(segment[delay:] > 0.9) >= 0.97, (start, np.where(segment < 0.9))


@pytest.mark.parametrize("channel", ["x", "y", "z", "p", "q", "r"])
def test_a_zeroed_channel_is_identified_among_seven_modes(channel):
    modes = list(single_fault_modes())
    imm, measurement, A = _bank(modes)
    fault = FaultMode.from_name(channel)
    zs = _simulate_oscillators(
        np.random.default_rng(100 + fault.bits), A, 200, lambda k: fault if k >= 80 else modes[0]
    )
    probs, est = _run(imm, measurement, zs)
    assert np.mean(probs[20:80, 0] > 0.9) >= 0.95  # fault-free before
    fault_index = modes.index(fault)
    after = probs[80:, fault_index]
    delay = int(np.argmax(after > 0.9))
    assert after[delay] > 0.9 and delay <= 2 * SWITCH_DETECTION_STEPS, after[:15]
    assert np.mean(after[delay:] > 0.9) >= 0.97
    assert est.most_likely_mode == fault_index


def test_transition_matrix_convention_is_checked():
    process, _ = oscillator_bank()
    with pytest.raises(ValueError, match="rows summing to 1"):
        ImmEstimator(UnscentedKalmanFilter(process), np.array([[0.9, 0.2], [0.1, 0.9]]))
    with pytest.raises(ValueError, match="square"):
        ImmEstimator(UnscentedKalmanFilter(process), np.ones((2, 3)) / 3)


def test_probability_floor_keeps_every_mode_alive():
    modes = list(single_fault_modes())
    imm, measurement, A = _bank(modes, floor=1e-3)
    zs = _simulate_oscillators(np.random.default_rng(9), A, 100, lambda k: modes[0])
    probs, _ = _run(imm, measurement, zs)
    assert probs.min() >= 1e-3 * (1 - 1e-9)
    np.testing.assert_allclose(probs.sum(axis=1), 1.0, rtol=1e-12)


def test_a_predict_only_step_is_the_textbook_mixing_and_combination():
    # two modes, a static noise-free process: the mode-matched filters return the mixed
    # initial conditions of eqs. (6)-(8), eq. (26) without likelihoods leaves c_j, and the
    # combination is eqs. (27)-(28); all hand-computed, with a non-uniform transition matrix
    process = ProcessModel(lambda t, x, u, v: x if v is None else x + v, 6, np.zeros((6, 6)))
    T = np.array([[0.95, 0.05], [0.2, 0.8]])
    imm = ImmEstimator(UnscentedKalmanFilter(process), T)
    rng = np.random.default_rng(2)
    means = rng.normal(size=(2, 6))
    covs = np.stack([np.eye(6) * 0.5, np.eye(6) * 2.0])
    mu = np.array([0.3, 0.7])
    previous = replace(
        imm.initial_estimate(0.0, means[0], covs[0], mu), mode_means=means, mode_covs=covs
    )
    est = imm.step(previous, 0.1, np.zeros(0), None)

    c = T.T @ mu  # eq. (6)
    mix = T * mu[:, None] / c[None, :]
    for j in range(2):
        x0 = sum(mix[i, j] * means[i] for i in range(2))  # eq. (7)
        P0 = sum(mix[i, j] * (covs[i] + np.outer(means[i] - x0, means[i] - x0)) for i in range(2))
        np.testing.assert_allclose(est.mode_means[j], x0, rtol=1e-12)
        np.testing.assert_allclose(est.mode_covs[j], P0, rtol=1e-12)
    np.testing.assert_allclose(est.mode_probabilities, c, rtol=1e-12)
    x = c @ est.mode_means  # eq. (27)
    P = sum(
        c[j] * (est.mode_covs[j] + np.outer(est.mode_means[j] - x, est.mode_means[j] - x))
        for j in range(2)
    )  # eq. (28)
    np.testing.assert_allclose(est.mean, x, rtol=1e-12)
    np.testing.assert_allclose(est.cov, P, rtol=1e-12)
    assert est.t_s == 0.1 and not est.updated and est.innovations is None


def test_a_history_floor_mixes_the_fault_modes_history_rows_with_floored_weights():
    # three modes, the same static process: rows 0-3 of modes 1 and 2 are mixed as if every
    # fault mode had at least the floor's probability (hand-computed), rows 4-5 and mode 0 as
    # the textbook mixes them, and eq. (26)'s c_j is the textbook's
    process = ProcessModel(lambda t, x, u, v: x if v is None else x + v, 6, np.zeros((6, 6)))
    T = np.array([[1 - 2e-3, 1e-3, 1e-3], [1e-3, 1 - 2e-3, 1e-3], [1e-3, 1e-3, 1 - 2e-3]])
    floor, rows = 0.05, slice(0, 4)
    imm = ImmEstimator(UnscentedKalmanFilter(process), T, history_floor=floor, history_states=rows)
    textbook = ImmEstimator(UnscentedKalmanFilter(process), T)
    rng = np.random.default_rng(5)
    means = rng.normal(size=(3, 6))
    covs = np.stack([np.eye(6) * v for v in (0.5, 1.0, 2.0)])
    mu = np.array([1 - 2e-4, 1e-4, 1e-4])
    previous = replace(
        imm.initial_estimate(0.0, means[0], covs[0], mu), mode_means=means, mode_covs=covs
    )
    est = imm.step(previous, 0.1, np.zeros(0), None)
    plain = textbook.step(previous, 0.1, np.zeros(0), None)

    seen = np.array([mu[0], max(mu[1], floor), max(mu[2], floor)])
    mix = T * seen[:, None] / (T.T @ seen)[None, :]
    for j in (1, 2):
        x0 = sum(mix[i, j] * means[i] for i in range(3))  # eq. (7), floored weights
        P0 = sum(mix[i, j] * (covs[i] + np.outer(means[i] - x0, means[i] - x0)) for i in range(3))
        np.testing.assert_allclose(est.mode_means[j, rows], x0[rows], rtol=1e-12)
        np.testing.assert_allclose(est.mode_covs[j][rows, rows], P0[rows, rows])
        assert mix[j, j] > 0.9  # a mode at the floor keeps most of its own history
    np.testing.assert_allclose(est.mode_means[0], plain.mode_means[0], rtol=1e-12)
    np.testing.assert_allclose(est.mode_means[:, 4:], plain.mode_means[:, 4:], rtol=1e-12)
    np.testing.assert_allclose(est.mode_covs[:, 4:, 4:], plain.mode_covs[:, 4:, 4:])
    np.testing.assert_allclose(est.mode_probabilities, T.T @ mu, rtol=1e-12)  # eq. (26)
    # a slot left out of the history slots (a recovery) is mixed as the textbook mixes it
    recovery = ImmEstimator(
        UnscentedKalmanFilter(process), T, history_floor=floor, history_states=rows,
        history_slots=np.array([False, True, False]),
    )  # fmt: skip
    mixed = recovery.step(previous, 0.1, np.zeros(0), None)
    np.testing.assert_allclose(mixed.mode_means[2], plain.mode_means[2], rtol=1e-12)
    seen = np.array([mu[0], max(mu[1], floor), mu[2]])
    mix = T * seen[:, None] / (T.T @ seen)[None, :]
    x1 = sum(mix[i, 1] * means[i] for i in range(3))  # eq. (7), slot 1's floored weights
    np.testing.assert_allclose(mixed.mode_means[1, rows], x1[rows], rtol=1e-12)
    with pytest.raises(ValueError, match="history_slots"):
        ImmEstimator(UnscentedKalmanFilter(process), T, history_slots=np.ones(3, dtype=bool))


def test_the_process_model_gets_the_start_of_the_step_and_the_output_model_its_end():
    calls = []
    process = ProcessModel(
        lambda t, x, u, v: calls.append(("f", t)) or (x if v is None else x + v),
        2,
        np.eye(2),
        additive_noise_cov=np.eye(2),
    )
    output = MeasurementModel(
        lambda t, x, u, w: calls.append(("g", t)) or (x if w is None else x + w), np.eye(2)
    )
    for noise_form in ("augmented", "additive"):
        imm = ImmEstimator(UnscentedKalmanFilter(process, noise_form=noise_form), np.ones((1, 1)))
        est = imm.initial_estimate(1.0, np.zeros(2), np.eye(2))
        calls.clear()
        est = imm.step(est, 1.25, np.zeros(0), Measurement(np.ones(2), output))
        assert calls == [("f", 1.0), ("g", 1.25)] and est.t_s == 1.25
        calls.clear()
        est = imm.step(est, 1.5, np.zeros(0), None)
        assert calls == [("f", 1.25)] and est.t_s == 1.5


def test_rescored_likelihood_is_the_gaussian_of_the_widened_covariance():
    """``S + diag(extra)`` on the leading outputs, against scipy's multivariate normal."""
    from scipy.stats import multivariate_normal

    from immukf_sitl.estimation.imm import rescored_log_likelihood

    rng = np.random.default_rng(41)
    a = rng.normal(size=(3, 5, 5))
    cov = a @ a.transpose(0, 2, 1) + 0.1 * np.eye(5)
    nu = rng.normal(size=(3, 5))
    extra = np.array([0.5, 0.0, 2.0])
    scored, widened = rescored_log_likelihood(np.array([0.0, -np.inf, 1.0]), nu, cov, extra)
    for b in (0, 2):
        want = cov[b] + np.diag(np.concatenate([extra, [0.0, 0.0]]))
        assert widened[b] == pytest.approx(want)
        assert scored[b] == pytest.approx(multivariate_normal(np.zeros(5), want).logpdf(nu[b]))
    assert scored[1] == -np.inf  # a filter reset this step stays unlikely


def test_rest_ratios_are_the_marginals_of_the_outputs_each_mode_keeps():
    """Mode ``j`` and mode 0 on the outputs ``j`` keeps, against scipy's multivariate normal."""
    from scipy.stats import multivariate_normal

    from immukf_sitl.estimation.imm import rest_log_likelihood_ratios

    rng = np.random.default_rng(43)
    a = rng.normal(size=(4, 8, 8))
    cov = a @ a.transpose(0, 2, 1) + 0.1 * np.eye(8)
    nu = rng.normal(size=(4, 8))
    left_out = np.zeros((4, 6), dtype=bool)
    left_out[1, 0] = left_out[2, 4] = True  # mode 3 leaves nothing out
    ratios, nis, dof = rest_log_likelihood_ratios(nu, cov, left_out)
    assert dof == 7
    for j, out in ((1, 0), (2, 4)):
        keep = [i for i in range(8) if i != out]

        def marginal(b, keep=keep):
            sub = cov[b][np.ix_(keep, keep)]
            return multivariate_normal(np.zeros(len(keep)), sub).logpdf(nu[b, keep])

        assert ratios[j] == pytest.approx(marginal(j) - marginal(0))
        sub = cov[j][np.ix_(keep, keep)]
        assert nis[j] == pytest.approx(nu[j, keep] @ np.linalg.solve(sub, nu[j, keep]))
    assert ratios[0] == ratios[3] == nis[0] == nis[3] == 0.0


def test_rest_left_out_must_leave_the_base_whole_and_the_others_alike():
    process, _ = oscillator_bank()
    transition = sticky_transition(3, 0.99)
    with pytest.raises(ValueError, match="base's leaving nothing out"):
        ImmEstimator(UnscentedKalmanFilter(process), transition, rest_left_out=np.eye(3, 2) > 0)
    uneven = np.array([[0, 0], [1, 0], [1, 1]], dtype=bool)
    with pytest.raises(ValueError, match="leaves as many"):
        ImmEstimator(UnscentedKalmanFilter(process), transition, rest_left_out=uneven)


def test_a_mode_scored_beyond_the_leading_outputs_gains_only_their_marginal_ratio():
    """Its eq. (25) is the first mode's plus the ratio of the two on the other outputs (scipy)."""
    from scipy.stats import multivariate_normal

    modes = [FaultMode(0), FaultMode.from_name("x"), FaultMode.from_name("p")]
    process, _ = oscillator_bank()
    model = MeasurementModel(
        fault_mode_output(identity_output, modes, "zero"), np.eye(6) * SENSOR_SIGMA**2, name="imu"
    )
    transition = sticky_transition(3, 0.99)
    beyond = np.zeros((3, 2), dtype=bool)
    beyond[1] = True  # mode 1 is scored on outputs 2-5 alone
    scored = ImmEstimator(UnscentedKalmanFilter(process), transition, scored_beyond=beyond)
    plain = UnscentedKalmanFilter(process)
    rng = np.random.default_rng(71)
    mean, cov = rng.normal(size=6), np.eye(6) * 0.2
    z = np.array([0.0, *rng.normal(size=5)])  # channel x reads zero: mode 1's failure
    start = scored.initial_estimate(0.0, mean, cov)
    est = scored.step(start, 0.1, np.zeros(0), Measurement(z, model))

    prior = plain.initial_estimate(0.0, np.repeat(mean[None], 3, 0), np.repeat(cov[None], 3, 0))
    filtered = plain.step(prior, 0.1, np.zeros(0), Measurement(z, model))
    rest = [2, 3, 4, 5]

    def marginal(j):
        sub = filtered.innovation_cov[j][np.ix_(rest, rest)]
        return multivariate_normal(np.zeros(4), sub).logpdf(filtered.innovation[j, rest])

    expected = np.array(filtered.log_likelihood, dtype=float)
    expected[1] = expected[0] + marginal(1) - marginal(0)
    np.testing.assert_allclose(est.log_likelihoods, expected, rtol=1e-9)
    # eq. (26) from equal odds through the chain: each mode's weight exp(its eq. 25)
    weights = np.exp(expected - expected.max())
    np.testing.assert_allclose(est.mode_probabilities, weights / weights.sum(), rtol=1e-9)
    # unscored, the zero on x is mode 1's evidence and it leads; scored beyond, from the same
    # prior, it predicts outputs 2-5 as mode 0 does and gains nothing
    assert filtered.log_likelihood[1] > filtered.log_likelihood[0] + 1.0
    assert est.mode_probabilities[1] == pytest.approx(est.mode_probabilities[0], rel=1e-9)


def test_scored_beyond_flags_whole_rows_and_never_the_first_mode():
    process, _ = oscillator_bank()
    transition = sticky_transition(3, 0.99)
    with pytest.raises(ValueError, match="first mode's flagging none"):
        ImmEstimator(UnscentedKalmanFilter(process), transition, scored_beyond=np.eye(3, 2) > 0)
    partial = np.array([[0, 0], [1, 0], [0, 0]], dtype=bool)
    with pytest.raises(ValueError, match="all leading outputs or none"):
        ImmEstimator(UnscentedKalmanFilter(process), transition, scored_beyond=partial)
