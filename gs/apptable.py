"""The applications behind a GCS gateway (``gs.gateway``): what tells one from another (``AppKey``), each
one (``App``: its GS component id, the key it signs with, its own parser), the table of them
(``AppTable``), a frame of one on its way (``AppFrame``), and the gateway's side of them
(``OperatorApps``): naming them, trusting them, signing replies, the replay state kept across restarts.

At most ``max_apps`` applications (16 by default) hold a component id at once; one silent for
``app_expiry`` seconds (30) or whose TCP connection closed is forgotten and its id freed for reuse. A
validly signed application always gets in: when the table is full, the unsigned application seen least
recently is evicted for it (``app_evicted``; only a table of signed applications alone refuses one). An
unsigned newcomer finds no room in a full table (``app_table_full``), and one peer address (UDP ip:port,
or a TCP connection) holds at most ``max_unsigned_per_peer`` unsigned applications (4;
``app_peer_full``), so one socket announcing many ids cannot take the table.
"""

from __future__ import annotations

import logging
import math
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

from pymavlink.dialects.v20 import common as mav

from gs.appkeys import STATE_DIR_ENV, AppSigning, read_signing_state, write_signing_state
from gs.opcontrol import Prompt
from zdrone.core import fcsign
from zdrone.core import records as rec
from zdrone.core.fleet import ConfigError
from zdrone.core.mavlink import FrameCodec, FrameError
from zdrone.vehicle.transport import MavTransport

#: the gateway's own logger: the warnings about its applications and their signing are the gateway's
log = logging.getLogger("gs.gateway")

#: the station's own component id (``gs.station.GCS_COMPID``), never given to an application
STATION_COMPID = mav.MAV_COMP_ID_MISSIONPLANNER
FIRST_APP_COMPID = 100
#: applications one gateway serves at once (each holds one GS component id)
MAX_APPS = 16
#: the most a gateway may be given: ids FIRST_APP_COMPID.. stay below the station's own component id
MAX_APPS_LIMIT = STATION_COMPID - FIRST_APP_COMPID
#: an application silent this long (seconds) is forgotten and its component id freed
APP_EXPIRY_S = 30.0
#: unsigned applications one peer address (UDP ip:port, a TCP connection) may hold at once
MAX_UNSIGNED_PER_PEER = 4
#: the replay state is written at most this often (seconds) while it changes (and when the gateway closes)
SIGNING_STATE_PERIOD_S = 1.0
#: at most one warning per this many seconds for a repeated drop reason
WARN_PERIOD_S = 5.0


@dataclass(frozen=True, slots=True)
class AppKey:
    """What tells one application from another: the gateway endpoint, the peer, its own ids."""

    transport: int
    peer: Any  # UDP address or TCP socket, as the transport reports it
    sysid: int
    compid: int


@dataclass
class App:
    """One application behind the gateway."""

    transport: int
    peer: Any
    sysid: int
    compid: int
    gs_compid: int
    last_seen: float = 0.0
    frames_in: int = 0
    frames_out: int = 0
    refused: int = 0
    last_text: float = -1e9  # when the last refusal STATUSTEXT went to it (at most one a second)
    signer: str | None = None  # the name of the key its frames are signed with (None: unsigned)
    prompt: Prompt = field(default_factory=Prompt)  # the other GS's request presented to it, and since when
    decoder: FrameCodec = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.decoder = FrameCodec(self.sysid, self.compid)  # its own parser state: one app cannot confuse another

    @property
    def key(self) -> AppKey:
        return AppKey(self.transport, self.peer, self.sysid, self.compid)


class RateLimit:
    """True at most once per ``period`` seconds of the caller's clock."""

    def __init__(self, period: float = WARN_PERIOD_S) -> None:
        self.period = period
        self._next = -math.inf

    def ready(self, now: float) -> bool:
        if now < self._next:
            return False
        self._next = now + self.period
        return True


class AppTable:
    """The applications of one gateway, at most ``max_apps``, each with its own GS component id.

    Pure bookkeeping: no sockets and no clock (time is the caller's ``now``). Component ids are
    ``first_compid`` .. ``first_compid + max_apps - 1``; a freed id goes to the back of the queue, so
    the id of a forgotten application is reused as late as possible. A new application that finds
    the table full (none expired) is refused: ``None``, counted under ``app_table_full``; unless it is
    signed (``add(..., signed=True)``): then the unsigned application seen least recently is evicted
    for it (``app_evicted``). A peer address holds at most ``max_unsigned_per_peer`` unsigned
    applications (``app_peer_full``). Applications the table let go of while adding (expired,
    evicted) are kept for the caller in ``take_gone()``.
    """

    def __init__(self, max_apps: int = MAX_APPS, expiry: float = APP_EXPIRY_S, first_compid: int = FIRST_APP_COMPID,
                 counters: Counter[str] | None = None, max_unsigned_per_peer: int = MAX_UNSIGNED_PER_PEER) -> None:
        if not 1 <= first_compid <= 255 or not 1 <= max_apps <= 256 - first_compid:
            raise ValueError(f"{max_apps} applications from component id {first_compid} do not fit in 1..255")
        if not expiry > 0:
            raise ValueError(f"application expiry must be positive, not {expiry}")
        if max_unsigned_per_peer < 1:
            raise ValueError(f"unsigned applications per peer must be at least 1, not {max_unsigned_per_peer}")
        self.max_apps = max_apps
        self.expiry = expiry
        self.max_unsigned_per_peer = max_unsigned_per_peer
        self._gone: list[tuple[App, str]] = []  # let go of while adding, for the caller (take_gone)
        self._peer_warning = RateLimit()
        self.counters: Counter[str] = counters if counters is not None else Counter()
        self._apps: dict[AppKey, App] = {}
        self._by_compid: dict[int, App] = {}
        self._free: deque[int] = deque(range(first_compid, first_compid + max_apps))
        self._full_warning = RateLimit()
        self._full_drops = 0  # since the last warning

    def __len__(self) -> int:
        return len(self._apps)

    def __iter__(self) -> Iterator[App]:
        return iter(list(self._apps.values()))

    def get(self, key: AppKey, now: float) -> App | None:
        """The known application ``key``, marked as seen at ``now``."""
        app = self._apps.get(key)
        if app is not None:
            app.last_seen = now
        return app

    def by_compid(self, gs_compid: int) -> App | None:
        return self._by_compid.get(gs_compid)

    def add(self, key: AppKey, now: float, signed: bool = False) -> App | None:
        """A new application, or ``None`` (counted) if the table is full and none has expired (and, for
        a ``signed`` one, none is unsigned), or if an unsigned one's peer holds its share already."""
        if not signed:
            held = sum(1 for a in self._apps.values() if a.peer == key.peer and a.signer is None)
            if held >= self.max_unsigned_per_peer:
                self.counters["app_peer_full"] += 1
                if self._peer_warning.ready(now):
                    log.warning("gateway: %s holds %d unsigned applications already: sysid %d compid %d dropped "
                                "(%d so far)", key.peer, held, key.sysid, key.compid, self.counters["app_peer_full"])
                return None
        if not self._free:
            self._gone.extend((a, "expired") for a in self.expire(now))
        if not self._free and signed:
            victim = min((a for a in self._apps.values() if a.signer is None), key=lambda a: a.last_seen, default=None)
            if victim is not None:  # a signed application always gets in: the stalest unsigned one makes room
                self.remove(victim.key)
                self.counters["app_evicted"] += 1
                self._gone.append((victim, "evicted"))
        if not self._free:
            self.counters["app_table_full"] += 1
            self._full_drops += 1
            if self._full_warning.ready(now):
                log.warning("gateway: %d applications already (none silent for %.0f s): %d frame(s) of new "
                            "applications dropped, latest sysid %d compid %d from %s", len(self._apps), self.expiry,
                            self._full_drops, key.sysid, key.compid, key.peer)
                self._full_drops = 0
            return None
        app = App(key.transport, key.peer, key.sysid, key.compid, self._free.popleft(), last_seen=now)
        self._apps[key] = app
        self._by_compid[app.gs_compid] = app
        return app

    def lookup_or_add(self, key: AppKey, now: float, signed: bool = False) -> App | None:
        """The application ``key`` (seen at ``now``), added if new; ``None`` if the table is full."""
        app = self.get(key, now)
        return app if app is not None else self.add(key, now, signed)

    def take_gone(self) -> list[tuple[App, str]]:
        """The applications let go of while adding (expired, evicted) since the last call, and why."""
        gone, self._gone = self._gone, []
        return gone

    def remove(self, key: AppKey) -> App | None:
        """Forget one application and free its component id."""
        app = self._apps.pop(key, None)
        if app is not None:
            del self._by_compid[app.gs_compid]
            self._free.append(app.gs_compid)
        return app

    def expire(self, now: float) -> list[App]:
        """Forget the applications silent for ``expiry`` seconds or more; return them."""
        gone = [a for a in self._apps.values() if now - a.last_seen >= self.expiry]
        for app in gone:
            self.remove(app.key)
            self.counters["app_expired"] += 1
        return gone


class AppFrame:
    """An application's frame on its way through the gateway: its bytes, and its message decoded by
    the application's own parser the first time a step asks for it (a full decode costs ~19 µs;
    most frames need only their header)."""

    __slots__ = ("app", "raw", "_msg", "_decoded")

    def __init__(self, app: App, raw: bytes) -> None:
        self.app, self.raw = app, raw
        self._msg: Any = None
        self._decoded = False

    @property
    def msg(self) -> Any:
        """The decoded message (None: it does not decode)."""
        if not self._decoded:
            self._msg, self._decoded = self.app.decoder.decode(self.raw), True
        return self._msg


class OperatorApps:
    """The gateway's side of its applications: how records and logs name one, whether it may speak for
    the operator, the signature on a reply to it and the drop of a frame wrongly signed, the replay
    state kept across restarts, and the table's comings and goings (logged, recorded). A mixin: the
    ``GcsGateway`` holds the state (named here) and is the one that calls these."""

    signing_mode: str
    signing: AppSigning
    _clock: Callable[[], float]  # the wall clock: signing timestamps are 10 us units since 2015
    state_path: Path | None
    _saved_changes: int  # ``signing.changes`` as last written (-1: never)
    _next_save: float
    _save_log: RateLimit
    _signed_peers: dict[int, dict[Any, str]] | None  # endpoint -> peer -> key name (None: stale)
    _drop_logs: dict[str, RateLimit]
    counters: Counter[str]
    apps: AppTable
    transports: list[MavTransport]
    station: Any
    _awaiting: dict[AppKey, float]
    _now: float

    def _restore_signing_state(self, path: Path) -> None:
        """The replay state of before this start; then written once, so an unwritable place is a
        configuration error now rather than a replay window later."""
        try:
            state = read_signing_state(path)
            restored = self.signing.restore(state) if state is not None else 0
        except ValueError as exc:
            self.signing.not_before = self._units()
            self.counters["signing_state_unreadable"] += 1
            log.warning("gateway: %s: replay state unreadable (%s), not trusted: no signed stream stamped before "
                        "now is taken", path, exc)
        else:
            log.info("gateway: replay state %s: %d stream(s) of before this start", path, restored)
        try:
            write_signing_state(path, self.signing)
        except OSError as exc:
            raise ConfigError(f"{path}: cannot write the GCS signing replay state ({exc.__class__.__name__}); "
                              f"set {STATE_DIR_ENV} to a writable directory") from None
        self._saved_changes = self.signing.changes

    def save_signing_state(self, now: float | None = None) -> bool:
        """Write the replay state if it changed (at most once per ``SIGNING_STATE_PERIOD_S`` of ``now``;
        ``now`` None: at once). A failure is counted and logged, never raised."""
        if self.state_path is None or self._saved_changes < 0 or self.signing.changes == self._saved_changes:
            return False
        if now is not None and now < self._next_save:
            return False
        if now is not None:
            self._next_save = now + SIGNING_STATE_PERIOD_S
        changes = self.signing.changes
        try:
            write_signing_state(self.state_path, self.signing)
        except OSError as exc:
            self.counters["signing_state_write_failed"] += 1
            if self._save_log.ready(self._now):
                log.warning("gateway: writing the replay state %s: %s (%d failure(s))", self.state_path, exc,
                            self.counters["signing_state_write_failed"])
            return False
        self._saved_changes = changes
        return True

    def identity(self, app: App) -> str:
        """How records and logs name an application: its key's name, else its address."""
        if app.signer is not None:
            return f"key:{app.signer}"
        peer = app.peer
        if isinstance(peer, tuple) and len(peer) >= 2:
            return f"unsigned:{peer[0]}:{peer[1]}"
        try:
            host, port = peer.getpeername()[:2]  # a TCP client
            return f"unsigned:tcp:{host}:{port}"
        except (AttributeError, OSError, ValueError, TypeError):
            return f"unsigned:{peer!r}"

    def trusted(self, app: App) -> bool:
        """May ``app`` speak for the operator and command? Always, but unsigned under ``require``."""
        return app.signer is not None or self.signing_mode != "require"

    def _units(self) -> int:
        return fcsign.units(self._clock())

    def _signing_drop(self, why: str, peer: Any, hdr: Any, now: float) -> None:
        name = f"signing_dropped:{why}"
        self.counters[name] += 1
        limit = self._drop_logs.setdefault(name, RateLimit())
        if limit.ready(now):
            log.warning("gateway: frame of sysid %d compid %d (msg %d) from %s dropped: %s (%d so far)", hdr.sysid,
                        hdr.compid, hdr.msgid, peer, why, self.counters[name])

    def _peer_signers(self) -> dict[int, dict[Any, str]]:
        """Endpoint -> peer -> the key its application signs with (rebuilt when applications change)."""
        if self._signed_peers is None:
            table: dict[int, dict[Any, str]] = {}
            for app in self.apps:
                if app.signer is not None:
                    table.setdefault(app.transport, {})[app.peer] = app.signer
            self._signed_peers = table
        return self._signed_peers

    def _signed(self, frame: bytes, signer: str, ti: int) -> bytes:
        """``frame`` signed with application key ``signer`` (link id: the endpoint's index); a frame that
        cannot be signed (MAVLink 1) goes as it is, counted."""
        try:
            return self.signing.sign(frame, signer, self._units(), ti & 0xFF)
        except (FrameError, KeyError):
            self.counters["unsignable"] += 1
            return frame

    def _app(self, ti: int, peer: Any, sysid: int, compid: int, now: float, signed: bool = False) -> App | None:
        key = AppKey(ti, peer, sysid, compid)
        app = self.apps.get(key, now)
        if app is None:
            app = self.apps.add(key, now, signed)
            gone = self.apps.take_gone()
            if gone:
                self._gone(gone)
            if app is None:
                return None
            log.info("gateway: application sysid %d compid %d on %s is GS component %d", sysid, compid,
                     self.transports[ti].endpoint, app.gs_compid)
            self.station.events.write_record(rec.GcsApp(sysid=sysid, compid=compid, gs_compid=app.gs_compid))
        return app

    def _forget_apps(self, now: float) -> None:
        """Free the component ids of applications gone silent or whose TCP connection closed."""
        gone = [(a, "expired") for a in self.apps.expire(now)]
        for app in self.apps:
            t = self.transports[app.transport]
            if t.sock is None and app.peer not in t.tcp_clients:
                self.apps.remove(app.key)
                self.counters["app_disconnected"] += 1
                gone.append((app, "disconnected"))
        if gone:
            self._gone(gone)

    def _gone(self, gone: list[tuple[App, str]]) -> None:
        """Applications no longer in the table (expired, disconnected, evicted): logged and recorded."""
        self._signed_peers = None
        for app, why in gone:
            self._awaiting.pop(app.key, None)
            log.info("gateway: application sysid %d compid %d (GS component %d) %s", app.sysid, app.compid,
                     app.gs_compid, why)
            self.station.events.write_record(rec.GcsAppGone(sysid=app.sysid, compid=app.compid, gs_compid=app.gs_compid, reason=why))
