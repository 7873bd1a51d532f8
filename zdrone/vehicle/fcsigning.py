"""MAVLink 2 signing of the companion's link to the flight controller: provisioned and kept here.

Theory of operation. The autopilot obeys any MAVLink that reaches it, on any of its links (a
telemetry radio on TELEM2, USB, a second companion process), unless it has a signing key: then
PX4 (>= 1.17) and ArduPilot refuse unsigned and wrongly signed commands. The companion is the one
trusted place to install and keep that key. ``FcSigning`` does it for one vehicle link:

* **Key store** (``FcKeyStore``): ``secrets/<drone>.fc-signing.json`` beside the node's secret
  (under systemd in the service's state directory, ``$ZDRONE_STATE_DIR``, as the authority state),
  mode 0600, replaced atomically (temporary file, fsync, rename, fsync of the directory): the key,
  the key it replaces while a rotation is unconfirmed, the timestamp reserved so far, and whether the
  autopilot has ever signed with a key of this node (``confirmed``: from then on the link never goes
  back to unsigned).
* **Provisioning** (``start``): with no key yet, or when a rotation is asked for, a fresh 32-byte
  key goes to the autopilot in SETUP_SIGNING, on the ground only (refused while armed, as PX4
  does). The first key is sent unsigned (PX4 takes it on trust); a new key is sent signed with the
  old one (an autopilot with a key drops an unsigned SETUP_SIGNING). With a stored key the node
  sends SETUP_SIGNING with the same key, signed, so an autopilot that lost its key gets it back and
  one that has it changes nothing; armed (a restart in the air), or over a UDP endpoint the link
  learned (``resend_stored`` False: whoever answers first there may not be the autopilot, and
  SETUP_SIGNING carries the key in clear), it sends none and only waits for the autopilot's signed
  frames.
* **Confirmation**: the autopilot signs its frames once signed traffic arrives; the first frame
  signed with the new key confirms it (``state`` SIGNED, the old key forgotten). Frames still signed
  with the old key make the node send SETUP_SIGNING again (once a second). No signed frame within
  ``confirm_timeout`` seconds: the autopilot does not sign (PX4 before 1.17): said once, counted, and
  the link goes on unsigned (``prefer``) or the node refuses to fly (``require``) -- and refuses with
  ``prefer`` too when this autopilot has signed before (``StoredKey.confirmed``): a vehicle that once
  held a key never goes back to unsigned (who answers unsigned now is someone else, or the autopilot
  lost its key: ``--rotate-fc-key`` on the ground installs one again).
* **Every frame out is signed** (``outgoing``) with link id ``link_id``, under a timestamp that
  never goes back, across restarts too: the larger of the last one + 1, the wall clock, the
  timestamps of the autopilot's signed frames (ArduPilot resumes 60 s past its last saved
  timestamp after a restart and refuses a new stream more than a minute behind it), and the value
  reserved in the store. A timestamp is used only once the store holds a larger one
  (``RESERVE_S`` ahead, so the file is written about once every ``RESERVE_S`` seconds).
* **Every frame in is checked** (``incoming``): signed ones must carry the key's signature and a
  timestamp that grows per stream (``StreamClock``); once the link is SIGNED an unsigned frame from
  the flight controller's side is dropped too (someone else on the wire). Each drop is counted by
  reason.
* **Only the autopilot's own stream proves the autopilot.** The companion signs with the same key:
  its own frames (its sysid, component 191, link id ``link_id``) and the GSs' frames it forwards. A
  process that can write into the link can send any of them straight back (a reflection): signed
  with the key, on a stream the autopilot never used, so "a new stream" to the replay check. So a
  signed frame on a stream the companion itself emits (``emitted``: every stream ``sign_with`` has
  signed, and the companion's own from the start) is dropped (``reflected``), and only a frame
  signed on the autopilot's ids (``expect``: the drone's sysid, component 1) confirms the key
  (``state`` SIGNED) or vouches for the autopilot (``vouches``; ``proves`` also wants its
  timestamp fresh: a copy of a frame already taken proves nothing). The link never signs a frame
  carrying the autopilot's ids itself (``VehicleLink.send``), so nothing the companion emits can be
  turned into that proof.

Thread-safe: the vehicle link's reader thread calls ``incoming``, its loop thread the rest.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import common as mav

from zdrone.core import fcsign
from zdrone.core.errors import UsageError
from zdrone.core.fleet import ConfigError
from zdrone.core.mavlink import FrameError
from zdrone.fleet.files import fleet_path, write_durably
from zdrone.net.authstore import STATE_DIR_ENV

log = logging.getLogger(__name__)

MODES = ("require", "prefer", "off")
#: The link id of the companion's link to the flight controller.
LINK_ID = 1
#: A timestamp is used only once the store holds one at least this much larger.
RESERVE_S = 10.0
#: No signed frame from the autopilot this long after provisioning: it does not sign.
CONFIRM_TIMEOUT_S = 4.0
#: SETUP_SIGNING is sent again this often while the autopilot still signs with the old key.
RESEND_S = 1.0


class FcSigningError(ConfigError):
    """Signing cannot be set up as asked (armed, the autopilot does not sign and it is required, ...)."""


class FcState(str, Enum):
    OFF = "off"  # --fc-signing off: nothing signed, nothing checked
    PROVISIONING = "provisioning"  # SETUP_SIGNING sent, waiting for the autopilot's first signed frame
    SIGNED = "signed"  # the autopilot signs with our key: every frame both ways is signed and checked
    UNSIGNED = "unsigned"  # the autopilot does not sign (prefer): the link goes on unsigned
    FAILED = "failed"  # require, and the autopilot does not sign; or it signs with a key we do not hold


@dataclass(frozen=True, slots=True)
class StoredKey:
    key: bytes
    timestamp: int  # reserved: every timestamp used so far is below it
    previous: bytes | None = None  # the key a rotation replaces, until the autopilot signs with the new one
    confirmed: bool = False  # the autopilot has signed with a key of this node: never unsigned again


def key_id(key: bytes | None) -> str | None:
    """A short public name of a key (the first 8 hex digits of its SHA-256), for logs and status."""
    return hashlib.sha256(key).hexdigest()[:8] if key else None


class FcKeyStore:
    """The flight controller's signing key of one drone, beside the node's secret."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)

    @classmethod
    def for_node(cls, fleet: str | Path, drone: str) -> FcKeyStore:
        """Beside the node's secret (``secrets/<drone>.fc-signing.json``); under systemd, whose unit
        keeps the bundle read-only, in the service's state directory (``$ZDRONE_STATE_DIR``) beside
        the authority state."""
        state_dir = os.environ.get(STATE_DIR_ENV)
        base = Path(state_dir) if state_dir else fleet_path(fleet).parent / "secrets"
        return cls(base / f"{drone}.fc-signing.json")

    def load(self) -> StoredKey | None:
        """The stored key, None if there is none. A file readable by others or unreadable is an error."""
        try:
            st = self.path.stat()
        except FileNotFoundError:
            return None
        if st.st_mode & 0o077:
            raise ConfigError(f"{self.path}: key file is accessible by others (mode {st.st_mode & 0o777:04o}); "
                              f"run chmod 600 {self.path}")
        try:
            raw = json.loads(self.path.read_text())
            key = bytes.fromhex(raw["key"])
            prev = bytes.fromhex(raw["previous"]) if raw.get("previous") else None
            stored = StoredKey(key, int(raw["timestamp"]), prev, bool(raw.get("confirmed", False)))
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise ConfigError(f"{self.path}: malformed signing key file: {exc}") from None
        if len(key) != fcsign.KEY_LEN or (prev is not None and len(prev) != fcsign.KEY_LEN):
            raise ConfigError(f"{self.path}: a signing key must be {fcsign.KEY_LEN} bytes")
        return stored

    def save(self, stored: StoredKey) -> None:
        """Write durably: temporary file (0600), fsync, rename over the old one, fsync the directory."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        body = {"key": stored.key.hex(), "timestamp": stored.timestamp,
                "previous": stored.previous.hex() if stored.previous else None, "confirmed": stored.confirmed}
        write_durably(self.path, json.dumps(body).encode())


def parse_mode(text: str) -> str:
    if text not in MODES:
        raise UsageError(f"--fc-signing {text!r}: expected one of {', '.join(MODES)}")
    return text


class FcSigning:
    """Signing state of one link to a flight controller (see the module's docstring)."""

    def __init__(self, store: FcKeyStore | None, mode: str = "prefer", rotate: bool = False,
                 clock: Callable[[], float] = time.time, link_id: int = LINK_ID,
                 confirm_timeout: float = CONFIRM_TIMEOUT_S, new_key: Callable[[], bytes] = lambda: os.urandom(32)) -> None:
        parse_mode(mode)
        if mode != "off" and store is None:
            raise ConfigError("MAVLink signing needs a key store")
        self.store, self.mode, self.rotate = store, mode, rotate
        self.clock, self.link_id, self.confirm_timeout, self._new_key = clock, link_id, confirm_timeout, new_key
        self.state = FcState.OFF
        self.counters: Counter[str] = Counter()
        self.stored: StoredKey | None = store.load() if store is not None and mode != "off" else None
        self.key: bytes | None = self.stored.key if self.stored else None
        self.previous: bytes | None = self.stored.previous if self.stored else None
        #: the autopilot has signed with a key of this node (persisted): the link never goes back to unsigned
        self.confirmed_before = bool(self.stored and self.stored.confirmed)
        self._reserved = self.stored.timestamp if self.stored else 0
        self.timestamp = self._reserved  # the last timestamp used (or reserved before a restart)
        self.peer = fcsign.StreamClock(self.timestamp)
        self.started_at: float | None = None
        self._setup: Any = None  # the SETUP_SIGNING message to (re)send while unconfirmed
        self._setup_key: bytes | None = None  # the key that signs it (None: unsigned)
        self._next_setup = 0.0
        self.reason = ""
        #: the ids (sysid, compid) whose signed frames confirm the key and vouch for the autopilot;
        #: None until ``expect`` (then any ids: the pure tests)
        self.autopilot_ids: tuple[int, int] | None = None
        #: the streams (link id, sysid, compid) the companion has signed: never the autopilot's
        self.emitted: set[tuple[int, int, int]] = set()
        self._lock = threading.RLock()
        if mode == "off" and store is not None and store.path.exists():
            log.warning("--fc-signing off, but %s holds a key: an autopilot that has it refuses unsigned commands",
                        store.path)

    def expect(self, autopilot: tuple[int, int], own: tuple[int, int]) -> None:
        """The autopilot's ids (only its signed frames prove it) and the companion's own (sysid, compid):
        its stream is the companion's from the start, so a reflection of it is dropped even before
        the first frame of this run went out."""
        with self._lock:
            self.autopilot_ids = autopilot
            self.emitted.add((self.link_id, *own))

    # -------------------------------------------------------------------- state
    @property
    def signing(self) -> bool:
        """True while frames to the autopilot are signed."""
        return self.state in (FcState.PROVISIONING, FcState.SIGNED)

    @property
    def settled(self) -> bool:
        """Provisioning is over (SIGNED, UNSIGNED, FAILED or OFF)."""
        return self.state is not FcState.PROVISIONING

    def status(self) -> dict[str, Any]:
        """For the drone's status: mode, state, whether the link is signed, key id, counters."""
        with self._lock:
            return {"mode": self.mode, "state": self.state.value, "signed": self.state is FcState.SIGNED,
                    "key": key_id(self.key), "timestamp": self.timestamp, "reason": self.reason,
                    "signed_before": self.confirmed_before, "counters": dict(self.counters)}

    # ------------------------------------------------------------ provisioning
    def start(self, now: float, armed: bool, target_system: int, target_component: int = 1,
              resend_stored: bool = True) -> None:
        """Begin: decide whether a key must be installed (a first one, or a rotation) and prepare the
        SETUP_SIGNING (``due_setup`` hands it out). ``resend_stored`` False: a stored key is not sent
        again (an endpoint the link learned: only a signed answer proves it is the autopilot). Raises
        ``FcSigningError`` when a key must be installed while the vehicle is armed."""
        with self._lock:
            self.started_at = now
            if self.mode == "off":
                self.state = FcState.OFF
                return
            fresh = self.key is None or self.rotate
            if fresh and armed:
                what = "rotate the flight controller's signing key" if self.key else "install a signing key"
                if self.mode == "require" or self.rotate:
                    raise FcSigningError(f"cannot {what} while the vehicle is armed (MAVLink signing: rejected while armed)")
                self._fall_back(f"no signing key and the vehicle is armed: cannot {what}")
                return
            if fresh:
                old, new = self.key, self._new_key()
                if len(new) != fcsign.KEY_LEN:
                    raise ValueError("a signing key is 32 bytes")
                ts = self._next_timestamp()
                self._save(StoredKey(new, self._reserved, old, self.confirmed_before))  # stored before it is sent
                self.key, self.previous = new, old
                self._setup_key = old  # None for the first key: sent unsigned, taken on trust
                log.warning("installing %s MAVLink signing key %s in the flight controller%s",
                            "a new" if old else "a first", key_id(new), f" (replacing {key_id(old)})" if old else "")
            elif armed or not resend_stored:  # a restart in the air (the autopilot refuses SETUP_SIGNING now),
                # or an endpoint not yet proven: the autopilot has the key and signs back
                self._setup = None
                self._next_setup = now
                self.state = FcState.PROVISIONING
                return
            else:
                ts = self._next_timestamp()
                self._setup_key = self.previous or self.key  # an unconfirmed rotation: signed by the old key
            self._setup = mav.MAVLink_setup_signing_message(target_system, target_component, list(self.key or b""), ts)
            self._next_setup = now
            self.state = FcState.PROVISIONING

    def due_setup(self, now: float) -> tuple[Any, bytes | None] | None:
        """The SETUP_SIGNING to send now and the key to sign it with (None: unsigned), or None; also
        settles a provisioning that timed out (``state`` UNSIGNED or FAILED)."""
        with self._lock:
            if self.state is not FcState.PROVISIONING:
                return None
            if self.started_at is not None and now - self.started_at >= self.confirm_timeout:
                self._no_signed_reply()
                return None
            if self._setup is None or now < self._next_setup:
                return None
            self._next_setup = now + RESEND_S
            self.counters["setup_sent"] += 1
            return self._setup, self._setup_key

    def _no_signed_reply(self) -> None:
        if self.confirmed_before:
            self.state, self.reason = FcState.FAILED, (
                f"the autopilot signed with key {key_id(self.key)} before and does not now: the link does not go "
                "back to unsigned (someone else answers as the autopilot, or it lost its key: --rotate-fc-key on "
                "the ground installs one again)")
            self.counters["downgrade_refused"] += 1
            log.error("MAVLink signing: %s", self.reason)
        elif self.counters["foreign_signature"]:
            self.state, self.reason = FcState.FAILED, "the autopilot signs with a key this node does not hold"
            log.error("MAVLink signing: %s", self.reason)
        elif self.mode == "require":
            self.state, self.reason = FcState.FAILED, "the autopilot does not sign (PX4 before 1.17?)"
            log.error("MAVLink signing: %s; --fc-signing require", self.reason)
        else:
            self._fall_back("the autopilot does not sign (PX4 before 1.17?): the link goes on unsigned")

    def _fall_back(self, why: str) -> None:
        self.state, self.reason = FcState.UNSIGNED, why
        self.counters["unsigned_fallback"] += 1
        log.warning("MAVLink signing: %s", why)

    # ---------------------------------------------------------------- frames
    def _save(self, stored: StoredKey) -> None:
        assert self.store is not None
        self.store.save(stored)
        self.stored = stored

    def _next_timestamp(self) -> int:
        ts = max(self.timestamp + 1, fcsign.units(self.clock()), self.peer.timestamp)
        if ts >= self._reserved:
            self._reserved = ts + int(RESERVE_S * fcsign.UNITS_PER_S)
            if self.key is not None:
                self._save(StoredKey(self.key, self._reserved, self.previous, self.confirmed_before))
                self.counters["timestamp_saved"] += 1
        self.timestamp = ts
        return ts

    def sign_with(self, frame: bytes, key: bytes | None) -> bytes:
        """``frame`` signed with ``key`` (None: as it is)."""
        if key is None:
            return frame
        with self._lock:
            try:
                out = fcsign.sign(frame, key, self.link_id, self._next_timestamp())
            except FrameError:
                self.counters["unsignable"] += 1  # a MAVLink 1 frame: goes as it is
                return frame
            self.counters["signed_out"] += 1
            self.emitted.add((self.link_id, out[5], out[6]))
            return out

    def outgoing(self, frame: bytes) -> bytes:
        """A frame to the autopilot as it must go: signed while signing."""
        if not self.signing:
            return frame
        return self.sign_with(frame, self.key)

    def incoming(self, frame: bytes) -> str | None:
        """Check a frame from the autopilot's side: None to take it, else the counted reason to drop it."""
        if self.state is FcState.OFF:
            return None
        with self._lock:
            if not fcsign.is_signed(frame):
                if self.state is FcState.SIGNED:
                    return self._drop("unsigned")
                self.counters["unsigned_in"] += 1
                return None
            key = self.key
            if key is not None and fcsign.signed_with(frame, key):
                if self._reflected(frame):
                    return self._drop("reflected")
                refusal = self.peer.check(frame, key)
                if refusal is not None:
                    return self._drop(refusal.value)
                self.counters["verified_in"] += 1
                if self.state is not FcState.SIGNED and self._autopilots(frame):
                    self._confirmed()
                return None
            if self.previous is not None and fcsign.signed_with(frame, self.previous):
                if self._reflected(frame):
                    return self._drop("reflected")
                self.counters["old_key_in"] += 1  # the autopilot has not taken the new key (yet)
                if self.state is FcState.PROVISIONING:
                    return None if self.peer.check(frame, self.previous) is None else self._drop("replay")
                return self._drop("old_key")
            self.counters["foreign_signature"] += 1
            return self._drop("bad_signature")

    def _reflected(self, frame: bytes) -> bool:
        """A signed frame on a stream the companion emits: its own, sent back (never the autopilot's)."""
        sig = fcsign.read_signature(frame)
        return sig is not None and sig.stream in self.emitted

    def _autopilots(self, frame: bytes) -> bool:
        """The frame carries the autopilot's ids (any ids before ``expect``)."""
        return self.autopilot_ids is None or (frame[5], frame[6]) == self.autopilot_ids

    def vouches(self, frame: bytes) -> bool:
        """The frame comes from the autopilot: signed with the link's key (or the one a rotation
        replaces) on the autopilot's own ids, on no stream the companion emits. Only meaningful for a
        frame ``incoming`` took (its timestamp checked there)."""
        if self.mode == "off" or not fcsign.is_signed(frame):
            return False
        with self._lock:
            return self._autopilots(frame) and not self._reflected(frame) and any(
                k is not None and fcsign.signed_with(frame, k) for k in (self.key, self.previous))

    def proves(self, frame: bytes) -> bool:
        """``vouches``, and ``incoming`` would take its timestamp (a new stream, or one that grows): a
        frame that proves which address is the autopilot, before ``incoming`` has seen it. A copy of
        a frame already taken (the autopilot's own frame relayed from elsewhere) proves nothing."""
        if not self.vouches(frame):
            return False
        sig = fcsign.read_signature(frame)
        if sig is None:
            return False
        with self._lock:
            last = self.peer.streams.get(sig.stream)
            if last is not None:
                return sig.timestamp > last
            return sig.timestamp + fcsign.NEW_STREAM_WINDOW >= self.peer.timestamp

    def _drop(self, reason: str) -> str:
        self.counters[f"dropped:{reason}"] += 1
        if self.counters[f"dropped:{reason}"] <= 3:
            log.warning("MAVLink signing: frame from the flight controller's link dropped: %s", reason)
        return reason

    def _confirmed(self) -> None:
        was = self.state
        self.state, self.reason = FcState.SIGNED, ""
        self._setup = None
        if (self.previous is not None or not self.confirmed_before) and self.key is not None and self.store is not None:
            self.previous, self.confirmed_before = None, True
            self._save(StoredKey(self.key, self._reserved, None, True))  # from now on never unsigned
        log.warning("MAVLink signing: the flight controller signs with key %s%s", key_id(self.key),
                    "" if was is FcState.PROVISIONING else f" (was {was.value})")
