"""The truth side: JSBSim aircraft, driver, autopilot, sensor models, flight loop, UDP shells.

The shells are the emitter behind ``immukf-sitl sim`` and the fault proxy.

One job: fly the aircraft and produce what its sensors read. Only :mod:`sim.driver` imports
JSBSim; the autopilot and the sensor models work on the records of :mod:`sim.truth` without it.
May import the models, the shared records and the scenario of ``immukf_sitl``; the emitter and
the proxy also the MAVLink adapter. This directory is the JSBSim root directory
(``aircraft/``, ``engine/``, ``systems/``).
"""
