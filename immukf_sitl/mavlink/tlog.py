"""Streaming tlog writer: frames recorded as they are sent or heard (``--tlog`` options).

A tlog is a sequence of records: an 8-byte big-endian UNIX time in microseconds, then one raw
MAVLink frame (:mod:`immukf_sitl.mavlink.flightlog` reads them and
batch-writes them).
The project's processes stamp records with **sim time** (seconds since the start of the flight,
so the stamps start at the UNIX epoch): the tlogs of one run then merge by record time, and a
reader aligns truth, stream and estimates without wall-clock jitter. Without a time the wall
clock is used, as MAVProxy does. A reader can follow a run that is still going after each
:meth:`TlogWriter.flush`.
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

    def write(self, frame: bytes | bytearray, time_s: float | None = None) -> None:
        """Append one frame.

        Parameters
        ----------
        frame : bytes
            A packed MAVLink frame (``msg.get_msgbuf()`` after sending, or the bytes heard).
        time_s : float, optional
            Record time: seconds of sim time (>= 0); default the wall clock (UNIX time).
        """
        t = time.time() if time_s is None else time_s
        stamp = max(0, int(round(t * 1e6)))
        self._file.write(_TIMESTAMP.pack(stamp) + bytes(frame))
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
