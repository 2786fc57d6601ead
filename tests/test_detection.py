"""Threshold, dwell, clearing and settling of the fault detector."""

import numpy as np
import pytest

from immukf_sitl.estimation import single_fault_modes
from immukf_sitl.service.detection import DetectorConfig, FaultDetector

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


def test_bad_thresholds_are_rejected():
    with pytest.raises(ValueError, match="clear_threshold <= threshold"):
        DetectorConfig(threshold=0.5, clear_threshold=0.8)


def test_a_single_mode_bank_declares_nothing():
    det = FaultDetector(MODES[5:6], DetectorConfig(dwell_s=0.0, settle_s=0.0), 0.0)
    assert det.update(0.0, np.array([1.0])) == [] and det.update(1.0, np.array([1.0])) == []
