"""MAVLink 2 signing of the GCS gateway's local link: a key per operator application.

Theory of operation
-------------------
Whatever reaches a gateway endpoint speaks for the GS's operator (consent, release, allow takeover,
commands), so the gateway must know *which* application spoke. Each application is given a 32-byte
MAVLink signing key of its own, listed by name in a key file (``zdrone gs --gcs-keys FILE``, mode
0600 like every secret file of the project). A signed frame names its application: the key whose
signature it carries (``key:<name>``); an unsigned one is named by its address only
(``unsigned:<ip:port>``), which any local process can take.

Key file: one application a line, ``NAME KEY``; blank lines and lines starting with ``#`` are
skipped. ``KEY`` is one of

* ``hex:<64 hex digits>``: the raw key (pymavlink's ``setup_signing(key)``, QGroundControl's raw keys);
* ``qgc:<passphrase>``: QGroundControl's passphrase keys (PBKDF2-HMAC-SHA256 of the UTF-8 passphrase,
  salt ``QGroundControl-MAVLink-Signing-v1``, 600 000 rounds, 32 bytes);
* ``passphrase:<passphrase>`` or the bare passphrase: SHA-256 of the passphrase, which is what
  MAVProxy's ``signing key <passphrase>`` / ``signing setup <passphrase>`` use (one word, ASCII), and
  QGroundControl's first signing builds.

Checks (``AppSigning.verify``), as the MAVLink signing spec has them: the signature (the first 6
bytes of SHA-256(key || frame up to and with the timestamp)) made with one of the listed keys, the key
last proven by the same peer tried first; then the timestamp: per (key, link id, sysid, compid)
stream it must grow; a stream not seen yet must be at most a minute behind the receiver's own
timestamp (the wall clock, or the largest timestamp accepted under that key if larger: a key holder's
clock moves its own key's window only). Each failure is a reason
(``bad_signature``, ``replay``, ``stale_stream``), never an exception. The work per frame is bounded
by the number of keys (``MAX_KEYS``).

Replies to a signed application are signed with its key (``AppSigning.sign``): link id of the
gateway's endpoint, a timestamp per key that never goes back (the larger of the last one + 1, the
wall clock, and the largest the application has sent), so that the application's own check (new
stream within a minute of its timestamp, growing per stream) accepts them.

No clock and no socket here: the caller passes every timestamp (``now_units``).
"""

from __future__ import annotations

import hashlib
import re
import stat
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

from zdrone.core import fcsign
from zdrone.core.errors import UsageError
from zdrone.core.fleet import ConfigError
from zdrone.core.mavlink import FrameError

MODES = ("off", "prefer", "require")
#: At most this many keys in one file: a frame with a signature no key made costs one SHA-256 per key.
MAX_KEYS = 64
#: Streams remembered per key (the oldest is forgotten beyond; it then counts as a new stream).
MAX_STREAMS_PER_KEY = 256
#: QGroundControl's passphrase keys: PBKDF2-HMAC-SHA256 with this fixed salt and round count.
QGC_SALT = b"QGroundControl-MAVLink-Signing-v1"
QGC_ROUNDS = 600_000
_NAME = re.compile(r"[A-Za-z0-9_.-]{1,32}")


def parse_mode(text: str) -> str:
    if text not in MODES:
        raise UsageError(f"--gcs-signing {text!r}: expected one of {', '.join(MODES)}")
    return text


def passphrase_key(passphrase: str) -> bytes:
    """The key MAVProxy's ``signing key``/``signing setup`` make of a passphrase: SHA-256 of its bytes."""
    return hashlib.sha256(passphrase.encode()).digest()


def qgc_passphrase_key(passphrase: str, rounds: int = QGC_ROUNDS) -> bytes:
    """The key QGroundControl makes of a passphrase (PBKDF2-HMAC-SHA256, its fixed salt)."""
    return hashlib.pbkdf2_hmac("sha256", passphrase.encode(), QGC_SALT, rounds, fcsign.KEY_LEN)


@dataclass(frozen=True, slots=True)
class SigningKey:
    """One application's key: its name in the key file and the 32 key bytes."""

    name: str
    key: bytes

    @property
    def identity(self) -> str:
        """How records and logs name the application that signs with it."""
        return f"key:{self.name}"

    def __repr__(self) -> str:  # never the key bytes in a log line or a traceback
        return f"SigningKey({self.name!r}, id {hashlib.sha256(self.key).hexdigest()[:8]})"


def parse_key(text: str, where: str = "key") -> bytes:
    """One ``KEY`` field of the key file (see the module's docstring). ``ConfigError`` if malformed."""
    kind, sep, rest = text.partition(":")
    if sep and kind == "hex":
        try:
            key = bytes.fromhex(rest.strip())
        except ValueError:
            raise ConfigError(f"{where}: hex: wants 64 hex digits") from None
        if len(key) != fcsign.KEY_LEN:
            raise ConfigError(f"{where}: hex: wants 64 hex digits (32 bytes), not {len(key)} bytes")
        if key == bytes(fcsign.KEY_LEN):
            raise ConfigError(f"{where}: an all-zero key means 'no signing' in MAVLink")
        return key
    if sep and kind == "qgc":
        if not rest:
            raise ConfigError(f"{where}: qgc: wants a passphrase")
        return qgc_passphrase_key(rest)
    passphrase = rest if sep and kind == "passphrase" else text
    if not passphrase:
        raise ConfigError(f"{where}: empty passphrase")
    return passphrase_key(passphrase)


def parse_keys(lines: Iterable[str], source: str = "keys") -> tuple[SigningKey, ...]:
    """The keys of a key file's lines; ``ConfigError`` naming the line for anything malformed, a name
    or a key given twice (one key must name one application), or more than ``MAX_KEYS``."""
    keys: list[SigningKey] = []
    names: set[str] = set()
    seen: dict[bytes, str] = {}
    for n, raw in enumerate(lines, 1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        name, _, value = line.partition(" ")
        where = f"{source}:{n}"
        if not _NAME.fullmatch(name):
            raise ConfigError(f"{where}: application name {name[:40]!r}: 1-32 of A-Z a-z 0-9 _ . -")
        value = value.strip()
        if not value:
            raise ConfigError(f"{where}: {name}: no key (NAME hex:<64 hex> | qgc:<passphrase> | <passphrase>)")
        key = parse_key(value, f"{where}: {name}")
        if name in names:
            raise ConfigError(f"{where}: application {name} listed twice")
        if key in seen:
            raise ConfigError(f"{where}: {name} has the same key as {seen[key]}: a key must name one application")
        names.add(name)
        seen[key] = name
        keys.append(SigningKey(name, key))
    if len(keys) > MAX_KEYS:
        raise ConfigError(f"{source}: {len(keys)} keys, at most {MAX_KEYS}")
    return tuple(keys)


def load_keys(path: str | Path) -> tuple[SigningKey, ...]:
    """The key file at ``path``; refused if it is readable by group or others (as every secret file)."""
    p = Path(path)
    try:
        st = p.stat()
    except FileNotFoundError:
        raise ConfigError(f"{p}: no such key file") from None
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read: {exc.__class__.__name__}") from None
    mode = stat.S_IMODE(st.st_mode)
    if mode & 0o077:
        raise ConfigError(f"{p}: key file is accessible by others (mode {mode:04o}); run chmod 600 {p}")
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: cannot read: {exc.__class__.__name__}") from None
    return parse_keys(text.splitlines(), str(p))


class AppSigning:
    """The signing state of one gateway: its keys, the streams seen under each, the timestamps it signs with."""

    def __init__(self, keys: Iterable[SigningKey] = ()) -> None:
        self.keys: dict[str, SigningKey] = {}
        for k in keys:
            if k.name in self.keys:
                raise ConfigError(f"application {k.name} listed twice")
            self.keys[k.name] = k
        if len(self.keys) > MAX_KEYS:
            raise ConfigError(f"{len(self.keys)} keys, at most {MAX_KEYS}")
        self._streams: dict[str, dict[tuple[int, int, int], int]] = {n: {} for n in self.keys}
        self._rx: dict[str, int] = {}  # per key: the receiver's timestamp (the largest accepted, or the clock)
        self._out: dict[str, int] = {}  # per key: the last timestamp signed with
        self._own: dict[str, set[tuple[int, int, int]]] = {n: set() for n in self.keys}  # streams we sign as

    def __len__(self) -> int:
        return len(self.keys)

    def _order(self, hint: str | None) -> Iterator[SigningKey]:
        first = self.keys.get(hint) if hint else None
        if first is not None:
            yield first
        for k in self.keys.values():
            if k is not first:
                yield k

    def verify(self, frame: bytes, now_units: int, hint: str | None = None) -> tuple[SigningKey | None, str | None]:
        """Check a signed frame: (its key, None) if authentic and fresh (its stream moves on), else
        (None, the reason to drop it). ``hint``: the key that peer proved last, tried first."""
        sig = fcsign.read_signature(frame)
        if sig is None:
            return None, "bad_signature"
        signed_part, mac = frame[:-6], frame[-6:]
        key = next((k for k in self._order(hint) if fcsign.signature(k.key, signed_part) == mac), None)
        if key is None:
            return None, "bad_signature"
        if sig.stream in self._own[key.name]:
            return None, "reflected"  # a frame this gateway signed, sent back: never the application's word
        mine = max(self._rx.get(key.name, 0), now_units)
        streams = self._streams[key.name]
        last = streams.get(sig.stream)
        if last is not None:
            if sig.timestamp <= last:
                return None, "replay"
        elif sig.timestamp + fcsign.NEW_STREAM_WINDOW < mine:
            return None, "stale_stream"
        if last is None and len(streams) >= MAX_STREAMS_PER_KEY:
            del streams[min(streams, key=streams.__getitem__)]
        streams[sig.stream] = sig.timestamp
        self._rx[key.name] = max(mine, sig.timestamp)
        return key, None

    def sign(self, frame: bytes, name: str, now_units: int, link_id: int = 0) -> bytes:
        """``frame`` signed with application ``name``'s key (a timestamp that never goes back).
        Raises ``KeyError`` for an unknown name and ``FrameError`` for a frame that cannot be signed
        (MAVLink 1, malformed)."""
        key = self.keys[name]
        ts = max(self._out.get(name, 0) + 1, now_units, self._rx.get(name, 0))
        out = fcsign.sign(frame, key.key, link_id, ts)
        self._out[name] = ts
        sig = fcsign.read_signature(out)
        if sig is not None:  # (link id, sysid, compid): the endpoints' ids times the ids the vehicle speaks as
            self._own[name].add(sig.stream)
        return out


__all__ = ["MODES", "MAX_KEYS", "AppSigning", "FrameError", "SigningKey", "load_keys", "parse_key", "parse_keys",
           "parse_mode", "passphrase_key", "qgc_passphrase_key"]
