"""Servo outputs to control surfaces the way ArduPilot assigns them: SERVOn_* and mixing.

An ArduPilot aircraft says which output drives what with ``SERVOn_FUNCTION`` (4 aileron,
19 elevator, 21 rudder, 70 throttle, 77/78 left/right elevon, 79/80 left/right V-tail) and
how each output's pulse width maps to its travel with ``SERVOn_MIN``, ``SERVOn_TRIM``,
``SERVOn_MAX`` and ``SERVOn_REVERSED``. :class:`ServoMap` holds those parameters;
:class:`ControlMap` turns a SERVO_OUTPUT_RAW into the model's controls
``[delta_e, delta_a, delta_r (rad), delta_t (0..1)]`` and back.

The chain, as ArduPlane's ``SRV_Channel::pwm_from_angle`` and ``channel_function_mixer`` run
it forwards:

1. the attitude controllers command pitch-up, roll-right and yaw-right as fractions of full
   travel in ``[-1, 1]`` and throttle in ``[0, 1]``;
2. elevons mix ``left = g (pitch - roll)``, ``right = g (pitch + roll)`` and a V-tail
   ``left = g (pitch + yaw)``, ``right = g (pitch - yaw)``, with ``g`` = ``MIXING_GAIN``
   (default 0.5, so a mixed output never saturates);
3. a surface output is ``TRIM + f (MAX - TRIM)`` for ``f >= 0``, ``TRIM + f (TRIM - MIN)``
   below, ``f`` negated when reversed; the throttle is ``MIN + t (MAX - MIN)``.

:meth:`ServoMap.commands` inverts the chain exactly (up to the 1 us quantisation); when one
function sits on several outputs their commands are averaged. The command's sign becomes the
model's deflection through the airframe's own control derivatives: a pitch-up command is
the deflection whose ``C_m_delta_e`` gives a nose-up moment (the autopilot was set up so that
it flies), and its size is the params file's ``limit_rad``. ``MIXING_OFFSET``, differential
throws, flaperons and spoilers are not modelled.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from immukf_sitl.errors import UserError
from immukf_sitl.models.params import MAX_SERVO_CHANNEL, Actuators, AircraftParams

__all__ = [
    "FUNCTION_NAMES",
    "ControlMap",
    "ServoMap",
    "ServoMapError",
    "ServoOutput",
    "control_map_source",
    "has_servo_functions",
    "load_servo_map",
    "servo_parameter_names",
]

#: SERVOn_FUNCTION values this tool reads, and their ArduPilot names
FUNCTION_NAMES: dict[int, str] = {
    4: "aileron",
    19: "elevator",
    21: "rudder",
    70: "throttle",
    77: "elevon_left",
    78: "elevon_right",
    79: "vtail_left",
    80: "vtail_right",
}
#: what assigns each of the model's controls, for the error that names a missing one
_ASSIGNS = {
    "elevator": "SERVOn_FUNCTION 19 (elevator), or 77+78 (elevons), or 79+80 (V-tail)",
    "aileron": "SERVOn_FUNCTION 4 (aileron), or 77+78 (elevons)",
    "rudder": "SERVOn_FUNCTION 21 (rudder), or 79+80 (V-tail)",
    "throttle": "SERVOn_FUNCTION 70 (throttle)",
}
_PARAM = re.compile(r"^SERVO(\d+)_(FUNCTION|MIN|TRIM|MAX|REVERSED)$")
_FIELDS = ("FUNCTION", "MIN", "TRIM", "MAX", "REVERSED")


class ServoMapError(UserError):
    """A servo map that cannot drive the model: a one-line reason naming the parameter."""


def servo_parameter_names(channels: int = MAX_SERVO_CHANNEL) -> list[str]:
    """The ArduPilot parameters a map is read from, in the order an autopilot is asked."""
    names = [f"SERVO{n}_{f}" for n in range(1, channels + 1) for f in _FIELDS]
    return [*names, "MIXING_GAIN"]


@dataclass(frozen=True)
class ServoOutput:
    """One output: its function and ArduPilot's pulse-width range (us) about the trim."""

    channel: int
    function: int
    pwm_min: int = 1100
    pwm_trim: int = 1500
    pwm_max: int = 1900
    reversed: bool = False

    def __post_init__(self) -> None:
        where = f"SERVO{self.channel}"
        if not 1 <= self.channel <= MAX_SERVO_CHANNEL:
            raise ServoMapError(f"{where}: output number must be 1..{MAX_SERVO_CHANNEL}")
        if not 0 < self.pwm_min < self.pwm_max:
            raise ServoMapError(
                f"{where}_MIN/MAX: need 0 < MIN < MAX, got {self.pwm_min} and {self.pwm_max}"
            )
        if self.is_surface and not self.pwm_min < self.pwm_trim < self.pwm_max:
            raise ServoMapError(
                f"{where}_TRIM: need MIN < TRIM < MAX for a control surface, got "
                f"{self.pwm_min} < {self.pwm_trim} < {self.pwm_max}"
            )

    @property
    def name(self) -> str:
        """The function's ArduPilot name (``aileron``, ``elevon_left`` ...)."""
        return FUNCTION_NAMES.get(self.function, f"function {self.function}")

    @property
    def is_surface(self) -> bool:
        """Whether the output drives a control surface (an angle, centred on the trim)."""
        return self.function in FUNCTION_NAMES and self.function != 70

    def fraction(self, pwm_us: float) -> float:
        """Command in ``[-1, 1]`` (surface) or ``[0, 1]`` (throttle) of a pulse width."""
        if self.function == 70:
            frac = (pwm_us - self.pwm_min) / (self.pwm_max - self.pwm_min)
            frac = 1.0 - frac if self.reversed else frac
            return min(max(frac, 0.0), 1.0)
        if pwm_us >= self.pwm_trim:
            frac = (pwm_us - self.pwm_trim) / (self.pwm_max - self.pwm_trim)
        else:
            frac = (pwm_us - self.pwm_trim) / (self.pwm_trim - self.pwm_min)
        frac = min(max(frac, -1.0), 1.0)
        return -frac if self.reversed else frac

    def pwm(self, fraction: float) -> int:
        """Pulse width (us, rounded) of a command: :meth:`fraction`'s inverse."""
        if self.function == 70:
            frac = min(max(fraction, 0.0), 1.0)
            frac = 1.0 - frac if self.reversed else frac
            return int(round(self.pwm_min + frac * (self.pwm_max - self.pwm_min)))
        frac = min(max(fraction, -1.0), 1.0)
        frac = -frac if self.reversed else frac
        span = (self.pwm_max - self.pwm_trim) if frac >= 0.0 else (self.pwm_trim - self.pwm_min)
        return int(round(self.pwm_trim + frac * span))


@dataclass(frozen=True)
class ServoMap:
    """The outputs that drive the aircraft, and the elevon/V-tail mixing gain.

    Construction checks that every control the model has (elevator, aileron, rudder,
    throttle) is driven, directly or through a mix, and raises :class:`ServoMapError`
    naming the first that is not.
    """

    outputs: tuple[ServoOutput, ...]
    mixing_gain: float = 0.5
    source: str = "<memory>"

    def __post_init__(self) -> None:
        if not (math.isfinite(self.mixing_gain) and 0.0 < self.mixing_gain <= 1.0):
            raise ServoMapError(
                f"{self.source}: MIXING_GAIN must be in (0, 1], got {self.mixing_gain}"
            )
        have = {o.function for o in self.outputs}
        for side in ((77, 78), (79, 80)):
            if (side[0] in have) != (side[1] in have):
                one, other = (side[0], side[1]) if side[0] in have else (side[1], side[0])
                raise ServoMapError(
                    f"{self.source}: SERVOn_FUNCTION {one} ({FUNCTION_NAMES[one]}) needs "
                    f"its pair {other} ({FUNCTION_NAMES[other]}) on another output"
                )
        drives = {
            "elevator": bool(have & {19, 77, 79}),
            "aileron": bool(have & {4, 77}),
            "rudder": bool(have & {21, 79}),
            "throttle": 70 in have,
        }
        for control, driven in drives.items():
            if not driven:
                raise ServoMapError(
                    f"{self.source}: the {control} is unassigned: set {_ASSIGNS[control]}"
                )

    @classmethod
    def from_params(cls, params: Mapping[str, float], source: str = "parameters") -> ServoMap:
        """The map ArduPilot's ``SERVOn_*`` and ``MIXING_GAIN`` parameters describe.

        Outputs whose function this tool does not read (0 disabled, cameras, flaps ...) are
        ignored; a function without MIN/TRIM/MAX takes ArduPilot's defaults (1100, 1500, 1900).
        """
        fields: dict[int, dict[str, float]] = {}
        for name, value in params.items():
            match = _PARAM.match(str(name).upper())
            if match is None:
                continue
            if not (isinstance(value, (int, float)) and math.isfinite(value)):
                raise ServoMapError(f"{source}: {name} is not a number ({value!r})")
            fields.setdefault(int(match[1]), {})[match[2]] = float(value)
        outputs = []
        for channel in sorted(fields):
            f = fields[channel]
            function = int(f.get("FUNCTION", 0))
            if function not in FUNCTION_NAMES:
                continue
            outputs.append(
                ServoOutput(
                    channel=channel,
                    function=function,
                    pwm_min=int(f.get("MIN", 1100)),
                    pwm_trim=int(f.get("TRIM", 1500)),
                    pwm_max=int(f.get("MAX", 1900)),
                    reversed=bool(f.get("REVERSED", 0)),
                )
            )
        gain = params.get("MIXING_GAIN", 0.5)
        return cls(tuple(outputs), float(gain), source)

    def to_params(self) -> dict[str, float]:
        """``SERVOn_*`` and ``MIXING_GAIN`` as an ArduPilot autopilot reports them."""
        params: dict[str, float] = {}
        for o in self.outputs:
            n = o.channel
            params |= {
                f"SERVO{n}_FUNCTION": float(o.function),
                f"SERVO{n}_MIN": float(o.pwm_min),
                f"SERVO{n}_TRIM": float(o.pwm_trim),
                f"SERVO{n}_MAX": float(o.pwm_max),
                f"SERVO{n}_REVERSED": float(o.reversed),
            }
        params["MIXING_GAIN"] = float(self.mixing_gain)
        return params

    @classmethod
    def layout(cls, name: str) -> ServoMap:
        """ArduPlane's default outputs for a tail layout: ``conventional``, ``elevon``, ``vtail``.

        Conventional is ArduPlane's AETR (1 aileron, 2 elevator, 3 throttle, 4 rudder); elevons
        take outputs 1 and 2 and V-tails 2 and 4, the others as AETR. Surfaces 1000-1500-2000 us.
        """
        functions = {
            "conventional": (4, 19, 70, 21),
            "elevon": (77, 78, 70, 21),
            "vtail": (4, 79, 70, 80),
        }
        if name not in functions:
            raise ServoMapError(f"servo layout {name!r}: expected one of {', '.join(functions)}")
        outputs = tuple(
            ServoOutput(channel=n, function=f, pwm_min=1000, pwm_trim=1500, pwm_max=2000)
            for n, f in enumerate(functions[name], start=1)
        )
        return cls(outputs, 0.5, f"ArduPlane {name} layout")

    def commands(self, pwm_us: Sequence[float]) -> np.ndarray:
        """``[pitch_up, roll_right, yaw_right, throttle]`` commanded by a SERVO_OUTPUT_RAW.

        ``pwm_us[i]`` is output ``i + 1``. Raises ``ValueError`` when an output the map uses
        is missing or not finite.
        """
        sums: dict[int, list[float]] = {}
        for o in self.outputs:
            try:
                value = float(pwm_us[o.channel - 1])
            except IndexError as exc:
                raise ValueError(f"servo output {o.channel} missing from PWM outputs") from exc
            if not math.isfinite(value) or value <= 0.0:
                raise ValueError(f"servo output {o.channel}: no pulse ({value})")
            sums.setdefault(o.function, []).append(o.fraction(value))
        mean = {f: sum(v) / len(v) for f, v in sums.items()}
        two_g = 2.0 * self.mixing_gain
        pitch, roll, yaw = (mean.get(f, 0.0) for f in (19, 4, 21))
        if 77 in mean:  # left = g (pitch - roll), right = g (pitch + roll)
            pitch = (mean[77] + mean[78]) / two_g
            roll = (mean[78] - mean[77]) / two_g
        if 79 in mean:  # left = g (pitch + yaw), right = g (pitch - yaw)
            pitch = (mean[79] + mean[80]) / two_g if 77 not in mean else pitch
            yaw = (mean[79] - mean[80]) / two_g
        return np.array([pitch, roll, yaw, mean[70]])

    def pwm(self, commands: Sequence[float]) -> dict[int, int]:
        """Pulse width per output of ``[pitch_up, roll_right, yaw_right, throttle]``."""
        pitch, roll, yaw, throttle = (float(c) for c in commands)
        g = self.mixing_gain
        by_function = {
            4: roll,
            19: pitch,
            21: yaw,
            70: throttle,
            77: g * (pitch - roll),
            78: g * (pitch + roll),
            79: g * (pitch + yaw),
            80: g * (pitch - yaw),
        }
        return {o.channel: o.pwm(by_function[o.function]) for o in self.outputs}


class ControlMap:
    """A :class:`ServoMap` on an airframe: SERVO_OUTPUT_RAW <-> the model's controls.

    Parameters
    ----------
    servo_map : ServoMap
    params : AircraftParams
        The airframe: its deflection limits (``actuators.*.limit_rad``) and the signs of
        ``C_m_delta_e``, ``C_ell_delta_a`` and ``C_n_delta_r`` (which deflection pitches up,
        rolls right, yaws right).
    """

    def __init__(self, servo_map: ServoMap, params: AircraftParams) -> None:
        self.servo_map = servo_map
        self.actuators = params.actuators
        aero = params.aero
        act = params.actuators
        signs = (
            math.copysign(1.0, aero.C_m_delta_e),
            math.copysign(1.0, aero.C_ell_delta_a),
            math.copysign(1.0, aero.C_n_delta_r),
        )
        limits = (act.elevator.limit_rad, act.aileron.limit_rad, act.rudder.limit_rad)
        #: radians of deflection per unit command, signed (pitch-up, roll-right, yaw-right)
        self.rad_per_command = np.array([s * lim for s, lim in zip(signs, limits, strict=True)])

    @property
    def source(self) -> str:
        """Where the map came from (for reports)."""
        return self.servo_map.source

    def pwm_to_controls(self, pwm_us: Sequence[float]) -> np.ndarray:
        """``[delta_e, delta_a, delta_r (rad), delta_t]`` commanded by the outputs."""
        commands = self.servo_map.commands(pwm_us)
        controls = np.empty(4)
        controls[:3] = commands[:3] * self.rad_per_command
        controls[3] = commands[3]
        return controls

    def controls_to_pwm(self, controls: Sequence[float] | np.ndarray) -> dict[int, int]:
        """Pulse width per output that commands the controls (the inverse)."""
        c = np.asarray(controls, dtype=float).reshape(4)
        commands = [*(c[:3] / self.rad_per_command), c[3]]
        return self.servo_map.pwm(commands)


def _read_parameter_file(text: str, source: str) -> dict[str, float]:
    """Parameters from ArduPilot's file formats, or a YAML mapping of the same names.

    ``NAME VALUE`` (MAVProxy) or ``NAME,VALUE`` (Mission Planner) per line, ``#`` comments.
    """
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError:
        data = None
    if isinstance(data, Mapping):
        return {str(k): v for k, v in data.items()}
    params: dict[str, float] = {}
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        parts = re.split(r"[,\s]+", line)
        if len(parts) < 2:
            raise ServoMapError(f"{source}:{number}: expected NAME VALUE, got {raw.strip()!r}")
        try:
            params[parts[0]] = float(parts[1])
        except ValueError:
            raise ServoMapError(
                f"{source}:{number}: {parts[0]} is not a number ({parts[1]!r})"
            ) from None
    return params


def load_servo_map(path: str | Path) -> ServoMap:
    """Read a ``--servo-map`` file: ArduPilot parameters (``.parm``/``.param`` or YAML).

    Raises :class:`ServoMapError` (one line) for an unreadable file, a bad line or a map that
    leaves a control unassigned.
    """
    file = Path(path)
    try:
        text = file.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ServoMapError(f"{file}: cannot read the servo map: {exc}") from None
    params = _read_parameter_file(text, str(file))
    if not any(_PARAM.match(str(k).upper()) for k in params):
        raise ServoMapError(f"{file}: no SERVOn_FUNCTION/MIN/TRIM/MAX/REVERSED in it")
    return ServoMap.from_params(params, str(file))


def has_servo_functions(params: Mapping[str, float]) -> bool:
    """Whether autopilot parameters (a log's, a vehicle's) say what its outputs drive."""
    return any(
        str(name).upper().endswith("_FUNCTION") and _PARAM.match(str(name).upper())
        for name in params
    )


def control_map_source(control_map: Actuators | ControlMap) -> str:
    """Where a pipeline's PWM-to-controls map comes from, for the operator."""
    if isinstance(control_map, ControlMap):
        return control_map.source
    a = control_map
    return (
        f"the params file's channels (aileron {a.aileron.servo_channel}, elevator "
        f"{a.elevator.servo_channel}, throttle {a.throttle.servo_channel}, rudder "
        f"{a.rudder.servo_channel})"
    )
