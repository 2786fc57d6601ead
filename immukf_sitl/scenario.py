"""Scenario files: a flight, its sensors and a schedule of injected faults (YAML).

A wrong file gets one line naming the file, the field and what was expected
(:class:`ScenarioError`). The schema, with every default (docs/scenarios.md shows it too)::

    name: q-gyro-zeroed            # required, a label
    description: ...               # optional
    duration_s: 90                 # required, > 0
    seed: 7                        # required, integer: every noise source derives from it
    start:                         # optional: initial position (also the sim's NED origin)
      lat_deg: 47.3977
      lon_deg: 8.5456
      alt_m: 150                   # WGS-84 height (m)
      airspeed_mps: 25
      heading_deg: 0
    flight_plan:                   # required
      loop: true
      acceptance_radius_m: 15
      waypoints:                   # north/east about the start, height above the ellipsoid
        - {north_m: 400, east_m: 0, alt_m: 150, airspeed_mps: 25}
    sensors:                       # optional, defaults of Beard & McLain ch. 7
      imu: {accel_sigma_mps2: 0.0245, gyro_sigma_radps: 0.00227,
            accel_bias_mps2: [0, 0, 0], gyro_bias_radps: [0, 0, 0],
            accel_bias_sigma_mps2: 0, gyro_bias_sigma_radps: 0,   # spec sheet: turn-on bias
            bias_instability: false,       # true: the bias also wanders (Gauss-Markov)
            accel_range_mps2: 156.9, gyro_range_radps: 34.9}  # full scale: 16 g, 2000 deg/s
      gps: {rate_hz: 1, north_east_sigma_m: 0.21, height_sigma_m: 0.40,
            ground_speed_sigma_mps: 0.05, course_sigma_mps: 0.05,
            k_gps_per_s: 0.000909}          # Gauss-Markov position error, 1/1100 1/s
    airframe:                      # optional: the flown aircraft differs from params.yaml
      scale: {mass_kg: 1.05, C_m_alpha: 1.1}   # multiply named parameters
      uncertainty: {aero: 0.10, mass: 0.05, inertia: 0.10}  # 1-sigma relative, drawn from seed
    wind:                          # optional: JSBSim's own atmosphere
      speed_mps: 6                 # steady wind at the start height
      from_deg: 270                # where it blows from, true north
      down_mps: 0
      turbulence: light            # none | light | moderate | severe (MIL-F-8785C)
    faults:                        # optional list, applied by the fault proxy
      - t_s: 30                    # start time (s, sim clock)
        end_t_s: 60                # optional: the sensor recovers
        channels: [q]              # any of x, y, z (accelerometers), p, q, r (gyros)
        kind: zero                 # zero | stuck | bias | drift | scale | noise | spikes
        value: 0.2                 # bias: offset (m/s^2 or rad/s); drift: its rate per s;
                                   # scale: gain; noise: sigma factor; spikes: size
                                   # (zero and stuck take none)
        rate_hz: 2                 # spikes only: spikes per second (Poisson)
        imu: 0                     # optional: which of the profile's IMUs fails (0 first;
                                   # ardupilot sends two), the others stay healthy
    manoeuvres:                    # optional: control doublets on top of the autopilot
      - t_s: 31                    # start (s)
        kind: rudder_doublet       # rudder_doublet | aileron_doublet | elevator_doublet
        amplitude_rad: 0.1         # first half +amplitude, second half -amplitude
        duration_s: 2.0
    profile: native                # optional: native | ardupilot | px4, or a mapping:
                                   # {name: ardupilot, imu_hz: 50, servo_hz: 10, gps_hz: 5,
                                   #  servo_layout: conventional | elevon | vtail}
    expect:                        # optional: what a run should report
      detect: q                    # fault mode name ("none" for a fault-free flight)
      within_s: 1.0                # detection delay from the fault becoming observable
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from immukf_sitl.errors import UserError
from immukf_sitl.estimation.fault_modes import IMU_CHANNELS, FaultMode
from immukf_sitl.fault_kinds import FAULT_KINDS, check_fault_parameters
from immukf_sitl.models.airframe import AirframeSpec, AirframeUncertainty, scalable_parameters
from immukf_sitl.models.params import load_aircraft_params
from immukf_sitl.models.sensors import GpsSpec, ImuSpec, SensorSpec
from immukf_sitl.models.wind import TURBULENCE_LEVELS, WindSpec
from immukf_sitl.stream_profile import StreamProfile
from immukf_sitl.yaml_fields import YamlFields

MANOEUVRE_KINDS = ("elevator_doublet", "aileron_doublet", "rudder_doublet")


class ScenarioError(UserError):
    """A scenario file that cannot be used; the message is one line."""


@dataclass(frozen=True)
class StartSpec:
    """Initial conditions (trimmed, wings level)."""

    lat_deg: float = 47.3977
    lon_deg: float = 8.5456
    alt_m: float = 150.0
    airspeed_mps: float = 25.0
    heading_deg: float = 0.0


@dataclass(frozen=True)
class Waypoint:
    """One point of a flight plan.

    Attributes
    ----------
    north_m, east_m : float
        Horizontal position in the NED frame of the simulation's origin (the start) (m).
    alt_m : float
        Height above the WGS-84 ellipsoid to hold on the leg towards this waypoint (m).
    airspeed_mps : float
        Airspeed to hold on the leg towards this waypoint (m/s).
    """

    north_m: float
    east_m: float
    alt_m: float
    airspeed_mps: float = 25.0

    def __post_init__(self) -> None:
        values = (self.north_m, self.east_m, self.alt_m, self.airspeed_mps)
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f"waypoint: expected finite values, got {values}")
        if not 12.0 <= self.airspeed_mps <= 40.0:
            raise ValueError(f"airspeed_mps: expected 12..40 m/s, got {self.airspeed_mps}")


@dataclass(frozen=True)
class FlightPlan:
    """Waypoints flown in order by straight legs (the autopilot's plan).

    Attributes
    ----------
    waypoints : tuple of Waypoint
        At least one waypoint. The first leg starts where the aircraft is when the autopilot
        starts.
    acceptance_radius_m : float
        A waypoint is reached within this horizontal distance (or when its perpendicular plane
        is crossed).
    loop : bool
        After the last waypoint, fly to the first again (``True``) or hold the last leg's line
        (``False``).
    """

    waypoints: tuple[Waypoint, ...]
    acceptance_radius_m: float = 15.0
    loop: bool = False

    def __post_init__(self) -> None:
        if len(self.waypoints) == 0:
            raise ValueError("waypoints: expected at least one waypoint")
        if not self.acceptance_radius_m > 0.0:
            raise ValueError(
                f"acceptance_radius_m: expected a value > 0, got {self.acceptance_radius_m}"
            )


@dataclass(frozen=True)
class FaultSpec:
    """One injected fault on one or more IMU channels (kinds: :mod:`immukf_sitl.fault_kinds`)."""

    t_s: float
    channels: tuple[str, ...]
    kind: str = "zero"
    value: float = 0.0
    end_t_s: float | None = None
    rate_hz: float = 0.0
    #: the failing IMU instance (a real failure takes one IMU; its siblings stay healthy)
    imu: int = 0

    @property
    def mode(self) -> FaultMode:
        """The fault mode these channels form."""
        return FaultMode.from_channels(self.channels)

    def active(self, time_s: float) -> bool:
        """Whether the fault acts at ``time_s``."""
        return time_s >= self.t_s and (self.end_t_s is None or time_s < self.end_t_s)


@dataclass(frozen=True)
class ManoeuvreSpec:
    """A control doublet added to the autopilot's command of one surface."""

    t_s: float
    kind: str
    amplitude_rad: float
    duration_s: float

    @property
    def control_index(self) -> int:
        """Index in ``[delta_e, delta_a, delta_r, delta_t]`` (docs/conventions.md)."""
        return MANOEUVRE_KINDS.index(self.kind)

    def offset_rad(self, time_s: float) -> float:
        """The doublet's deflection at ``time_s`` (0 outside it)."""
        elapsed = time_s - self.t_s
        if elapsed < 0.0 or elapsed >= self.duration_s:
            return 0.0
        return self.amplitude_rad if elapsed < 0.5 * self.duration_s else -self.amplitude_rad


@dataclass(frozen=True)
class ExpectSpec:
    """What a run of this scenario should report."""

    detect: str = "none"
    within_s: float = 1.0


@dataclass(frozen=True)
class Scenario:
    """A validated scenario file."""

    name: str
    duration_s: float
    seed: int
    flight_plan: FlightPlan
    start: StartSpec = field(default_factory=StartSpec)
    sensors: SensorSpec = field(default_factory=SensorSpec)
    airframe: AirframeSpec = field(default_factory=AirframeSpec)
    wind: WindSpec = field(default_factory=WindSpec)
    faults: tuple[FaultSpec, ...] = ()
    manoeuvres: tuple[ManoeuvreSpec, ...] = ()
    expect: ExpectSpec | None = None
    description: str = ""
    path: str = ""
    profile: StreamProfile = field(default_factory=StreamProfile)


# -- parsing -------------------------------------------------------------------------------------


def _reader(path: str, where: str, data: Any) -> YamlFields:
    """A reader of one mapping of a scenario file: its errors are :class:`ScenarioError`."""
    return YamlFields(path, where, data, ScenarioError)


def _waypoint(path: str, where: str, data: Any) -> Waypoint:
    r = _reader(path, where, data)
    wp = Waypoint(
        north_m=r.number("north_m"),
        east_m=r.number("east_m"),
        alt_m=r.number("alt_m", lo=-400.0, hi=10000.0),
        airspeed_mps=r.number("airspeed_mps", 25.0, lo=18.0, hi=32.0),
    )
    r.done()
    return wp


def _flight_plan(r: YamlFields) -> FlightPlan:
    raw = r.raw("waypoints")
    if not isinstance(raw, list) or not raw:
        r.fail("waypoints", "a non-empty list of waypoints", raw)
    waypoints = tuple(
        _waypoint(r.path, f"{r.name('waypoints')}[{i}]", item) for i, item in enumerate(raw)
    )
    plan = FlightPlan(
        waypoints=waypoints,
        loop=r.boolean("loop", True),
        acceptance_radius_m=r.number("acceptance_radius_m", 15.0, lo=0.0, lo_open=True),
    )
    r.done()
    return plan


def _fault(path: str, where: str, data: Any, duration_s: float) -> FaultSpec:
    r = _reader(path, where, data)
    t_s = r.number("t_s", lo=0.0, hi=duration_s)
    channels = r.raw("channels")
    if isinstance(channels, str):
        channels = [channels]
    if (
        not isinstance(channels, list)
        or not channels
        or any(c not in IMU_CHANNELS for c in channels)
        or len(set(channels)) != len(channels)
    ):
        r.fail("channels", f"a list of distinct channels from {', '.join(IMU_CHANNELS)}", channels)
    kind = r.string("kind", "zero")
    if kind not in FAULT_KINDS:
        r.fail("kind", f"one of {', '.join(FAULT_KINDS)}", kind)
    value = r.number("value") if r.has("value") else None
    rate_hz = r.number("rate_hz") if r.has("rate_hz") else None
    problem = check_fault_parameters(kind, value, rate_hz)
    if problem is not None:
        raise r.error(f"{r.path}: {r.where}.{problem}")
    end_t_s = None
    if r.has("end_t_s"):
        end_t_s = r.number("end_t_s", lo=t_s, lo_open=True)
    imu = r.integer("imu", 0)
    r.done()
    ordered = tuple(c for c in IMU_CHANNELS if c in channels)
    return FaultSpec(
        t_s=t_s,
        channels=ordered,
        kind=kind,
        value=value or 0.0,
        end_t_s=end_t_s,
        rate_hz=rate_hz or 0.0,
        imu=imu,
    )


def _manoeuvre(path: str, where: str, data: Any, duration_s: float) -> ManoeuvreSpec:
    r = _reader(path, where, data)
    kind = r.string("kind")
    if kind not in MANOEUVRE_KINDS:
        r.fail("kind", f"one of {', '.join(MANOEUVRE_KINDS)}", kind)
    spec = ManoeuvreSpec(
        t_s=r.number("t_s", lo=0.0, hi=duration_s),
        kind=kind,
        amplitude_rad=r.number("amplitude_rad", lo=-0.44, hi=0.44),
        duration_s=r.number("duration_s", lo=0.0, hi=60.0, lo_open=True),
    )
    r.done()
    return spec


def _sensors(r: YamlFields) -> SensorSpec:
    """The ``sensors:`` block; every default is that of :class:`SensorSpec`."""
    imu_r = r.child("imu", {})
    d_imu = ImuSpec()
    imu = ImuSpec(
        accel_sigma_mps2=imu_r.number("accel_sigma_mps2", d_imu.accel_sigma_mps2, lo=0.0),
        gyro_sigma_radps=imu_r.number("gyro_sigma_radps", d_imu.gyro_sigma_radps, lo=0.0),
        accel_bias_mps2=imu_r.vector3("accel_bias_mps2", d_imu.accel_bias_mps2),
        gyro_bias_radps=imu_r.vector3("gyro_bias_radps", d_imu.gyro_bias_radps),
        accel_bias_sigma_mps2=imu_r.number(
            "accel_bias_sigma_mps2", d_imu.accel_bias_sigma_mps2, lo=0.0, hi=1.0
        ),
        gyro_bias_sigma_radps=imu_r.number(
            "gyro_bias_sigma_radps", d_imu.gyro_bias_sigma_radps, lo=0.0, hi=0.1
        ),
        bias_instability=imu_r.boolean("bias_instability", d_imu.bias_instability),
        accel_bias_instability_mps2=imu_r.number(
            "accel_bias_instability_mps2", d_imu.accel_bias_instability_mps2, lo=0.0, hi=1.0
        ),
        gyro_bias_instability_radps=imu_r.number(
            "gyro_bias_instability_radps", d_imu.gyro_bias_instability_radps, lo=0.0, hi=0.1
        ),
        bias_time_constant_s=imu_r.number(
            "bias_time_constant_s", d_imu.bias_time_constant_s, lo=1.0, hi=1e5
        ),
        accel_range_mps2=imu_r.number(
            "accel_range_mps2", d_imu.accel_range_mps2, lo=0.0, lo_open=True
        ),
        gyro_range_radps=imu_r.number(
            "gyro_range_radps", d_imu.gyro_range_radps, lo=0.0, lo_open=True
        ),
    )
    imu_r.done()
    gps_r = r.child("gps", {})
    d_gps = GpsSpec()
    gps = GpsSpec(
        rate_hz=gps_r.number("rate_hz", d_gps.rate_hz, lo=0.0, hi=100.0, lo_open=True),
        north_east_sigma_m=gps_r.number("north_east_sigma_m", d_gps.north_east_sigma_m, lo=0.0),
        height_sigma_m=gps_r.number("height_sigma_m", d_gps.height_sigma_m, lo=0.0),
        ground_speed_sigma_mps=gps_r.number(
            "ground_speed_sigma_mps", d_gps.ground_speed_sigma_mps, lo=0.0
        ),
        course_sigma_mps=gps_r.number("course_sigma_mps", d_gps.course_sigma_mps, lo=0.0),
        k_gps_per_s=gps_r.number("k_gps_per_s", d_gps.k_gps_per_s, lo=0.0, hi=10.0),
        velocity_down_sigma_mps=gps_r.number(
            "velocity_down_sigma_mps", d_gps.velocity_down_sigma_mps, lo=0.0, lo_open=True
        ),
        reports_velocity_down=gps_r.boolean("reports_velocity_down", d_gps.reports_velocity_down),
    )
    gps_r.done()
    r.done()
    return SensorSpec(imu=imu, gps=gps)


def _airframe(r: YamlFields) -> AirframeSpec:
    """The ``airframe:`` block; ``scale`` names are checked against the parameter file."""
    scale_r = r.child("scale", {})
    known = scalable_parameters(load_aircraft_params())
    for name in scale_r.data:
        if name not in known:
            raise ScenarioError(
                f"{r.path}: {scale_r.name(name)}: unknown parameter (expected a numeric field of "
                "params.yaml, e.g. mass_kg, Jx_kgm2, C_m_alpha)"
            )
    scale = {name: scale_r.number(name, lo=0.0, hi=10.0, lo_open=True) for name in scale_r.data}
    scale_r.done()
    unc_r = r.child("uncertainty", {})
    uncertainty = AirframeUncertainty(
        aero=unc_r.number("aero", 0.0, lo=0.0, hi=0.5),
        mass=unc_r.number("mass", 0.0, lo=0.0, hi=0.5),
        inertia=unc_r.number("inertia", 0.0, lo=0.0, hi=0.5),
    )
    unc_r.done()
    r.done()
    return AirframeSpec(scale=scale, uncertainty=uncertainty)


def _wind(r: YamlFields) -> WindSpec:
    """The ``wind:`` block."""
    turbulence = r.string("turbulence", "none")
    if turbulence not in TURBULENCE_LEVELS:
        r.fail("turbulence", f"one of {', '.join(TURBULENCE_LEVELS)}", turbulence)
    wind = WindSpec(
        speed_mps=r.number("speed_mps", 0.0, lo=0.0, hi=30.0),
        from_deg=r.number("from_deg", 0.0, lo=-360.0, hi=360.0),
        down_mps=r.number("down_mps", 0.0, lo=-5.0, hi=5.0),
        turbulence=turbulence,
    )
    r.done()
    return wind


def _profile(path: str, r: YamlFields) -> StreamProfile:
    """The ``profile:`` field: a name, or a mapping with the name and its rates."""
    raw = r.raw("profile", "native")
    if isinstance(raw, str):
        raw = {"name": raw}
    p = _reader(path, "profile", raw)
    values = {
        "name": p.string("name", "native"),
        "servo_layout": p.string("servo_layout", "conventional"),
    }
    for key in ("imu_hz", "servo_hz", "gps_hz"):
        if p.raw(key, None) is not None:
            values[key] = p.number(key)
    p.done()
    try:
        return StreamProfile(**values)
    except ValueError as exc:
        raise ScenarioError(f"{path}: profile: {exc}") from None


def parse_sensors(data: Any, path: str = "<sensors>") -> SensorSpec:
    """Validate a ``sensors:`` mapping (a scenario's block, or a ``--sensors`` file's content).

    A file may hold the block itself or a mapping with a ``sensors:`` key (a whole scenario).
    """
    if isinstance(data, Mapping) and "sensors" in data:
        return _sensors(_reader(path, "sensors", data["sensors"]))
    return _sensors(_reader(path, "", data if data is not None else {}))


def sensors_to_yaml(spec: SensorSpec) -> str:
    """A ``--sensors`` file holding ``spec`` (every key the ``sensors:`` schema has)."""
    imu, gps = spec.imu, spec.gps
    data = {
        "imu": {
            "accel_sigma_mps2": imu.accel_sigma_mps2,
            "gyro_sigma_radps": imu.gyro_sigma_radps,
            "accel_bias_mps2": list(imu.accel_bias_mps2),
            "gyro_bias_radps": list(imu.gyro_bias_radps),
            "accel_bias_sigma_mps2": imu.accel_bias_sigma_mps2,
            "gyro_bias_sigma_radps": imu.gyro_bias_sigma_radps,
            "bias_instability": imu.bias_instability,
            "accel_bias_instability_mps2": imu.accel_bias_instability_mps2,
            "gyro_bias_instability_radps": imu.gyro_bias_instability_radps,
            "bias_time_constant_s": imu.bias_time_constant_s,
        },
        "gps": {
            "rate_hz": gps.rate_hz,
            "north_east_sigma_m": gps.north_east_sigma_m,
            "height_sigma_m": gps.height_sigma_m,
            "ground_speed_sigma_mps": gps.ground_speed_sigma_mps,
            "course_sigma_mps": gps.course_sigma_mps,
            "k_gps_per_s": gps.k_gps_per_s,
        },
    }
    return yaml.safe_dump({"sensors": data}, sort_keys=False)


def load_sensors(path: str | Path) -> SensorSpec:
    """Read a ``--sensors`` file; raises :class:`ScenarioError` with one line."""
    return parse_sensors(_load_yaml(Path(path), "sensors file"), str(path))


def parse_scenario(data: Any, path: str = "<scenario>") -> Scenario:
    """Validate parsed YAML into a :class:`Scenario`; raises :class:`ScenarioError`."""
    r = _reader(path, "", data)
    duration_s = r.number("duration_s", lo=1.0, hi=24 * 3600.0)
    start_r = r.child("start", {})
    start = StartSpec(
        lat_deg=start_r.number("lat_deg", 47.3977, lo=-85.0, hi=85.0),
        lon_deg=start_r.number("lon_deg", 8.5456, lo=-180.0, hi=180.0),
        alt_m=start_r.number("alt_m", 150.0, lo=-400.0, hi=10000.0),
        airspeed_mps=start_r.number("airspeed_mps", 25.0, lo=18.0, hi=32.0),
        heading_deg=start_r.number("heading_deg", 0.0, lo=-360.0, hi=360.0),
    )
    start_r.done()
    sensors = _sensors(r.child("sensors", {}))
    raw_faults = r.raw("faults", [])
    if raw_faults is None:
        raw_faults = []
    if not isinstance(raw_faults, list):
        r.fail("faults", "a list of faults", raw_faults)
    faults = tuple(
        _fault(path, f"faults[{i}]", item, duration_s) for i, item in enumerate(raw_faults)
    )
    raw_manoeuvres = r.raw("manoeuvres", []) or []
    if not isinstance(raw_manoeuvres, list):
        r.fail("manoeuvres", "a list of manoeuvres", raw_manoeuvres)
    manoeuvres = tuple(
        _manoeuvre(path, f"manoeuvres[{i}]", item, duration_s)
        for i, item in enumerate(raw_manoeuvres)
    )
    expect = None
    if r.raw("expect", None) is not None:
        expect_r = r.child("expect")
        detect = expect_r.string("detect", "none")
        try:
            FaultMode.from_name(detect)
        except ValueError:
            expect_r.fail("detect", "none or channel names joined by + (e.g. q, x+q)", detect)
        expect = ExpectSpec(detect=detect, within_s=expect_r.number("within_s", 1.0, lo=0.0))
        expect_r.done()
    scenario = Scenario(
        name=r.string("name"),
        description=r.string("description", "") if r.has("description") else "",
        duration_s=duration_s,
        seed=r.integer("seed"),
        start=start,
        flight_plan=_flight_plan(r.child("flight_plan")),
        sensors=sensors,
        airframe=_airframe(r.child("airframe", {})),
        wind=_wind(r.child("wind", {})),
        faults=faults,
        manoeuvres=manoeuvres,
        expect=expect,
        path=path,
        profile=_profile(path, r),
    )
    r.done()
    return scenario


def check_fault_imus(scenario: Scenario) -> None:
    """Each fault's ``imu`` is one the profile sends (a one-line :class:`ScenarioError`).

    Checked where the profile is final (``sim`` and ``run`` take ``--profile`` over the file's).
    """
    sent = scenario.profile.imu_messages
    for i, fault in enumerate(scenario.faults):
        if fault.imu >= len(sent):
            raise ScenarioError(
                f"{scenario.path}: faults[{i}].imu: {fault.imu}, but the {scenario.profile.name} "
                "profile sends "
                + ", ".join(f"imu {k} as {message}" for k, message in enumerate(sent))
            )


def _load_yaml(path: Path, what: str) -> Any:
    """The parsed YAML of ``path``; any failure is a one-line :class:`ScenarioError`."""
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise ScenarioError(f"{path}: not a text (UTF-8) file") from None
    except FileNotFoundError:
        raise ScenarioError(f"{path}: no such {what}") from None
    except OSError as exc:
        raise ScenarioError(f"{path}: cannot read: {exc.strerror}") from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        raise ScenarioError(f"{path}: not valid YAML{where}") from None


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario file; raises :class:`ScenarioError` with one line."""
    return parse_scenario(_load_yaml(Path(path), "scenario file"), str(path))
