"""MAVLink frame helpers for the pure core.

The security module only needs the header (sysid, compid, msgid), which is read straight from the
bytes: a full pymavlink decode costs about five times the AEAD. Full decoding and encoding use the
generated dialect class sans-IO (never ``mavutil``, which has globals and env-var dialect choice).
"""

from __future__ import annotations

import msgspec

from pymavlink.dialects.v20 import common as mavlink2
from pymavlink.generator.mavcrc import x25crc

MAGIC_V2 = 0xFD
MAGIC_V1 = 0xFE
SIGNED_FLAG = 0x01
SIGNATURE_LEN = 13

#: message id -> message class of the common dialect
MESSAGE_CLASSES = mavlink2.mavlink_map

#: Message ids whose frames command the vehicle. Only the authority GS may send these.
COMMANDING_MSGIDS: frozenset[int] = frozenset(
    {
        mavlink2.MAVLINK_MSG_ID_COMMAND_LONG,
        mavlink2.MAVLINK_MSG_ID_COMMAND_INT,
        mavlink2.MAVLINK_MSG_ID_SET_MODE,
        mavlink2.MAVLINK_MSG_ID_MISSION_COUNT,
        mavlink2.MAVLINK_MSG_ID_MISSION_ITEM,
        mavlink2.MAVLINK_MSG_ID_MISSION_ITEM_INT,
        mavlink2.MAVLINK_MSG_ID_MISSION_CLEAR_ALL,
        mavlink2.MAVLINK_MSG_ID_MISSION_SET_CURRENT,
        mavlink2.MAVLINK_MSG_ID_MISSION_WRITE_PARTIAL_LIST,
        mavlink2.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED,
        mavlink2.MAVLINK_MSG_ID_SET_POSITION_TARGET_GLOBAL_INT,
        mavlink2.MAVLINK_MSG_ID_SET_ATTITUDE_TARGET,
        mavlink2.MAVLINK_MSG_ID_MANUAL_CONTROL,
        mavlink2.MAVLINK_MSG_ID_RC_CHANNELS_OVERRIDE,
        mavlink2.MAVLINK_MSG_ID_PARAM_SET,
        mavlink2.MAVLINK_MSG_ID_SET_HOME_POSITION,
    }
)


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
        """True if this frame commands the vehicle (see ``COMMANDING_MSGIDS``)."""
        return self.msgid in COMMANDING_MSGIDS


class FrameError(ValueError):
    """The bytes are not exactly one well-formed MAVLink frame."""


def read_header(frame: bytes) -> FrameHeader:
    """Read and check the header of exactly one MAVLink 1 or 2 frame.

    Checks magic, declared payload length against the byte count, and that the message id is
    known to the dialect. Raises ``FrameError`` otherwise. The CRC is not recomputed: the envelope's
    AEAD already proves the bytes are the sender's.
    """
    n = len(frame)
    if n < 8:
        raise FrameError("too short for a MAVLink header")
    magic = frame[0]
    if magic == MAGIC_V2:
        if n < 12:
            raise FrameError("too short for a MAVLink 2 header")
        plen, incompat, _compat, seq, sysid, compid = frame[1], frame[2], frame[3], frame[4], frame[5], frame[6]
        msgid = frame[7] | (frame[8] << 8) | (frame[9] << 16)
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
    if msgid not in MESSAGE_CLASSES:
        raise FrameError(f"unknown message id {msgid}")
    return FrameHeader(version, seq, sysid, compid, msgid, n)


def crc_ok(frame: bytes) -> bool:
    """True if the frame's X.25 checksum (with the message's CRC_EXTRA) is right."""
    if frame[0] == MAGIC_V2:
        hdr, msgid = 10, frame[7] | (frame[8] << 8) | (frame[9] << 16)
        plen = frame[1]
    else:
        hdr, msgid, plen = 6, frame[5], frame[1]
    cls = MESSAGE_CLASSES.get(msgid)
    if cls is None:
        return False
    crc = x25crc(frame[1 : hdr + plen])
    crc.accumulate(bytes([cls.crc_extra]))
    return frame[hdr + plen] | (frame[hdr + plen + 1] << 8) == crc.crc


def split_frames(data: bytes) -> tuple[list[bytes], bytes, int]:
    """Split a byte stream into whole MAVLink frames; return (frames, leftover, bytes skipped).

    A candidate frame whose checksum is wrong is not a frame: the splitter moves one byte on and
    looks for the next magic byte, so garbage never swallows the real frames behind it. Used by
    stream adapters (TCP/serial) that must cut frames before sealing each one.
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
        if not crc_ok(candidate):
            i += 1
            skipped += 1
            continue
        frames.append(candidate)
        i += total
    return frames, bytes(data[i:]), skipped


class FrameCodec:
    """Sans-IO MAVLink 2 encoder/decoder for one (sysid, compid), owning its sequence number."""

    def __init__(self, sysid: int, compid: int = 1) -> None:
        self.mav = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self.mav.robust_parsing = True
        self.sysid = sysid
        self.compid = compid

    def encode(self, msg: mavlink2.MAVLink_message) -> bytes:
        """Pack ``msg`` with this codec's ids and advance the sequence number."""
        frame = msg.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) % 256
        return bytes(frame)

    def decode(self, frame: bytes) -> mavlink2.MAVLink_message | None:
        """Decode one frame fully; ``None`` if it does not decode (bad CRC, unknown id)."""
        try:
            msgs = self.mav.parse_buffer(frame)
        except Exception:  # pymavlink raises assorted errors on garbage
            return None
        if not msgs:
            return None
        msg = msgs[0]
        if msg.get_type() == "BAD_DATA":
            return None
        return msg


def _crc(frame_wo_crc: bytes, crc_extra: int) -> bytes:
    crc = x25crc(frame_wo_crc[1:])
    crc.accumulate(bytes([crc_extra]))
    return bytes([crc.crc & 0xFF, crc.crc >> 8])


def rewrite_source(frame: bytes, sysid: int, compid: int) -> bytes:
    """The same frame with another source (sysid, compid) and a fresh checksum.

    Used by the GCS gateway: every application's frames leave the GS under the GS's fleet sysid,
    one component id per application. A MAVLink 2 signature cannot survive the change, so it is
    removed (the sealed envelope authenticates the frame instead).
    """
    hdr = read_header(frame)
    cls = MESSAGE_CLASSES[hdr.msgid]
    if hdr.version == 2:
        body = bytearray(frame[: 10 + frame[1]])
        body[2] &= ~SIGNED_FLAG
        body[5], body[6] = sysid, compid
    else:
        body = bytearray(frame[: 6 + frame[1]])
        body[3], body[4] = sysid, compid
    return bytes(body) + _crc(bytes(body), cls.crc_extra)


def encode_raw(msgid: int, crc_extra: int, payload: bytes, sysid: int, compid: int, seq: int = 0) -> bytes:
    """A MAVLink 2 frame for a message this dialect does not define (e.g. CONTROL_STATUS, 512)."""
    while len(payload) > 1 and payload[-1] == 0:  # MAVLink 2 drops trailing zero bytes
        payload = payload[:-1]
    body = bytes([MAGIC_V2, len(payload), 0, 0, seq & 0xFF, sysid, compid, msgid & 0xFF, (msgid >> 8) & 0xFF,
                  msgid >> 16]) + payload
    return body + _crc(body, crc_extra)
