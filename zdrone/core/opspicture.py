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
may be hostile: every field is shown as *who said it*. Per drone, the authority shown (owner, epoch,
state, pending recipient) is the drone's own: of the attestations the GSs carry, those that check
against the drone's signing keys over time (``AttestationCheck``: once per new attestation, then
remembered), the one with the highest (epoch, drone's time) gives it, ``verified``. A GS's claim that
no valid attestation backs (a higher epoch, another owner in that epoch, a forgery, another drone's
word replayed) is listed apart as ``unverified`` and never shown as the owner; an honest GS that lags
(a lower epoch) is not listed. Only when no GS carries a valid attestation (a drone without a signing
key) is the claim of the highest epoch shown, not ``verified`` (``disputed`` when two GSs name
different owners at that epoch). A failsafe that a GS of the shown epoch heard of shows at once (an
alarm errs on the safe side). The vehicle's fields come from the owner's claim while it is fresh (a GS in standby
hears the drone's status, its telemetry only now and then), else from the freshest claim. The age of the drone's last
report is, per GS, the GS's own age (at its sending) plus the time since the viewer received it:
a silent GS ages like a silent drone. A drone whose freshest word is older than ``STALE_S`` is
**stale**: shown as such (its last values, and how old they are), never as live.
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

from .attestation import AttestationCheck
from .keys import Identity, hkdf, public_key
from .ratelimit import TokenBucket
from .replay import ReplayWindow
from .wire import AuthorityAttestation

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
@dataclass
class _Claim:
    ops: DroneOps
    received: float  # the viewer's monotonic time
    proven: bool = False  # ``ops.attest`` is the drone's own (``AttestationCheck``)

    @property
    def backed(self) -> bool:
        """The GS's claim (owner, epoch) is what the drone's own attestation it carries says."""
        a = self.ops.attest
        return self.proven and a is not None and (a.owner, a.epoch) == (self.ops.owner, self.ops.epoch)


@dataclass
class _Track:
    points: deque = field(default_factory=lambda: deque(maxlen=TRACK_LEN))  # (lat, lon, owner)


def _metres(a: tuple[float, float], b: tuple[float, float]) -> float:
    from .geometry import GeoPoint, distance_m

    return distance_m(GeoPoint(a[0], a[1]), GeoPoint(b[0], b[1]))


class FleetPicture:
    """Every GS's word merged into one picture of the fleet (see the module docstring)."""

    def __init__(self, drone_keys: Mapping[str, Sequence[bytes]] | None = None) -> None:
        """``drone_keys``: each drone's public signing keys over time, oldest first (its attestations
        are checked against them); a drone without keys has only unverified claims."""
        self.check = AttestationCheck(drone_keys or {})
        self.claims: dict[str, dict[str, _Claim]] = {}  # drone -> GS -> its latest word
        self.heard: dict[str, float] = {}  # GS -> when its last part arrived
        self.feed: deque[dict[str, Any]] = deque(maxlen=FEED_LEN)  # newest last
        self.tracks: dict[str, _Track] = {}
        self.version = 0  # moves on with every report taken

    def on_report(self, report: OpsReport, now: float) -> None:
        self.heard[report.gs] = now
        for d in report.drones:
            proven = self.check.valid(report.gs, d.drone, d.attest, now)
            self.claims.setdefault(d.drone, {})[report.gs] = _Claim(d, now, proven)
        for ev in report.events:
            self.feed.append({"t": ev.t, "gs": report.gs, "drone": ev.drone, "kind": ev.kind, "text": ev.text})
        for drone in {d.drone for d in report.drones}:
            self._track(drone, now)
        self.version += 1

    def _track(self, drone: str, now: float) -> None:
        row = self.drone(drone, now)
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
        if not c.ops.linked or c.ops.since_last is None:
            return None
        return c.ops.since_last + max(0.0, now - c.received)

    def drone(self, name: str, now: float) -> dict[str, Any]:
        """One drone's row: the merged authority, the freshest vehicle fields, each GS's link."""
        claims = self.claims.get(name, {})
        aged = [(self._age(c, now), gs, c) for gs, c in claims.items()]
        live = sorted(((a, gs, c) for a, gs, c in aged if a is not None), key=lambda x: x[0])
        age = live[0][0] if live else None
        auth = self._authority(claims)
        owner = auth["owner"]
        # the vehicle's fields from the owner's word while it is fresh (a GS in standby hears the drone's
        # status, but its telemetry only now and then), else from the freshest
        mine = [c for a, gs, c in live if gs == owner and a <= STALE_S]
        best = mine[0].ops if mine else (live[0][2].ops if live else (next(iter(claims.values())).ops if claims else None))
        links = {gs: {"link": c.ops.link, "age": None if a is None else round(a, 2), "holds": c.ops.holds,
                      "says": c.ops.owner, "epoch": c.ops.epoch, "silent": now - self.heard.get(gs, now) > GS_SILENT_S}
                 for a, gs, c in sorted(aged, key=lambda x: x[1])}
        requests = [{"at": gs, **msgspec.structs.asdict(c.ops.request)} for gs, c in claims.items() if c.ops.request]
        stale = age is None or age > STALE_S
        return {"drone": name, **auth,
                "stale": stale, "age": None if age is None else round(age, 2),
                "mode": best.mode if best else "", "armed": best.armed if best else False,
                "position": list(best.position) if best and best.position else None,
                "mission_seq": best.mission_seq if best else None, "stage": best.stage if best else "",
                "fc_signed": best.fc_signed if best else None, "links": links, "requests": requests,
                "takeover": any(c.ops.takeover for c in claims.values())}

    @staticmethod
    def _authority(claims: dict[str, _Claim]) -> dict[str, Any]:
        """Who commands the drone: the drone's own attestation with the highest (epoch, time) that any
        GS carries, ``verified``; the GSs' claims it does not back (a higher epoch, or another owner in
        its epoch) listed apart as ``unverified``, never shown as the owner. Without any valid
        attestation: the GSs' claim of the highest epoch, not ``verified``."""
        heard = [c for c in claims.values() if c.ops.state != "unknown"]
        proofs = [c for c in claims.values() if c.proven and c.ops.attest is not None]
        if proofs:
            best = max(proofs, key=lambda c: (c.ops.attest.epoch, c.ops.attest.at, c.received))  # type: ignore[union-attr]
            att = best.ops.attest
            assert att is not None
            owner, epoch, state, pending_to = att.owner, att.epoch, att.state.value, att.pending_to
            owners = {c.ops.attest.owner or "-" for c in proofs if c.ops.attest is not None and c.ops.attest.epoch == epoch}
            unverified = [{"gs": gs, "owner": c.ops.owner, "epoch": c.ops.epoch} for gs, c in sorted(claims.items())
                          if c.ops.state != "unknown" and not c.backed and (c.ops.epoch, c.ops.owner) != (epoch, owner)
                          and c.ops.epoch >= epoch]
        else:
            top = max(heard, key=lambda c: (c.ops.epoch, c.received)) if heard else None
            owner, epoch = (top.ops.owner, top.ops.epoch) if top else (None, 0)
            state, pending_to = (top.ops.state, top.ops.pending_to) if top else ("unknown", None)
            owners = {c.ops.owner or "-" for c in heard if c.ops.epoch == epoch}
            unverified = []
        # a failsafe a GS of this epoch heard of shows at once (an alarm errs on the safe side)
        failsafe = state == "failsafe" or any(c.ops.failsafe for c in heard if c.ops.epoch == epoch)
        return {"owner": owner, "epoch": epoch, "state": state, "pending_to": pending_to,
                "verified": bool(proofs), "unverified": unverified,
                "disputed": sorted(owners) if len(owners) > 1 else [], "failsafe": failsafe}

    def snapshot(self, now: float) -> dict[str, Any]:
        """The whole picture at ``now``: drones (sorted by name), GSs heard, the feed newest first."""
        return {"drones": [self.drone(d, now) for d in sorted(self.claims, key=_natural)],
                "stations": {gs: {"age": round(now - t, 2), "silent": now - t > GS_SILENT_S}
                             for gs, t in sorted(self.heard.items())},
                "feed": list(reversed(self.feed))}

    def track_points(self) -> dict[str, list[tuple[float, float, str | None]]]:
        return {d: list(t.points) for d, t in self.tracks.items()}


def _natural(name: str) -> tuple[str, int]:
    head = name.rstrip("0123456789")
    tail = name[len(head):]
    return head, int(tail) if tail else -1
