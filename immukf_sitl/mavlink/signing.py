"""MAVLink 2 signing of the project's links (``--signing-key FILE``), with pymavlink's own code.

The key is a file holding the 32-byte secret as 64 hexadecimal characters (docs/security.md).
Signing and checking are pymavlink's (``mavfile.setup_signing``, ``MAVLink.check_signature``,
``MAVLink_message.sign_packet``): this module writes no HMAC. What it adds:

- every rejection is counted by its cause (:class:`SigningCounters`): an unsigned frame, a
  frame whose signature is wrong, and a replay (a timestamp not newer than the last one of its
  stream, or a new stream more than pymavlink's one-minute window behind our own clock);
- one signing state is shared by every parser and encoder of a process, so that a stream's
  timestamps are checked across them all;
- pymavlink records a stream's timestamp *before* it compares the signature, so one forged
  frame with a far-future timestamp would make every genuine frame after it look like a replay
  (a denial of service by anyone who can reach the socket). A frame that fails its check here
  leaves the stream's timestamp as it was.
"""

from __future__ import annotations

import os
import secrets
import struct
import weakref
from dataclasses import asdict, dataclass
from pathlib import Path

from immukf_sitl.errors import UserError
from immukf_sitl.mavlink.wire import MavConnection, MavMessage, mavlink

__all__ = [
    "KEY_BYTES",
    "LinkSigning",
    "SigningCounters",
    "frame_signature_fields",
    "load_key",
    "write_key",
]

#: MAVLink 2 secret keys are 32 bytes (64 hex characters in a key file).
KEY_BYTES = 32
#: The reason pymavlink gives a frame its signing check rejected.
INVALID_SIGNATURE = "Invalid signature"
_TIMESTAMP = struct.Struct("<IH")  # the signature block's 48-bit timestamp, 10 us units


def load_key(path: str | Path) -> bytes:
    """The 32-byte secret of a key file (64 hex characters; surrounding whitespace ignored).

    Raises
    ------
    UserError
        One line naming the file and what is wrong: missing, unreadable, wrong length, not hex.
    """
    where = f"--signing-key {path}"
    try:
        text = Path(path).read_text(encoding="ascii").strip()
    except FileNotFoundError:
        raise UserError(f"{where}: no such file") from None
    except IsADirectoryError:
        raise UserError(f"{where}: is a directory, expected a key file") from None
    except UnicodeDecodeError:
        raise UserError(f"{where}: expected {2 * KEY_BYTES} hex characters, got binary") from None
    except OSError as exc:
        raise UserError(f"{where}: cannot read: {exc.strerror}") from None
    if len(text) != 2 * KEY_BYTES:
        raise UserError(
            f"{where}: expected {2 * KEY_BYTES} hex characters (a {KEY_BYTES}-byte key), "
            f"got {len(text)}"
        )
    try:
        return bytes.fromhex(text)
    except ValueError:
        raise UserError(f"{where}: expected hex characters 0-9, a-f only") from None


def write_key(path: str | Path) -> bytes:
    """Create a key file readable by its owner only, holding a fresh random key; returns it."""
    key = secrets.token_bytes(KEY_BYTES)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w", encoding="ascii") as f:
        f.write(key.hex() + "\n")
    return key


def frame_signature_fields(frame: bytes | bytearray) -> tuple[int, int]:
    """``(link_id, timestamp)`` of a signed MAVLink 2 frame's signature block."""
    low, high = _TIMESTAMP.unpack(bytes(frame[-12:-6]))
    return frame[-13], low + (high << 32)


@dataclass
class SigningCounters:
    """Frames the signing check rejected, by cause (none of them is ever used)."""

    unsigned_rejected: int = 0
    bad_signature: int = 0
    replayed: int = 0

    def as_dict(self) -> dict[str, int]:
        """The counts by name."""
        return asdict(self)


class LinkSigning:
    """One process's signing: signs what it sends, accepts only correctly signed frames.

    Parameters
    ----------
    key : bytes
        The 32-byte secret (:func:`load_key`).

    Notes
    -----
    :meth:`enable` a connection first (it sets the link id and our clock, as pymavlink's
    ``setup_signing`` does), then :meth:`watch` any further parser or encoder of the process.
    Every one of them shares :attr:`state`, pymavlink's ``MAVLinkSigning``.
    """

    def __init__(self, key: bytes) -> None:
        if len(key) != KEY_BYTES:
            raise ValueError(f"key: expected {KEY_BYTES} bytes, got {len(key)}")
        self.key = bytes(key)
        self.counters = SigningCounters()
        self.state = mavlink.MAVLinkSigning()
        self.state.secret_key = self.key
        self.state.allow_unsigned_callback = self._reject_unsigned
        self._failed_check = False

    def enable(self, conn: MavConnection, link_id: int) -> None:
        """Sign everything ``conn`` sends from now on and check everything it hears.

        Parameters
        ----------
        conn : MavConnection
        link_id : int
            This process's link id (the signature's stream is ``(link_id, system, component)``).
        """
        conn.mav.signing = self.state
        conn.setup_signing(
            self.key,
            sign_outgoing=True,
            allow_unsigned_callback=self._reject_unsigned,
            link_id=link_id,
        )
        self.watch(conn.mav)

    def watch(self, mav: mavlink.MAVLink) -> mavlink.MAVLink:
        """Make a parser or encoder share this signing state (and count its rejections)."""
        mav.signing = self.state
        # a weak reference and the class's function: a closure holding ``mav`` would make a
        # reference cycle per parser, garbage that only the rare full collections free
        owner = weakref.ref(mav)
        original = type(mav).check_signature

        def check_signature(msgbuf: bytearray, src_system: int, src_component: int) -> bool:
            return self._check(original, owner(), msgbuf, src_system, src_component)

        mav.check_signature = check_signature
        return mav

    def parser(self) -> mavlink.MAVLink:
        """A new robust parser that checks signatures with this state."""
        parser = mavlink.MAVLink(None)
        parser.robust_parsing = True
        return self.watch(parser)

    def _check(self, original, mav, msgbuf: bytearray, src_system: int, src_component: int) -> bool:
        """Run pymavlink's check; classify a failure and keep the stream's clock."""
        link_id, _ = frame_signature_fields(msgbuf)
        stream = (link_id, src_system, src_component)
        streams = self.state.stream_timestamps
        had, before = stream in streams, streams.get(stream)
        if original(mav, msgbuf, src_system, src_component):
            return True
        self._failed_check = True
        if streams.get(stream) == before and (stream in streams) == had:
            self.counters.replayed += 1  # rejected on its timestamp, before the signature
        else:
            self.counters.bad_signature += 1
        if had:
            streams[stream] = before
        else:
            streams.pop(stream, None)
        return False

    def _reject_unsigned(self, mav: mavlink.MAVLink, msg_id: int) -> bool:
        """Reject every unsigned frame (pymavlink's ``allow_unsigned_callback``)."""
        if self._failed_check:
            self._failed_check = False  # a signed frame that failed: already counted
        else:
            self.counters.unsigned_rejected += 1
        return False

    @staticmethod
    def is_rejection(msg: MavMessage) -> bool:
        """Whether a parsed BAD_DATA is a frame the signing check rejected (counted here)."""
        return getattr(msg, "reason", None) == INVALID_SIGNATURE
