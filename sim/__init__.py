"""JSBSim side of immukf-sitl: aircraft definition, driver, autopilot, sensor models, flight loop.

This package directory is also the JSBSim root directory (``aircraft/``, ``engine/``,
``systems/``).
"""
