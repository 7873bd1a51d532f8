"""The simulated autopilot's MAVLink 2 signing, as PX4 1.17 and ArduCopter 4.7 enforce it.

Theory of operation: one ``SimSigning`` per autopilot, its links numbered (0: the main endpoint,
1: TELEM2). Without a key everything is accepted (signed frames too, their signature unchecked).
SETUP_SIGNING installs a key: the first one on trust, signed or not; once a key exists only a
correctly signed one may replace it (or, all zero, remove it); any of them is refused while armed.
With a key, ``admit`` passes a frame only if it is signed with the key and its stream's timestamp
grows (a new stream: no more than a minute behind the autopilot's own), except the personality's
unsigned ids (PX4: HEARTBEAT, RADIO_STATUS, ADSB_VEHICLE, COLLISION; ArduPilot: RADIO_STATUS and
RADIO) and, on ArduPilot, anything on link 0 (SERIAL0, "assumed secure": it always accepts
unsigned frames). A link's outgoing frames are signed (``outgoing``) once a frame correctly signed
with the key has arrived on it.

The key and the timestamp persist in ``storage`` (``SigningStorage``, the simulator's SD card /
parameter storage): kept across restarts; the timestamp is saved every ``save_every_s`` seconds and,
on ArduPilot, resumed ``resume_ahead_s`` = 60 s past the saved value.

The timestamp follows the wall clock given (``wall``; the simulator's own time from a fixed origin
when none is), never goes back, and moves up to the newest accepted signed frame's.
"""

from __future__ import annotations

import logging
import os
import struct
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import common as mav

from zdrone.core import fcsign
from zdrone.core.mavlink import FrameError
from zdrone.vehicle.personality import Say

log = logging.getLogger(__name__)

MSG_SETUP_SIGNING = 256


@dataclass(frozen=True, slots=True)
class SigningRules:
    """How one autopilot enforces signing."""

    unsigned_ok: frozenset[int]  # message ids accepted unsigned on every link
    open_links: frozenset[int]  # links that accept anything unsigned (ArduPilot's SERIAL0)
    resume_ahead_s: float  # after a restart, the timestamp resumes this far past the saved one
    save_every_s: float  # the timestamp is saved this often (wall seconds)
    key_file: str  # where in the storage directory


RULES: dict[str, SigningRules] = {
    "px4": SigningRules(frozenset({0, 109, 246, 247}), frozenset(), 0.0, 30.0, "mavlink/mavlink-signing-key.bin"),
    "ardupilot": SigningRules(frozenset({109, 166}), frozenset({0}), 60.0, 30.0, "signing-key.bin"),
}
#: What the autopilot says about its key (PX4's texts).
TEXTS: dict[str, Say] = {
    "signing_key_accepted": Say("MAVLink signing key accepted"),
    "signing_rejected_armed": Say("MAVLink signing: rejected while armed", mav.MAV_SEVERITY_WARNING),
    "signing_disabled": Say("MAVLink signing disabled"),
}
#: Where the simulator's clock starts when no wall clock is given (2026-01-01 00:00 UTC).
SIM_EPOCH = 1767225600.0


class SigningStorage:
    """The key and timestamp on disk: 32 bytes of key and a little-endian uint64 timestamp (mode 0600)."""

    def __init__(self, directory: str | Path, rules: SigningRules) -> None:
        self.path = Path(directory) / rules.key_file

    def load(self) -> tuple[bytes, int] | None:
        try:
            raw = self.path.read_bytes()
        except FileNotFoundError:
            return None
        if len(raw) != 40:
            log.warning("sim: %s: not a signing key file, ignored", self.path)
            return None
        return raw[:32], struct.unpack("<Q", raw[32:])[0]

    def save(self, key: bytes | None, timestamp: int) -> None:
        if key is None:
            self.path.unlink(missing_ok=True)
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.path.with_suffix(".tmp")
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        try:
            os.write(fd, key + struct.pack("<Q", timestamp))
        finally:
            os.close(fd)
        os.replace(tmp, self.path)


class SimSigning:
    """The signing state of one simulated autopilot (``rules``: None = an autopilot without signing,
    PX4 before 1.17: SETUP_SIGNING ignored, every frame accepted, nothing signed)."""

    def __init__(self, rules: SigningRules | None, storage: SigningStorage | None = None,
                 wall: Callable[[], float] | None = None, sim_time: Callable[[], float] = lambda: 0.0) -> None:
        self.rules = rules
        self.storage = storage
        self.wall = wall if wall is not None else (lambda: SIM_EPOCH + sim_time())
        self.counters: Counter[str] = Counter()
        self.key: bytes | None = None
        self.clock = fcsign.StreamClock(0)
        self.sign_links: set[int] = set()
        self._next_save = 0.0
        loaded = storage.load() if storage is not None and rules is not None else None
        if loaded is not None:
            assert rules is not None
            self.key = loaded[0]
            self.clock.timestamp = loaded[1] + int(rules.resume_ahead_s * fcsign.UNITS_PER_S)
            log.info("sim: MAVLink signing key kept across the restart (timestamp resumes at %d)", self.clock.timestamp)

    @property
    def active(self) -> bool:
        return self.key is not None

    def admit(self, frame: bytes, link: int) -> str | None:
        """None to handle the frame, else why it is dropped (counted)."""
        if self.key is None or self.rules is None:
            return None
        if fcsign.is_signed(frame):
            refusal = self.clock.check(frame, self.key)
            if refusal is None:
                self.sign_links.add(link)
                self.counters["signed_ok"] += 1
                return None
            if fcsign.signed_with(frame, self.key):
                self.sign_links.add(link)  # the right key, an old timestamp: it answers signed, so the sender learns
            return self._refuse(refusal.value)
        msgid = frame[7] | (frame[8] << 8) | (frame[9] << 16) if frame[0] == fcsign.MAGIC_V2 else frame[5]
        if link in self.rules.open_links or msgid in self.rules.unsigned_ok:
            self.counters["unsigned_ok"] += 1
            return None
        return self._refuse("unsigned")

    def _refuse(self, why: str) -> str:
        self.counters[f"refused:{why}"] += 1
        return why

    def setup(self, msg: Any, signed: bool, armed: bool, link: int = 0) -> Say | None:
        """SETUP_SIGNING (already admitted; ``signed``: it came correctly signed): what the autopilot
        says, or None when it says nothing (ignored, or dropped)."""
        if self.rules is None:
            self.counters["ignored:setup_signing"] += 1
            return None
        if armed:
            self.counters["refused:setup_armed"] += 1
            return TEXTS["signing_rejected_armed"]
        key = bytes(msg.secret_key)
        if self.key is not None and not signed and link not in self.rules.open_links:  # ArduPilot's SERIAL0 takes it
            self.counters["refused:setup_unsigned"] += 1
            return None
        if not any(key):
            self.key = None
            self.sign_links.clear()
            self.counters["signing_disabled"] += 1
            self._save()
            return TEXTS["signing_disabled"]
        self.key = key
        self.clock.timestamp = max(self.clock.timestamp, int(msg.initial_timestamp))
        self.clock.streams.clear()
        self.sign_links.clear()
        self.counters["key_accepted"] += 1
        self._save()
        return TEXTS["signing_key_accepted"]

    def _save(self) -> None:
        if self.storage is not None:
            self.storage.save(self.key, self.clock.timestamp)

    def tick(self) -> None:
        """Follow the wall clock; save the timestamp every ``save_every_s``."""
        if self.key is None or self.rules is None:
            return
        wall = self.wall()
        self.clock.timestamp = max(self.clock.timestamp, fcsign.units(wall))
        if wall >= self._next_save:
            self._next_save = wall + self.rules.save_every_s
            self._save()

    def outgoing(self, frame: bytes, link: int) -> bytes:
        """The frame as it leaves on ``link``: signed once signed traffic arrived there."""
        if self.key is None or link not in self.sign_links:
            return frame
        self.clock.timestamp = max(self.clock.timestamp + 1, fcsign.units(self.wall()))
        try:
            return fcsign.sign(frame, self.key, link, self.clock.timestamp)
        except FrameError:
            return frame
