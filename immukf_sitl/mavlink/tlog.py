"""Recording MAVLink frames into a tlog, the ecosystem's log format (MAVProxy, QGC, pymavlink).

Each record is an 8-byte big-endian UNIX time in microseconds followed by one raw MAVLink frame
(DESIGN.md section 7); :func:`immukf_sitl.mavlink.wire.open_tlog_reader` reads it back. The
record time is the wall clock when the frame was sent or heard, as MAVProxy writes it; the
simulation time travels inside the messages (``time_usec``, ``time_boot_ms``).
"""

from __future__ import annotations

import struct
import time
from pathlib import Path
from types import TracebackType

from immukf_sitl.errors import UserError

__all__ = ["TlogWriter"]

_TIMESTAMP = struct.Struct(">Q")


class TlogWriter:
    """Append-only tlog file.

    Parameters
    ----------
    path : str or pathlib.Path
        File to create (an existing file is replaced).

    Raises
    ------
    UserError
        One line when the file cannot be created.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        try:
            self._file = open(self.path, "wb")  # closed by close()
        except OSError as exc:
            raise UserError(f"{self.path}: cannot write the tlog: {exc.strerror}") from None
        self.records = 0

    def write(self, frame: bytes | bytearray, unix_time_s: float | None = None) -> None:
        """Append one frame.

        Parameters
        ----------
        frame : bytes
            A packed MAVLink frame (``msg.get_msgbuf()`` after sending, or bytes heard).
        unix_time_s : float, optional
            Record time (s since 1970); default now.
        """
        t = time.time() if unix_time_s is None else unix_time_s
        self._file.write(_TIMESTAMP.pack(int(t * 1e6)) + bytes(frame))
        self.records += 1

    def flush(self) -> None:
        """Flush buffered records to the file."""
        self._file.flush()

    def close(self) -> None:
        """Flush and close (idempotent)."""
        if not self._file.closed:
            self._file.close()

    def __enter__(self) -> TlogWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
