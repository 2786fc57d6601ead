"""Ask an ArduPilot vehicle for its servo outputs' parameters and build the servo map from them.

ArduPilot answers PARAM_REQUEST_READ by name with one PARAM_VALUE. :class:`ServoParamRequest`
asks for every ``SERVOn_FUNCTION/MIN/TRIM/MAX/REVERSED`` and ``MIXING_GAIN`` (81 names), asks
again for those still unanswered every :data:`RETRY_S`, and after :data:`ATTEMPTS` rounds takes
the silence for absence (a board with fewer than 16 outputs has no SERVO15_*). It also reads
PARAM_VALUEs nobody asked for (a ground station's parameter download on the same link).

Only a vehicle whose HEARTBEAT says ``MAV_AUTOPILOT_ARDUPILOTMEGA`` is asked; with no answer
at all after the last round the service goes on with the aircraft file's channel map and says
so once.
"""

from __future__ import annotations

from immukf_sitl.mavlink.wire import MavMessage, mavlink
from immukf_sitl.models.servo_map import ServoMap, servo_parameter_names

__all__ = ["ATTEMPTS", "RETRY_S", "ServoParamRequest"]

#: seconds between rounds of requests for the names still unanswered
RETRY_S = 1.0
#: rounds before an unanswered name counts as absent
ATTEMPTS = 3


class ServoParamRequest:
    """The parameters of the servo map, requested from one ArduPilot vehicle and collected."""

    def __init__(self) -> None:
        self.names = servo_parameter_names()
        self.values: dict[str, float] = {}
        self.target: tuple[int, int] | None = None
        self.rounds = 0
        self._next_round_s = 0.0

    def on_heartbeat(self, msg: MavMessage) -> None:
        """Note an ArduPilot vehicle (the first one heard) as the one to ask."""
        if self.target is None and msg.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA:
            self.target = (msg.get_srcSystem(), msg.get_srcComponent())

    def on_param_value(self, msg: MavMessage) -> None:
        """Keep a PARAM_VALUE if it is one of the map's."""
        name = msg.param_id.rstrip("\x00") if isinstance(msg.param_id, str) else ""
        if name in self.names:
            self.values[name] = float(msg.param_value)

    @property
    def missing(self) -> list[str]:
        """Names asked for and not answered yet."""
        return [n for n in self.names if n not in self.values]

    @property
    def done(self) -> bool:
        """Whether every name has been answered, or the last round has passed."""
        return not self.missing or self.rounds >= ATTEMPTS

    def requests(self, now_s: float) -> list[MavMessage]:
        """PARAM_REQUEST_READ for each unanswered name, when a round is due (else none)."""
        if self.target is None or self.done or now_s < self._next_round_s:
            return []
        self.rounds += 1
        self._next_round_s = now_s + RETRY_S
        system, component = self.target
        return [
            mavlink.MAVLink_param_request_read_message(system, component, name.encode(), -1)
            for name in self.missing
        ]

    def servo_map(self) -> ServoMap | None:
        """The map the answers describe (None when nothing was answered).

        Raises :class:`~immukf_sitl.models.servo_map.ServoMapError` when it leaves a control
        surface unassigned.
        """
        if not any(name.startswith("SERVO") for name in self.values):
            return None
        return ServoMap.from_params(self.values, "the vehicle's SERVOn_* parameters")
