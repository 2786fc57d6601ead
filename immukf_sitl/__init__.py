"""immukf-sitl: IMM-UKF inertial-sensor fault detection for fixed-wing UAVs.

Implements *Sensor Fault Detection for UAVs using a Nonlinear Dynamic Model and the IMM-UKF
Algorithm* as a MAVLink software-in-the-loop estimator service.
"""

__version__ = "0.1.0"
