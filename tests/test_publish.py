"""The publisher's schedule: rates of the IMU clock, and a detection's STATUSTEXT repeated."""

import numpy as np

from immukf_sitl.estimation.fault_modes import FaultMode, single_fault_modes
from immukf_sitl.fault_kinds import FAULT_KINDS
from immukf_sitl.mavlink.publish import (
    FAULT_EVENT_NAME,
    KIND_EVENT_NAME,
    SIZE_EVENT_NAME,
    STATUSTEXT_REPEATS_S,
    OutputRates,
    Publisher,
)
from immukf_sitl.service.alignment import NavSolution
from immukf_sitl.service.detection import DetectionEvent
from immukf_sitl.service.pipeline import EstimateOutput

MODES = single_fault_modes()
DT_S = 0.01


def output(t_s: float, events: tuple[DetectionEvent, ...] = ()) -> EstimateOutput:
    nav = NavSolution(
        t_s, np.zeros(3), np.array([25.0, 0.0, 0.0]), np.zeros(3), np.zeros(3),
        np.ones(3), np.ones(3), np.ones(3), np.ones(3),
    )  # fmt: skip
    probs = np.full(len(MODES), 1.0 / len(MODES))
    return EstimateOutput(t_s, nav, 47.0, 8.0, 150.0, MODES, probs, events, 100.0)


def fly(events_at: dict[int, DetectionEvent], steps: int) -> list[tuple[float, object]]:
    """Every STATUSTEXT and IMM_FAULT published over ``steps`` IMU samples, with its time."""
    publisher = Publisher(OutputRates())
    sent = []
    for k in range(steps):
        t_s = k * DT_S
        event = events_at.get(k)
        for msg in publisher.messages(output(t_s, (event,) if event else ())):
            if msg.get_type() in ("STATUSTEXT", "NAMED_VALUE_INT"):
                sent.append((t_s, msg))
    return sent


def test_a_detection_text_is_sent_three_times_over_two_seconds_and_its_event_once() -> None:
    q = DetectionEvent("detected", FaultMode.from_name("q"), 1.0, 0.97)
    sent = fly({100: q}, 500)
    texts = [(t, m.text) for t, m in sent if m.get_type() == "STATUSTEXT"]
    assert [round(t, 6) for t, _ in texts] == [1.0] + [1.0 + dt for dt in STATUSTEXT_REPEATS_S]
    assert {text for _, text in texts} == {"IMM: q gyro fault detected, p=0.97"}
    records = [m for _, m in sent if m.get_type() == "NAMED_VALUE_INT"]
    assert len(records) == 1 and records[0].name == FAULT_EVENT_NAME and records[0].value == 16


def test_a_lost_first_datagram_still_delivers_the_detection() -> None:
    q = DetectionEvent("detected", FaultMode.from_name("q"), 1.0, 0.97)
    sent = fly({100: q}, 500)
    texts = [t for t, m in sent if m.get_type() == "STATUSTEXT"]
    delivered = texts[1:]  # the ground station lost the first
    assert delivered and delivered[0] - 1.0 <= max(STATUSTEXT_REPEATS_S)


def test_a_newer_event_supersedes_the_pending_repeats() -> None:
    mode = FaultMode.from_name("q")
    detected = DetectionEvent("detected", mode, 1.0, 0.97)
    cleared = DetectionEvent("cleared", mode, 1.5, 0.2)
    sent = fly({100: detected, 150: cleared}, 500)
    texts = [(round(t, 6), m.text) for t, m in sent if m.get_type() == "STATUSTEXT"]
    assert texts[0] == (1.0, detected.text())
    assert [t for t, text in texts if text == detected.text()] == [1.0]
    assert [t for t, text in texts if text == cleared.text()] == [
        1.5 + dt for dt in (0.0, *STATUSTEXT_REPEATS_S)
    ]


def test_a_naming_sends_its_words_kind_and_size_and_no_fault_record() -> None:
    mode = FaultMode.from_name("q")
    detected = DetectionEvent("detected", mode, 1.0, 0.97)
    named = DetectionEvent("named", mode, 2.0, 0.99, "stuck", 0.21)
    publisher = Publisher(OutputRates())
    sent = []
    for k in range(300):
        t_s = k * DT_S
        event = {100: detected, 200: named}.get(k)
        sent += [
            (round(t_s, 6), m)
            for m in publisher.messages(output(t_s, (event,) if event else ()))
            if m.get_type() in ("STATUSTEXT", "NAMED_VALUE_INT", "NAMED_VALUE_FLOAT")
        ]
    at_2 = [m for t, m in sent if t == 2.0]
    assert [m.text for m in at_2 if m.get_type() == "STATUSTEXT"] == [
        "IMM: q gyro stuck at 0.21 rad/s, p=0.99"
    ]
    ints = {m.name: m.value for m in at_2 if m.get_type() == "NAMED_VALUE_INT"}
    assert ints == {KIND_EVENT_NAME: FAULT_KINDS.index("stuck") + 1}
    floats = [m for m in at_2 if m.get_type() == "NAMED_VALUE_FLOAT" and m.name == SIZE_EVENT_NAME]
    assert len(floats) == 1 and floats[0].value == np.float32(0.21)
    faults = [
        m for _, m in sent if m.get_type() == "NAMED_VALUE_INT" and m.name == FAULT_EVENT_NAME
    ]
    assert len(faults) == 1  # the detection's only


def test_naming_words_fit_a_statustext_for_every_kind() -> None:
    for kind, size in [("zero", None), ("stuck", -0.123456), ("bias", 2.0), ("drift", 0.3),
                       ("scale", 0.5), ("noise", 5.0), ("spikes", 0.3)]:  # fmt: skip
        for mode in MODES[1:]:
            text = DetectionEvent("named", mode, 1.0, 0.99, kind, size).text()
            assert len(text) <= 50 and text.endswith("p=0.99"), text


def test_a_rebased_bank_publishes_the_probability_that_each_channel_failed() -> None:
    """With p declared the bank's slots are p, x+p, ...: MP_P is the sum over the slots that
    hold p, MP_NONE the slot that holds nothing; the declared set rides on IMM_FAULT."""
    from immukf_sitl.estimation import bank_modes

    modes = bank_modes(FaultMode.from_name("p"))
    probs = np.array([0.6, 0.05, 0.05, 0.05, 0.1, 0.1, 0.05])
    nav = output(0.0).nav
    x = FaultMode.from_name("x")
    event = DetectionEvent("detected", x, 0.0, 0.97, declared_after=FaultMode.from_name("x+p"))
    out = EstimateOutput(0.0, nav, 47.0, 8.0, 150.0, modes, probs, (event,), 100.0)
    msgs = Publisher(OutputRates()).messages(out)
    floats = {m.name: m.value for m in msgs if m.get_type() == "NAMED_VALUE_FLOAT"}
    assert floats["MP_NONE"] == np.float32(0.1)
    assert floats["MP_P"] == np.float32(0.9)
    assert floats["MP_Q"] == np.float32(0.1) and floats["MP_AX"] == np.float32(0.05)
    (fault,) = [m for m in msgs if m.get_type() == "NAMED_VALUE_INT"]
    assert fault.name == FAULT_EVENT_NAME and fault.value == 1 + 8  # x and p
    unisolated = DetectionEvent("unisolated", FaultMode.from_name("x+y"), 1.0, 0.95)
    out = EstimateOutput(1.0, nav, 47.0, 8.0, 150.0, modes, probs, (unisolated,), 100.0)
    kinds = [m.get_type() for m in Publisher(OutputRates()).messages(out)]
    assert "STATUSTEXT" in kinds and "NAMED_VALUE_INT" not in kinds
