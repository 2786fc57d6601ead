"""Build the simulation of a scenario file: start, flight plan, sensors, airframe, air, seed.

The scenario's records (:mod:`immukf_sitl.scenario`: flight plan, sensor specs, manoeuvres,
airframe, wind) are the sim's own; here the start's heading changes unit and a perturbed
airframe is rendered into a JSBSim aircraft of its own, so that the emitter, the tests and the
experiments fly the same thing.
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

from immukf_sitl.models.airframe import airframe_factors, scaled_params
from immukf_sitl.models.params import AircraftParams, load_aircraft_params
from immukf_sitl.scenario import Scenario, StartSpec
from sim.aircraft_xml import AIRCRAFT_NAME, render_aircraft_xml
from sim.flight import Flight
from sim.truth import InitialConditions

__all__ = ["flight_from_scenario", "initial_conditions", "write_aircraft"]


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


def flight_from_scenario(
    scenario: Scenario, params: AircraftParams | None = None, out_dir: Path | None = None
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
        Where a perturbed airframe's JSBSim aircraft is written (default: a new temporary
        directory).

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
    root_dir = None
    if factors:
        base = Path(out_dir) if out_dir is not None else Path(tempfile.mkdtemp(prefix="airframe-"))
        root_dir = write_aircraft(flown, base)
    flight = Flight(
        scenario.flight_plan,
        scenario.seed,
        initial=initial_conditions(scenario.start),
        params=flown,
        imu_spec=scenario.sensors.imu,
        gps_spec=scenario.sensors.gps,
        manoeuvres=scenario.manoeuvres,
        wind=scenario.wind,
        root_dir=root_dir,
    )
    flight.airframe_factors = factors
    return flight
