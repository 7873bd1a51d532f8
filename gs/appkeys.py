"""MAVLink 2 signing of the GCS gateway's local link: a key per operator application.

Theory of operation
-------------------
Whatever reaches a gateway endpoint speaks for the GS's operator (consent, release, allow takeover,
commands), so the gateway must know *which* application spoke. Each application is given a 32-byte
MAVLink signing key of its own, listed by name in a key file (``zdrone gs --gcs-keys FILE``). A signed
frame names its application: the key whose signature it carries (``key:<name>``); an unsigned one is
named by its address only (``unsigned:<ip:port>``), which any local process can take.

Key file: one application a line, ``NAME KEY``; blank lines are skipped and ``#`` starts a comment at
the start of a line or after a blank (so ``NAME KEY   # note`` is ``NAME KEY``; a passphrase may hold a
``#`` only where no blank precedes it). ``KEY`` is one of

* ``hex:<64 hex digits>``: the raw key (pymavlink's ``setup_signing(key)``, QGroundControl's raw keys);
* ``qgc:<passphrase>``: QGroundControl's passphrase keys (PBKDF2-HMAC-SHA256 of the UTF-8 passphrase,
  salt ``QGroundControl-MAVLink-Signing-v1``, 600 000 rounds, 32 bytes);
* ``passphrase:<passphrase>`` or the bare passphrase: SHA-256 of the passphrase, which is what
  MAVProxy's ``signing key <passphrase>`` / ``signing setup <passphrase>`` use (one word, ASCII), and
  QGroundControl's first signing builds.

A line ``gs: <ID>`` names the GS the file is for: another GS refuses it (a whole file copied).

The file itself (``load_keys``) is opened without following a symbolic link (``O_NOFOLLOW``), must be a
regular file owned by the user running the GS (or root) and readable by nobody else (mode 0600), as
every secret file of the project: a root GS must not take a file another user wrote.

One key, one GS (``load_gs_keys``): a signed frame carries nothing that names its receiver (the link id
is the sender's choice, and QGroundControl and MAVProxy cannot be made to pick a GS-specific one), so a
key listed at two GSs lets a frame one refused be replayed to the other. A GS therefore refuses to start
when one of its keys is also in the key file of another GS of the fleet that it can read beside its own
(``<prefix>.<GS>``: ``gcs-keys.A`` beside ``gcs-keys.B``), and the documentation says one key per GS.

Passphrase strength: one captured signed frame lets anyone test passphrases offline, one SHA-256 each
(MAVProxy's key), at ~10^10 a second on one GPU. ``passphrase_bits`` is a rough, deliberately low
estimate of a passphrase's entropy; a key under ``STRONG_BITS`` (80) of guessing work (the estimate, plus
log2 of PBKDF2's rounds for ``qgc:``) is reported by ``weak_keys`` and the GS warns at start. Raw
``hex:`` keys are 256 bits.

Checks (``AppSigning.verify``), as the MAVLink signing spec has them: the signature (the first 6
bytes of SHA-256(key || frame up to and with the timestamp)) made with one of the listed keys, the key
last proven by the same peer tried first; then the timestamp: per (key, link id, sysid, compid)
stream it must grow; a stream not seen yet must be at most a minute behind the receiver's own
timestamp (the wall clock, or the largest timestamp accepted under that key if larger: a key holder's
clock moves its own key's window only). Each failure is a reason
(``bad_signature``, ``replay``, ``stale_stream``, ``before_start``), never an exception. The work per
frame is bounded by the number of keys (``MAX_KEYS``).

Across restarts: the streams' last timestamps (and the gateway's own) are the replay state
(``AppSigning.snapshot``/``restore``, by key fingerprint), which the gateway writes durably beside the
key file or in ``$ZDRONE_STATE_DIR`` (``signing_state_path``) at most once a second and when it stops,
and reads when it starts: a frame captured before a restart is a replay after it. A state that cannot
be read is not trusted: the gateway then takes no stream stamped before it started (``not_before``).

Replies to a signed application are signed with its key (``AppSigning.sign``): link id of the
gateway's endpoint, a timestamp per key that never goes back (the larger of the last one + 1, the
wall clock, and the largest the application has sent), so that the application's own check (new
stream within a minute of its timestamp, growing per stream) accepts them.

No clock and no socket here: the caller passes every timestamp (``now_units``).
"""

from __future__ import annotations

import errno
import hashlib
import json
import logging
import math
import os
import re
import stat
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from zdrone.core import fcsign
from zdrone.core.errors import UsageError
from zdrone.core.fleet import ConfigError
from zdrone.core.mavlink import FrameError

log = logging.getLogger(__name__)

MODES = ("off", "prefer", "require")
#: At most this many keys in one file: a frame with a signature no key made costs one SHA-256 per key.
MAX_KEYS = 64
#: Streams remembered per key (the oldest is forgotten beyond; it then counts as a new stream).
MAX_STREAMS_PER_KEY = 256
#: QGroundControl's passphrase keys: PBKDF2-HMAC-SHA256 with this fixed salt and round count.
QGC_SALT = b"QGroundControl-MAVLink-Signing-v1"
QGC_ROUNDS = 600_000
#: The guessing work (bits) a passphrase key should need at least: one GPU tests ~2^33 SHA-256 a
#: second, so 40 bits fall in minutes, 60 in years on one GPU (days on a thousand), 80 in ~2^47 s.
STRONG_BITS = 80.0
#: The replay state's file name in ``$ZDRONE_STATE_DIR`` (``<GS>.gcs-signing.json``) or beside the key
#: file (``<key file>.signing-state.json``).
STATE_DIR_ENV = "ZDRONE_STATE_DIR"
_NAME = re.compile(r"[A-Za-z0-9_.-]{1,32}")
_COMMENT = re.compile(r"\s#")
_GS_LINE = "gs:"
_STATE_VERSION = 1


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


_SEPARATORS = set(" -_.,:;/+")


def passphrase_bits(passphrase: str) -> float:
    """A rough, deliberately low estimate of a passphrase's guessing entropy in bits.

    The passphrase is cut into runs of letters, digits and other characters (a run of letters and
    digits mixed is one run); each run counts as random over the smallest alphabet that holds it
    (10 digits, 16 hex digits, 36 or 62 letters and digits), except a run of letters only, which
    counts 2 bits a character (a word is far from random: English text is ~1-2.5 bits a letter;
    random letters are under-credited, so a warning may be pessimistic); a separator counts 1 bit,
    another symbol ~5; a run seen before adds nothing. ``opsA-5f1c9e27b1`` is ~49 bits (10 hex digits
    and a short word), 32 random hex digits 128."""
    total, seen = 0.0, set()
    for run in re.findall(r"[A-Za-z0-9]+|[^A-Za-z0-9]", passphrase):
        if run in seen:
            continue
        seen.add(run)
        if not run.isascii() or not run.isalnum():  # one symbol (or a non-ASCII character)
            total += 1.0 if run in _SEPARATORS else math.log2(33)
            continue
        digits = any(c.isdigit() for c in run)
        if run.isdigit():
            per = math.log2(10)
        elif digits and all(c in "0123456789abcdef" for c in run) or digits and all(c in "0123456789ABCDEF" for c in run):
            per = 4.0
        elif digits:
            per = math.log2(10 + 26 * any(c.islower() for c in run) + 26 * any(c.isupper() for c in run))
        else:
            per = 2.0  # letters only: a word, as far as a guesser is concerned
        total += per * len(run)
    return total


def key_bits(text: str) -> float | None:
    """The guessing work (bits) of one ``KEY`` field: None for a raw ``hex:`` key (256 bits), the
    passphrase's estimate for the others (plus log2 of the PBKDF2 rounds for ``qgc:``)."""
    kind, sep, rest = text.partition(":")
    if sep and kind == "hex":
        return None
    if sep and kind == "qgc":
        return passphrase_bits(rest) + math.log2(QGC_ROUNDS)
    return passphrase_bits(rest if sep and kind == "passphrase" else text)


@dataclass(frozen=True, slots=True)
class SigningKey:
    """One application's key: its name in the key file and the 32 key bytes (``bits``: the guessing
    work of a passphrase key, None for a raw one; not part of the key's identity)."""

    name: str
    key: bytes
    bits: float | None = field(default=None, compare=False)

    @property
    def identity(self) -> str:
        """How records and logs name the application that signs with it."""
        return f"key:{self.name}"

    @property
    def fingerprint(self) -> str:
        """A name for the key bytes that does not give them away (the replay state's key)."""
        return hashlib.sha256(b"zdrone gcs application key\0" + self.key).hexdigest()[:16]

    def __repr__(self) -> str:  # never the key bytes in a log line or a traceback
        return f"SigningKey({self.name!r}, id {hashlib.sha256(self.key).hexdigest()[:8]})"


@dataclass(frozen=True, slots=True)
class KeyFile:
    """A parsed key file: its keys, and the GS it says it is for (``gs: <ID>``; None: not said)."""

    keys: tuple[SigningKey, ...]
    gs: str | None = None


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


def _uncommented(raw: str) -> str:
    """A key file line without its comment (``#`` at the start or after a blank) and outer blanks."""
    line = raw.strip()
    if line.startswith("#"):
        return ""
    m = _COMMENT.search(line)
    return (line[: m.start()] if m else line).strip()


def parse_key_file(lines: Iterable[str], source: str = "keys") -> KeyFile:
    """A key file's lines; ``ConfigError`` naming the line for anything malformed, a name or a key
    given twice (one key must name one application), more than ``MAX_KEYS``, two ``gs:`` lines."""
    keys: list[SigningKey] = []
    names: set[str] = set()
    seen: dict[bytes, str] = {}
    gs: str | None = None
    for n, raw in enumerate(lines, 1):
        line = _uncommented(raw)
        if not line:
            continue
        name, _, value = line.partition(" ")
        where = f"{source}:{n}"
        value = value.strip()
        if name == _GS_LINE:
            if gs is not None:
                raise ConfigError(f"{where}: a second 'gs:' line (the file is for {gs})")
            if not _NAME.fullmatch(value):
                raise ConfigError(f"{where}: 'gs: <ID>' wants the GS's name in the fleet, not {value[:40]!r}")
            gs = value
            continue
        if not _NAME.fullmatch(name):
            raise ConfigError(f"{where}: application name {name[:40]!r}: 1-32 of A-Z a-z 0-9 _ . -")
        if not value:
            raise ConfigError(f"{where}: {name}: no key (NAME hex:<64 hex> | qgc:<passphrase> | <passphrase>)")
        key = parse_key(value, f"{where}: {name}")
        if name in names:
            raise ConfigError(f"{where}: application {name} listed twice")
        if key in seen:
            raise ConfigError(f"{where}: {name} has the same key as {seen[key]}: a key must name one application")
        names.add(name)
        seen[key] = name
        keys.append(SigningKey(name, key, key_bits(value)))
    if len(keys) > MAX_KEYS:
        raise ConfigError(f"{source}: {len(keys)} keys, at most {MAX_KEYS}")
    return KeyFile(tuple(keys), gs)


def parse_keys(lines: Iterable[str], source: str = "keys") -> tuple[SigningKey, ...]:
    """The keys of a key file's lines (``parse_key_file``)."""
    return parse_key_file(lines, source).keys


def _read_secret(p: Path) -> str:
    """The text of the secret file ``p``: not through a symbolic link, a regular file owned by this
    process's user (or root) that nobody else may read; ``ConfigError`` in one line otherwise."""
    flags = os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(p, flags)
    except FileNotFoundError:
        raise ConfigError(f"{p}: no such key file") from None
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise ConfigError(f"{p}: key file is a symbolic link; give the file itself (owned by the GS's user, "
                              "mode 0600)") from None
        raise ConfigError(f"{p}: cannot read: {exc.__class__.__name__}") from None
    try:
        st = os.fstat(fd)  # the file opened, not whatever the name points to now
        if not stat.S_ISREG(st.st_mode):
            raise ConfigError(f"{p}: key file is not a regular file")
        me = os.geteuid()
        if st.st_uid not in (me, 0):
            raise ConfigError(f"{p}: key file is owned by uid {st.st_uid}, not by the GS's user (uid {me}) or root; "
                              f"a file another user can replace is not a secret (chown {me} {p})")
        mode = stat.S_IMODE(st.st_mode)
        if mode & 0o077:
            raise ConfigError(f"{p}: key file is accessible by others (mode {mode:04o}); run chmod 600 {p}")
        with os.fdopen(os.dup(fd), "rb") as f:
            data = f.read()
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read: {exc.__class__.__name__}") from None
    finally:
        os.close(fd)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise ConfigError(f"{p}: cannot read: not UTF-8") from None


def load_key_file(path: str | Path) -> KeyFile:
    """The key file at ``path`` (``_read_secret``'s checks, then ``parse_key_file``)."""
    p = Path(path)
    return parse_key_file(_read_secret(p).splitlines(), str(p))


def load_keys(path: str | Path, gs: str | None = None) -> tuple[SigningKey, ...]:
    """The keys of the key file at ``path``; refused (``ConfigError``) if it is a symbolic link, not
    this user's (or root's), readable by group or others, or (``gs`` given) says it is another GS's."""
    kf = load_key_file(path)
    if gs is not None and kf.gs is not None and kf.gs != gs:
        raise ConfigError(f"{path}: key file is for GS {kf.gs} ('gs: {kf.gs}'), not {gs}: one key file, one GS")
    return kf.keys


def sibling_key_files(path: str | Path, gs: str, others: Iterable[str]) -> dict[str, Path]:
    """The key files of the GSs ``others`` beside ``path`` by the naming convention ``<prefix>.<GS>``
    (``gcs-keys.A`` -> ``gcs-keys.B``; ``gcs-keys`` -> ``gcs-keys.B``) that exist."""
    p = Path(path)
    prefix = p.name[: -len(gs) - 1] if p.name.endswith(f".{gs}") else p.name
    out: dict[str, Path] = {}
    for other in others:
        if other == gs:
            continue
        q = p.with_name(f"{prefix}.{other}")
        if q.is_file() and not q.samefile(p):
            out[other] = q
    return out


def shared_keys(keys: Iterable[SigningKey], path: str | Path, gs: str, others: Iterable[str]) -> list[str]:
    """Which of ``keys`` another GS's key file beside ``path`` also holds, as messages. A sibling that
    cannot be read (another user's, malformed) cannot be checked: logged, skipped."""
    mine = {k.key: k.name for k in keys}
    found: list[str] = []
    for other, q in sibling_key_files(path, gs, others).items():
        try:
            kf = parse_key_file(q.read_text(encoding="utf-8").splitlines(), str(q))
        except (OSError, UnicodeDecodeError, ConfigError) as exc:
            log.info("%s: GS %s's key file not checked for keys shared with %s: %s", q, other, gs,
                     str(exc) if isinstance(exc, ConfigError) else exc.__class__.__name__)
            continue
        for k in kf.keys:
            if k.key in mine:
                found.append(f"application {mine[k.key]}'s key is also GS {other}'s ({k.name} in {q})")
    return found


def fleet_gss(fleet: str | Path) -> tuple[str, ...]:
    """The GSs of the fleet at ``fleet``; () if it cannot be loaded (the station says why itself)."""
    from zdrone.fleet.files import load_fleet

    try:
        return tuple(load_fleet(fleet).ground_stations())
    except (ConfigError, OSError, ValueError):
        return ()


def load_gs_keys(path: str | Path, gs: str, fleet: str | Path | None = None,
                 others: Iterable[str] | None = None) -> tuple[SigningKey, ...]:
    """GS ``gs``'s application keys: ``load_keys``, then refused if a key is also in the key file of
    another GS (``others``, by default the fleet's GSs) beside it: one key, one GS (a signed frame names
    no receiver, so a frame refused at one would be taken at the other)."""
    keys = load_keys(path, gs)
    if others is None:
        others = fleet_gss(fleet) if fleet is not None else ()
    shared = shared_keys(keys, path, gs, others)
    if shared:
        raise ConfigError(f"{path}: {shared[0]}{f' (and {len(shared) - 1} more)' if len(shared) > 1 else ''}: "
                          "one key per GS (a frame one GS refused would be taken by the other)")
    return keys


def weak_keys(keys: Iterable[SigningKey], strong: float = STRONG_BITS) -> list[SigningKey]:
    """The passphrase keys estimated under ``strong`` bits of guessing work."""
    return [k for k in keys if k.bits is not None and k.bits < strong]


def weak_key_warning(key: SigningKey, source: str = "") -> str:
    """The start-up warning for a weak passphrase key, in one line."""
    return (f"{source + ': ' if source else ''}application {key.name}: passphrase of about {key.bits:.0f} bits "
            f"(a rough estimate; {STRONG_BITS:.0f} wanted): one captured signed frame lets anyone test passphrases "
            "offline (MAVProxy's key is SHA-256 of it, ~10^10 tries a second on one GPU); use 20+ random hex "
            "digits (openssl rand -hex 16) or a raw hex: key")


def signing_state_path(keys_path: str | Path, gs: str) -> Path:
    """Where GS ``gs`` keeps its gateway's replay state: ``$ZDRONE_STATE_DIR/<gs>.gcs-signing.json``
    (``zdrone service`` sets it; the bundle stays read-only), else beside the key file."""
    state_dir = os.environ.get(STATE_DIR_ENV)
    if state_dir:
        return Path(state_dir) / f"{gs}.gcs-signing.json"
    p = Path(keys_path)
    return p.with_name(p.name + ".signing-state.json")


class AppSigning:
    """The signing state of one gateway: its keys, the streams seen under each, the timestamps it signs with.

    ``not_before``: no stream stamped before it is taken (the gateway's start, when the replay state
    of before it was lost); 0: none."""

    def __init__(self, keys: Iterable[SigningKey] = (), not_before: int = 0) -> None:
        self.keys: dict[str, SigningKey] = {}
        for k in keys:
            if k.name in self.keys:
                raise ConfigError(f"application {k.name} listed twice")
            self.keys[k.name] = k
        if len(self.keys) > MAX_KEYS:
            raise ConfigError(f"{len(self.keys)} keys, at most {MAX_KEYS}")
        self.not_before = not_before
        self.changes = 0  # grows with every stream moved on (what the replay state must keep)
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
        elif sig.timestamp < self.not_before:
            return None, "before_start"
        if last is None and len(streams) >= MAX_STREAMS_PER_KEY:
            del streams[min(streams, key=streams.__getitem__)]
        streams[sig.stream] = sig.timestamp
        self._rx[key.name] = max(mine, sig.timestamp)
        self.changes += 1
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
        if sig is not None and sig.stream not in self._own[name]:
            # (link id, sysid, compid): the endpoints' ids times the ids the vehicle speaks as
            self._own[name].add(sig.stream)
            self.changes += 1
        return out

    # ------------------------------------------------------------ the replay state
    def snapshot(self) -> dict[str, Any]:
        """What a restarted gateway needs to refuse what this one took: per key (by fingerprint), each
        stream's last timestamp, the receiver's and the signing timestamp, the streams it signs as."""
        out: dict[str, Any] = {}
        for name, k in self.keys.items():
            streams, own = self._streams[name], self._own[name]
            if not streams and not own and name not in self._out and name not in self._rx:
                continue
            out[k.fingerprint] = {"rx": self._rx.get(name, 0), "out": self._out.get(name, 0),
                                  "streams": [[*s, ts] for s, ts in streams.items()],
                                  "own": [list(s) for s in sorted(own)][:MAX_STREAMS_PER_KEY]}
        return {"version": _STATE_VERSION, "keys": out}

    def restore(self, state: Any) -> int:
        """Take a ``snapshot`` of before a restart (keys no longer listed are ignored); the number of
        streams restored. ``ValueError`` if it is not one (nothing taken then)."""
        if not isinstance(state, dict) or state.get("version") != _STATE_VERSION or not isinstance(state.get("keys"), dict):
            raise ValueError("not a replay state of this version")
        by_fp = {k.fingerprint: name for name, k in self.keys.items()}
        taken: list[tuple[str, int, int, dict[tuple[int, int, int], int], set[tuple[int, int, int]]]] = []
        for fp, entry in state["keys"].items():
            name = by_fp.get(fp)
            if name is None:
                continue
            if not isinstance(entry, dict):
                raise ValueError(f"key {fp}: not an object")
            rx, out = _timestamp(entry.get("rx", 0)), _timestamp(entry.get("out", 0))
            streams: dict[tuple[int, int, int], int] = {}
            for s in entry.get("streams", []):
                if not isinstance(s, list) or len(s) != 4:
                    raise ValueError(f"key {fp}: a stream is not [link, sysid, compid, timestamp]")
                streams[_stream(s[:3])] = _timestamp(s[3])
            own = {_stream(s) for s in entry.get("own", [])}
            if len(streams) > MAX_STREAMS_PER_KEY or len(own) > MAX_STREAMS_PER_KEY:
                raise ValueError(f"key {fp}: more than {MAX_STREAMS_PER_KEY} streams")
            taken.append((name, rx, out, streams, own))
        n = 0
        for name, rx, out, streams, own in taken:
            for s, ts in streams.items():
                self._streams[name][s] = max(ts, self._streams[name].get(s, 0))
            while len(self._streams[name]) > MAX_STREAMS_PER_KEY:
                del self._streams[name][min(self._streams[name], key=self._streams[name].__getitem__)]
            self._own[name] |= own
            self._rx[name] = max(self._rx.get(name, 0), rx)
            self._out[name] = max(self._out.get(name, 0), out)
            n += len(streams)
        return n


def _timestamp(v: Any) -> int:
    if not isinstance(v, int) or isinstance(v, bool) or not 0 <= v <= fcsign.MAX_TIMESTAMP:
        raise ValueError(f"timestamp {v!r} out of range")
    return v


def _stream(v: Any) -> tuple[int, int, int]:
    if (not isinstance(v, list) or len(v) != 3
            or not all(isinstance(x, int) and not isinstance(x, bool) and 0 <= x <= 255 for x in v)):
        raise ValueError(f"stream {v!r} is not [link, sysid, compid]")
    return (v[0], v[1], v[2])


def read_signing_state(path: Path) -> Any | None:
    """The replay state file's content; None if there is none (a first start). ``ValueError`` if it
    is there but cannot be read (then it must not be trusted)."""
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{exc.__class__.__name__}") from None


def write_signing_state(path: Path, signing: AppSigning) -> None:
    """Write ``signing``'s replay state durably (``write_durably``: temporary file, fsync, rename, fsync
    of the directory; mode 0600). Raises ``OSError``."""
    from zdrone.fleet.files import write_durably

    write_durably(path, json.dumps(signing.snapshot(), separators=(",", ":")).encode())


__all__ = ["MODES", "MAX_KEYS", "STRONG_BITS", "AppSigning", "FrameError", "KeyFile", "SigningKey", "key_bits",
           "load_gs_keys", "load_key_file", "load_keys", "parse_key", "parse_key_file", "parse_keys", "parse_mode",
           "passphrase_bits", "passphrase_key", "qgc_passphrase_key", "read_signing_state", "shared_keys",
           "signing_state_path", "weak_key_warning", "weak_keys", "write_signing_state"]
