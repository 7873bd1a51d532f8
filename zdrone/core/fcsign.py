"""MAVLink 2 message signing of raw frames, pure (the flight-controller link's, not the envelope's).

A signed MAVLink 2 frame has the SIGNED incompat flag set (so its checksum changes) and 13 bytes
appended: the link id (1 byte), a 48-bit timestamp in 10 µs units since 2015-01-01 00:00 UTC, and
the first 6 bytes of SHA-256(secret key || frame up to and with the timestamp). The receiver keeps
the last timestamp of each stream (link id, sysid, compid) and refuses one that does not grow; a new
stream is accepted only within a minute of the receiver's own timestamp (the MAVLink signing spec,
as the C library and pymavlink check it).

``sign`` works on any well-formed MAVLink 2 frame, ids of no dialect included: the checksum is
recomputed with the seed its own checksum was made with (``crc_seed``). MAVLink 1 frames cannot be
signed. No clock here: the caller gives every timestamp.
"""

from __future__ import annotations

import hashlib
import hmac
import struct
from dataclasses import dataclass
from enum import Enum

from zdrone.core.mavlink import CRC_EXTRA, MAGIC_V2, SIGNATURE_LEN, SIGNED_FLAG, FrameError, _crc, crc_seed

KEY_LEN = 32
#: 2015-01-01 00:00:00 UTC in Unix seconds: the signing timestamp's origin.
EPOCH_2015 = 1420070400
#: Timestamp units per second (10 µs each).
UNITS_PER_S = 100_000
#: A new stream's first timestamp may lag the receiver's own by this much at most (one minute).
NEW_STREAM_WINDOW = 60 * UNITS_PER_S
MAX_TIMESTAMP = (1 << 48) - 1


def units(unix_s: float) -> int:
    """A Unix time as a signing timestamp (10 µs units since 2015), never negative."""
    return max(0, int((unix_s - EPOCH_2015) * UNITS_PER_S))


def is_signed(frame: bytes) -> bool:
    return len(frame) > 2 and frame[0] == MAGIC_V2 and bool(frame[2] & SIGNED_FLAG)


def _msgid(frame: bytes) -> int:
    return frame[7] | (frame[8] << 8) | (frame[9] << 16)


def _seed(frame: bytes) -> int:
    extra = CRC_EXTRA.get(_msgid(frame))
    if extra is not None:
        return extra
    seed = crc_seed(frame)
    if seed is None:
        raise FrameError("the checksum fits no CRC_EXTRA (corrupted frame)")
    return seed


def _reflag(frame: bytes, signed: bool) -> bytes:
    """The frame's header and payload with the SIGNED flag set or cleared, and its checksum for that
    header (no signature)."""
    if len(frame) < 12 or frame[0] != MAGIC_V2 or len(frame) < 12 + frame[1]:
        raise FrameError("not a MAVLink 2 frame")
    end = 10 + frame[1]
    seed = _seed(frame[: end + 2])
    body = bytearray(frame[:end])
    if signed:
        body[2] |= SIGNED_FLAG
    else:
        body[2] &= ~SIGNED_FLAG & 0xFF
    return bytes(body) + _crc(bytes(body), seed)


def strip(frame: bytes) -> bytes:
    """The frame without its signature (unchanged if it has none). Raises ``FrameError`` if it is
    not a well-formed MAVLink 2 frame."""
    if not is_signed(frame):
        return frame
    return _reflag(frame[: len(frame) - SIGNATURE_LEN], signed=False)


def signature(key: bytes, signed_part: bytes) -> bytes:
    """The 6-byte signature of a frame up to and with its timestamp."""
    return hashlib.sha256(key + signed_part).digest()[:6]


def sign(frame: bytes, key: bytes, link_id: int, timestamp: int) -> bytes:
    """``frame`` (a MAVLink 2 frame; a signature it has is replaced) signed with ``key`` under
    ``link_id`` and ``timestamp``. Raises ``FrameError`` for a MAVLink 1 or malformed frame."""
    if is_signed(frame):
        frame = frame[: len(frame) - SIGNATURE_LEN]
    head = _reflag(frame, signed=True) + struct.pack("<BQ", link_id & 0xFF, timestamp & MAX_TIMESTAMP)[:7]
    return head + signature(key, head)


@dataclass(frozen=True, slots=True)
class Signature:
    """The signature block of a signed frame."""

    link_id: int
    timestamp: int
    sysid: int
    compid: int

    @property
    def stream(self) -> tuple[int, int, int]:
        return (self.link_id, self.sysid, self.compid)


def read_signature(frame: bytes) -> Signature | None:
    """The signature block of a signed frame, None for an unsigned (or too short) one."""
    if not is_signed(frame) or len(frame) < 10 + SIGNATURE_LEN + 2:
        return None
    block = frame[-SIGNATURE_LEN:]
    lo, hi = struct.unpack_from("<IH", block, 1)
    return Signature(block[0], lo | (hi << 32), frame[5], frame[6])


def signed_with(frame: bytes, key: bytes) -> bool:
    """True if the signed ``frame``'s signature was made with ``key`` (its timestamp not judged)."""
    return is_signed(frame) and hmac.compare_digest(signature(key, frame[:-6]), frame[-6:])


class Refusal(Enum):
    """Why a signed frame is refused."""

    BAD_SIGNATURE = "bad_signature"  # another key, or altered
    REPLAY = "replay"  # its stream's timestamp did not grow
    STALE_STREAM = "stale_stream"  # a new stream more than a minute behind the receiver's timestamp


class StreamClock:
    """The receiving side's replay check: the last timestamp of each stream and the receiver's own
    timestamp (the largest it has sent or accepted)."""

    def __init__(self, timestamp: int = 0) -> None:
        self.timestamp = timestamp
        self.streams: dict[tuple[int, int, int], int] = {}

    def check(self, frame: bytes, key: bytes) -> Refusal | None:
        """None if the signed ``frame`` is authentic and fresh (then its stream and the receiver's
        timestamp move on), else why it is refused (nothing moves)."""
        sig = read_signature(frame)
        if sig is None or not signed_with(frame, key):
            return Refusal.BAD_SIGNATURE
        last = self.streams.get(sig.stream)
        if last is not None:
            if sig.timestamp <= last:
                return Refusal.REPLAY
        elif sig.timestamp + NEW_STREAM_WINDOW < self.timestamp:
            return Refusal.STALE_STREAM
        self.streams[sig.stream] = sig.timestamp
        self.timestamp = max(self.timestamp, sig.timestamp)
        return None
