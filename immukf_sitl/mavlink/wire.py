"""Connections: MAVLink 2 and the dialect (ardupilotmega) chosen once, here, for the project.

pymavlink picks MAVLink 1 or 2 from the ``MAVLINK20`` environment variable at import time and
emits MAVLink 1 frames without it; this module sets it before the first import of
``pymavlink.mavutil`` and checks the result, so every sender in the project speaks MAVLink 2.
Every other module gets pymavlink through here.
"""

from __future__ import annotations

import os
import socket
import struct
import sys
import time

os.environ["MAVLINK20"] = "1"

from pymavlink import mavutil  # noqa: E402
from pymavlink.DFReader import DFMessage, DFReader_binary  # noqa: E402, F401 (DataFlash logs)

from immukf_sitl.errors import UserError  # noqa: E402

#: ArduPilot's dialect: MAVLink common plus the messages ArduPilot adds (AHRS, HWSTATUS, ...),
#: so that an ArduPilot stream or tlog parses whole instead of as unknown ids (MAVProxy's default)
DIALECT = "ardupilotmega"
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
#: MAVLink 2 signing link ids: a signed stream is (link id, system, component).
SIM_LINK_ID = 1
ESTIMATOR_LINK_ID = 2

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


#: Linux's SO_TIMESTAMPNS (= SCM_TIMESTAMPNS), which Python's socket module does not name.
_SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)
_TIMESPEC = struct.Struct("qq")
_TIMESPEC_32 = struct.Struct("ii")  # a 32-bit userspace's timespec (an armhf companion computer)
_MAX_DATAGRAM = 65535


def _timespec_ns(payload: bytes) -> int | None:
    """A ``struct timespec`` of the kernel's ABI in nanoseconds (64- or 32-bit longs)."""
    if len(payload) >= _TIMESPEC.size:
        seconds, nanoseconds = _TIMESPEC.unpack(payload[: _TIMESPEC.size])
    elif len(payload) >= _TIMESPEC_32.size:
        seconds, nanoseconds = _TIMESPEC_32.unpack(payload[: _TIMESPEC_32.size])
    else:
        return None
    return seconds * 1_000_000_000 + nanoseconds


class DatagramReader:
    """Datagrams of a UDP connection with their kernel receive time, for pymavlink to parse.

    pymavlink's ``recv_msg`` reads the socket itself and keeps no arrival time. This reader takes
    each datagram off the connection's socket with ``recvmsg`` and the kernel's receive stamp
    (``SO_TIMESTAMPNS``, Linux; CLOCK_REALTIME, so it includes the time the datagram waited in
    the socket's queue), and the caller hands the bytes to a pymavlink parser. Elsewhere the
    stamp is the time of the read (``kernel_stamps`` is then False). Some kernels (sandboxes such
    as gVisor) accept the option and attach no stamp: the first datagram that arrives without
    one (its ancillary data not cut short) turns ``kernel_stamps`` False, and every datagram from
    then on is stamped at its read, so one report never mixes the two. Linux switches arrival
    stamping on lazily when the machine's first socket asks for it: the first datagrams after
    the reader opens may carry the time of their read.

    Parameters
    ----------
    conn : MavConnection
        A ``udpin`` or ``udpout`` connection (``mavutil.mavudp``).
    receive_buffer_bytes : int
        Socket receive buffer asked for (the kernel caps it at ``rmem_max``).
    """

    def __init__(self, conn: MavConnection, receive_buffer_bytes: int = 4 << 20) -> None:
        self.conn = conn
        self.sock: socket.socket = conn.port
        try:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, receive_buffer_bytes)
        except OSError:  # pragma: no cover - a platform without it keeps its default
            pass
        self.kernel_stamps = False
        if sys.platform.startswith("linux"):
            try:
                self.sock.setsockopt(socket.SOL_SOCKET, _SO_TIMESTAMPNS, 1)
                self.kernel_stamps = True
            except OSError:  # pragma: no cover - an old kernel
                pass
        self._ancillary = 4 * socket.CMSG_SPACE(_TIMESPEC.size)  # room beside the stamp

    def fileno(self) -> int:
        """The socket's descriptor (for ``select``)."""
        return self.sock.fileno()

    def read(self) -> tuple[bytes, int, tuple] | None:
        """The next datagram: ``(bytes, arrival_ns, sender)``; None when none is waiting.

        ``arrival_ns`` is on the ``time.time_ns()`` clock.
        """
        try:
            data, ancillary, flags, sender = self.sock.recvmsg(_MAX_DATAGRAM, self._ancillary)
        except (BlockingIOError, InterruptedError):
            return None
        except ConnectionRefusedError:  # an ICMP error of an earlier send: nothing to read
            return None
        if not self.kernel_stamps:
            return data, time.time_ns(), sender
        for level, kind, payload in ancillary:
            if level == socket.SOL_SOCKET and kind == _SO_TIMESTAMPNS:
                stamp_ns = _timespec_ns(payload)
                if stamp_ns is not None:
                    return data, stamp_ns, sender
        if not flags & getattr(socket, "MSG_CTRUNC", 0):
            self.kernel_stamps = False  # the option was accepted but no stamp came: read times
        return data, time.time_ns(), sender

    def accept_peer(self, sender: tuple) -> None:
        """Reply to ``sender`` from now on, as pymavlink's own ``recv`` does for ``udpin``.

        Called only for a sender whose datagram held a frame the parser accepted, so that a
        sender of junk or of unsigned frames on a signed link gets no replies.
        """
        conn = self.conn
        if getattr(conn, "udp_server", False):
            conn.clients.add(sender)
            conn.clients_last_alive[sender] = time.time()


def is_udp(conn: object) -> bool:
    """Whether ``conn`` is a pymavlink UDP connection (one datagram, whole frames)."""
    return isinstance(conn, mavutil.mavudp)
