"""The summary's definitions: delays from observability, false alarms, errors, expectations."""

import numpy as np
import pytest

from immukf_sitl.estimation.fault_modes import FaultMode
from immukf_sitl.experiments.report import (
    EstimateTrack,
    estimation_errors,
    human_summary,
    summarize,
)
from immukf_sitl.samples import TruthSample
from immukf_sitl.scenario import ExpectSpec, FaultSpec
from immukf_sitl.service.detection import DetectionEvent
from immukf_sitl.service.timing import TimingStats

DT = 0.01


def _truth(n, q_of_t=lambda t: 0.0):
    out = []
    for k in range(n):
        t = k * DT
        out.append(
            TruthSample(t, 47.0, 8.0, 150.0, np.array([0.1, 0.05, 1.0]),
                        np.array([0.0, q_of_t(t), 0.0]), np.array([25.0, 0.0, 0.0]),
                        np.array([0.5, 0.0, -9.8]))
        )  # fmt: skip
    return out


def _track(truth, euler_offset=(0.0, 0.0, 0.0), north_offset_m=0.0):
    t = np.array([s.t_s for s in truth])
    euler = np.array([s.euler_rad for s in truth]) + np.array(euler_offset)
    lla = np.array([(s.lat_deg + north_offset_m / 111_000.0, s.lon_deg, s.alt_m) for s in truth])
    return EstimateTrack(t, euler, t, lla)


def test_delay_counts_from_when_the_fault_became_observable():
    # q is 0 until 2.0 s, then 0.05 rad/s (22 sigma): a zeroed q gyro is observable from 2.0 s
    truth = _truth(400, lambda t: 0.05 if t >= 2.0 else 0.0)
    fault = FaultSpec(1.0, ("q",), "zero")
    events = [DetectionEvent("detected", FaultMode.from_name("q"), 2.3, 0.97)]
    s = summarize("t", [fault], truth, events, _track(truth), TimingStats(600.0, 500.0, 900.0),
                  expect=ExpectSpec("q", 1.0)).to_json()  # fmt: skip
    (row,) = s["faults"]
    assert row["observable_t_s"] == pytest.approx(2.0)
    assert row["detection_delay_s"] == pytest.approx(0.3)
    assert s["false_alarms"] == 0 and s["expectation"]["met"]
    assert s["step_us"] == {"median": 500.0, "p99": 900.0}


def test_wrong_mode_or_early_detection_is_a_false_alarm():
    truth = _truth(400, lambda t: 0.05)
    fault = FaultSpec(2.0, ("q",), "zero")
    events = [
        DetectionEvent("detected", FaultMode.from_name("p"), 1.0, 0.95),  # before any fault
        DetectionEvent("detected", FaultMode.from_name("r"), 2.5, 0.95),  # wrong channel
        DetectionEvent("detected", FaultMode.from_name("q"), 2.6, 0.99),
    ]
    s = summarize(
        "t", [fault], truth, events, _track(truth), TimingStats(), expect=ExpectSpec("q", 1.0)
    ).to_json()
    assert s["false_alarms"] == 2
    assert [d["mode"] for d in s["false_alarm_detections"]] == ["p", "r"]
    assert s["faults"][0]["detection_delay_s"] == pytest.approx(0.6)
    assert not s["expectation"]["met"]


def test_unobservable_fault_has_no_observable_time_and_no_delay():
    truth = _truth(300)  # q stays 0: a zeroed q gyro reads what a healthy one would
    s = summarize(
        "t", [FaultSpec(1.0, ("q",), "zero")], truth, [], _track(truth), TimingStats()
    ).to_json()
    assert s["faults"][0]["observable_t_s"] is None
    assert s["faults"][0]["detection_delay_s"] is None


def test_errors_against_known_offsets():
    truth = _truth(100)
    err = estimation_errors(truth, _track(truth, euler_offset=(np.radians(3), 0, np.radians(4)),
                                          north_offset_m=2.0))  # fmt: skip
    assert err["att_max_deg"] == pytest.approx(5.0, rel=1e-9)
    assert err["att_mse_deg2"] == pytest.approx(25.0, rel=1e-9)
    assert err["pos_max_m"] == pytest.approx(2.0 * 111_000.0 / 111_195.0, rel=2e-2)


def test_a_single_truth_sample_is_enough():
    truth = _truth(1)
    err = estimation_errors(truth, _track(truth))
    assert err["att_max_deg"] == pytest.approx(0.0, abs=1e-12)


def test_yaw_error_wraps_across_pi():
    truth = _truth(10)
    track = _track(truth, euler_offset=(0.0, 0.0, 2 * np.pi - np.radians(1.0)))
    assert estimation_errors(truth, track)["att_max_deg"] == pytest.approx(1.0, rel=1e-9)


def test_a_naming_lands_on_its_detection_in_the_json_and_the_text():
    """The naming that follows a detection of the same mode gives it its kind and size; a
    later detection of another mode keeps none."""
    truth = _truth(400, lambda t: 0.05)
    q, r = FaultMode.from_name("q"), FaultMode.from_name("r")
    events = [
        DetectionEvent("detected", q, 1.2, 0.97),
        DetectionEvent("named", q, 2.2, 0.99, "bias", 0.0492),
        DetectionEvent("detected", r, 3.0, 0.95),
    ]
    fault = FaultSpec(1.0, ("q",), "bias", 0.05)
    summary = summarize("t", [fault], truth, events, _track(truth), TimingStats(1.0, 1.0, 1.0))
    s = summary.to_json()
    assert [(d["mode"], d["kind"], d["size"]) for d in s["detections"]] == [
        ("q", "bias", 0.0492),
        ("r", None, None),
    ]
    assert s["faults"][0]["named_kind"] == "bias" and s["faults"][0]["named_size"] == 0.0492
    assert "q@1.20s (bias +0.0492), r@3.00s;" in human_summary(summary)


def test_a_double_fault_is_detected_once_both_channels_are_declared_together():
    """Declared one channel at a time by a re-based bank: the fault's detection is the event
    that left both declared, and neither channel's declaration is a false alarm; a detector
    that holds one mode at a time (the paper's) never covers both."""
    truth = _truth(400, lambda t: 0.05)
    fault = FaultSpec(1.0, ("x", "q"), "zero")
    xq = FaultMode.from_name("x+q")
    events = [
        DetectionEvent("detected", FaultMode.from_name("q"), 1.2, 0.99,
                       declared_after=FaultMode.from_name("q")),
        DetectionEvent("detected", FaultMode.from_name("x"), 1.7, 0.98, declared_after=xq),
    ]  # fmt: skip
    s = summarize("t", [fault], truth, events, _track(truth), TimingStats(1.0, 1.0, 1.0))
    (row,) = s.to_json()["faults"]
    assert row["detected_t_s"] == pytest.approx(1.7) and s.false_alarms == ()
    one_at_a_time = [
        DetectionEvent("detected", FaultMode.from_name("q"), 1.2, 0.99),
        DetectionEvent("cleared", FaultMode.from_name("q"), 1.7, 0.2),
        DetectionEvent("detected", FaultMode.from_name("x"), 1.7, 0.98),
    ]
    s = summarize("t", [fault], truth, one_at_a_time, _track(truth), TimingStats(1.0, 1.0, 1.0))
    assert s.to_json()["faults"][0]["detected_t_s"] is None


def test_each_fault_of_a_pair_is_matched_to_the_declaration_of_its_own_channel():
    """x fails at 1 s, q at 2 s, each its own fault: each is detected by the declaration that
    added its channel to the declared set, x's still standing. A q declared before q failed
    (falsely) is not detected by a later declaration of another channel."""
    truth = _truth(400, lambda t: 0.05)
    x, q, y = (FaultMode.from_name(c) for c in "xqy")
    faults = [FaultSpec(1.0, ("x",), "zero"), FaultSpec(2.0, ("q",), "zero")]
    xq, xqy = FaultMode.from_name("x+q"), FaultMode.from_name("x+q+y")
    in_turn = [
        DetectionEvent("detected", x, 1.2, 0.99, declared_after=x),
        DetectionEvent("detected", q, 2.4, 0.98, declared_after=xq),
    ]
    s = summarize("t", faults, truth, in_turn, _track(truth), TimingStats(1.0, 1.0, 1.0))
    first, second = s.faults
    assert (first.detected_t_s, second.detected_t_s) == (1.2, 2.4) and s.false_alarms == ()
    assert second.observable_t_s == pytest.approx(2.0)
    assert second.detection_delay_s == pytest.approx(0.4)
    q_too_early = [
        DetectionEvent("detected", x, 1.2, 0.99, declared_after=x),
        DetectionEvent("detected", q, 1.5, 0.97, declared_after=xq),
        DetectionEvent("detected", y, 2.3, 0.96, declared_after=xqy),
    ]
    s = summarize("t", faults, truth, q_too_early, _track(truth), TimingStats(1.0, 1.0, 1.0))
    assert s.faults[0].detected_t_s == 1.2 and s.faults[1].detected_t_s is None
    assert [e.mode.name for e in s.false_alarms] == ["q", "y"]
