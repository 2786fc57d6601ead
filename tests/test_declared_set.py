"""Declarations and releases over a bank re-based on the declared set (untrusted modes)."""

import math

import numpy as np
import pytest
from scipy.stats import norm

from immukf_sitl.estimation import FaultMode, bank_modes
from immukf_sitl.service.declared_set import (
    _DECISIVE_NATS,
    DeclaredSetDetector,
    NamedFailure,
    shows_life,
)
from immukf_sitl.service.detection import DetectorConfig

SIGMAS = np.array([0.0245] * 3 + [0.00227] * 3)
Q, X = 4, 0  # channel indices
VAR = np.tile(SIGMAS**2 * 4.0, (7, 1))  # each slot's prediction: 2 noise sigmas wide


def _probs(slot: int, p: float) -> np.ndarray:
    """``p`` on ``slot``, the rest on the base slot 0."""
    out = np.zeros(7)
    out[slot] = p
    out[0] += 1.0 - p
    return out


def _innovations(rng, off_sigmas: dict[tuple[int, int], float] | None = None):
    """Each slot's residual of each channel: N(0, VAR), some ``(slot, channel)`` moved off."""
    nu = rng.normal(0.0, 1.0, (7, 6)) * np.sqrt(VAR)
    for (j, i), k in (off_sigmas or {}).items():
        nu[j, i] += k * np.sqrt(VAR[j, i])
    return nu, VAR.copy()


def _imu(rng, q_radps: float = 0.05) -> np.ndarray:
    return np.array([0.5, 0.5, -9.8, 0.05, q_radps, 0.05]) + rng.normal(0.0, SIGMAS)


def test_a_channel_is_declared_only_while_it_disagrees_with_the_others():
    """Slot q at 0.99 on readings that agree with its prediction (a model error elsewhere) and
    do not read zero is not declared; once q sits 4 sigma off its prediction, it is."""
    rng = np.random.default_rng(12)
    det = DeclaredSetDetector(DetectorConfig(dwell_s=0.1, settle_s=0.0), 0.0)
    events = []
    for k in range(100):
        events += det.update(k * 0.01, _probs(5, 0.99), _imu(rng), SIGMAS, _innovations(rng))
    assert events == []
    for k in range(100, 200):
        nu = _innovations(rng, {(5, Q): 4.0})
        events += det.update(k * 0.01, _probs(5, 0.99), _imu(rng), SIGMAS, nu)
    assert [(e.kind, e.mode.name, e.declared_after.name) for e in events] == [
        ("detected", "q", "q")
    ]
    # its offset at 4 sigma: the window's mean e^2 / P reaches 10.8 (chi-square(1), 0.999) once 13
    # of the 20 samples are in (13 * 17 + 7 * 1 = 228 > 216.6)
    assert 1.0 <= events[0].t_s <= 1.19
    assert det.declared == FaultMode.from_name("q")
    assert det.modes == bank_modes(FaultMode.from_name("q"))


def _q_evidence(ratio_q: float) -> np.ndarray:
    """Slot log-likelihoods with slot q (5) ``ratio_q`` nats above the base, the rest tied."""
    out = np.full(7, -10.0)
    out[5] += ratio_q
    return out


def test_one_outlier_of_the_base_does_not_declare_a_channel():
    """Slot q learnt an offset beyond its uncertainty and leads at 0.99, but its lead over the
    base is one sample the base's Gaussian tail priced at 5.5 sigma, then ties: nothing is
    declared. The same offset with the base 1 sigma off sample after sample declares q."""
    rng = np.random.default_rng(12)
    det = DeclaredSetDetector(DetectorConfig(dwell_s=0.1, settle_s=0.0), 0.0)
    events = []
    # the one gust: the base's density at 5.5 sigma against the slot's at its own residual
    outlier = norm.logpdf(0.5) - norm.logpdf(5.5)
    for k in range(200):
        ratio = outlier if k == 50 else 0.0
        nu = _innovations(rng, {(5, Q): 4.0})
        events += det.update(
            k * 0.01, _probs(5, 0.99), _imu(rng), SIGMAS, nu, log_likelihoods=_q_evidence(ratio)
        )
    assert outlier > 14.0 and events == []
    for k in range(200, 300):
        base_nu = rng.normal(1.0, 1.0)  # the base 1 sigma off, the slot's offset explains it
        ratio = norm.logpdf(base_nu - 1.0) - norm.logpdf(base_nu)
        nu = _innovations(rng, {(5, Q): 4.0})
        events += det.update(
            k * 0.01, _probs(5, 0.99), _imu(rng), SIGMAS, nu, log_likelihoods=_q_evidence(ratio)
        )
    assert [(e.kind, e.mode.name) for e in events] == [("detected", "q")]


@pytest.mark.parametrize(("evidence", "declared"), [(False, False), (True, True)])
def test_a_noisy_channel_the_base_cannot_explain_is_declared_with_sustained_evidence(
    evidence, declared
):
    """Slot q leads at 0.99 with its offset at zero (a noise has none) and the base reads q at
    three times its predicted sigma: declared once the slot out-scores the base sample after
    sample (its density of N(0, 9 S) against the base's N(0, S)), not on the spread alone."""
    rng = np.random.default_rng(4)
    det = DeclaredSetDetector(DetectorConfig(dwell_s=0.1, settle_s=0.0), 0.0)
    events = []
    for k in range(100):
        nu, var = _innovations(rng)
        nu[0, Q] *= 3.0  # the base's residual of a noise of factor 3 over its prediction
        ratio = norm.logpdf(nu[0, Q], scale=3.0 * math.sqrt(var[0, Q])) - norm.logpdf(
            nu[0, Q], scale=math.sqrt(var[0, Q])
        )
        scores = _q_evidence(ratio if evidence else 0.0)
        events += det.update(
            k * 0.01, _probs(5, 0.99), _imu(rng), SIGMAS, (nu, var), log_likelihoods=scores
        )
    assert [(e.kind, e.mode.name) for e in events] == ([("detected", "q")] if declared else [])
    if declared:
        assert events[0].t_s <= 0.3  # the dwell and one window


@pytest.mark.parametrize(("ratio", "declared"), [(0.35, False), (0.38, True)])
def test_the_sustained_evidence_is_the_signature_quantile_over_the_window(ratio, declared):
    """Constant evidence: 19 of the 20 samples must carry ln(q / (1 - q)) = 6.907 nats."""
    rng = np.random.default_rng(3)
    cfg = DetectorConfig(dwell_s=0.0, settle_s=0.0)
    assert math.log(cfg.signature_quantile / (1 - cfg.signature_quantile)) == pytest.approx(
        6.907, abs=1e-3
    )
    det = DeclaredSetDetector(cfg, 0.0)
    events = []
    for k in range(cfg.signature_window):
        nu = _innovations(rng, {(5, Q): 4.0})
        events += det.update(
            k * 0.01, _probs(5, 0.99), _imu(rng), SIGMAS, nu, log_likelihoods=_q_evidence(ratio)
        )
    assert bool(events) is declared


def test_a_second_failure_is_declared_beside_the_first():
    """With q declared, the slot q+x at 0.99 and the x accelerometer reading zero declares x
    too: the first declaration masks nothing."""
    rng = np.random.default_rng(4)
    det = DeclaredSetDetector(DetectorConfig(dwell_s=0.0, settle_s=0.0), 0.0, FaultMode(1 << Q))
    dead_x = _imu(rng)
    dead_x[X] = rng.normal(0.0, SIGMAS[X])
    events = []
    for k in range(25):
        reading = _imu(rng)
        reading[X] = rng.normal(0.0, SIGMAS[X])
        events += det.update(k * 0.01, _probs(1, 0.99), reading, SIGMAS, _innovations(rng))
    assert [(e.kind, e.mode.name, e.declared_after.name) for e in events] == [
        ("detected", "x", "x+q")
    ]
    assert det.modes[0] == FaultMode.from_name("x+q")


def test_a_release_needs_life_relative_to_the_named_failure():
    """q declared and named stuck at 0.05 rad/s: readings that agree with a prediction near the
    held value are no life, whatever the release slot's probability; readings that agree while
    the prediction is far from it are, and after the clear dwell the channel is released."""
    rng = np.random.default_rng(8)
    cfg = DetectorConfig(dwell_s=0.0, settle_s=0.0, clear_dwell_s=0.5)
    det = DeclaredSetDetector(cfg, 0.0, FaultMode(1 << Q))
    det.named(Q, "stuck", 0.05, 0.0)
    release = 1 + Q  # slot D - q
    events = []
    for k in range(200):  # the aircraft holds q = 0.05: the stuck value agrees, but proves nothing
        events += det.update(k * 0.01, _probs(release, 0.99), _imu(rng), SIGMAS, _innovations(rng))
    assert events == []
    for k in range(200, 300):  # a pull-up: q = 0.3, read and predicted alike
        nu = _innovations(rng)
        events += det.update(k * 0.01, _probs(release, 0.99), _imu(rng, 0.3), SIGMAS, nu)
    assert [(e.kind, e.mode.name) for e in events] == [("cleared", "q")]
    assert events[0].declared_after == FaultMode(0)
    assert det.declared is None and det.modes == bank_modes(None)


def test_life_decays():
    """Three readings of life long ago count for less than three now: no release on them."""
    rng = np.random.default_rng(9)
    cfg = DetectorConfig(dwell_s=0.0, settle_s=0.0, clear_dwell_s=0.5)
    det = DeclaredSetDetector(cfg, 0.0, FaultMode(1 << Q))
    det.named(Q, "zero", None, 0.0)
    events = []
    for k in range(3):  # life, while the release slot is not yet believed
        events += det.update(k * 0.01, _probs(0, 1.0), _imu(rng, 0.3), SIGMAS, _innovations(rng))
    for k in range(3, 400):  # then a believed release on a q that reads zero-like values
        reading = _imu(rng, 0.0)
        events += det.update(k * 0.01, _probs(1 + Q, 0.99), reading, SIGMAS, _innovations(rng))
    assert events == []
    # with no decay the three would have released it: the count is what decays
    assert det._life[Q] < 0.01


def test_split_evidence_is_said_once_as_cannot_isolate():
    rng = np.random.default_rng(10)
    det = DeclaredSetDetector(DetectorConfig(dwell_s=0.1, settle_s=0.0), 0.0)
    split = np.array([0.02, 0.49, 0.49, 0.0, 0.0, 0.0, 0.0])
    events = []
    for k in range(50):
        events += det.update(k * 0.01, split, _imu(rng), SIGMAS, _innovations(rng))
    assert [(e.kind, e.mode.name) for e in events] == [("unisolated", "x+y")]
    assert events[0].text().startswith("IMM: cannot isolate fault: x or y")


@pytest.mark.parametrize(
    ("kind", "size", "reading", "expected"),
    [
        ("zero", None, 0.3, True),
        ("zero", None, 0.001, False),
        ("stuck", 0.05, 0.3, True),
        ("stuck", 0.05, 0.051, False),
        ("bias", 0.1, 0.3, True),
        ("noise", 3.0, 0.0, True),
        (None, None, 0.3, False),
    ],
)
def test_life_is_a_reading_the_named_failure_would_not_give(kind, size, reading, expected):
    assert shows_life(NamedFailure(kind, size, 0.0), reading, SIGMAS[Q], 5.0) is expected


def test_no_life_before_the_failure_is_named():
    """Agreement says nothing until it is known what the failure would read."""
    rng = np.random.default_rng(2)
    cfg = DetectorConfig(dwell_s=0.0, settle_s=0.0, clear_dwell_s=0.1)
    det = DeclaredSetDetector(cfg, 0.0, FaultMode(1 << Q))
    events = []
    for k in range(100):
        events += det.update(
            k * 0.01, _probs(1 + Q, 0.99), _imu(rng, 0.3), SIGMAS, _innovations(rng)
        )
    assert events == [] and det._life[Q] == 0.0


def _outliers(*pairs: tuple[int, int]) -> np.ndarray:
    """The ``(slot, channel)`` samples the bank kept out of its update as outliers."""
    out = np.zeros((7, 6), dtype=bool)
    for j, i in pairs:
        out[j, i] = True
    return out


def test_a_spike_train_is_declared_at_its_second_spike_and_not_released_between_spikes():
    """Slot q at 0.99 on a channel its offset explains between spikes: an outlier its gate kept
    out is a spike only where the base paid for it (the slot 6.9 nats ahead on that sample:
    a gust's 5-sigma tail costs both alike); the first spike could be one tail sample, the
    second declares. Declared and named, an offset of zero between spikes is no recovery; once
    the spikes stop it is, after the clear dwell."""
    rng = np.random.default_rng(5)
    cfg = DetectorConfig(dwell_s=0.1, settle_s=0.0, clear_dwell_s=1.0)
    det = DeclaredSetDetector(cfg, 0.0)
    events = []
    for k in range(100):
        spike = _outliers((5, Q)) if k in (20, 30, 50, 80) else _outliers()
        ratio = _q_evidence(6.8 if k in (20, 50) else 6.95 if k in (30, 80) else 0.0)
        nu = _innovations(rng)
        events += det.update(k * 0.01, _probs(5, 0.99), _imu(rng), SIGMAS, nu, None, ratio, spike)
    assert [(e.kind, e.mode.name, round(e.t_s, 2)) for e in events] == [("detected", "q", 0.8)]
    det.named(Q, "spikes", 0.3, 0.8)
    events = []
    for k in range(100, 400):  # the base keeps a spike out every half second: still failed
        spike = _outliers((0, Q)) if k % 50 == 0 else _outliers()
        nu = _innovations(rng)
        events += det.update(k * 0.01, _probs(0, 1.0), _imu(rng), SIGMAS, nu, None, None, spike)
    assert events == []
    for k in range(400, 600):  # no more spikes: the zero offset releases it after 1 s
        events += det.update(k * 0.01, _probs(0, 1.0), _imu(rng), SIGMAS, _innovations(rng))
    assert [(e.kind, e.mode.name) for e in events] == [("cleared", "q")]
    assert 4.5 <= events[0].t_s <= 4.55  # the last spike at 3.50 s, and the clear dwell


def test_the_spike_that_lifts_a_slot_to_the_threshold_is_its_first():
    """A train's first spike puts slot q from its floor to 0.99 in one sample (50 nats): no
    offset is learnt yet to call it an outlier of, but it counts, and the next spike declares
    (after the dwell). A slot lifted by evidence that builds up over samples has seen no spike:
    its one outlier does not declare."""
    for build_up in (False, True):
        rng = np.random.default_rng(7)
        det = DeclaredSetDetector(DetectorConfig(dwell_s=0.1, settle_s=0.0), 0.0)
        events = []
        for k in range(100):
            p = 0.99 if k >= 20 else 0.5 * k / 20 if build_up else 1e-9
            nats = (
                6.95 if k == 40 else 50.0 if k == 20 and not build_up else 1.0 if build_up else 0.0
            )
            spike = _outliers((5, Q)) if k == 40 else _outliers()
            nu = _innovations(rng)
            events += det.update(
                k * 0.01, _probs(5, p), _imu(rng), SIGMAS, nu, None, _q_evidence(nats), spike
            )
        got = [(e.kind, e.mode.name, round(e.t_s, 2)) for e in events]
        assert got == ([] if build_up else [("detected", "q", 0.4)]), build_up


def test_a_decisive_first_spike_declares_after_the_dwell():
    """The tuning draw's calm p train in small: its first spike lifts slot q from the floor
    by thousands of nats on the channel slot 0 reads 90 sigmas off, and the channel is
    declared once the slot has held the threshold for the dwell, without a second spike."""
    rng = np.random.default_rng(7)
    det = DeclaredSetDetector(DetectorConfig(dwell_s=0.1, settle_s=0.0), 0.0)
    events = []
    for k in range(100):
        p = 0.99 if k >= 20 else 1e-9
        nu = _innovations(rng, {(0, Q): 90.0} if k == 20 else None)
        ratio = _q_evidence(9000.0 if k == 20 else 0.0)
        events += det.update(k * 0.01, _probs(5, p), _imu(rng), SIGMAS, nu, None, ratio)
    assert [(e.kind, e.mode.name) for e in events] == [("detected", "q")]
    assert 0.3 <= events[0].t_s <= 0.31  # the dwell after 0.20 s, to a step's rounding


@pytest.mark.parametrize(
    ("nats", "base_off_sigmas", "declared"),
    [
        (18.0, {(0, Q): 30.0}, False),  # within the Markov bound: a tail sample could give it
        (19.0, {(0, Q): 30.0}, True),  # beyond it, on the channel slot 0 reads worst
        (50.0, {(0, Q): 30.0, (0, X): 40.0}, False),  # slot 0 reads x worse: not q's spike
        (50.0, {}, False),  # q no worse read than the others
    ],
)
def test_one_spike_declares_its_channel_only_beyond_chance(nats, base_off_sigmas, declared):
    """Slot q leads at 0.99 and keeps one outlier out, ``nats`` ahead of the base on its
    sample. One sample passes ``h`` nats of likelihood ratio with probability at most
    ``exp(-h)`` when the base is right: beyond ``_DECISIVE_NATS`` (18.7 nats, 5 % for one false
    declaration over six slots at 100 Hz in 3 h) one spike declares its channel after the dwell,
    provided slot 0 read that channel worst on the sample; short of it, it takes a second."""
    assert 18.0 < _DECISIVE_NATS < 19.0
    rng = np.random.default_rng(6)
    det = DeclaredSetDetector(DetectorConfig(dwell_s=0.1, settle_s=0.0), 0.0)
    events = []
    for k in range(300):
        spike = _outliers((5, Q)) if k == 50 else _outliers()
        ratio = _q_evidence(nats if k == 50 else 0.0)
        nu = _innovations(rng, base_off_sigmas if k == 50 else None)
        events += det.update(k * 0.01, _probs(5, 0.99), _imu(rng), SIGMAS, nu, None, ratio, spike)
    got = [(e.kind, e.mode.name, round(e.t_s, 2)) for e in events]
    assert got == ([("detected", "q", 0.5)] if declared else []), got


def _rest(slot: int, nats_per_fix: float, nis: float = 5.0):
    """Evidence at a GPS fix: ``slot`` ahead of the base by ``nats_per_fix`` on its 5 outputs,
    the others a little behind; every slot's normalised innovation squared ``nis``."""
    ratios = np.full(7, -0.2)
    ratios[0] = 0.0
    ratios[slot] = nats_per_fix
    return ratios, np.full(7, nis), 5


def _fly_fixes(det, seconds, evidence, rng):
    """IMU samples at 100 Hz, a fix (and its evidence) once a second."""
    events = []
    for k in range(int(seconds * 100)):
        rest = evidence if k % 100 == 0 else None
        events += det.update(
            k * 0.01, _probs(6, 1e-9), _imu(rng), SIGMAS, _innovations(rng), rest=rest
        )
    return events


def test_the_slow_threshold_is_a_five_percent_chance_over_three_hours_of_six_slots():
    from immukf_sitl.service.declared_set import _REST_NATS

    # exp(-h) per window (Markov's inequality on a likelihood ratio), 6 slots x 100 Hz x 3 h
    assert 6 * 100 * 3 * 3600 * math.exp(-_REST_NATS) == pytest.approx(0.05)


@pytest.mark.parametrize(("per_fix", "declared"), [(6.2, False), (6.3, True)])
def test_a_slot_that_predicts_the_fixes_better_over_three_seconds_is_declared(per_fix, declared):
    """Slot r (6) at its probability floor, ahead of the base at each 1 Hz fix: the three
    fixes of the window must reach ln(6 x 100 x 3 x 3600 / 0.05) = 18.68 nats."""
    det = DeclaredSetDetector(DetectorConfig(settle_s=0.0), 0.0)
    events = _fly_fixes(det, 6.0, _rest(6, per_fix), np.random.default_rng(5))
    assert [(e.kind, e.mode.name) for e in events] == ([("detected", "r")] if declared else [])
    if declared:
        assert det.declared == FaultMode.from_name("r")
        assert events[0].t_s == pytest.approx(2.0)
        # what chance leaves: at most exp(-18.9) that the window passed with r healthy (the
        # others' median is below 0, so nothing is taken off)
        assert events[0].probability == pytest.approx(-math.expm1(-3 * per_fix), abs=1e-12)


def test_two_slots_ahead_at_the_fixes_alike_are_not_told_apart():
    """Slots p and r 30 and 25.5 nats ahead over three fixes, short of the 6.9-nat margin:
    nothing is declared; once r leads by more, r is."""
    rng = np.random.default_rng(6)
    det = DeclaredSetDetector(DetectorConfig(settle_s=0.0), 0.0)
    tied = _rest(6, 10.0)
    tied[0][4] = 8.5
    assert _fly_fixes(det, 5.0, tied, rng) == []
    ahead = _rest(6, 13.0)
    ahead[0][4] = 8.5
    events = _fly_fixes(det, 5.0, ahead, rng)
    assert [(e.kind, e.mode.name) for e in events] == [("detected", "r")]


def test_the_slow_test_waits_for_the_settling():
    det = DeclaredSetDetector(DetectorConfig(settle_s=2.5), 0.0)
    events = _fly_fixes(det, 5.0, _rest(6, 30.0), np.random.default_rng(7))
    assert [(e.kind, e.mode.name, round(e.t_s, 2)) for e in events] == [("detected", "r", 2.5)]


def test_a_slot_that_does_not_fit_the_fixes_is_not_declared_slowly():
    """Slot r 10 nats a fix ahead of the base, but its own innovations at three times their
    chi-square mean (the 0.999 quantile of two fixes of 5 degrees of freedom, when the
    evidence passes the threshold, is 2.96 times): its model does not explain the fixes
    either."""
    from scipy.stats import chi2

    assert chi2.ppf(0.999, 10) / 10 == pytest.approx(2.96, abs=0.01)
    det = DeclaredSetDetector(DetectorConfig(settle_s=0.0), 0.0)
    assert _fly_fixes(det, 6.0, _rest(6, 10.0, nis=15.0), np.random.default_rng(8)) == []


def test_a_fix_most_slots_predict_better_than_the_base_is_the_base_s_error():
    """Every fault slot 8 to 12 nats ahead of the base at each fix (the base's model erred:
    a turn in moderate air, traced on fault-free flights), r the most: r is 4 nats beyond the
    others' median, 12 over the window, and nothing is declared; r alone ahead is."""
    det = DeclaredSetDetector(DetectorConfig(settle_s=0.0), 0.0)
    shared = _rest(6, 12.0)
    shared[0][1:6] = [8.0, 9.0, 7.0, 8.0, 8.5]
    assert _fly_fixes(det, 6.0, shared, np.random.default_rng(9)) == []
    alone = _rest(6, 12.0)
    events = _fly_fixes(det, 6.0, alone, np.random.default_rng(9))
    assert [(e.kind, e.mode.name) for e in events] == [("detected", "r")]


@pytest.mark.parametrize(("leader", "declared"), [(6, []), (4, [("detected", "r", 0.0)])])
def test_the_slow_test_waits_only_for_the_slot_it_would_declare(leader, declared):
    """Slot r 30 nats a fix ahead at the fixes, and slot ``leader`` at 0.99 with no
    signature. The leader r itself: the slow test leaves the decision to the probabilities'
    tests (whose dwell lets the slot learn its offset), and nothing is declared. The leader p,
    which the fixes put 30 nats behind r: r is declared at the first fix, past p's lead."""
    rng = np.random.default_rng(10)
    det = DeclaredSetDetector(DetectorConfig(settle_s=0.0), 0.0)
    events = []
    for k in range(500):
        rest = _rest(6, 30.0) if k % 100 == 0 else None
        events += det.update(
            k * 0.01, _probs(leader, 0.99), _imu(rng), SIGMAS, _innovations(rng), rest=rest
        )
    assert [(e.kind, e.mode.name, round(e.t_s, 2)) for e in events] == declared


def _fly_q_failing(det, seconds, evidence, rng):
    """Slot q at 0.99, its channel 4 sigma off the base's prediction sample after sample from
    2.5 s on (a failure the probabilities' tests declare within about 0.2 s), a fix once a
    second."""
    events = []
    for k in range(int(seconds * 100)):
        rest = evidence if k % 100 == 0 else None
        nu = _innovations(rng, {(5, Q): 4.0} if k >= 250 else None)
        events += det.update(k * 0.01, _probs(5, 0.99), _imu(rng), SIGMAS, nu, rest=rest)
    return events


@pytest.mark.parametrize(
    ("q_nats", "r_nats", "declared"),
    [
        (0.0, 0.0, [("detected", "q", 2.6, 2.8)]),  # no slot ahead at the fixes
        (9.5, 10.0, []),  # r a little ahead at the fixes (30 against 28.5 nats): q held
        (10.0, 9.5, [("detected", "q", 2.6, 2.8)]),  # q a little ahead: the probabilities'
        (0.0, 12.0, [("detected", "r", 0.99, 1.01)]),  # r alone ahead: at its second fix
    ],
)
def test_the_fixes_hold_a_declaration_they_contradict(q_nats, r_nats, declared):
    """Slot q leads the probabilities with a failure it would declare, while the fixes' window
    holds slot r at the slow test's 18.7 nats: q is declared only if the fixes do not put r
    ahead of it, and r past q's lead once r is ahead of every slot by the sustained 6.9 nats.
    A drift's slot and another that reads its effect alike (a roll gyro and the lateral
    accelerometer) run close at the fixes, and the IMU samples after a fix tipped the lead to
    the one the fixes put behind (traced on the tuning draw: a calm p drift declared y, the
    estimate lost)."""
    rng = np.random.default_rng(11)
    det = DeclaredSetDetector(DetectorConfig(dwell_s=0.1, settle_s=0.0), 0.0)
    evidence = _rest(6, r_nats)
    evidence[0][5] = q_nats
    events = _fly_q_failing(det, 5.0, evidence, rng)[:1]  # q fails after r as well
    got = [(e.kind, e.mode.name) for e in events]
    assert got == [(kind, name) for kind, name, _, _ in declared]
    for event, (_, _, lo, hi) in zip(events, declared, strict=True):
        assert lo <= event.t_s <= hi


@pytest.mark.parametrize(
    ("kind", "size", "expected"),
    [("noise", 3.0, 9.0), ("noise", 0.8, None), ("bias", 0.1, None), ("spikes", 0.3, None)],
)
def test_a_declared_channel_named_noisy_is_read_at_its_factor_squared(kind, size, expected):
    det = DeclaredSetDetector(DetectorConfig(settle_s=0.0), 0.0, FaultMode(1 << Q))
    assert det.read_var_scales() is None  # not named yet
    det.named(Q, kind, size, 1.0)
    got = det.read_var_scales()
    if expected is None:
        assert got is None
    else:
        want = np.ones(6)
        want[Q] = expected
        np.testing.assert_allclose(got, want)
    det.named(0, "noise", 5.0, 1.0)  # x is not declared: no way to read it is kept
    again = det.read_var_scales()
    assert (again is None) if got is None else np.array_equal(again, got)


def test_a_named_channels_gain_is_known_unless_its_name_is_a_gain_or_a_dead_reading():
    """q named a bias, a drift, a noise or spikes reads at its own gain (g = 0; the drift rate
    held at 0 too but for a drift); renamed a gain, or named stuck or zero, its gain is learnt
    again; an undeclared channel's name is not kept, and a release forgets the channel's."""
    det = DeclaredSetDetector(DetectorConfig(settle_s=0.0), 0.0, FaultMode(1 << Q))
    assert det.error_holds() == {}  # not named yet: all learnt
    for t_s, kind in enumerate(("bias", "drift", "noise", "spikes")):
        det.named(Q, kind, 2.0, float(t_s))
        assert det.error_holds() == {Q: (None if kind == "drift" else 0.0, 0.0)}, kind
    det.named(Q, "drift", 0.01, 5.0)
    det.named(0, "bias", 1.0, 6.0)  # x is not declared
    assert det.error_holds() == {Q: (None, 0.0)}
    for kind in ("scale", "bias", "stuck", "bias", "zero"):
        det.named(Q, kind, 0.5, 7.0)
        assert det.error_holds() == ({Q: (0.0, 0.0)} if kind == "bias" else {}), kind
    det.named(Q, "noise", 3.0, 8.0)
    det._change(Q)  # released
    assert det.error_holds() == {}


def test_a_bias_the_slow_test_declared_keeps_its_drift_rate_learnt():
    """r declared slowly at the GPS fixes (a failure that grew too slowly for the
    probabilities) and named a bias, a noise or spikes: its drift rate stays learnt; released
    and declared again by the probabilities, a bias holds it at 0."""
    det = DeclaredSetDetector(DetectorConfig(settle_s=0.0), 0.0)
    events = _fly_fixes(det, 4.0, _rest(6, 30.0), np.random.default_rng(11))
    assert [(e.kind, e.mode.name) for e in events] == [("detected", "r")]
    for kind in ("noise", "spikes", "bias"):
        det.named(5, kind, 0.02, 3.0)
        assert det.error_holds() == {5: (None, 0.0)}, kind
    det._change(5)  # released
    det._change(5)  # declared again, not by the slow test
    det.named(5, "bias", 0.02, 9.0)
    assert det.error_holds() == {5: (0.0, 0.0)}


@pytest.mark.parametrize(("kind", "released"), [("bias", True), ("noise", False)])
def test_a_zero_offset_releases_a_bias_but_not_a_noise(kind, released):
    """q declared, its offset known and zero, the base believed: a channel named biased reads
    healthy again and is released after the clear dwell; one named noisy had a zero offset
    all along (its failure is its spread) and stays declared until the slot that reads it at
    its healthy noise is believed."""
    rng = np.random.default_rng(12)
    cfg = DetectorConfig(dwell_s=0.0, settle_s=0.0, clear_dwell_s=1.0)
    det = DeclaredSetDetector(cfg, 0.0, FaultMode(1 << Q))
    det.named(Q, kind, 3.0, 0.0)
    events = []
    for k in range(300):
        events += det.update(k * 0.01, _probs(0, 1.0), _imu(rng), SIGMAS, _innovations(rng))
    assert [(e.kind, e.mode.name) for e in events] == ([("cleared", "q")] if released else [])
    if not released:
        for k in range(300, 500):  # the slot that trusts q again is believed: released
            events += det.update(
                k * 0.01, _probs(1 + Q, 0.999), _imu(rng), SIGMAS, _innovations(rng)
            )
        assert [(e.kind, e.mode.name) for e in events] == [("cleared", "q")]


def test_the_slow_window_holds_three_fixes_at_1_hz_whatever_the_times_rounding():
    """Sample times are sums of steps, a few 1e-12 s off, older ones by more (as traced in
    flight): a fix exactly one window old leaves it all the same. Evidence of 2/7 of the
    threshold a fix passes it over four fixes, not over three: nothing is declared."""
    from immukf_sitl.service.declared_set import _REST_NATS

    det = DeclaredSetDetector(DetectorConfig(dwell_s=0.1, settle_s=0.0), 0.0)
    rng = np.random.default_rng(13)
    evidence = _rest(6, _REST_NATS * 2.0 / 7.0)
    events = []
    for k in range(800):
        t_s = k * 0.01 + 2e-12 - 1e-13 * k / 100.0  # the older, the further off
        rest = evidence if k % 100 == 0 else None
        events += det.update(t_s, _probs(6, 1e-9), _imu(rng), SIGMAS, _innovations(rng), rest=rest)
    assert events == []


Z = 2


def _flipping(k: int) -> np.ndarray:
    """The lead handed between slot z (3) and slot q (5) every third sample; the base at 0."""
    out = np.zeros(7)
    out[3 if k % 3 else 5] = 1.0
    return out


@pytest.mark.parametrize(("z_ahead_nats", "declared"), [(40.0, "z"), (0.0, None)])
def test_a_lead_handed_between_failure_slots_is_settled_by_the_window_evidence(
    z_ahead_nats, declared
):
    """x and z dead at once: no slot of the bank is right, and the lead flips between slot z and
    slot q (which explains a dead z by a pitch rate of its own) every third sample, so no
    slot holds the threshold for the dwell. Over the window, slot z's log-likelihoods beat
    slot q's by ``z_ahead_nats`` (2 nats a sample) and the base's by far more: z is declared
    at the dwell. Tied with slot q, nothing is declared (not told apart)."""
    rng = np.random.default_rng(21)
    det = DeclaredSetDetector(DetectorConfig(settle_s=0.0), 0.0)
    events = []
    for k in range(60):
        reading = _imu(rng)
        reading[[X, Z]] = rng.normal(0.0, SIGMAS[[X, Z]])
        ll = np.full(7, -500.0)
        ll[3] = -50.0 + z_ahead_nats / 20
        ll[5] = -50.0
        events += det.update(
            k * 0.01, _flipping(k), reading, SIGMAS, _innovations(rng), log_likelihoods=ll
        )
    assert [e.mode.name for e in events if e.kind == "detected"] == ([declared] if declared else [])
    if declared:  # the dwell counts from the first sample of the bank's certainty
        assert events[0].t_s == pytest.approx(0.2)


def test_what_the_slow_test_declared_is_released_on_the_fixes():
    """r declared at the GPS fixes is the declared set the fixes release (its recovery slot
    scored on them alone); released and declared again by the probabilities, it is not."""
    det = DeclaredSetDetector(DetectorConfig(settle_s=0.0), 0.0)
    assert det.declared_slowly is None
    events = _fly_fixes(det, 4.0, _rest(6, 30.0), np.random.default_rng(11))
    assert [(e.kind, e.mode.name) for e in events] == [("detected", "r")]
    assert det.declared_slowly == FaultMode.from_name("r")
    det._change(5)  # released
    assert det.declared_slowly is None
    det._change(5)  # declared again, not by the slow test
    assert det.declared == FaultMode.from_name("r") and det.declared_slowly is None
