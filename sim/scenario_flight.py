"""Build the simulation of a scenario file: start, flight plan, sensors, airframe, air, seed.

The scenario's records (:mod:`immukf_sitl.scenario`: flight plan, sensor specs, manoeuvres,
airframe, wind) are the sim's own; here the start's heading changes unit and a perturbed
airframe is rendered into a JSBSim aircraft of its own, so that the emitter, the tests and the
experiments fly the same thing.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import tempfile
from pathlib import Path

from immukf_sitl.models.airframe import airframe_factors, scaled_params
from immukf_sitl.models.params import AircraftParams, load_aircraft_params
from immukf_sitl.models.sensors import SensorSpec
from immukf_sitl.models.servo_map import ControlMap, ServoMap
from immukf_sitl.scenario import Scenario, StartSpec
from immukf_sitl.stream_profile import StreamProfile
from sim.aircraft_xml import AIRCRAFT_NAME, render_aircraft_xml
from sim.flight import Flight
from sim.profile_stream import ParamServer, ProfileStream, second_imu
from sim.truth import InitialConditions

__all__ = [
    "flight_from_scenario",
    "initial_conditions",
    "profile_sensors",
    "profile_stream",
    "write_aircraft",
]


def initial_conditions(start: StartSpec) -> InitialConditions:
    """The sim's initial conditions of a scenario's ``start`` (heading deg -> rad)."""
    return InitialConditions(
        lat_deg=start.lat_deg,
        lon_deg=start.lon_deg,
        alt_m=start.alt_m,
        airspeed_mps=start.airspeed_mps,
        heading_rad=math.radians(start.heading_deg),
    )


def write_aircraft(params: AircraftParams, out_dir: Path) -> Path:
    """Render ``params`` as a JSBSim aircraft under ``out_dir``; returns the JSBSim root.

    The root holds ``aircraft/<name>/<name>.xml`` and empty ``engine/`` and ``systems/``
    directories, as :class:`~sim.driver.JsbsimDriver` expects.
    """
    root = Path(out_dir) / "jsbsim"
    aircraft_dir = root / "aircraft" / AIRCRAFT_NAME
    aircraft_dir.mkdir(parents=True, exist_ok=True)
    for sub in ("engine", "systems"):
        (root / sub).mkdir(exist_ok=True)
    (aircraft_dir / f"{AIRCRAFT_NAME}.xml").write_text(render_aircraft_xml(params))
    return root


def profile_sensors(sensors: SensorSpec, profile: StreamProfile) -> SensorSpec:
    """The sensors the truth samples under a profile: per-step noise and the GPS rate.

    The spec's white-noise sigmas are per 10 ms sample; a truth step of ``dt`` raises them by
    ``sqrt(0.01 / dt)`` (the same noise density), and the GPS fixes at the profile's rate.
    """
    factor = profile.noise_factor
    imu = dataclasses.replace(
        sensors.imu,
        accel_sigma_mps2=sensors.imu.accel_sigma_mps2 * factor,
        gyro_sigma_radps=sensors.imu.gyro_sigma_radps * factor,
    )
    gps = dataclasses.replace(sensors.gps, rate_hz=profile.gps_rate_hz(sensors.gps.rate_hz))
    return dataclasses.replace(sensors, imu=imu, gps=gps)


def profile_stream(
    flight: Flight, profile: StreamProfile
) -> tuple[ProfileStream, ParamServer | None]:
    """The stream a flight sends under a profile, and the parameter server that goes with it."""
    if profile.name != "ardupilot":
        return ProfileStream(profile, flight.params.actuators), None
    servo_map = ServoMap.layout(profile.servo_layout)
    imu2 = second_imu(flight.imu.spec, flight.seed, flight.driver.dt_s)
    stream = ProfileStream(
        profile, flight.params.actuators, ControlMap(servo_map, flight.params), imu2
    )
    return stream, ParamServer(servo_map)


def flight_from_scenario(
    scenario: Scenario,
    params: AircraftParams | None = None,
    out_dir: Path | None = None,
    profile: StreamProfile | None = None,
) -> Flight:
    """A :class:`~sim.flight.Flight` (not yet started) that flies the scenario.

    Parameters
    ----------
    scenario : Scenario
        A validated scenario (:func:`immukf_sitl.scenario.load_scenario`).
    params : AircraftParams, optional
        The book's aircraft (default: the packaged file). The scenario's ``airframe:`` block
        scales it; the factors used are the flight's ``airframe_factors``.
    out_dir : Path, optional
        Where a perturbed airframe's JSBSim aircraft is written (default: a temporary
        directory, removed once JSBSim has loaded it).
    profile : StreamProfile, optional
        The stream the flight is sent as (default: the scenario's ``profile``): it sets the
        truth step, the per-step IMU noise and the GPS rate (:func:`profile_sensors`).

    Returns
    -------
    Flight
        Seeded with ``scenario.seed``, with the scenario's manoeuvres and air; call
        :meth:`~sim.flight.Flight.start` then :meth:`~sim.flight.Flight.step` for
        ``round(scenario.duration_s / dt)`` steps. The scenario's faults are not the sim's
        business: the fault proxy applies them.
    """
    book = params if params is not None else load_aircraft_params()
    factors = airframe_factors(book, scenario.airframe, scenario.seed)
    flown = scaled_params(book, factors)
    profile = profile if profile is not None else scenario.profile
    sensors = profile_sensors(scenario.sensors, profile)
    with contextlib.ExitStack() as scratch:
        root_dir = None
        if factors:
            if out_dir is None:
                # JSBSim reads the aircraft once, when the flight is built: the files go with it
                out_dir = scratch.enter_context(tempfile.TemporaryDirectory(prefix="airframe-"))
            root_dir = write_aircraft(flown, Path(out_dir))
        flight = Flight(
            scenario.flight_plan,
            scenario.seed,
            initial=initial_conditions(scenario.start),
            params=flown,
            imu_spec=sensors.imu,
            gps_spec=sensors.gps,
            dt_s=profile.truth_dt_s,
            manoeuvres=scenario.manoeuvres,
            wind=scenario.wind,
            root_dir=root_dir,
        )
    flight.airframe_factors = factors
    return flight
