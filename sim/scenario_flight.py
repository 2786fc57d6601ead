"""Build the simulation of a scenario file: its start, flight plan, sensors, seed and manoeuvres.

The scenario schema (:mod:`immukf_sitl.scenario`) is the user's view; the sim's own types
(:class:`~sim.driver.InitialConditions`, :class:`~sim.autopilot.FlightPlan`,
:class:`~sim.sensors.ImuSpec`, :class:`~sim.sensors.GpsSpec`) are built from it here and only
here, so that the emitter, the tests and the experiments fly the same thing.
"""

from __future__ import annotations

import math

from immukf_sitl.models.params import AircraftParams
from immukf_sitl.scenario import (
    FlightPlanSpec,
    GpsNoiseSpec,
    ImuNoiseSpec,
    Scenario,
    StartSpec,
)
from sim.autopilot import FlightPlan, Waypoint
from sim.driver import InitialConditions
from sim.flight import Flight
from sim.sensors import GpsSpec, ImuSpec

__all__ = [
    "flight_from_scenario",
    "flight_plan",
    "gps_spec",
    "imu_spec",
    "initial_conditions",
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


def flight_plan(spec: FlightPlanSpec) -> FlightPlan:
    """The autopilot's flight plan of a scenario's ``flight_plan``."""
    return FlightPlan(
        waypoints=tuple(
            Waypoint(
                north_m=wp.north_m, east_m=wp.east_m, alt_m=wp.alt_m, airspeed_mps=wp.airspeed_mps
            )
            for wp in spec.waypoints
        ),
        acceptance_radius_m=spec.acceptance_radius_m,
        loop=spec.loop,
    )


def imu_spec(noise: ImuNoiseSpec) -> ImuSpec:
    """The IMU model's spec of a scenario's ``sensors.imu``."""
    return ImuSpec(
        accel_sigma_mps2=noise.accel_sigma_mps2,
        gyro_sigma_radps=noise.gyro_sigma_radps,
        accel_bias_mps2=noise.accel_bias_mps2,
        gyro_bias_radps=noise.gyro_bias_radps,
    )


def gps_spec(noise: GpsNoiseSpec) -> GpsSpec:
    """The GPS model's spec of a scenario's ``sensors.gps`` (Gauss-Markov constant: B&M's)."""
    return GpsSpec(
        rate_hz=noise.rate_hz,
        north_east_sigma_m=noise.north_east_sigma_m,
        height_sigma_m=noise.height_sigma_m,
        ground_speed_sigma_mps=noise.ground_speed_sigma_mps,
        course_sigma_mps=noise.course_sigma_mps,
    )


def flight_from_scenario(scenario: Scenario, params: AircraftParams | None = None) -> Flight:
    """A :class:`~sim.flight.Flight` (not yet started) that flies the scenario.

    Parameters
    ----------
    scenario : Scenario
        A validated scenario (:func:`immukf_sitl.scenario.load_scenario`).
    params : AircraftParams, optional
        Aircraft parameters (default: the packaged file).

    Returns
    -------
    Flight
        Seeded with ``scenario.seed``, with the scenario's manoeuvres; call
        :meth:`~sim.flight.Flight.start` then :meth:`~sim.flight.Flight.step` for
        ``round(scenario.duration_s / dt)`` steps. The scenario's faults are not the sim's
        business: the fault proxy applies them.
    """
    return Flight(
        flight_plan(scenario.flight_plan),
        scenario.seed,
        initial=initial_conditions(scenario.start),
        params=params,
        imu_spec=imu_spec(scenario.sensors.imu),
        gps_spec=gps_spec(scenario.sensors.gps),
        manoeuvres=scenario.manoeuvres,
    )
