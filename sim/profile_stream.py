"""The sim's stream shaped as one autopilot sends it: messages, rates, units and parameters.

:class:`ProfileStream` turns each truth record (one per truth step) into what a
:class:`~immukf_sitl.stream_profile.StreamProfile` puts on the wire at that moment, in
sending order: HEARTBEAT (1 Hz of sim time, with the profile's autopilot), GPS_RAW_INT (when
the record has a fix; the native profile's HIL_GPS for a receiver that reports its vertical
velocity, which ArduPilot's and PX4's GPS_RAW_INT drop), SERVO_OUTPUT_RAW (when due at the
servo rate) and the IMU messages (when due at the IMU rate). An IMU message carries the mean of
the samples since the last one (the mean of one sample is the sample itself), stamped with the
last sample's time, in the message's own units and integer quantisation
(:func:`immukf_sitl.mavlink.codec.imu_message`). The ArduPilot profile sends a second IMU
as SCALED_IMU2, with its own noise and turn-on bias, as a Pixhawk's second IMU would.

:class:`ParamServer` answers PARAM_REQUEST_READ and PARAM_REQUEST_LIST the way ArduPilot does,
with the ``SERVOn_*`` and ``MIXING_GAIN`` of the profile's servo layout (outputs it does not use
report function 0 and ArduPilot's default range). Both autopilot profiles take
MAV_CMD_SET_MESSAGE_INTERVAL for their IMU and servo messages (COMMAND_ACK ACCEPTED, DENIED for
anything else, GPS included: a receiver's rate is its own) and REQUEST_DATA_STREAM of
RAW_SENSORS and RC_CHANNELS, as ``serve --request-streams`` asks.
"""

from __future__ import annotations

import numpy as np

from immukf_sitl.mavlink.codec import (
    gps_message,
    gps_raw_int_message,
    heartbeat_message,
    imu_message,
    servo_output_raw_message,
)
from immukf_sitl.mavlink.wire import MavMessage, mavlink
from immukf_sitl.models.params import MAX_SERVO_CHANNEL, Actuators
from immukf_sitl.models.sensors import ImuSpec
from immukf_sitl.models.servo_map import ControlMap, ServoMap
from immukf_sitl.samples import ActuatorSample, ImuSample
from immukf_sitl.stream_profile import TRUTH_RATE_HZ, StreamProfile
from sim.flight import FlightRecord
from sim.sensors import ImuModel

__all__ = ["AUTOPILOTS", "ParamServer", "ProfileStream", "SECOND_IMU_STREAM_INDEX"]

#: HEARTBEAT ``autopilot`` of each profile
AUTOPILOTS = {
    "native": mavlink.MAV_AUTOPILOT_INVALID,
    "ardupilot": mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
    "px4": mavlink.MAV_AUTOPILOT_PX4,
}
#: seed spawn key of the second IMU's noise (its bias: the next one)
SECOND_IMU_STREAM_INDEX = 6
#: tolerance of "a message is due" against float step times (s)
_DUE_TOL_S = 1e-6


class _Due:
    """A periodic stream's schedule: due at its first call, then every ``period_s``."""

    def __init__(self, rate_hz: float) -> None:
        self.period_s = 1.0 / rate_hz
        self.next_s: float | None = None

    def __call__(self, time_s: float) -> bool:
        if self.next_s is None:
            self.next_s = time_s
        if time_s < self.next_s - _DUE_TOL_S:
            return False
        while self.next_s <= time_s + _DUE_TOL_S:
            self.next_s += self.period_s
        return True


class _Mean:
    """The IMU samples since the last message, and their mean."""

    def __init__(self) -> None:
        self.samples: list[ImuSample] = []

    def add(self, sample: ImuSample) -> None:
        self.samples.append(sample)

    def take(self) -> ImuSample:
        samples, self.samples = self.samples, []
        if len(samples) == 1:
            return samples[0]
        return ImuSample(
            time_s=samples[-1].time_s,
            accel_mps2=np.mean([s.accel_mps2 for s in samples], axis=0),
            gyro_radps=np.mean([s.gyro_radps for s in samples], axis=0),
        )


class ProfileStream:
    """The MAVLink messages of each truth record under a profile (no sockets).

    Parameters
    ----------
    profile : StreamProfile
    actuators : Actuators
        The airframe's channel map (``params.actuators``): the native and PX4 outputs.
    control_map : ControlMap, optional
        The ArduPilot profile's servo layout on the airframe (required for ``ardupilot``).
    second_imu : ImuModel, optional
        The ArduPilot profile's second IMU (SCALED_IMU2).
    heartbeat_period_s : float, optional
        Sim time between HEARTBEATs (s).
    """

    def __init__(
        self,
        profile: StreamProfile,
        actuators: Actuators,
        control_map: ControlMap | None = None,
        second_imu: ImuModel | None = None,
        heartbeat_period_s: float = 1.0,
    ) -> None:
        if profile.name == "ardupilot" and (control_map is None or second_imu is None):
            raise ValueError("the ardupilot profile needs its servo layout and second IMU")
        self.profile = profile
        self.outputs: Actuators | ControlMap = control_map if control_map else actuators
        self.second_imu = second_imu
        self.autopilot = AUTOPILOTS[profile.name]
        self.heartbeat_period_s = float(heartbeat_period_s)
        self._next_heartbeat_s = 0.0
        self._servo_due = _Due(profile.servo_rate_hz)
        self._imu_due = _Due(profile.imu_rate_hz)
        self._means = [_Mean() for _ in profile.imu_messages]
        #: whether the last record's messages carried the IMU (the lock-step acknowledges it)
        self.sent_imu = False

    def set_rate(self, message: str, rate_hz: float) -> bool:
        """Stream ``message`` at ``rate_hz`` from now on, as the autopilot would be asked to.

        Takes the IMU messages (up to the truth's own rate) and SERVO_OUTPUT_RAW; the GPS
        rate is the receiver's and cannot change. Returns whether the rate was taken.
        """
        truth_hz = max(self.profile.imu_rate_hz, TRUTH_RATE_HZ)
        if message in self.profile.imu_messages and 0.0 < rate_hz <= truth_hz + 1e-9:
            self._imu_due = _Due(rate_hz)
            return True
        if message == "SERVO_OUTPUT_RAW" and 0.0 < rate_hz <= truth_hz + 1e-9:
            self._servo_due = _Due(rate_hz)
            return True
        return False

    def on_request(self, request: MavMessage) -> list[MavMessage]:
        """Answers to SET_MESSAGE_INTERVAL (COMMAND_ACK) and REQUEST_DATA_STREAM (none)."""
        if self.profile.name == "native":
            return []
        kind = request.get_type()
        if kind == "COMMAND_LONG" and request.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            name = mavlink.mavlink_map.get(int(request.param1))
            interval_us = float(request.param2)
            rate_hz = 1e6 / interval_us if interval_us > 0 else 0.0
            taken = name is not None and rate_hz > 0 and self.set_rate(name.msgname, rate_hz)
            result = mavlink.MAV_RESULT_ACCEPTED if taken else mavlink.MAV_RESULT_DENIED
            return [mavlink.MAVLink_command_ack_message(request.command, result)]
        if kind == "REQUEST_DATA_STREAM" and request.start_stop and request.req_message_rate > 0:
            names = {
                mavlink.MAV_DATA_STREAM_RAW_SENSORS: self.profile.imu_messages,
                mavlink.MAV_DATA_STREAM_RC_CHANNELS: ("SERVO_OUTPUT_RAW",),
            }.get(request.req_stream_id, ())
            for name in names[:1]:
                self.set_rate(name, float(request.req_message_rate))
        return []

    def actuator_sample(self, record: FlightRecord) -> ActuatorSample:
        """The record's controls as PWM per servo output (1..16, 0 = unused)."""
        pwm = [0] * MAX_SERVO_CHANNEL
        for channel, value in self.outputs.controls_to_pwm(record.controls).items():
            pwm[channel - 1] = value
        return ActuatorSample(record.time_s, tuple(pwm))

    def messages(self, record: FlightRecord) -> list[MavMessage]:
        """What goes on the wire for this record, in sending order."""
        out: list[MavMessage] = []
        if record.time_s >= self._next_heartbeat_s - _DUE_TOL_S:
            out.append(heartbeat_message(mavlink.MAV_TYPE_FIXED_WING, self.autopilot))
            self._next_heartbeat_s += self.heartbeat_period_s
        if record.gps is not None:
            native = self.profile.name == "native"
            out.append(gps_message(record.gps) if native else gps_raw_int_message(record.gps))
        if self._servo_due(record.time_s):
            out.append(servo_output_raw_message(self.actuator_sample(record)))
        self._means[0].add(record.imu)
        if self.second_imu is not None:
            self._means[1].add(self.second_imu.read(record.truth))
        self.sent_imu = self._imu_due(record.time_s)
        if self.sent_imu:
            for instance, (kind, mean) in enumerate(
                zip(self.profile.imu_messages, self._means, strict=True)
            ):
                out.append(imu_message(kind, mean.take(), instance))
        return out


def second_imu(spec: ImuSpec, seed: int, dt_s: float) -> ImuModel:
    """The ArduPilot profile's second IMU: the same spec, its own noise and turn-on bias."""
    noise = np.random.SeedSequence(seed, spawn_key=(SECOND_IMU_STREAM_INDEX,))
    bias = np.random.SeedSequence(seed, spawn_key=(SECOND_IMU_STREAM_INDEX + 1,))
    return ImuModel(spec, np.random.default_rng(noise), np.random.default_rng(bias), dt_s)


class ParamServer:
    """ArduPilot's answers to parameter requests: the servo layout's ``SERVOn_*``."""

    def __init__(self, servo_map: ServoMap) -> None:
        params = {
            **{
                f"SERVO{n}_{f}": v
                for n in range(1, MAX_SERVO_CHANNEL + 1)
                for f, v in (
                    ("FUNCTION", 0.0),
                    ("MIN", 1100.0),
                    ("TRIM", 1500.0),
                    ("MAX", 1900.0),
                    ("REVERSED", 0.0),
                )
            },
            **servo_map.to_params(),
        }
        self.params = params
        self.names = list(params)

    def _value(self, name: str) -> MavMessage:
        kind = (
            mavlink.MAV_PARAM_TYPE_REAL32
            if name == "MIXING_GAIN"
            else (mavlink.MAV_PARAM_TYPE_INT16)
        )
        return mavlink.MAVLink_param_value_message(
            name.encode(), self.params[name], kind, len(self.names), self.names.index(name)
        )

    def answer(self, request: MavMessage) -> list[MavMessage]:
        """PARAM_VALUEs answering a PARAM_REQUEST_READ or _LIST (nothing for an unknown name)."""
        kind = request.get_type()
        if kind == "PARAM_REQUEST_LIST":
            return [self._value(name) for name in self.names]
        if kind != "PARAM_REQUEST_READ":
            return []
        name = request.param_id.rstrip("\x00") if isinstance(request.param_id, str) else ""
        if name in self.params:
            return [self._value(name)]
        if 0 <= request.param_index < len(self.names) and not name:
            return [self._value(self.names[request.param_index])]
        return []
