"""MAVLink frame helpers for the pure core.

The security module only needs the header (sysid, compid, msgid), which is read straight from the
bytes: a full pymavlink decode costs about five times the AEAD. Full decoding and encoding use the
generated dialect classes sans-IO (never ``mavutil``, which has globals and env-var dialect choice).

Every well-formed frame passes, whatever its dialect: reading the header needs no message table, and
the only operation that needs a message's CRC_EXTRA (rewriting the source of a frame, for the GCS
gateway) recovers it from the frame's own checksum when no table here has it. Decoding knows the
union of pymavlink's ``common``, ``development`` and ``ardupilotmega`` dialects (PX4's CURRENT_MODE,
ArduPilot's MEMINFO, ...) and answers ``None`` for any other id.
"""

from __future__ import annotations

import struct

from collections.abc import Mapping
from types import MappingProxyType
from typing import Any

import msgspec

from pymavlink.dialects.v20 import ardupilotmega, common as mavlink2
from pymavlink.generator.mavcrc import x25crc

from zdrone.core.uplink import DEFAULT_POLICY, UplinkClass

try:  # not in every pymavlink release
    from pymavlink.dialects.v20 import development
except ImportError:  # pragma: no cover
    development = None  # type: ignore[assignment]

MAGIC_V2 = 0xFD
MAGIC_V1 = 0xFE
SIGNED_FLAG = 0x01
SIGNATURE_LEN = 13


def _known_messages() -> dict[int, type]:
    """message id -> message class over the dialects a vehicle may speak (common first)."""
    out: dict[int, type] = {}
    for dialect in (mavlink2, development, ardupilotmega):
        if dialect is not None:
            for msgid, cls in dialect.mavlink_map.items():
                out.setdefault(msgid, cls)
    return out


#: message id -> message class, union of pymavlink's v20 common, development and ardupilotmega
MESSAGE_CLASSES: dict[int, type] = _known_messages()
#: CRC_EXTRA of message ids PX4 v1.16 sends or answers that none of those pymavlink dialects defines
#: (computed from the MAVLink XML definitions): LINK_NODE_STATUS, TIME_ESTIMATE_TO_TARGET, EVENT,
#: CURRENT_EVENT_SEQUENCE, REQUEST_EVENT, RESPONSE_EVENT_ERROR. A dialect's own value wins if one
#: ever defines them.
EXTRA_CRC: Mapping[int, int] = MappingProxyType({8: 117, 380: 232, 410: 160, 411: 106, 412: 33, 413: 77})
#: message id -> CRC_EXTRA byte (the checksum seed of the message's definition)
CRC_EXTRA: dict[int, int] = {**EXTRA_CRC, **{msgid: cls.crc_extra for msgid, cls in MESSAGE_CLASSES.items()}}

_READ_ONLY = UplinkClass.READ_ONLY


class FrameHeader(msgspec.Struct, frozen=True):
    """The fields of a MAVLink header the security module checks."""

    version: int
    seq: int
    sysid: int
    compid: int
    msgid: int
    length: int  # total length of the frame in bytes

    @property
    def commanding(self) -> bool:
        """True if only the GS holding authority may send this frame under the default uplink policy
        (``zdrone.core.uplink``): every id that is not read-only, unknown ids included."""
        return DEFAULT_POLICY.classify(self.msgid) is not _READ_ONLY


class FrameError(ValueError):
    """The bytes are not exactly one well-formed MAVLink frame."""


_V2_HEADER = struct.Struct("<7BHB")  # magic, len, incompat, compat, seq, sysid, compid, msgid (24 bit LE)


def read_header(frame: bytes) -> FrameHeader:
    """Read and check the header of exactly one MAVLink 1 or 2 frame.

    Checks magic, declared payload length against the byte count and (MAVLink 2) the incompat
    flags. Raises ``FrameError`` otherwise. Any message id is accepted, including ids no dialect
    known here defines (PX4's EVENT, a vendor's messages): what a GS may send up is the uplink
    policy's business, and downlink passes every well-formed frame. The CRC is not recomputed: the
    envelope's AEAD already proves the bytes are the sender's.
    """
    n = len(frame)
    if n < 8:
        raise FrameError("too short for a MAVLink header")
    magic = frame[0]
    if magic == MAGIC_V2:
        if n < 12:
            raise FrameError("too short for a MAVLink 2 header")
        _magic, plen, incompat, _compat, seq, sysid, compid, lo, hi = _V2_HEADER.unpack_from(frame)
        msgid = lo | (hi << 16)
        expected = 10 + plen + 2 + (SIGNATURE_LEN if incompat & SIGNED_FLAG else 0)
        if incompat & ~SIGNED_FLAG:
            raise FrameError(f"unknown incompat flags 0x{incompat:02x}")
        version = 2
    elif magic == MAGIC_V1:
        plen, seq, sysid, compid, msgid = frame[1], frame[2], frame[3], frame[4], frame[5]
        expected = 6 + plen + 2
        version = 1
    else:
        raise FrameError(f"bad magic 0x{magic:02x}")
    if n != expected:
        raise FrameError(f"length {n} does not match header ({expected})")
    return FrameHeader(version, seq, sysid, compid, msgid, n)


def crc_ok(frame: bytes) -> bool:
    """True if the frame's X.25 checksum (with the message's CRC_EXTRA) is right.

    False for a message id without a CRC_EXTRA here (no dialect here defines it, nor ``EXTRA_CRC``):
    its checksum cannot be checked against a definition (``crc_seed`` still says which seed fits it).
    """
    if frame[0] == MAGIC_V2:
        hdr, msgid = 10, frame[7] | (frame[8] << 8) | (frame[9] << 16)
        plen = frame[1]
    else:
        hdr, msgid, plen = 6, frame[5], frame[1]
    extra = CRC_EXTRA.get(msgid)
    if extra is None:
        return False
    crc = x25crc(frame[1 : hdr + plen])
    crc.accumulate(bytes([extra]))
    return frame[hdr + plen] | (frame[hdr + plen + 1] << 8) == crc.crc


def split_frames(data: bytes) -> tuple[list[bytes], bytes, int]:
    """Split a byte stream into whole MAVLink frames; return (frames, leftover, bytes skipped).

    A candidate frame whose checksum is wrong is not a frame: the splitter moves one byte on and
    looks for the next magic byte, so garbage never swallows the real frames behind it. A message id
    no known dialect defines cannot have its checksum checked; such a candidate is taken as a frame
    when it is well formed (``read_header``'s checks, a non-empty payload) and delimited: the data
    ends with it or the next byte is a magic byte. Used by stream adapters (TCP/serial) that must
    cut frames before sealing each one.
    """
    frames: list[bytes] = []
    i, n, skipped = 0, len(data), 0
    while i < n:
        b = data[i]
        if b == MAGIC_V2:
            if n - i < 10:
                break
            total = 10 + data[i + 1] + 2 + (SIGNATURE_LEN if data[i + 2] & SIGNED_FLAG else 0)
        elif b == MAGIC_V1:
            if n - i < 6:
                break
            total = 6 + data[i + 1] + 2
        else:
            i += 1
            skipped += 1
            continue
        if n - i < total:
            break
        candidate = bytes(data[i : i + total])
        if not (crc_ok(candidate) or _framed_unknown(candidate, data, i + total)):
            i += 1
            skipped += 1
            continue
        frames.append(candidate)
        i += total
    return frames, bytes(data[i:]), skipped


def _framed_unknown(candidate: bytes, data: bytes, end: int) -> bool:
    """True if ``candidate`` has a message id of no known dialect, is well formed and delimited."""
    if candidate[0] == MAGIC_V2:
        msgid = candidate[7] | (candidate[8] << 8) | (candidate[9] << 16)
        if candidate[2] & ~SIGNED_FLAG:
            return False
    else:
        msgid = candidate[5]
    if msgid in CRC_EXTRA or candidate[1] == 0:
        return False
    return end == len(data) or data[end] in (MAGIC_V2, MAGIC_V1)


def _decoders() -> tuple[tuple[frozenset[int], type], ...]:
    """(ids, MAVLink class) per dialect, ardupilotmega (which includes common) first."""
    out = [(frozenset(ardupilotmega.mavlink_map), ardupilotmega.MAVLink)]
    if development is not None:
        out.append((frozenset(development.mavlink_map) - out[0][0], development.MAVLink))
    return tuple(out)


_DECODERS = _decoders()


class FrameCodec:
    """Sans-IO MAVLink 2 encoder/decoder for one (sysid, compid), owning its sequence number.

    Decodes the ids of pymavlink's common, ardupilotmega and development dialects; ``decode`` answers
    ``None`` for any other id (the frame itself is still a frame: see ``read_header``)."""

    def __init__(self, sysid: int, compid: int = 1) -> None:
        self.sysid = sysid
        self.compid = compid
        self._parsers: list[tuple[frozenset[int], Any]] = []
        for ids, cls in _DECODERS:
            parser = cls(None, srcSystem=sysid, srcComponent=compid)
            parser.robust_parsing = True
            self._parsers.append((ids, parser))
        #: the encoder (ardupilotmega's, a superset of common); its ``seq`` is this codec's sequence number
        self.mav = self._parsers[0][1]

    def encode(self, msg: Any) -> bytes:
        """Pack ``msg`` with this codec's ids and advance the sequence number."""
        frame = msg.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) % 256
        return bytes(frame)

    def decode(self, frame: bytes) -> Any | None:
        """Decode exactly one frame fully; ``None`` if it does not decode (malformed, bad CRC, or an
        id none of the dialects defines). Never raises."""
        try:
            msgid = read_header(frame).msgid
        except FrameError:
            return None
        parser = next((p for ids, p in self._parsers if msgid in ids), None)
        if parser is None:
            return None
        try:  # the dialect's decoder on the one frame (its byte-by-byte parser costs as much again)
            msg = parser.decode(bytearray(frame))
        except Exception:  # pymavlink raises assorted errors on garbage
            return None
        if msg is None:
            return None
        if msg.get_type() == "BAD_DATA" or msg.get_type().startswith("UNKNOWN_"):
            return None
        return msg


def _crc(frame_wo_crc: bytes, crc_extra: int) -> bytes:
    crc = x25crc(frame_wo_crc[1:])
    crc.accumulate(bytes([crc_extra]))
    return bytes([crc.crc & 0xFF, crc.crc >> 8])


def _x25_last_step(t: int) -> int:
    return ((t << 8) ^ (t << 3) ^ (t >> 4)) & 0xFFFF


#: The X.25 checksum's last step (the CRC_EXTRA byte) is a bijection of that byte: inverse table.
_LAST_STEP = {_x25_last_step(t): t for t in range(256)}


def crc_seed(frame: bytes) -> int | None:
    """The CRC_EXTRA byte under which the checksum of ``frame`` (one well-formed frame) is right.

    Recovered from the checksum itself, no message table needed: the X.25 step over the seed byte
    maps the 256 possible seeds to 256 different checksums, so at most one seed fits. ``None`` if
    none does (the frame is corrupted). For a message id of a known dialect and an intact frame this
    is the dialect's CRC_EXTRA.
    """
    end = (10 if frame[0] == MAGIC_V2 else 6) + frame[1]
    state = x25crc(frame[1:end]).crc
    got = frame[end] | (frame[end + 1] << 8)
    t = _LAST_STEP.get(got ^ (state >> 8))
    if t is None:
        return None
    return t ^ ((t << 4) & 0xFF) ^ (state & 0xFF)


def rewrite_source(frame: bytes, sysid: int, compid: int) -> bytes:
    """The same frame with another source (sysid, compid) and a fresh checksum.

    Used by the GCS gateway: every application's frames leave the GS under the GS's fleet sysid,
    one component id per application. A MAVLink 2 signature cannot survive the change, so it is
    removed (the sealed envelope authenticates the frame instead). The checksum is recomputed with
    the seed the frame's own checksum was made with (``crc_seed``), so any message id passes, ids of
    no dialect included, and the rewritten frame is valid exactly when the original was. Raises
    ``FrameError`` for a malformed frame or a checksum no seed fits (a corrupted frame: dropped,
    and the gateway counts it as ``rewrite_failed``).
    """
    hdr = read_header(frame)
    seed = crc_seed(frame)
    if seed is None:
        raise FrameError(f"message id {hdr.msgid}: the checksum fits no CRC_EXTRA (corrupted frame)")
    if hdr.version == 2:
        body = bytearray(frame[: 10 + frame[1]])
        body[2] &= ~SIGNED_FLAG
        body[5], body[6] = sysid, compid
    else:
        body = bytearray(frame[: 6 + frame[1]])
        body[3], body[4] = sysid, compid
    return bytes(body) + _crc(bytes(body), seed)


def encode_raw(msgid: int, crc_extra: int, payload: bytes, sysid: int, compid: int, seq: int = 0) -> bytes:
    """A MAVLink 2 frame for a message this dialect does not define (e.g. CONTROL_STATUS, 512)."""
    while len(payload) > 1 and payload[-1] == 0:  # MAVLink 2 drops trailing zero bytes
        payload = payload[:-1]
    body = bytes([MAGIC_V2, len(payload), 0, 0, seq & 0xFF, sysid, compid, msgid & 0xFF, (msgid >> 8) & 0xFF,
                  msgid >> 16]) + payload
    return body + _crc(body, crc_extra)
