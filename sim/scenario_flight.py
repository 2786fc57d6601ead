"""Build the simulation of a scenario file: its start, flight plan, sensors, seed and manoeuvres.

The scenario's records (:mod:`immukf_sitl.scenario`: flight plan, sensor specs, manoeuvres) are
the sim's own; only the start's heading changes unit here, so that the emitter, the tests and
the experiments fly the same thing.
"""

from __future__ import annotations

import math

from immukf_sitl.models.params import AircraftParams
from immukf_sitl.scenario import Scenario, StartSpec
from sim.flight import Flight
from sim.truth import InitialConditions

__all__ = ["flight_from_scenario", "initial_conditions"]


def initial_conditions(start: StartSpec) -> InitialConditions:
    """The sim's initial conditions of a scenario's ``start`` (heading deg -> rad)."""
    return InitialConditions(
        lat_deg=start.lat_deg,
        lon_deg=start.lon_deg,
        alt_m=start.alt_m,
        airspeed_mps=start.airspeed_mps,
        heading_rad=math.radians(start.heading_deg),
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
        scenario.flight_plan,
        scenario.seed,
        initial=initial_conditions(scenario.start),
        params=params,
        imu_spec=scenario.sensors.imu,
        gps_spec=scenario.sensors.gps,
        manoeuvres=scenario.manoeuvres,
    )
