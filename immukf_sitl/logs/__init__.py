"""Autopilot logs in: MAVLink tlogs, ArduPilot DataFlash ``.bin`` and PX4 ULog ``.ulg``."""
