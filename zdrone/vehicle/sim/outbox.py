"""What the simulated autopilot sends: its frames in order, its texts, and the count of bad input.

Theory of operation: one ``Outbox`` per autopilot, shared by its protocols. ``send`` encodes a
pymavlink message with the autopilot's codec (its system, component and sequence numbers);
``send_raw`` a message no pymavlink dialect here defines, under the same sequence. ``say`` tells the
GCS one of the personality's texts (or a given ``Say``): a STATUSTEXT (PX4 numbers every text and
splits a long one into 50-byte chunks; ArduPilot cuts it) and, for PX4, the EVENT (410) behind it,
marked by a tab at the end of the STATUSTEXT as PX4's mavlink_log does; every text is also kept in
``events`` with the time it was said. ``count`` records one piece of bad input or one refusal by
name in ``counters`` (and the log). ``drain`` hands the frames over, oldest first.
"""

from __future__ import annotations

import logging
import struct
from collections import Counter
from collections.abc import Callable
from typing import Any

from pymavlink.dialects.v20 import common as mav

from zdrone.core.mavlink import FrameCodec, encode_raw
from zdrone.vehicle.personality import MSG_EVENT, RAW_CRC_EXTRA, Personality, Say, px4_event_id

log = logging.getLogger(__name__)

STATUSTEXT_CHUNK = 50  # bytes of text in one STATUSTEXT


class Outbox:
    """Frames to send, texts said and counters; ``clock()`` is the autopilot's simulated time."""

    def __init__(self, codec: FrameCodec, personality: Personality, boot: float, clock: Callable[[], float]) -> None:
        self.codec = codec
        self.p = personality
        self.boot = boot
        self.clock = clock
        self.frames: list[bytes] = []
        self.counters: Counter[str] = Counter()
        self.events: list[tuple[float, str]] = []  # (simulated time, text) of everything said
        self.text_id = 0  # STATUSTEXT id (PX4 numbers every text)
        self.event_seq = 0  # sequence of the next EVENT (PX4)

    def send(self, msg: Any) -> None:
        self.frames.append(self.codec.encode(msg))

    def send_raw(self, msgid: int, payload: bytes) -> None:
        """A message no pymavlink dialect here defines, under this codec's sequence number."""
        self.frames.append(encode_raw(msgid, RAW_CRC_EXTRA[msgid], payload, self.codec.sysid,
                                      self.codec.compid, self.codec.mav.seq))
        self.codec.mav.seq = (self.codec.mav.seq + 1) % 256

    def drain(self) -> list[bytes]:
        """Frames to send, oldest first."""
        out, self.frames = self.frames, []
        return out

    def count(self, what: str, detail: str = "") -> None:
        self.counters[what] += 1
        log.info("sim: %s %s", what, detail)

    def say(self, what: str | Say, **fmt: object) -> None:
        """Tell the GCS: the personality's text ``what`` (a key; nothing if it has none) or a given
        ``Say``, its ``{placeholders}`` filled from ``fmt``."""
        say = self.p.text(what) if isinstance(what, str) else what
        if say is None:
            return
        if fmt:
            say = say.format(**fmt)
        log.info("sim: %s", say.text)
        self.events.append((self.clock(), say.text))
        evented = self.p.events and say.event is not None
        self._statustext(say.severity, say.text + ("\t" if evented else ""))
        if evented:
            self._send_event(say)

    def _statustext(self, severity: int, text: str) -> None:
        raw = text.encode()
        if not self.p.chunk_statustext or len(raw) <= STATUSTEXT_CHUNK:
            self.send(mav.MAVLink_statustext_message(severity, raw[:STATUSTEXT_CHUNK],
                                                     self.text_id if self.p.chunk_statustext else 0, 0))
        else:  # PX4: 50-byte chunks sharing one id, numbered by chunk_seq
            for i, start in enumerate(range(0, len(raw), STATUSTEXT_CHUNK)):
                self.send(mav.MAVLink_statustext_message(severity, raw[start:start + STATUSTEXT_CHUNK], self.text_id, i))
        self.text_id = (self.text_id + 1) & 0xFFFF

    def _send_event(self, say: Say) -> None:
        assert say.event is not None
        boot_ms = int((self.clock() - self.boot) * 1000) & 0xFFFFFFFF
        payload = struct.pack("<IIHBBB", px4_event_id(say.event), boot_ms, self.event_seq, 0, 0, say.log_levels)
        self.send_raw(MSG_EVENT, payload + say.args[:40].ljust(40, b"\0"))
        self.event_seq = (self.event_seq + 1) & 0xFFFF
