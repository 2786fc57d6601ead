"""The MAVLink edge: the only package that imports pymavlink.

:mod:`immukf_sitl.mavlink.wire` opens connections (MAVLink 2, common dialect, set once here);
:mod:`immukf_sitl.mavlink.codec` converts between messages and the SI samples of
:mod:`immukf_sitl.samples`.
"""
