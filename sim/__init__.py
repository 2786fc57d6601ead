"""The truth side: JSBSim aircraft (generated), driver, autopilot, sensor models, flight loop,
and the two UDP shells (the emitter behind ``immukf-sitl sim``, the fault proxy).

One job: fly the aircraft and produce what its sensors read. Only :mod:`sim.driver` imports
JSBSim; the autopilot and the sensor models work on the records of :mod:`sim.truth` without it.
May import the models, the shared records and the scenario of ``immukf_sitl``; the emitter and
the proxy also the MAVLink adapter. This directory is the JSBSim root directory
(``aircraft/``, ``engine/``, ``systems/``).
"""
