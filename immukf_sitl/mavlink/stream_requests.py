"""``serve --request-streams``: ask the autopilot for the messages detection needs, at its rates.

First MAV_CMD_SET_MESSAGE_INTERVAL (COMMAND_LONG, one per message, ``param2`` the interval in
us), which ArduPilot 4.0+ and PX4 both take. A message whose command is not ACCEPTED within
:data:`ACK_WAIT_S` is asked for the old way, REQUEST_DATA_STREAM of the stream group ArduPilot
sends it in (``SRn_RAW_SENS`` for the IMU, ``SRn_RC_CHAN`` for the servo outputs,
``SRn_EXT_STAT`` for GPS_RAW_INT). :data:`REPORT_AFTER_S` after the first request the service
reports what arrived, at what rate, beside what it asked for.

The rates asked for are the lowest the measured rate table supports with every zeroed channel
found within 1 s and no false declaration (docs/autopilots.md): IMU 50 Hz, servo outputs
25 Hz, GPS 5 Hz.
"""

from __future__ import annotations

from immukf_sitl.mavlink.wire import MavMessage, mavlink

__all__ = ["ACK_WAIT_S", "REPORT_AFTER_S", "WANTED_HZ", "StreamRequest"]

#: message -> rate asked for (Hz); the IMU message depends on the autopilot
WANTED_HZ = {"IMU": 50.0, "SERVO_OUTPUT_RAW": 25.0, "GPS_RAW_INT": 5.0}
#: the IMU message each autopilot streams
IMU_MESSAGE = {
    mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA: "RAW_IMU",
    mavlink.MAV_AUTOPILOT_PX4: "HIGHRES_IMU",
}
#: REQUEST_DATA_STREAM group of each message (ArduPilot's SRn_* groups)
DATA_STREAM = {
    "RAW_IMU": mavlink.MAV_DATA_STREAM_RAW_SENSORS,
    "HIGHRES_IMU": mavlink.MAV_DATA_STREAM_RAW_SENSORS,
    "SERVO_OUTPUT_RAW": mavlink.MAV_DATA_STREAM_RC_CHANNELS,
    "GPS_RAW_INT": mavlink.MAV_DATA_STREAM_EXTENDED_STATUS,
}
#: seconds to wait for COMMAND_ACK before asking with REQUEST_DATA_STREAM
ACK_WAIT_S = 1.0
#: seconds after the first request before reporting what arrived
REPORT_AFTER_S = 5.0


class StreamRequest:
    """The requests to one autopilot, their acknowledgements and the report."""

    def __init__(self) -> None:
        self.target: tuple[int, int] | None = None
        self.wanted: dict[str, float] = {}
        self.accepted: set[str] = set()
        self.fallback: set[str] = set()
        self._asked_s: float | None = None
        self.reported = False

    def on_heartbeat(self, msg: MavMessage) -> None:
        """The first autopilot heard (ArduPilot or PX4) is the one asked."""
        if self.target is not None or msg.autopilot not in IMU_MESSAGE:
            return
        self.target = (msg.get_srcSystem(), msg.get_srcComponent())
        imu = IMU_MESSAGE[msg.autopilot]
        self.wanted = {imu: WANTED_HZ["IMU"]} | {k: v for k, v in WANTED_HZ.items() if k != "IMU"}

    def on_command_ack(self, msg: MavMessage) -> None:
        """Note which SET_MESSAGE_INTERVAL the autopilot accepted."""
        if msg.command != mavlink.MAV_CMD_SET_MESSAGE_INTERVAL or self._asked_s is None:
            return
        if msg.result == mavlink.MAV_RESULT_ACCEPTED:
            # acknowledgements come in the order asked; the first not yet accepted is this one
            for name in self.wanted:
                if name not in self.accepted:
                    self.accepted.add(name)
                    break

    def requests(self, now_s: float) -> list[MavMessage]:
        """What to send now: the interval commands first, REQUEST_DATA_STREAM once they lapse."""
        if self.target is None:
            return []
        system, component = self.target
        if self._asked_s is None:
            self._asked_s = now_s
            return [
                mavlink.MAVLink_command_long_message(
                    system,
                    component,
                    mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
                    0,
                    float(getattr(mavlink, f"MAVLINK_MSG_ID_{name}")),
                    1e6 / hz,
                    0,
                    0,
                    0,
                    0,
                    0,
                )  # fmt: skip
                for name, hz in self.wanted.items()
            ]
        if now_s - self._asked_s < ACK_WAIT_S:
            return []
        out = []
        for name, hz in self.wanted.items():
            if name in self.accepted or name in self.fallback:
                continue
            self.fallback.add(name)
            out.append(
                mavlink.MAVLink_request_data_stream_message(
                    system, component, DATA_STREAM[name], int(round(hz)), 1
                )
            )
        return out

    def report_due(self, now_s: float) -> bool:
        """Whether it is time for the one report of what arrived."""
        return (
            not self.reported
            and self._asked_s is not None
            and now_s - self._asked_s >= REPORT_AFTER_S
        )

    def report(self, rates_hz: dict[str, float | None]) -> str:
        """One line: each message asked for, how, and the rate that arrived."""
        self.reported = True
        parts = []
        for name, hz in self.wanted.items():
            how = (
                "SET_MESSAGE_INTERVAL"
                if name in self.accepted
                else "REQUEST_DATA_STREAM"
                if name in self.fallback
                else "no answer"
            )
            got = rates_hz.get(name)
            seen = "nothing" if got is None else f"{got:.1f} Hz"
            parts.append(f"{name} asked {hz:g} Hz ({how}), got {seen}")
        return "streams: " + "; ".join(parts)
