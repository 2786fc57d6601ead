"""Aircraft parameters: the YAML file validated into frozen dataclasses.

The one parameter file (``sim/aircraft/aerosonde/params.yaml``) is read by both the JSBSim truth
aircraft and the filter's aerodynamic model, so that they share mass, geometry, aerodynamic
coefficients, propulsion and the actuator map (SERVO_OUTPUT_RAW PWM <-> deflection).

Every field is required and no unknown field is accepted; a bad file raises a single
:class:`AircraftParamsError` whose one-line message names the file, the field and what was
expected. Controls follow ``docs/conventions.md``: ``u = [delta_e, delta_a, delta_r, delta_t]``.
"""

import dataclasses
import importlib.resources
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import yaml

from immukf_sitl.errors import UserError

__all__ = [
    "AeroCoefficients",
    "AircraftParams",
    "AircraftParamsError",
    "Actuators",
    "Geometry",
    "MassProperties",
    "Propulsion",
    "ServoChannel",
    "ThrottleChannel",
    "default_params_path",
    "load_aircraft_params",
]

#: Highest channel number of MAVLink's SERVO_OUTPUT_RAW (servo1_raw .. servo16_raw).
MAX_SERVO_CHANNEL = 16


class AircraftParamsError(UserError, ValueError):
    """A missing, unknown, mistyped or non-physical aircraft parameter.

    Parameters
    ----------
    message : str
        One-line description naming the file (when known), the field and what was expected.
    field : str, optional
        Dotted name of the offending field, relative to the object that raised it.
    """

    def __init__(self, message: str, field: str | None = None) -> None:
        super().__init__(message)
        self.field = field
        self.detail = message


def _fail(field: str, expected: str, got: object) -> AircraftParamsError:
    """Build the error of one field (``field: expected ..., got ...``)."""
    err = AircraftParamsError(f"{field}: expected {expected}, got {got!r}", field=field)
    err.detail = f"expected {expected}, got {got!r}"
    return err


def _require(ok: bool, field: str, expected: str, got: object) -> None:
    if not ok:
        raise _fail(field, expected, got)


def _positive(obj: object, names: Sequence[str]) -> None:
    for name in names:
        value = getattr(obj, name)
        _require(value > 0.0, name, "a value > 0", value)


@dataclass(frozen=True)
class MassProperties:
    """Mass and inertia about the CG in body FRD axes (Beard & McLain eq. 3.x convention).

    The inertia matrix is ``[[Jx, 0, -Jxz], [0, Jy, 0], [-Jxz, 0, Jz]]`` (book sign of Jxz).
    """

    mass_kg: float
    Jx_kgm2: float
    Jy_kgm2: float
    Jz_kgm2: float
    Jxz_kgm2: float

    def __post_init__(self) -> None:
        _positive(self, ("mass_kg", "Jx_kgm2", "Jy_kgm2", "Jz_kgm2"))
        det_xz = self.Jx_kgm2 * self.Jz_kgm2 - self.Jxz_kgm2**2
        _require(
            det_xz > 0.0,
            "Jxz_kgm2",
            f"Jx*Jz > Jxz^2 (positive definite inertia), Jx*Jz = {self.Jx_kgm2 * self.Jz_kgm2:.6g}",
            self.Jxz_kgm2,
        )
        principal = np.linalg.eigvalsh(self.inertia_kgm2)
        # A rigid body's principal moments obey the triangle inequality.
        _require(
            bool(principal[0] + principal[1] >= principal[2] * (1.0 - 1e-12)),
            "Jz_kgm2",
            "principal moments obeying the triangle inequality (physical rigid body)",
            self.Jz_kgm2,
        )

    @property
    def inertia_kgm2(self) -> np.ndarray:
        """The 3x3 inertia matrix about the CG, body FRD axes (kg m^2)."""
        return np.array(
            [
                [self.Jx_kgm2, 0.0, -self.Jxz_kgm2],
                [0.0, self.Jy_kgm2, 0.0],
                [-self.Jxz_kgm2, 0.0, self.Jz_kgm2],
            ]
        )


@dataclass(frozen=True)
class Geometry:
    """Reference geometry and the IMU lever arm (body FRD, metres from the CG)."""

    S_m2: float
    b_m: float
    c_m: float
    e: float
    imu_position_m: tuple[float, float, float]

    def __post_init__(self) -> None:
        _positive(self, ("S_m2", "b_m", "c_m"))
        _require(0.0 < self.e <= 1.0, "e", "an Oswald efficiency in (0, 1]", self.e)
        _require(
            len(self.imu_position_m) == 3 and max(abs(v) for v in self.imu_position_m) < 10.0,
            "imu_position_m",
            "3 coordinates within 10 m of the CG",
            self.imu_position_m,
        )


@dataclass(frozen=True)
class AeroCoefficients:
    """Non-dimensional aerodynamic coefficients of Beard & McLain ch. 4 (angles in rad).

    Rate derivatives are per unit of the non-dimensional rates ``b p / (2 Va)``,
    ``c q / (2 Va)``, ``b r / (2 Va)``.
    """

    C_L_0: float
    C_L_alpha: float
    C_L_q: float
    C_L_delta_e: float
    M: float
    alpha0_rad: float
    C_D_0: float
    C_D_alpha: float
    C_D_q: float
    C_D_delta_e: float
    epsilon: float
    C_m_0: float
    C_m_alpha: float
    C_m_q: float
    C_m_delta_e: float
    C_Y_0: float
    C_Y_beta: float
    C_Y_p: float
    C_Y_r: float
    C_Y_delta_a: float
    C_Y_delta_r: float
    C_ell_0: float
    C_ell_beta: float
    C_ell_p: float
    C_ell_r: float
    C_ell_delta_a: float
    C_ell_delta_r: float
    C_n_0: float
    C_n_beta: float
    C_n_p: float
    C_n_r: float
    C_n_delta_a: float
    C_n_delta_r: float

    def __post_init__(self) -> None:
        _positive(self, ("M", "alpha0_rad"))
        _require(
            self.alpha0_rad < math.pi / 2, "alpha0_rad", "a stall angle < pi/2", self.alpha0_rad
        )


@dataclass(frozen=True)
class Propulsion:
    """DC motor + propeller of the Beard & McLain supplement (chapter 4).

    ``C_T`` and ``C_Q`` are polynomial coefficients ``(c0, c1, c2)`` in the advance ratio
    ``J = 2 pi Va / (Omega D)``. The motor voltage is ``V_max_V * delta_t``.
    """

    prop_diameter_m: float
    KV_rpm_per_V: float
    R_motor_ohm: float
    i0_A: float
    V_max_V: float
    C_T: tuple[float, float, float]
    C_Q: tuple[float, float, float]
    prop_torque_on_roll: bool

    def __post_init__(self) -> None:
        _positive(self, ("prop_diameter_m", "KV_rpm_per_V", "R_motor_ohm", "V_max_V"))
        _require(self.i0_A >= 0.0, "i0_A", "a value >= 0", self.i0_A)
        _require(len(self.C_T) == 3, "C_T", "3 polynomial coefficients [c0, c1, c2]", self.C_T)
        _require(len(self.C_Q) == 3, "C_Q", "3 polynomial coefficients [c0, c1, c2]", self.C_Q)
        _require(self.C_T[0] > 0.0, "C_T", "a static thrust coefficient c0 > 0", self.C_T)
        # c0 > 0 makes the propeller-speed quadratic's leading coefficient positive.
        _require(self.C_Q[0] > 0.0, "C_Q", "a static torque coefficient c0 > 0", self.C_Q)

    @property
    def K_V_Vs_per_rad(self) -> float:
        """Back-EMF constant K_V = (1/KV)(60/2pi) in V s/rad (equal to K_Q in N m/A)."""
        return 60.0 / (2.0 * math.pi * self.KV_rpm_per_V)

    @property
    def K_Q_Nm_per_A(self) -> float:
        """Torque constant K_Q, equal to K_V in SI units."""
        return self.K_V_Vs_per_rad


def _check_channel(servo_channel: int) -> None:
    _require(
        1 <= servo_channel <= MAX_SERVO_CHANNEL,
        "servo_channel",
        f"a SERVO_OUTPUT_RAW channel in 1..{MAX_SERVO_CHANNEL}",
        servo_channel,
    )


@dataclass(frozen=True)
class ServoChannel:
    """PWM map of one control surface: piecewise linear about trim, +-limit at the ends."""

    servo_channel: int
    limit_rad: float
    pwm_min: int
    pwm_trim: int
    pwm_max: int
    reversed: bool

    def __post_init__(self) -> None:
        _check_channel(self.servo_channel)
        _require(
            0.0 < self.limit_rad < math.pi / 2,
            "limit_rad",
            "a deflection limit in (0, pi/2)",
            self.limit_rad,
        )
        _require(self.pwm_min > 0, "pwm_min", "a PWM > 0 us", self.pwm_min)
        _require(
            self.pwm_min < self.pwm_trim < self.pwm_max,
            "pwm_trim",
            f"pwm_min < pwm_trim < pwm_max ({self.pwm_min} < trim < {self.pwm_max})",
            self.pwm_trim,
        )

    def pwm_to_rad(self, pwm: float) -> float:
        """Deflection (rad) commanded by a PWM pulse width (us), clipped to +-limit."""
        if pwm >= self.pwm_trim:
            frac = (pwm - self.pwm_trim) / (self.pwm_max - self.pwm_trim)
        else:
            frac = (pwm - self.pwm_trim) / (self.pwm_trim - self.pwm_min)
        frac = min(max(frac, -1.0), 1.0)
        return (-frac if self.reversed else frac) * self.limit_rad

    def rad_to_pwm(self, deflection_rad: float) -> int:
        """PWM pulse width (us, rounded) that commands a deflection, clipped to +-limit."""
        frac = min(max(deflection_rad / self.limit_rad, -1.0), 1.0)
        if self.reversed:
            frac = -frac
        span = (self.pwm_max - self.pwm_trim) if frac >= 0.0 else (self.pwm_trim - self.pwm_min)
        return int(round(self.pwm_trim + frac * span))


@dataclass(frozen=True)
class ThrottleChannel:
    """PWM map of the throttle: linear from 0 at pwm_min to 1 at pwm_max."""

    servo_channel: int
    pwm_min: int
    pwm_max: int

    def __post_init__(self) -> None:
        _check_channel(self.servo_channel)
        _require(self.pwm_min > 0, "pwm_min", "a PWM > 0 us", self.pwm_min)
        _require(
            self.pwm_min < self.pwm_max,
            "pwm_max",
            f"pwm_max > pwm_min ({self.pwm_min})",
            self.pwm_max,
        )

    def pwm_to_throttle(self, pwm: float) -> float:
        """Throttle in [0, 1] commanded by a PWM pulse width (us)."""
        frac = (pwm - self.pwm_min) / (self.pwm_max - self.pwm_min)
        return min(max(frac, 0.0), 1.0)

    def throttle_to_pwm(self, delta_t: float) -> int:
        """PWM pulse width (us, rounded) commanding a throttle, clipped to [0, 1]."""
        frac = min(max(delta_t, 0.0), 1.0)
        return int(round(self.pwm_min + frac * (self.pwm_max - self.pwm_min)))


@dataclass(frozen=True)
class Actuators:
    """Channel map and PWM maps of the four controls ``[delta_e, delta_a, delta_r, delta_t]``."""

    elevator: ServoChannel
    aileron: ServoChannel
    rudder: ServoChannel
    throttle: ThrottleChannel

    def __post_init__(self) -> None:
        channels = [self.elevator, self.aileron, self.rudder, self.throttle]
        numbers = [c.servo_channel for c in channels]
        _require(
            len(set(numbers)) == len(numbers),
            "servo_channel",
            "distinct channels for elevator, aileron, rudder, throttle",
            numbers,
        )

    @property
    def lower_limits(self) -> np.ndarray:
        """Lower bounds of ``[delta_e, delta_a, delta_r, delta_t]`` (rad, rad, rad, 1)."""
        return np.array(
            [-self.elevator.limit_rad, -self.aileron.limit_rad, -self.rudder.limit_rad, 0.0]
        )

    @property
    def upper_limits(self) -> np.ndarray:
        """Upper bounds of ``[delta_e, delta_a, delta_r, delta_t]`` (rad, rad, rad, 1)."""
        return np.array(
            [self.elevator.limit_rad, self.aileron.limit_rad, self.rudder.limit_rad, 1.0]
        )

    def pwm_to_controls(self, pwm_by_channel: Mapping[int, float] | Sequence[float]) -> np.ndarray:
        """Controls commanded by the servo outputs.

        Parameters
        ----------
        pwm_by_channel : Mapping[int, float] or Sequence[float]
            PWM pulse widths (us), either a mapping from 1-based channel number, or a sequence
            whose element ``i`` is channel ``i + 1`` (SERVO_OUTPUT_RAW ``servo1_raw`` ...).

        Returns
        -------
        numpy.ndarray
            ``(4,)`` array ``[delta_e, delta_a, delta_r (rad), delta_t (0..1)]``, each clipped
            to its limits.

        Raises
        ------
        ValueError
            If a channel the aircraft uses is missing or its PWM is not finite.
        """

        def pwm_of(channel: int) -> float:
            try:
                if isinstance(pwm_by_channel, Mapping):
                    value = float(pwm_by_channel[channel])
                else:
                    value = float(pwm_by_channel[channel - 1])
            except (KeyError, IndexError) as exc:
                raise ValueError(f"servo channel {channel} missing from PWM outputs") from exc
            if not math.isfinite(value):
                raise ValueError(f"servo channel {channel}: PWM is not finite ({value})")
            return value

        return np.array(
            [
                self.elevator.pwm_to_rad(pwm_of(self.elevator.servo_channel)),
                self.aileron.pwm_to_rad(pwm_of(self.aileron.servo_channel)),
                self.rudder.pwm_to_rad(pwm_of(self.rudder.servo_channel)),
                self.throttle.pwm_to_throttle(pwm_of(self.throttle.servo_channel)),
            ]
        )

    def controls_to_pwm(self, controls: Sequence[float] | np.ndarray) -> dict[int, int]:
        """PWM pulse widths (us) that command the controls (inverse of :meth:`pwm_to_controls`).

        Parameters
        ----------
        controls : array_like
            ``(4,)`` ``[delta_e, delta_a, delta_r (rad), delta_t (0..1)]``; values beyond the
            limits are clipped.

        Returns
        -------
        dict[int, int]
            PWM per 1-based servo channel.
        """
        de, da, dr, dt = (float(c) for c in np.asarray(controls, dtype=float).reshape(4))
        return {
            self.elevator.servo_channel: self.elevator.rad_to_pwm(de),
            self.aileron.servo_channel: self.aileron.rad_to_pwm(da),
            self.rudder.servo_channel: self.rudder.rad_to_pwm(dr),
            self.throttle.servo_channel: self.throttle.throttle_to_pwm(dt),
        }


@dataclass(frozen=True)
class AircraftParams:
    """Everything the aircraft model and the truth simulator share."""

    mass: MassProperties
    geometry: Geometry
    aero: AeroCoefficients
    propulsion: Propulsion
    actuators: Actuators
    source: str = "<memory>"

    _sections: ClassVar[tuple[str, ...]] = (
        "mass",
        "geometry",
        "aero",
        "propulsion",
        "actuators",
    )


# ---------------------------------------------------------------------------------------------
# Loading


def default_params_path() -> Path:
    """Path of the packaged Aerosonde parameter file, located relative to the ``sim`` package."""
    try:
        root = importlib.resources.files("sim")
        candidate = Path(str(root / "aircraft" / "aerosonde" / "params.yaml"))
        if candidate.is_file():
            return candidate
    except ModuleNotFoundError:
        pass
    # Source checkout without the ``sim`` package importable: the repository layout.
    return Path(__file__).resolve().parents[2] / "sim" / "aircraft" / "aerosonde" / "params.yaml"


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _convert(value: Any, annotation: Any, where: str) -> Any:
    """Check one YAML value against a field's annotation and convert it."""
    if annotation is float:
        if not _is_number(value) or not math.isfinite(value):
            raise AircraftParamsError(f"{where}: expected a finite number, got {value!r}")
        return float(value)
    if annotation is int:
        if not isinstance(value, int) or isinstance(value, bool):
            raise AircraftParamsError(f"{where}: expected an integer, got {value!r}")
        return value
    if annotation is bool:
        if not isinstance(value, bool):
            raise AircraftParamsError(f"{where}: expected true or false, got {value!r}")
        return value
    if annotation == tuple[float, float, float]:
        if (
            not isinstance(value, list)
            or len(value) != 3
            or not all(_is_number(v) and math.isfinite(v) for v in value)
        ):
            raise AircraftParamsError(
                f"{where}: expected a list of 3 finite numbers, got {value!r}"
            )
        return tuple(float(v) for v in value)
    if dataclasses.is_dataclass(annotation):
        return _build(annotation, value, where)
    raise TypeError(f"no converter for {annotation!r}")  # pragma: no cover - programming error


def _build(cls: Any, data: Any, where: str) -> Any:
    """Build the dataclass ``cls`` from a YAML mapping, naming ``where`` in any error."""
    if not isinstance(data, Mapping):
        raise AircraftParamsError(f"{where}: expected a mapping, got {data!r}")
    fields = [f for f in dataclasses.fields(cls) if f.name != "source"]
    names = [f.name for f in fields]
    unknown = [k for k in data if k not in names]
    if unknown:
        raise AircraftParamsError(
            f"{where}.{unknown[0]}: unknown field (expected one of {', '.join(names)})"
        )
    values = {}
    for f in fields:
        if f.name not in data:
            raise AircraftParamsError(f"{where}.{f.name}: missing field")
        values[f.name] = _convert(data[f.name], f.type, f"{where}.{f.name}")
    try:
        return cls(**values)
    except AircraftParamsError as exc:
        if exc.field is None:
            raise
        raise AircraftParamsError(f"{where}.{exc.field}: {exc.detail}", field=exc.field) from None


def load_aircraft_params(path: str | Path | None = None) -> AircraftParams:
    """Read and validate an aircraft parameter file.

    Parameters
    ----------
    path : str or pathlib.Path, optional
        YAML file; default: the packaged Aerosonde (:func:`default_params_path`).

    Returns
    -------
    AircraftParams
        The validated, immutable parameters.

    Raises
    ------
    AircraftParamsError
        With a one-line message naming the file, the field and what was expected, for any
        missing, unknown, mistyped or non-physical field, or an unreadable file.
    """
    file = Path(path) if path is not None else default_params_path()
    try:
        text = file.read_text(encoding="utf-8")
        data = yaml.safe_load(text)
    except (OSError, yaml.YAMLError) as exc:
        detail = " ".join(str(exc).split())
        raise AircraftParamsError(f"{file}: cannot read aircraft parameters: {detail}") from None
    try:
        if not isinstance(data, Mapping):
            raise AircraftParamsError(f"top level: expected a mapping, got {data!r}")
        values = {}
        unknown = [k for k in data if k not in AircraftParams._sections]
        if unknown:
            raise AircraftParamsError(
                f"{unknown[0]}: unknown section (expected {', '.join(AircraftParams._sections)})"
            )
        hints = {f.name: f.type for f in dataclasses.fields(AircraftParams)}
        for section in AircraftParams._sections:
            if section not in data:
                raise AircraftParamsError(f"{section}: missing section")
            values[section] = _build(hints[section], data[section], section)
        return AircraftParams(source=str(file), **values)
    except AircraftParamsError as exc:
        raise AircraftParamsError(f"{file}: {exc.detail}", field=exc.field) from None
