"""The proxy's fault annotations: every kind's parameters survive the STATUSTEXT round trip."""

from __future__ import annotations

import pytest

from immukf_sitl.mavlink.flightlog import (
    FAULT_TEXT,
    Annotations,
    FaultRecord,
    FlightLog,
    fault_annotation,
)


@pytest.mark.parametrize(
    ("kind", "channels", "value", "rate_hz"),
    [
        ("zero", ("q",), 0.0, 0.0),
        ("bias", ("x", "z"), 0.2, 0.0),
        ("drift", ("r",), -0.0125, 0.0),
        ("scale", ("p",), 0.75, 0.0),
        ("noise", ("y",), 4.0, 0.0),
        ("spikes", ("q",), -0.35, 2.5),
    ],
)
def test_annotation_round_trip(kind, channels, value, rate_hz):
    text = fault_annotation(kind, channels, 31.25, value, rate_hz=rate_hz)
    assert len(text) <= 50
    match = FAULT_TEXT.match(text)
    assert match is not None
    assert match["kind"] == kind
    assert tuple(match["channels"].split("+")) == channels
    assert float(match["t"]) == 31.25
    assert float(match["v"] or 0.0) == value
    assert float(match["r"] or 0.0) == rate_hz


def test_six_channels_of_spikes_fit_with_fewer_digits():
    text = fault_annotation("spikes", "xyzpqr", 1234.5678, -0.123456789, rate_hz=12.3456789)
    assert len(text) <= 50
    match = FAULT_TEXT.match(text)
    assert float(match["v"]) == pytest.approx(-0.12, abs=0.01)
    assert float(match["r"]) == pytest.approx(12.0, abs=0.5)


def test_the_imu_instance_survives_the_round_trip_and_pairs_the_end_with_its_start():
    notes = Annotations()
    for text in (
        fault_annotation("stuck", ("q",), 10.0, imu=1),
        fault_annotation("zero", ("q",), 12.0),
        fault_annotation("stuck", ("q",), 20.0, end=True, imu=1),
    ):
        notes.feed(text)
    stuck, zero = notes.faults
    assert (stuck.kind, stuck.imu, stuck.end_t_s) == ("stuck", 1, 20.0)
    assert (zero.kind, zero.imu, zero.end_t_s) == ("zero", 0, None)
    assert stuck.spec().imu == 1


def test_a_log_scores_only_the_faults_of_the_imu_it_follows():
    faults = [FaultRecord("zero", ("q",), 10.0), FaultRecord("stuck", ("p",), 20.0, imu=1)]
    assert [f.channels for f in FlightLog(faults=faults, imu_instance=0).faults_seen()] == [("q",)]
    assert [f.channels for f in FlightLog(faults=faults, imu_instance=1).faults_seen()] == [("p",)]
    assert len(FlightLog(faults=faults).faults_seen()) == 2  # the log does not say which IMU
