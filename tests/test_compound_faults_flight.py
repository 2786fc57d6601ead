"""Flown on the paper's model and its twin: faults after faults, at once, and a recovery, on the
bank re-based on its declarations (untrusted modes)."""

from __future__ import annotations

import pytest
from flights import fly

from immukf_sitl.scenario import FaultSpec
from immukf_sitl.service.filter_models import PaperModel

# flies JSBSim and the estimator
pytestmark = pytest.mark.slow


def test_a_second_fault_is_identified_beside_the_first():
    """A p gyro freezes, then the x accelerometer takes a bias: both identified, each named,
    the first still declared when the second is."""
    faults = (
        FaultSpec(t_s=14.0, channels=("p",), kind="stuck"),
        FaultSpec(t_s=24.0, channels=("x",), kind="bias", value=0.5),
    )
    out = fly("q_gyro_zeroed.yaml", PaperModel(fault_signature="untrusted"), faults, 34.0)
    assert out["false_alarms"] == 0 and out["clearings"] == [], out["detections"]
    stuck, bias = out["faults"]
    assert stuck["detection_delay_s"] <= 1.0 and stuck["named_kind"] == "stuck"
    assert bias["detection_delay_s"] <= 1.0 and bias["named_kind"] == "bias"
    assert bias["named_size"] == pytest.approx(0.5, rel=0.2)


def test_two_channels_failing_at_once_are_both_identified():
    faults = (FaultSpec(t_s=14.0, channels=("x", "q"), kind="zero"),)
    out = fly("q_gyro_zeroed.yaml", PaperModel(fault_signature="untrusted"), faults, 24.0)
    (both,) = out["faults"]
    assert out["false_alarms"] == 0, out["detections"]
    assert both["detection_delay_s"] is not None and both["detection_delay_s"] <= 1.0
    assert sorted(d["mode"] for d in out["detections"]) == ["q", "x"]


def test_two_biases_at_once_are_both_identified():
    """An x accelerometer bias and an r gyro bias in the same sample: x is declared, and the
    bank re-based on it, re-run from before the failure, sees r fail too. Re-based from the
    estimate at x's declaration, whose rates had followed the biased r for the dwell, it
    found r only at 0.65 s, and declared p and y wrongly."""
    faults = (
        FaultSpec(t_s=14.0, channels=("x",), kind="bias", value=0.8),
        FaultSpec(t_s=14.0, channels=("r",), kind="bias", value=-0.07),
    )
    out = fly("q_gyro_zeroed.yaml", PaperModel(fault_signature="untrusted"), faults, 20.0)
    assert out["false_alarms"] == 0, out["detections"]
    x, r = out["faults"]
    assert x["detection_delay_s"] <= 0.5 and r["detection_delay_s"] <= 0.5, out["detections"]
    assert x["named_kind"] == "bias" and x["named_size"] == pytest.approx(0.8, rel=0.2)


def test_a_recovered_channel_is_released_once_it_shows_life():
    """An r gyro frozen from 14 to 29 s: declared, then released after the recovery (the clear
    dwell, 5 s, plus the life it must show), and not declared again."""
    faults = (FaultSpec(t_s=14.0, channels=("r",), kind="stuck", end_t_s=29.0),)
    out = fly("q_gyro_zeroed.yaml", PaperModel(fault_signature="untrusted"), faults, 49.0)
    assert [d["mode"] for d in out["detections"]] == ["r"]
    (cleared,) = out["clearings"]
    # the dwell from the recovery, less a step's rounding of the sample clock
    assert cleared["mode"] == "r" and 29.0 + 5.0 - 0.005 <= cleared["t_s"] <= 40.0
