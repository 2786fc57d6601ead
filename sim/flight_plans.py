"""Flight plans used by the tests, the experiments and the SITL demo."""

from __future__ import annotations

from immukf_sitl.scenario import FlightPlan, Waypoint

__all__ = ["default_flight_plan"]


def default_flight_plan(base_alt_m: float = 150.0, airspeed_mps: float = 25.0) -> FlightPlan:
    """The manoeuvring plan: turns both ways, a climb and a descent, about 110 s per lap.

    Starting at the origin heading north: 400 m north, a 49 deg right turn climbing 30 m, a
    98 deg left turn, a 68 deg left turn descending 50 m, a 75 deg left turn, a 34 deg left turn
    climbing back, and (looping) a 135 deg right turn onto the first leg. About 2.7 km per lap,
    100-200 m above the origin's ellipsoidal height of 0 m by default.

    Parameters
    ----------
    base_alt_m : float, optional
        Height of the first and last legs above the WGS-84 ellipsoid (m); the plan flies
        between ``base_alt_m - 20`` and ``base_alt_m + 30``.
    airspeed_mps : float, optional
        Airspeed of every leg (m/s).

    Returns
    -------
    FlightPlan
        Six waypoints, looping.
    """
    h, v = base_alt_m, airspeed_mps
    return FlightPlan(
        waypoints=(
            Waypoint(north_m=400.0, east_m=0.0, alt_m=h, airspeed_mps=v),
            Waypoint(north_m=700.0, east_m=350.0, alt_m=h + 30.0, airspeed_mps=v),
            Waypoint(north_m=1000.0, east_m=0.0, alt_m=h + 30.0, airspeed_mps=v),
            Waypoint(north_m=800.0, east_m=-400.0, alt_m=h - 20.0, airspeed_mps=v),
            Waypoint(north_m=300.0, east_m=-300.0, alt_m=h - 20.0, airspeed_mps=v),
            Waypoint(north_m=0.0, east_m=0.0, alt_m=h, airspeed_mps=v),
        ),
        acceptance_radius_m=15.0,
        loop=True,
    )
