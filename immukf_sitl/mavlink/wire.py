"""Connections: MAVLink 2 and the dialect chosen once, here, for the whole project.

pymavlink picks MAVLink 1 or 2 from the ``MAVLINK20`` environment variable at import time and
emits MAVLink 1 frames without it; this module sets it before the first import of
``pymavlink.mavutil`` and checks the result, so every sender in the project speaks MAVLink 2.
Every other module gets pymavlink through here.
"""

from __future__ import annotations

import os

os.environ["MAVLINK20"] = "1"

from pymavlink import mavutil  # noqa: E402

from immukf_sitl.errors import UserError  # noqa: E402

DIALECT = "common"
mavutil.set_dialect(DIALECT)
mavlink = mavutil.mavlink
if mavlink.WIRE_PROTOCOL_VERSION != "2.0":  # pragma: no cover - import-order guard
    raise ImportError(
        "pymavlink was imported before immukf_sitl.mavlink.wire could select MAVLink 2; "
        "import immukf_sitl.mavlink.wire first"
    )

#: Stable source ids of the project's three processes (MAVProxy's own is 255:230).
SIM_SYSTEM_ID = 1
SIM_COMPONENT_ID = 1  # QGroundControl creates a vehicle only from a component-1 heartbeat
PROXY_COMPONENT_ID = 195
ESTIMATOR_SYSTEM_ID = 1
ESTIMATOR_COMPONENT_ID = mavlink.MAV_COMP_ID_ONBOARD_COMPUTER  # 191

MavConnection = mavutil.mavfile
MavMessage = mavlink.MAVLink_message


class ConnectionError_(UserError):
    """A connection string that cannot be opened (bad syntax, busy port)."""


def _check_address(url: str) -> None:
    """Check HOST:PORT of a connection string: a resolvable host, a port in 0..65535."""
    import socket

    parts = url.split(":")
    if len(parts) != 3 or not parts[2].isdigit() or not 0 <= int(parts[2]) < 65536:
        raise ConnectionError_(f"connection {url!r}: expected SCHEME:HOST:PORT, port 0..65535")
    try:
        socket.getaddrinfo(parts[1], int(parts[2]), socket.AF_INET, socket.SOCK_DGRAM)
    except OSError:
        raise ConnectionError_(f"connection {url!r}: cannot resolve host {parts[1]!r}") from None


def connect(
    url: str, source_system: int, source_component: int, *, input_: bool = True
) -> MavConnection:
    """Open a pymavlink connection (``udpin:HOST:PORT``, ``udpout:HOST:PORT``, ``file.tlog``).

    Raises
    ------
    ConnectionError_
        With a one-line reason when the string is malformed or the port cannot be bound.
    """
    scheme = url.split(":", 1)[0]
    if scheme in ("udpin", "udpout", "udp", "tcp", "tcpin"):
        _check_address(url)
    if scheme not in ("udpin", "udpout", "udp", "tcp", "tcpin") and not url.endswith(".tlog"):
        raise ConnectionError_(
            f"connection {url!r}: expected udpin:HOST:PORT, udpout:HOST:PORT or a .tlog file"
        )
    try:
        conn = mavutil.mavlink_connection(
            url,
            source_system=source_system,
            source_component=source_component,
            dialect=DIALECT,
            input=input_,
        )
    except OSError as exc:
        raise ConnectionError_(f"connection {url!r}: {exc.strerror or exc}") from None
    except (ValueError, OverflowError) as exc:
        raise ConnectionError_(f"connection {url!r}: {exc}") from None
    conn.mav.robust_parsing = True
    return conn


def open_tlog_reader(path: str) -> MavConnection:
    """A recorded tlog for reading (``recv_match`` until ``None``)."""
    return mavutil.mavlink_connection(path, dialect=DIALECT, robust_parsing=True)
