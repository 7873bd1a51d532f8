"""The operations picture: what each GS tells the fleet's viewer, sealed for it, and the fleet picture
the viewer merges from every GS's word. Pure: time comes in as ``now``, randomness as arguments.

Theory of operation
-------------------
Each GS publishes, on its own key ``zdrone-ops/<gs>``, an ``OpsReport``: per drone it serves what it
knows (owner and epoch as the drone told it, with the drone's own signed word on them as it came,
``zdrone.core.attestation``; its own TBM link state to the drone, mode, altitude, armed, mission
progress, fc_signed, the pending operator-control request, failsafe, the age of its last report) and the authority events it logged since its last report. A report is cut into parts
under ``OPS_MAX_BYTES`` each (``report_parts``), msgspec-encoded, each part sealed on its own.

**Sealed for the viewer, by the GS** (``OpsSealer`` / ``OpsOpener``). Router passwords leak and the
router hop is watched, so the picture (where every drone is, who commands it) travels encrypted and
authenticated end to end. The key is ``HKDF(X25519(GS static, viewer static), names, salt)``: only
that GS and the viewer can make it, so a part that opens was sealed by the GS the viewer names it
after (a static-static DH is an implicit mutual authentication; no signature, no extra round trip,
and a GS needs nothing but the viewer's public key from the fleet file). A GS picks a fresh random
``salt`` each time it starts: each start has a key of its own, so its 64-bit counter nonce (which
restarts at 0) never repeats under one key. The associated data binds the key expression, both
names and the header. On the viewer, per GS, a replay window (``zdrone.core.replay``) refuses a
counter seen twice within a start; a *new* start (another salt) is taken only if its report is newer
(the GS's wall time) than everything taken from that GS so far and, when none was, within
``MAX_SKEW_S`` of the viewer's clock: a recorded old start replayed later is refused, not shown as
live. New salts cost a DH each: at most ``NEW_SALT_BURST`` per GS, one per ``1/NEW_SALT_HZ`` s.
Why not HPKE base mode: it authenticates nobody (anyone holding the viewer's public key, i.e. the
whole fleet, could seal a report "from A"); auth mode would do, at a DH per message.

**The fleet picture** (``FleetPicture``). A GS may be silent (stopped, cut off) and one authorized GS
may be hostile: every field is shown as *who said it*, and what a GS says is taken only where the
fleet lets it speak. A GS's word on a drone it is not authorized for, on a name outside the fleet (an
event naming no drone too), or beyond its rate (``REPORT_RATE_PER_DRONE`` per drone it serves) is dropped and counted; a request
naming a GS outside the fleet loses that request. A GS's word counts for ``REPORT_TTL_S`` after it
arrived (its link, the request its operator was asked, the failsafe it saw, the position it heard),
then it is shown silent and counts for nothing; it is forgotten after ``CLAIM_KEEP_S``.

**The drone's word** decides who commands it. Every drone signs its authority (owner, epoch, state,
pending recipient, takeover and its window) at every status beacon and every change
(``zdrone.core.attestation``); per drone the picture holds the newest valid one by the drone's own
(time, counter): one no newer is not even checked (an old word replayed loses, whoever carries it),
one dated beyond ``MAX_SKEW_S`` ahead of the viewer's clock is refused, one under a retired key is
refused (``AttestationCheck``: every key older than the one the revisions held name), and one under
a newer key than the word held replaces it (a rotation). The owner, epoch, state, pending recipient,
takeover window and failsafe shown are that word's; it is ``verified``, and the drone **live**, only while the word is recent
(``ATTEST_LIVE_S``: two beacons and a GS's period) *and* an authorized GS heard the drone within
``STALE_S``. How recent: the older of its time at the viewer since it first arrived and its own time
against the viewer's clock, less the drone's clock offset (the least seen over ``OFFSET_WINDOW_S``,
from ``OFFSET_MAX_S`` ahead to ``OFFSET_BEHIND_S`` behind), so a word a GS held back and let go later
is old on arrival: held back by one GS that carries every word, it is credited ``OFFSET_BEHIND_S`` at
most (its delay and a clock running behind look the same). A drone whose clock stepped back shows
stale until its time passes the newest word's (a restart with a corrected clock), one whose clock
runs behind the viewer's shows its words that much older, less ``OFFSET_BEHIND_S``. Else the drone is **stale**, shown with
its age (its last values, never as live). A GS's claim the word does not back (a higher epoch,
another owner in its epoch) is listed apart as ``unverified``; an honest GS that lags (a lower epoch)
is not listed; a GS that says it saw a failsafe is listed (``reports_failsafe``), the alarm itself is
the drone's word. Only a drone the fleet gave no signing key is shown from its GSs' claims (the
highest epoch, not ``verified``, ``disputed`` when two GSs name different owners at that epoch).
The vehicle's fields come from the owner's fresh word, else from the freshest authorized one
(``position_from`` names the GS). The age of a GS's word is the GS's own age (at its sending) plus the
time since the viewer received it: a silent GS ages like a silent drone.
"""

from __future__ import annotations

import enum
import struct
from collections import Counter, deque
from dataclasses import dataclass, field
from typing import Any, Iterable, Mapping, Sequence

import msgspec
from cryptography.exceptions import InvalidTag
from cryptography.hazmat.primitives.ciphers.aead import ChaCha20Poly1305

from zdrone.core.attestation import BEACON_S, AttestationCheck
from zdrone.core.fleet import Fleet
from zdrone.core.keys import Identity, hkdf, public_key
from zdrone.core.ratelimit import TokenBucket
from zdrone.core.replay import ReplayWindow
from zdrone.core.wire import AuthorityAttestation

#: The largest sealed part: far under the router's largest message (``routerconfig.MAX_MESSAGE_SIZE``)
#: and its size limit on ``zdrone-ops/*`` (``OPS_MAX_BYTES`` there too).
OPS_MAX_BYTES = 16 * 1024
#: A GS publishes its picture this often, and at once (at most every ``OPS_MIN_GAP_S``) when an
#: authority event happens.
OPS_PERIOD_S = 0.5
OPS_MIN_GAP_S = 0.1
#: Events carried per report at most (the newest); the rest are counted as dropped.
OPS_MAX_EVENTS = 64
#: A drone whose freshest report is older than this is stale (the TBM's DEGRADED threshold).
STALE_S = 1.0
#: A GS not heard for this long is shown as silent.
GS_SILENT_S = 1.5
#: A new start of a GS with no earlier one known is taken only this close to the viewer's wall clock.
MAX_SKEW_S = 30.0
NEW_SALT_HZ = 1.0
NEW_SALT_BURST = 3.0
#: Authority events the fleet picture keeps (newest first).
FEED_LEN = 200
#: Track points kept per drone; a point is added when the drone moved this far or its owner changed.
TRACK_LEN = 4000
TRACK_STEP_M = 3.0

VERSION = 1
SALT_LEN = 16
_HEADER = struct.Struct(">B16sQ")
HEADER_LEN = _HEADER.size
TAG_LEN = 16
LABEL = b"zdrone-ops/v1"


class OpsRequest(msgspec.Struct, frozen=True, array_like=True):
    """An operator-control request the GS's operator is asked about (the consent state)."""

    requester: str
    to: str
    epoch: int
    age_s: float
    timeout_s: float
    consent: str = "asked"  # asked | allowed (the owner's standing takeover)


class DroneOps(msgspec.Struct, frozen=True, array_like=True):
    """One drone as one GS knows it."""

    drone: str
    linked: bool
    owner: str | None = None
    epoch: int = 0
    state: str = "unknown"  # the drone's authority state as it last said (``authority.State``)
    pending_to: str | None = None
    link: str = "none"  # this GS's TBM state of its link: ok | degraded | lost | none
    since_last: float | None = None  # seconds since this GS's last authentic frame from it
    mode: str = ""
    armed: bool = False
    position: tuple[float, float, float] | None = None  # lat, lon, alt (m)
    mission_seq: int | None = None
    stage: str = ""
    fc_signed: bool | None = None
    failsafe: bool = False
    holds: bool = False  # this GS commands it now
    request: OpsRequest | None = None
    takeover: bool = False
    attest: AuthorityAttestation | None = None  # the drone's newest signed word on its authority, as it came


class OpsEvent(msgspec.Struct, frozen=True, array_like=True):
    """An authority event a GS logged: ``t`` its wall time, ``kind`` the record's type."""

    t: float
    drone: str
    kind: str
    text: str


class OpsReport(msgspec.Struct, frozen=True, array_like=True):
    """One part of a GS's picture."""

    gs: str
    sent_at: float  # the GS's wall clock
    part: int
    parts: int
    drones: list[DroneOps]
    events: list[OpsEvent]


_ENC = msgspec.msgpack.Encoder()
_DEC = msgspec.msgpack.Decoder(OpsReport)


def report_parts(gs: str, sent_at: float, drones: Iterable[DroneOps], events: list[OpsEvent],
                 max_bytes: int = OPS_MAX_BYTES - HEADER_LEN - TAG_LEN) -> list[bytes]:
    """The picture as encoded parts, each at most ``max_bytes`` (events in the first, newest kept)."""
    events = events[-OPS_MAX_EVENTS:]
    sizes = [(d, len(_ENC.encode(d))) for d in drones]
    base = len(_ENC.encode(OpsReport(gs, sent_at, 0, 0, [], events))) + 16
    groups: list[list[DroneOps]] = [[]]
    used = base
    for d, n in sizes:
        if groups[-1] and used + n > max_bytes:
            groups.append([])
            used = len(_ENC.encode(OpsReport(gs, sent_at, 0, 0, [], []))) + 16
        groups[-1].append(d)
        used += n
    out = [_ENC.encode(OpsReport(gs, sent_at, i, len(groups), g, events if i == 0 else []))
           for i, g in enumerate(groups)]
    if any(len(p) > max_bytes for p in out):
        raise ValueError("one drone's record is larger than a part")
    return out


def _key(shared: bytes, gs: str, viewer: str, salt: bytes) -> bytes:
    return hkdf(shared, b"\0".join((LABEL, gs.encode(), viewer.encode(), salt)))


def _ad(keyexpr: str, gs: str, viewer: str, header: bytes) -> bytes:
    return b"\0".join((LABEL, keyexpr.encode(), gs.encode(), viewer.encode(), header))


class OpsSealer:
    """A GS's sealing of its picture for the viewer (one per start: ``salt`` fresh and random)."""

    def __init__(self, identity: Identity, gs: str, viewer: str, viewer_public: bytes, keyexpr: str, salt: bytes) -> None:
        if len(salt) != SALT_LEN:
            raise ValueError(f"salt: {SALT_LEN} bytes")
        shared = identity.private_key().exchange(public_key(viewer_public))
        self._aead = ChaCha20Poly1305(_key(shared, gs, viewer, salt))
        self.gs, self.viewer, self.keyexpr, self.salt = gs, viewer, keyexpr, salt
        self.viewer_public, self.public = viewer_public, identity.public
        self.counter = 0

    def seal(self, part: bytes) -> bytes:
        header = _HEADER.pack(VERSION, self.salt, self.counter)
        self.counter += 1
        return header + self._aead.encrypt(b"\0\0\0\0" + header[-8:], part, _ad(self.keyexpr, self.gs, self.viewer, header))


class OpsDrop(enum.Enum):
    """Why a part was not taken, in the order the checks run."""

    MALFORMED = "malformed"
    UNKNOWN_SENDER = "unknown_sender"
    RATE_LIMITED = "new_start_rate_limited"
    AUTH_FAILED = "auth_failed"
    REPLAY = "replay"
    UNDECODABLE = "undecodable"
    SENDER_MISMATCH = "sender_mismatch"
    OLD_START = "old_start"


@dataclass
class _Start:
    salt: bytes
    aead: ChaCha20Poly1305
    window: ReplayWindow = field(default_factory=lambda: ReplayWindow(1024))


class OpsOpener:
    """The viewer's side: opens parts from the GSs of ``senders`` (name -> X25519 public key)."""

    def __init__(self, identity: Identity, viewer: str, senders: dict[str, bytes]) -> None:
        self.identity, self.viewer = identity, viewer
        self.senders = dict(senders)
        self._starts: dict[str, _Start] = {}
        self._newest: dict[str, float] = {}  # GS -> newest sent_at taken
        self._buckets: dict[str, TokenBucket] = {}
        self.drops: Counter[str] = Counter()
        self.opened = 0

    def _drop(self, reason: OpsDrop) -> OpsDrop:
        self.drops[reason.value] += 1
        return reason

    def set_senders(self, senders: Mapping[str, bytes]) -> None:
        """The GSs in force (a fleet revision taken live): a revoked GS is no sender any more; a GS
        whose key was rotated must start anew under its new key (its start under the old key is
        forgotten; the newest time taken from it is kept, so an old start is still refused)."""
        for gs in [g for g in self._starts if senders.get(g) != self.senders.get(g)]:
            del self._starts[gs]
        self.senders = dict(senders)

    def open(self, gs: str, keyexpr: str, data: bytes, now: float, wall: float) -> OpsReport | OpsDrop:
        """One part heard on ``keyexpr`` (whose last chunk names ``gs``), at monotonic ``now`` and wall ``wall``."""
        public = self.senders.get(gs)
        if public is None:
            return self._drop(OpsDrop.UNKNOWN_SENDER)
        if len(data) < HEADER_LEN + TAG_LEN:
            return self._drop(OpsDrop.MALFORMED)
        version, salt, counter = _HEADER.unpack_from(data)
        if version != VERSION:
            return self._drop(OpsDrop.MALFORMED)
        start = self._starts.get(gs)
        new = start is None or start.salt != salt
        if new:
            bucket = self._buckets.setdefault(gs, TokenBucket.full(NEW_SALT_HZ, NEW_SALT_BURST, now))
            if not bucket.take(now):
                return self._drop(OpsDrop.RATE_LIMITED)
            shared = self.identity.private_key().exchange(public_key(public))
            start = _Start(salt, ChaCha20Poly1305(_key(shared, gs, self.viewer, salt)))
        assert start is not None
        if not start.window.is_fresh(counter):
            return self._drop(OpsDrop.REPLAY)
        header = data[:HEADER_LEN]
        try:
            part = start.aead.decrypt(b"\0\0\0\0" + header[-8:], data[HEADER_LEN:], _ad(keyexpr, gs, self.viewer, header))
        except InvalidTag:
            return self._drop(OpsDrop.AUTH_FAILED)
        try:
            report = _DEC.decode(part)
        except (msgspec.DecodeError, msgspec.ValidationError):
            return self._drop(OpsDrop.UNDECODABLE)
        if report.gs != gs:
            return self._drop(OpsDrop.SENDER_MISMATCH)
        newest = self._newest.get(gs)
        if new and ((newest is not None and report.sent_at <= newest)
                    or (newest is None and abs(report.sent_at - wall) > MAX_SKEW_S)):
            return self._drop(OpsDrop.OLD_START)
        if new:
            self._starts[gs] = start
        start.window.mark(counter)
        self._newest[gs] = max(report.sent_at, newest or report.sent_at)
        self.opened += 1
        return report


# ------------------------------------------------------------------ the fleet picture
#: A GS's word on a drone counts this long after it arrived (its link, requests, failsafe, position,
#: the drone's liveness); after it the GS is shown silent for that drone and its word counts for nothing.
REPORT_TTL_S = GS_SILENT_S
#: A GS's word on a drone is kept (shown as silent) this long after it arrived, then forgotten.
CLAIM_KEEP_S = 60.0
#: The drone's own signed word counts as recent this long: two beacons (one lost on the way), a GS's
#: period, and slack for the way. Older, the drone is stale and its owner no longer ``verified``.
ATTEST_LIVE_S = 2 * BEACON_S + OPS_PERIOD_S + 0.5
#: Each drone's clock against the viewer's is learnt as the least (arrival - signed at) seen over this
#: long (the drone's clock offset plus the quickest way here; a word held back arrives late and looks old) ...
OFFSET_WINDOW_S = 120.0
#: ... within this much ahead of the viewer's clock (a word can reach the viewer no sooner than it was
#: signed: a drone whose clock runs ahead has its words aged by it, whoever carries them) ...
OFFSET_MAX_S = 5.0
#: ... and this much behind it. A word arriving later than its time says is as much a carrier holding
#: it back as a drone's clock running behind, and the viewer cannot tell them apart when one GS carries
#: every word: lateness beyond this ages the word (a stopped drone shows stale ``ATTEST_LIVE_S`` plus
#: this after its last word at most, whoever carries it and however late; a drone whose clock runs
#: further behind shows its words that much older, live still while that stays under ``ATTEST_LIVE_S``
#: less a beacon).
OFFSET_BEHIND_S = 0.5
#: Drone records and events taken per GS per second: this many per drone the GS is authorized for,
#: and a base (an honest GS sends at most 1 / ``OPS_MIN_GAP_S`` = 10 pictures a second); bursts of
#: ``REPORT_BURST`` seconds' worth. The rest are counted (``rate_limited``), not taken.
REPORT_RATE_PER_DRONE = 12.0
REPORT_RATE_BASE = 12.0
REPORT_BURST_S = 3.0
#: Forgotten words are looked for this often.
EXPIRE_EVERY_S = 5.0


@dataclass
class _Claim:
    ops: DroneOps
    received: float  # the viewer's monotonic time


@dataclass
class _Attested:
    att: AuthorityAttestation
    key: int  # the index of the drone's key it verified under
    first_seen: float  # the viewer's monotonic time it first arrived
    gs: str  # the GS that first carried it


class _Offset:
    """The least (arrival, by the viewer's time of day, minus the drone's ``at``) seen over the last
    ``OFFSET_WINDOW_S``: a monotonic queue (oldest first, values rising), bounded."""

    def __init__(self) -> None:
        self.q: deque[tuple[float, float]] = deque(maxlen=256)

    def add(self, wall: float, sample: float) -> None:
        while self.q and self.q[-1][1] >= sample:
            self.q.pop()
        self.q.append((wall, sample))

    def least(self, wall: float) -> float:
        while self.q and self.q[0][0] < wall - OFFSET_WINDOW_S:
            self.q.popleft()
        return self.q[0][1] if self.q else 0.0


@dataclass
class _Track:
    points: deque = field(default_factory=lambda: deque(maxlen=TRACK_LEN))  # (lat, lon, owner)


def _metres(a: tuple[float, float], b: tuple[float, float]) -> float:
    from zdrone.core.geometry import GeoPoint, distance_m

    return distance_m(GeoPoint(a[0], a[1]), GeoPoint(b[0], b[1]))


class FleetPicture:
    """Every GS's word merged into one picture of the fleet (see the module docstring)."""

    def __init__(self, authorized: Mapping[str, Iterable[str]],
                 drone_keys: Mapping[str, Sequence[bytes]] | None = None, stations: Iterable[str] | None = None) -> None:
        """``authorized``: each drone of the fleet and the GSs authorized for it (revoked ones left
        out); ``drone_keys``: each drone's public signing keys over time, oldest first (its
        attestations are checked against them); a drone without keys has only unverified claims;
        ``stations``: the fleet's GSs (revoked ones left out; default: those authorized for a drone)."""
        self.check = AttestationCheck(drone_keys or {})
        self.claims: dict[str, dict[str, _Claim]] = {}  # drone -> GS -> its latest word
        self.attested: dict[str, _Attested] = {}  # drone -> its newest valid word under a key in force
        self._offsets: dict[str, _Offset] = {}
        self.heard: dict[str, float] = {}  # GS -> when its last part arrived
        self.feed: deque[dict[str, Any]] = deque(maxlen=FEED_LEN)  # newest last
        self.tracks: dict[str, _Track] = {}
        self.drops: Counter[str] = Counter()  # what was not taken, by reason
        self.older = 0  # the drone's words carried after a newer one (a GS that lags, or replays): not news
        self._buckets: dict[str, TokenBucket] = {}
        self._next_expiry = float("-inf")
        self.version = 0  # moves on with every report taken
        self.set_fleet(authorized, stations)

    def set_fleet(self, authorized: Mapping[str, Iterable[str]], stations: Iterable[str] | None = None) -> None:
        """The fleet as now in force (a revision taken live): words of drones no longer in it and of
        GSs no longer authorized for a drone (revoked ones) are forgotten."""
        self.authorized = {d: frozenset(g) for d, g in authorized.items()}
        self.stations = frozenset(g for gss in self.authorized.values() for g in gss) | frozenset(stations or ())
        self._per_gs = Counter(g for gss in self.authorized.values() for g in gss)
        for drone in list(self.claims):
            allowed = self.authorized.get(drone, frozenset())
            kept = {g: c for g, c in self.claims[drone].items() if g in allowed}
            if kept:
                self.claims[drone] = kept
            else:
                del self.claims[drone]
        for table in (self.attested, self._offsets, self.tracks):
            for drone in [d for d in table if d not in self.authorized]:
                del table[drone]
        self.heard = {g: t for g, t in self.heard.items() if g in self.stations}
        self._buckets.clear()
        self.version += 1

    def _bucket(self, gs: str, now: float) -> TokenBucket:
        b = self._buckets.get(gs)
        if b is None:
            rate = REPORT_RATE_PER_DRONE * self._per_gs[gs] + REPORT_RATE_BASE
            b = self._buckets[gs] = TokenBucket.full(rate, rate * REPORT_BURST_S, now)
        return b

    def on_report(self, report: OpsReport, now: float, wall: float) -> None:
        """One part from GS ``report.gs`` (opened: it is that GS's), at monotonic ``now`` and the
        viewer's time of day ``wall``. What the GS says of a drone it is not authorized for, of a name
        outside the fleet, or beyond its rate, is dropped and counted."""
        gs = report.gs
        if gs not in self.stations:
            self.drops["unknown_gs"] += 1
            return
        self.heard[gs] = now
        bucket = self._bucket(gs, now)
        touched: list[str] = []
        for d in report.drones:
            allowed = self.authorized.get(d.drone)
            if allowed is None:
                self.drops["unknown_drone"] += 1
                continue
            if gs not in allowed:
                self.drops["not_authorized"] += 1
                continue
            if not bucket.take(now):
                self.drops["rate_limited"] += 1
                continue
            if d.request is not None and not (d.request.requester in self.stations and d.request.to in self.stations):
                self.drops["request_unknown_gs"] += 1
                d = msgspec.structs.replace(d, request=None)
            self.claims.setdefault(d.drone, {})[gs] = _Claim(d, now)
            if d.attest is not None:
                self._attestation(gs, d.drone, d.attest, now, wall)
            touched.append(d.drone)
        for ev in report.events:
            # every authority event names its drone: one naming none (or a drone outside the fleet)
            # is no GS's word on a drone it serves, whoever sends it
            if gs not in self.authorized.get(ev.drone, frozenset()):
                self.drops["event_not_authorized"] += 1
                continue
            if not bucket.take(now):
                self.drops["rate_limited"] += 1
                continue
            self.feed.append({"t": ev.t, "gs": gs, "drone": ev.drone, "kind": ev.kind, "text": ev.text})
        for drone in dict.fromkeys(touched):
            self._track(drone, now, wall)
        if now >= self._next_expiry:
            self._expire(now)
        self.version += 1

    def _attestation(self, gs: str, drone: str, att: AuthorityAttestation, now: float, wall: float) -> None:
        """The drone's word as ``gs`` carried it: taken if it is newer than the one held (by the
        drone's (time, counter)) and valid under a key in force, or under a newer key than the one
        held (a rotation: the word under the retired key goes, whatever time it names)."""
        cur = self.attested.get(drone)
        if cur is not None and cur.att == att:
            return
        older = cur is not None and (att.at, att.seq) <= (cur.att.at, cur.att.seq)
        if older and cur is not None and cur.key == self.check.newest_key(drone):
            self.older += 1
            return
        if att.at > wall + MAX_SKEW_S:
            self.drops["attest_future"] += 1  # a word that would shadow the drone's true ones
            return
        key = self.check.key_of(gs, drone, att, now)
        if key is None:
            return
        if older and cur is not None and key <= cur.key:
            self.older += 1
            return
        if cur is not None and key > cur.key:
            self._offsets.pop(drone, None)  # what the retired key's words taught of the drone's clock goes too
        self.attested[drone] = _Attested(att, key, now, gs)
        self._offsets.setdefault(drone, _Offset()).add(wall, min(max(wall - att.at, -OFFSET_MAX_S), OFFSET_BEHIND_S))

    def add_key(self, drone: str, public: bytes) -> None:
        """A revision in force gives ``drone`` the signing key ``public``: in force at once, every
        earlier one retired (``AttestationCheck.add_key``); a word held under a retired key goes, with
        what it taught of the drone's clock."""
        self.check.add_key(drone, public)
        held = self.attested.get(drone)
        if held is not None and held.key < self.check.in_force[drone]:
            del self.attested[drone]
            self._offsets.pop(drone, None)
            self.version += 1

    def _expire(self, now: float) -> None:
        self._next_expiry = now + EXPIRE_EVERY_S
        for drone in list(self.claims):
            kept = {g: c for g, c in self.claims[drone].items() if now - c.received <= CLAIM_KEEP_S}
            if kept:
                self.claims[drone] = kept
            else:
                del self.claims[drone]

    def _track(self, drone: str, now: float, wall: float) -> None:
        row = self.drone(drone, now, wall)
        pos = row["position"]
        if pos is None:
            return
        points = self.tracks.setdefault(drone, _Track()).points
        owner = row["owner"]
        if points:
            lat, lon, was = points[-1]
            if was == owner and _metres((lat, lon), (pos[0], pos[1])) < TRACK_STEP_M:
                return
        points.append((round(pos[0], 7), round(pos[1], 7), owner))

    @staticmethod
    def _age(c: _Claim, now: float) -> float | None:
        """How old the GS's last authentic frame from the drone is now (None: it has no link)."""
        if not c.ops.linked or c.ops.since_last is None:
            return None
        return max(0.0, c.ops.since_last) + max(0.0, now - c.received)

    def attest_age(self, drone: str, now: float, wall: float) -> float | None:
        """How old the drone's newest valid word is: by the viewer's clock since it first arrived, and
        by the drone's own time in it against the viewer's clock (less the drone's offset learnt:
        ``OFFSET_WINDOW_S``), whichever is older. None: no valid word."""
        a = self.attested.get(drone)
        if a is None:
            return None
        base = self._offsets[drone].least(wall) if drone in self._offsets else 0.0
        return max(0.0, now - a.first_seen, wall - a.att.at - base)

    def drone(self, name: str, now: float, wall: float) -> dict[str, Any]:
        """One drone's row: the authority the drone signed (else its GSs' claims, unverified), live
        only while that word is recent and an authorized GS heard the drone lately; each GS's link."""
        claims = self.claims.get(name, {})
        fresh = {gs: c for gs, c in claims.items() if now - c.received <= REPORT_TTL_S}
        ages = {gs: a for gs, c in claims.items() if (a := self._age(c, now)) is not None}
        fresh_ages = sorted((a, gs) for gs, a in ages.items() if gs in fresh)
        link_age = fresh_ages[0][0] if fresh_ages else None
        att = self.attested.get(name)
        att_age = self.attest_age(name, now, wall)
        heard = {gs: c for gs, c in fresh.items() if c.ops.state != "unknown"}
        if att is not None:
            a = att.att
            owner, epoch, state, pending_to = a.owner, a.epoch, a.state.value, a.pending_to
            takeover, takeover_to = a.takeover, a.takeover_to
            recent = att_age is not None and att_age <= ATTEST_LIVE_S
            disputed: list[str] = []
            failsafe = state == "failsafe"
        else:
            top = max(heard.values(), key=lambda c: (c.ops.epoch, c.received)) if heard else None
            owner, epoch = (top.ops.owner, top.ops.epoch) if top else (None, 0)
            state, pending_to = (top.ops.state, top.ops.pending_to) if top else ("unknown", None)
            takeover, takeover_to = any(c.ops.takeover for c in fresh.values()), None
            owners = {c.ops.owner or "-" for c in heard.values() if c.ops.epoch == epoch}
            disputed = sorted(owners) if len(owners) > 1 else []
            # a drone that signs nothing (no key in the fleet) has only its GSs' word; one that has a
            # key is never live on it
            recent = name not in self.check.keys
            failsafe = state == "failsafe" or any(c.ops.failsafe for c in heard.values() if c.ops.epoch == epoch)
        # GSs' claims the drone's word does not back (a higher epoch, another owner in its epoch),
        # listed apart, never the owner; an honest GS that lags (a lower epoch) is not listed
        unverified = [{"gs": gs, "owner": c.ops.owner, "epoch": c.ops.epoch} for gs, c in sorted(heard.items())
                      if att is not None and (c.ops.owner, c.ops.epoch) != (owner, epoch) and c.ops.epoch >= epoch]
        live = recent and link_age is not None and link_age <= STALE_S
        if live:
            age = link_age
        else:
            known = [x for x in (att_age, min(ages.values()) if ages else None) if x is not None]
            age = max(known) if known else None
        # the vehicle's fields from the owner's word while it is fresh (a GS in standby hears the
        # drone's status, its telemetry only now and then), else from the freshest authorized word
        by_age = sorted(fresh, key=lambda g: (ages.get(g, float("inf")), g))
        mine = [g for g in by_age if g == owner and ages.get(g, float("inf")) <= STALE_S]
        source = mine[0] if mine else (by_age[0] if by_age else None)
        best = fresh[source].ops if source is not None else None
        links = {gs: {"link": c.ops.link, "age": None if gs not in ages else round(ages[gs], 2), "holds": c.ops.holds,
                      "says": c.ops.owner, "epoch": c.ops.epoch, "silent": gs not in fresh}
                 for gs, c in sorted(claims.items()) if c.ops.linked or c.ops.holds}  # its prepared GSs, not every GS
        requests = [{"at": gs, **msgspec.structs.asdict(c.ops.request)} for gs, c in sorted(fresh.items()) if c.ops.request]
        return {"drone": name, "owner": owner, "epoch": epoch, "state": state, "pending_to": pending_to,
                "verified": att is not None and recent, "attested_age": None if att_age is None else round(att_age, 2),
                "unverified": unverified, "disputed": disputed, "failsafe": failsafe,
                "reports_failsafe": sorted(gs for gs, c in fresh.items() if c.ops.failsafe),
                "stale": not live, "age": None if age is None else round(age, 2),
                "mode": best.mode if best else "", "armed": best.armed if best else False,
                "position": list(best.position) if best and best.position else None,
                "position_from": source if best and best.position else None,
                "mission_seq": best.mission_seq if best else None, "stage": best.stage if best else "",
                "fc_signed": best.fc_signed if best else None, "links": links, "requests": requests,
                "takeover": takeover, "takeover_to": takeover_to}

    def snapshot(self, now: float, wall: float) -> dict[str, Any]:
        """The whole picture at ``now``: drones (sorted by name), GSs heard, the feed newest first."""
        names = sorted({*self.claims, *self.attested}, key=_natural)
        return {"drones": [self.drone(d, now, wall) for d in names],
                "stations": {gs: {"age": round(now - t, 2), "silent": now - t > GS_SILENT_S}
                             for gs, t in sorted(self.heard.items())},
                "feed": list(reversed(self.feed))}

    def track_points(self) -> dict[str, list[tuple[float, float, str | None]]]:
        return {d: list(t.points) for d, t in self.tracks.items()}


def fleet_senders(fleet: Fleet) -> dict[str, bytes]:
    """The GSs whose pictures a viewer opens: every GS of ``fleet`` not revoked, with its public key."""
    return {g: fleet.nodes[g].public_bytes for g in fleet.ground_stations() if not fleet.is_revoked(g)}


def fleet_authorized(fleet: Fleet) -> dict[str, frozenset[str]]:
    """Each drone of ``fleet`` not revoked and the GSs authorized for it (``FleetPicture``'s ``authorized``)."""
    return {d: frozenset(g for g in fleet.ground_stations() if fleet.is_authorized(d, g))
            for d in fleet.drones() if not fleet.is_revoked(d)}


def _natural(name: str) -> tuple[str, int, str, str]:
    """The sort key of a name: its text, then the number it ends with (compared as digits, never
    converted: a name may end in thousands of them), then the name itself."""
    head = name.rstrip("0123456789")
    digits = name[len(head):].lstrip("0")
    return head, len(digits), digits, name
