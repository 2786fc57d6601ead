"""Outbound messages of the estimator service (README, "The wire").

Builds ATTITUDE, ATTITUDE_QUATERNION, GLOBAL_POSITION_INT, NAMED_VALUE_FLOAT (P(no failure)
and P(each channel failed), the mode probabilities of the paper's bank), NAMED_VALUE_INT
``IMM_FAULT`` (the bits of every channel declared after each detection or
clearing, time-stamped, so a tlog reader sees when it happened) and STATUSTEXT from an
:class:`~immukf_sitl.service.pipeline.EstimateOutput`, at configurable rates of the IMU clock.

A detection is announced once, but UDP may lose that one datagram: a ground station under load
once recorded 2466 of the estimator's NAMED_VALUE_FLOAT and not its single STATUSTEXT. So each
event's STATUSTEXT is sent again :data:`STATUSTEXT_REPEATS_S` after it (three sends over 2 s of
the IMU clock), unless a newer event supersedes it. The IMM_FAULT record, which tlog readers
take as the event, is sent once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from immukf_sitl.estimation.fault_modes import FaultMode, failure_marginals, single_fault_modes
from immukf_sitl.fault_kinds import FAULT_KINDS
from immukf_sitl.mavlink.codec import euler_to_quaternion, heartbeat_message
from immukf_sitl.mavlink.wire import MavMessage, mavlink
from immukf_sitl.service.detection import DetectionEvent
from immukf_sitl.service.pipeline import EstimateOutput

_CHANNEL_TAGS = {"x": "AX", "y": "AY", "z": "AZ", "p": "P", "q": "Q", "r": "R"}
FAULT_EVENT_NAME = "IMM_FAULT"
#: NAMED_VALUE_INT of a named failure: 1 + its index in ``fault_kinds.FAULT_KINDS``
KIND_EVENT_NAME = "IMM_KIND"
#: NAMED_VALUE_FLOAT of a named failure's size (NaN for a zero)
SIZE_EVENT_NAME = "IMM_SIZE"
#: when an event's STATUSTEXT is sent again, after the event (s of the IMU clock)
STATUSTEXT_REPEATS_S = (1.0, 2.0)


def probability_name(mode: FaultMode) -> str:
    """NAMED_VALUE_FLOAT name of a mode's probability: ``MP_NONE``, ``MP_AX`` ... ``MP_R``."""
    if mode.bits == 0:
        return "MP_NONE"
    return ("MP_" + "".join(_CHANNEL_TAGS[c] for c in mode.channels))[:10]


@dataclass(frozen=True)
class OutputRates:
    """Publication rates (Hz of the IMU clock); at most the IMU rate."""

    attitude_hz: float = 50.0
    position_hz: float = 10.0
    probabilities_hz: float = 10.0
    heartbeat_hz: float = 1.0


class _Every:
    """True once per period of a (sample) clock."""

    def __init__(self, rate_hz: float) -> None:
        self.period_s = 1.0 / rate_hz if rate_hz > 0 else math.inf
        self.next_s = -math.inf

    def due(self, t_s: float) -> bool:
        if t_s + 1e-9 >= self.next_s:
            base = t_s if self.next_s == -math.inf else self.next_s
            self.next_s = max(base + self.period_s, t_s)
            return True
        return False


def heartbeat() -> MavMessage:
    """The estimator's HEARTBEAT: onboard controller, no autopilot."""
    return heartbeat_message(mavlink.MAV_TYPE_ONBOARD_CONTROLLER)


def event_text(event: DetectionEvent) -> MavMessage:
    """STATUSTEXT of a detection or naming (WARNING) or clearing (INFO)."""
    severity = (
        mavlink.MAV_SEVERITY_INFO if event.kind == "cleared" else mavlink.MAV_SEVERITY_WARNING
    )
    return mavlink.MAVLink_statustext_message(severity, event.text().encode())


def event_messages(event: DetectionEvent) -> list[MavMessage]:
    """STATUSTEXT and IMM_FAULT of a detection or clearing; of a naming, IMM_KIND and IMM_SIZE."""
    ms = int(round(event.t_s * 1000.0))
    if event.kind == "named":
        kind = FAULT_KINDS.index(event.failure) + 1 if event.failure in FAULT_KINDS else 0
        size = math.nan if event.size is None else float(event.size)
        return [
            event_text(event),
            mavlink.MAVLink_named_value_int_message(ms, KIND_EVENT_NAME.encode(), kind),
            mavlink.MAVLink_named_value_float_message(ms, SIZE_EVENT_NAME.encode(), size),
        ]
    if event.kind == "unisolated":
        return [event_text(event)]
    if event.declared_after is not None:
        value = event.declared_after.bits
    else:
        value = event.mode.bits if event.kind == "detected" else 0
    return [
        event_text(event),
        mavlink.MAVLink_named_value_int_message(ms, FAULT_EVENT_NAME.encode(), value),
    ]


class Publisher:
    """Turns estimator outputs into outbound messages at the configured rates."""

    def __init__(self, rates: OutputRates | None = None) -> None:
        self.rates = rates if rates is not None else OutputRates()
        self._attitude = _Every(self.rates.attitude_hz)
        self._position = _Every(self.rates.position_hz)
        self._probs = _Every(self.rates.probabilities_hz)
        self._heartbeat = _Every(self.rates.heartbeat_hz)
        self._repeats: list[tuple[float, DetectionEvent]] = []  # (due time, event), in order

    def messages(self, out: EstimateOutput) -> list[MavMessage]:
        """Everything due at this output's time (events always)."""
        t_s = out.t_s
        ms = int(round(t_s * 1000.0))
        nav = out.nav
        msgs: list[MavMessage] = []
        if self._heartbeat.due(t_s):
            msgs.append(heartbeat())
        if out.events:
            self._repeats = []  # a newer event supersedes what was pending
        while self._repeats and t_s + 1e-9 >= self._repeats[0][0]:
            msgs.append(event_text(self._repeats.pop(0)[1]))
        for event in out.events:
            msgs.extend(event_messages(event))
            self._repeats.extend((event.t_s + dt, event) for dt in STATUSTEXT_REPEATS_S)
        self._repeats.sort(key=lambda due: due[0])
        roll, pitch, yaw = (float(a) for a in nav.euler_rad)
        p, q, r = (float(w) for w in nav.rates_radps)
        if self._attitude.due(t_s):
            msgs.append(mavlink.MAVLink_attitude_message(ms, roll, pitch, yaw, p, q, r))
            quat = euler_to_quaternion(nav.euler_rad)
            msgs.append(
                mavlink.MAVLink_attitude_quaternion_message(
                    ms, *(float(c) for c in quat), p, q, r, [0.0, 0.0, 0.0, 0.0]
                )
            )
        if self._position.due(t_s):
            vel = nav.velocity_ned_mps
            heading_cdeg = int(round(math.degrees(yaw) * 100.0)) % 36000
            msgs.append(
                mavlink.MAVLink_global_position_int_message(
                    ms,
                    int(round(out.lat_deg * 1e7)),
                    int(round(out.lon_deg * 1e7)),
                    int(round(out.alt_m * 1000.0)),
                    int(round(-nav.position_ned_m[2] * 1000.0)),
                    *(int(np.clip(round(v * 100.0), -32767, 32767)) for v in vel),
                    heading_cdeg,
                )
            )
        if self._probs.due(t_s):
            marginals = failure_marginals(out.modes, out.mode_probabilities)
            for mode, prob in zip(single_fault_modes(), marginals, strict=True):
                msgs.append(
                    mavlink.MAVLink_named_value_float_message(
                        ms, probability_name(mode).encode(), float(prob)
                    )
                )
        return msgs
