"""Threshold, dwell, clearing and settling of the fault detector."""

import numpy as np
import pytest
from scipy.stats import chi2

from immukf_sitl.estimation import FaultMode, single_fault_modes
from immukf_sitl.options import FilterOptions
from immukf_sitl.service.detection import (
    DetectionEvent,
    DetectorConfig,
    FaultDetector,
    SignatureWindow,
)
from immukf_sitl.service.filter_models import PaperModel, RealAirModel
from immukf_sitl.service.pipeline import PipelineConfig

MODES = single_fault_modes()


def _probs(q):
    p = np.zeros(7)
    p[5] = q
    p[0] = 1 - q
    return p


def _run(detector, series, dt=0.01, t0=0.0):
    events = []
    for k, q in enumerate(series):
        events += detector.update(t0 + k * dt, _probs(q))
    return events


def test_detection_needs_the_dwell_and_reports_the_time_it_fired():
    det = FaultDetector(MODES, DetectorConfig(threshold=0.9, dwell_s=0.1, settle_s=0.0), 0.0)
    events = _run(det, [0.0] * 10 + [0.95] * 5 + [0.1] + [0.95] * 20)
    assert len(events) == 1
    ev = events[0]
    assert ev.kind == "detected" and ev.mode.name == "q"
    assert ev.t_s == pytest.approx(0.26)  # 0.16 onset of the second run + 0.10 dwell
    assert ev.text() == "IMM: q gyro fault detected, p=0.95"


def test_clearing_after_clear_dwell_and_nothing_during_settling():
    cfg = DetectorConfig(
        threshold=0.9, dwell_s=0.0, clear_threshold=0.5, clear_dwell_s=0.5, settle_s=1.0
    )
    det = FaultDetector(MODES, cfg, start_s=0.0)
    series = [0.99] * 90 + [0.0] * 30 + [0.99] * 10 + [0.2] * 60
    events = _run(det, series)
    kinds = [(e.kind, round(e.t_s, 2)) for e in events]
    # nothing before 1.0 s (settling) although q was at 0.99 from the start
    assert kinds == [("detected", 1.2), ("cleared", 1.8)]


def test_switching_directly_to_another_fault_clears_the_first():
    det = FaultDetector(MODES, DetectorConfig(dwell_s=0.0, settle_s=0.0), 0.0)
    p_q = np.zeros(7)
    p_q[5] = 0.95
    p_r = np.zeros(7)
    p_r[6] = 0.97
    events = det.update(0.0, p_q) + det.update(0.01, p_r)
    assert [(e.kind, e.mode.name) for e in events] == [
        ("detected", "q"),
        ("cleared", "q"),
        ("detected", "r"),
    ]


def test_a_dead_declared_channel_is_not_replaced_by_another_mode():
    """While the declared q gyro reads zero plus noise, an r mode that leads is not declared in
    its place; once q has read beyond 5 sigma three times (alive), the switch goes ahead."""
    rng = np.random.default_rng(5)
    cfg = DetectorConfig(dwell_s=0.0, settle_s=0.0, signature_window=5)
    det = FaultDetector(MODES, cfg, 0.0)
    p_q, p_r = np.zeros(7), np.zeros(7)
    p_q[5], p_r[6] = 0.95, 0.97
    reading = _imu(rng, 0.0) * [1, 1, 1, 1, 0, 0]  # q and r both read zero plus nothing
    events = det.update(0.0, p_q, reading, SIGMAS)
    for k in range(1, 50):  # r leads, q still dead
        events += det.update(k * 0.01, p_r, reading, SIGMAS)
    assert [(e.kind, e.mode.name) for e in events] == [("detected", "q")]
    alive = reading + [0, 0, 0, 0, 10 * SIGMAS[4], 0]
    for k in range(50, 53):  # q shows life three times
        events += det.update(k * 0.01, p_r, alive, SIGMAS)
    events += det.update(0.53, p_r, reading, SIGMAS)
    assert [(e.kind, e.mode.name) for e in events] == [
        ("detected", "q"),
        ("cleared", "q"),
        ("detected", "r"),
    ]


def test_bad_thresholds_are_rejected():
    with pytest.raises(ValueError, match="clear_threshold <= threshold"):
        DetectorConfig(threshold=0.5, clear_threshold=0.8)


def test_a_single_mode_bank_declares_nothing():
    det = FaultDetector(MODES[5:6], DetectorConfig(dwell_s=0.0, settle_s=0.0), 0.0)
    assert det.update(0.0, np.array([1.0])) == [] and det.update(1.0, np.array([1.0])) == []


SIGMAS = np.array([0.0245] * 3 + [0.00227] * 3)


def _imu(rng, q_radps):
    """Six readings of healthy sensors about a flight with q = ``q_radps`` (others near 0.5)."""
    imu = np.array([0.5, 0.5, -9.8, 0.05, q_radps, 0.05]) + rng.normal(0.0, SIGMAS)
    return imu


def test_a_fault_is_declared_only_while_its_channel_reads_zero_plus_noise():
    """The IMM's probability alone does not declare a q fault while the q gyro reads 0.05 rad/s."""
    rng = np.random.default_rng(11)
    det = FaultDetector(MODES, DetectorConfig(dwell_s=0.1, settle_s=0.0), 0.0)
    events = []
    for k in range(100):  # q mode certain, but the gyro reads a turn: a model error, not a fault
        events += det.update(k * 0.01, _probs(0.99), _imu(rng, 0.05), SIGMAS)
    assert events == []
    dead_from = 100
    for k in range(dead_from, 200):  # the gyro dies: zero plus its noise
        events += det.update(k * 0.01, _probs(0.99), _imu(rng, 0.0) * [1, 1, 1, 1, 0, 1]
                             + [0, 0, 0, 0, rng.normal(0.0, SIGMAS[4]), 0], SIGMAS)  # fmt: skip
    assert [(e.kind, e.mode.name) for e in events] == [("detected", "q")]
    # declared once a full window (20 samples) of zeros is in: dead at 1.00 s, window full at
    # 1.19 s, which is after the 0.1 s dwell
    assert events[0].t_s == pytest.approx(1.19)


def test_the_zero_test_rejects_a_dead_channel_at_its_stated_rate():
    """Chi-square over the window: a zeroed channel fails it 1 - signature_quantile of the time."""
    cfg = DetectorConfig(signature_window=20, signature_quantile=0.99)
    rng = np.random.default_rng(5)
    q = np.arange(6) == 4
    rejected = 0
    n = 4000
    for _ in range(n):
        window = SignatureWindow(cfg)
        for _ in range(cfg.signature_window):
            window.push(rng.normal(0.0, 1.0, 6), None)
        rejected += not window.reads_zero(q)
    rate = rejected / n
    # binomial: 1 % of 4000 is 40 +- 6.3; four sigma either side
    assert 0.01 - 4 * 0.00157 < rate < 0.01 + 4 * 0.00157


def test_the_offset_test_passes_a_held_consistent_offset_at_its_stated_rate():
    """A learnt offset is one estimate held over the window: chi-square(1) flags 1 - q of them."""
    cfg = DetectorConfig(signature_window=20, signature_quantile=0.99)
    rng = np.random.default_rng(6)
    q = np.arange(6) == 4
    flagged = 0
    n = 4000
    for _ in range(n):
        window = SignatureWindow(cfg)
        held = rng.normal(0.0, 1.0, (7, 6)) ** 2
        for _ in range(cfg.signature_window):
            window.push(None, held)
        flagged += window.offset_beyond(5, q)
    # binomial: 1 % of 4000 is 40 +- 6.3; four sigma either side
    assert 0.01 - 4 * 0.00157 < flagged / n < 0.01 + 4 * 0.00157


def test_the_offset_test_errs_towards_consistent_on_independent_residuals():
    """Twenty independent chi-square(1) residuals: their mean passes far more often than 1 - q."""
    cfg = DetectorConfig(signature_window=20, signature_quantile=0.99)
    rng = np.random.default_rng(7)
    q = np.arange(6) == 4
    flagged = 0
    for _ in range(4000):
        window = SignatureWindow(cfg)
        for _ in range(cfg.signature_window):
            window.push(None, rng.normal(0.0, 1.0, (7, 6)) ** 2)
        flagged += window.offset_beyond(5, q)
    # the mean of 20 exceeds chi2(1)'s 6.63 with probability chi2.sf(132.7, 20) ~ 1e-18
    assert flagged == 0
    window = SignatureWindow(cfg)
    for _ in range(cfg.signature_window):
        window.push(None, np.full((7, 6), 3.0**2))  # an offset held at 3 sigma: beyond 2.58
    assert window.offset_beyond(5, q)


def test_the_base_test_is_the_sum_without_its_largest_sample_against_chi_square():
    """Mode 0's residuals on a channel: their sum without the largest, against chi2(n - 1)."""
    cfg = DetectorConfig(signature_window=20, signature_quantile=0.99)
    q = np.arange(6) == 4
    limit = chi2.ppf(0.99, 19)
    for level, expected in ((limit / 19 * 1.001, True), (limit / 19 * 0.999, False)):
        window = SignatureWindow(cfg)
        for _ in range(cfg.signature_window):
            residuals = np.zeros((7, 6))
            residuals[0, 4] = level
            residuals[5, 4] = 1e6  # the fault mode's own residual is not what is judged
            window.push(None, residuals)
        assert window.base_inconsistent(q) is expected
    window = SignatureWindow(cfg)
    window.push(None, np.full((7, 6), 1e6))
    assert not window.base_inconsistent(q)  # one sample is no sum without its largest


def test_the_base_test_errs_towards_consistent_on_a_healthy_channel():
    """Twenty chi-square(1) residuals: flagged as the order statistics say, at most 1 - q."""
    cfg = DetectorConfig(signature_window=20, signature_quantile=0.99)
    rng = np.random.default_rng(8)
    q = np.arange(6) == 4
    n = 4000
    draws = rng.normal(0.0, 1.0, (n, cfg.signature_window, 7, 6)) ** 2
    flagged = 0
    for windowed in draws:
        window = SignatureWindow(cfg)
        for residuals in windowed:
            window.push(None, residuals)
        flagged += window.base_inconsistent(q)
    ordered = np.sort(draws[:, :, 0, 4], axis=1)
    expected = int(np.sum(np.sum(ordered[:, :-1], axis=1) > chi2.ppf(0.99, 19)))
    assert flagged == expected
    assert flagged / n <= 0.01
    noisy = 3.0**2 * draws  # a noise of factor 3 over a prediction as wide as the sensor
    found = 0
    for windowed in noisy[:400]:
        window = SignatureWindow(cfg)
        for residuals in windowed:
            window.push(None, residuals)
        found += window.base_inconsistent(q)
    ordered = np.sort(noisy[:400, :, 0, 4], axis=1)
    assert found == int(np.sum(np.sum(ordered[:, :-1], axis=1) > chi2.ppf(0.99, 19)))
    assert found / 400 >= 0.99


def test_signature_test_settings_are_checked():
    with pytest.raises(ValueError, match="signature test"):
        DetectorConfig(signature_window=0)
    with pytest.raises(ValueError, match="signature test"):
        DetectorConfig(signature_quantile=1.0)


def test_an_event_round_trips_through_json_with_the_declared_set():
    event = DetectionEvent(
        "detected", FaultMode.from_name("x"), 1.5, 0.97, declared_after=FaultMode.from_name("x+p")
    )
    assert DetectionEvent.from_json(event.to_json()) == event
    plain = DetectionEvent("cleared", FaultMode.from_name("q"), 2.0, 0.3)
    assert "declared_after" not in plain.to_json()
    assert DetectionEvent.from_json(plain.to_json()) == plain


def test_the_settling_time_is_the_filter_models_unless_given():
    """The paper model settles for the alignment's transient (3 s); the real-air model for one
    correction time constant, until the airframe's model error is learnt; --settle wins."""
    real_air = RealAirModel(correction_time_constant_s=12.0)
    assert PipelineConfig(filter_model=PaperModel()).detector.settle_s == 3.0
    assert PipelineConfig(filter_model=real_air).detector.settle_s == 12.0
    given = DetectorConfig(settle_s=1.5)
    assert PipelineConfig(filter_model=real_air, detector=given).detector.settle_s == 1.5
    assert FilterOptions(filter_model=real_air).detector.settle_s == 12.0
    with pytest.raises(ValueError, match="settle_s"):
        FaultDetector(MODES, DetectorConfig(), 0.0)
