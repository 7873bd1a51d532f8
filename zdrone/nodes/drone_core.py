"""The drone companion's protocol logic, sans-IO: link keys, pairing answers, key grants, the
handover authority, the region, forwarding. ``zdrone/nodes/drone.py`` is its thin adapter.

Theory of operation
-------------------
``DroneCore`` holds everything the companion decides: one ``LinkSlot`` per ground station (the
live key, candidates waiting for their proof, the key just replaced), the pairing responder, the
``AuthorityMachine`` and the counters. Time comes in as ``now`` (monotonic seconds) and, where a
peer's time stamp is compared, ``wall`` (time of day); bytes and facts come in through ``on_*``
methods; what the adapter must do comes out as values (``zdrone.nodes.drone_actions``):

* ``Put(gs, payload)``: publish a sealed envelope on ``down/<gs>`` (``zdrone.core.outputs``);
* ``ToVehicle(frame)``: send a MAVLink frame to the flight controller;
* ``CommandVehicle(command, reason, ...)``: the failsafe (LAND or RTL);
* ``Listen(gss)``: the uplinks to subscribe from now on (only when the set changes);
* ``Emit(record)``: a typed event-log record (``zdrone.core.records``; ``zdrone.core.outputs``);
* ``Persist(owner, epoch, state)``: the authority to keep across a restart, in the air or on the
  ground (only when it changes; a restart on the ground keeps what was saved until the next owner).

The inputs: ``on_envelope`` (an uplink envelope of GS ``gs``), ``on_pair_query`` (a pairing message
1; the adapter replies with the typed result), ``on_vehicle`` (the vehicle's own position, None
while it has no fix, and whether it is on the ground), ``on_telemetry`` (a vehicle frame for the
GSs), ``restore`` (the authority saved before a restart) and ``handle_timer`` at ``get_timer()``:
link-state thresholds, the machine's deadlines, a pairing probation's end, the status beacon.
The fleet's revisions come in through ``on_revision``, ``on_revision_stamp`` and ``adopt_own_keys``
(the core's part in them, with the owner's lease: ``zdrone.nodes.drone_revisions``).

Side effects that follow from the state (which uplinks to listen to, what to persist) are computed
once at the end of every input from the old and the new state (``_effects``), never appended by
hand in handlers. The rules of authority are the machine's alone: the core never asks it twice.
"""

from __future__ import annotations

import logging
from collections import Counter
from dataclasses import dataclass
from typing import Any

import msgspec

from zdrone.core import authority as ha
from zdrone.core import records as rec
from zdrone.core import wire
from zdrone.core.attestation import BEACON_S, Attester
from zdrone.core.bundle import MAX_BUNDLE
from zdrone.core.envelope import Dropped, Opened, SecureLink
from zdrone.core.fleet import Fleet
from zdrone.core.geometry import Circle, GeoPoint
from zdrone.core.keys import Identity, LinkKey, SigningKey
from zdrone.core.kk import check_message1, is_hybrid
from zdrone.core.lease import OwnerLease
from zdrone.core.linkplan import LinkGrace
from zdrone.core.linkslot import LinkSlot, Promoted
from zdrone.core.linktraffic import LinkTraffic
from zdrone.core.mavlink import FrameError, read_header
from zdrone.core.outputs import Emit, Put
from zdrone.core.pairing import (PairAccepted, PairingResponder, PairRefusal, PairRefused, PairRepeated, PairResult,
                                 _prologue as pairing_prologue)
from zdrone.core.standby import STREAMED, StandbyStream
from zdrone.core.tbm import TbmThresholds
from zdrone.core.uplink import UplinkClass
from zdrone.core.wire import KeyGrant, KeyGrantAck
from zdrone.fleet import keyexprs
from zdrone.nodes.drone_actions import CommandVehicle, Countersign, Listen, Out, Persist, ToVehicle
from zdrone.nodes.drone_links import DroneLinks
from zdrone.nodes.drone_revisions import DroneRevisions

log = logging.getLogger(__name__)

#: A pairing candidate must be proven by the GS within this time (the drone listens to it meanwhile).
PAIRING_TTL = 10.0
#: The authority status goes to every linked GS at least this often (besides every change), so a
#: GS that was hung or missed a change learns who holds authority within a second; each beacon
#: carries a new signature of the drone's (``zdrone.core.attestation``: the viewer's proof that the
#: drone's word is recent).
STATUS_BEACON_S = BEACON_S
#: The first few of each drop or refusal reason go to the event log; all of them to the counters.
LOGGED_PER_REASON = 5
#: A pairing query from a GS we heard under its live key within this long is refused as ``linked``
#: (``_heard_lately``): the GS's own silence rule (``gs.context.SILENT_REPAIR_S``) is as long.
LINKED_HEARD_S = 1.0

Position = tuple[float, float, float]


_NOTE_RECORDS: dict[str, type[rec.AuthorityNote]] = {
    cls.__struct_config__.tag: cls for cls in rec.AuthorityNote.__subclasses__()  # type: ignore[misc]
}


@dataclass(frozen=True, slots=True)
class DroneCoreOptions:
    thresholds: TbmThresholds = TbmThresholds()
    failsafe: str = "LAND"
    handover_timeout: float = ha.DEFAULT_HANDOVER_TIMEOUT
    cipher: str = "zdrone"  # "plain" / "fernet" only for bench traffic
    status_beacon: float = STATUS_BEACON_S
    pairing_ttl: float = PAIRING_TTL
    first_claim: float = ha.FIRST_CLAIM_S  # after a restart on the ground: the last owner pairs back first this long
    #: the owner's lease (s) where the fleet sets none (``Fleet.revision_lease`` wins; 0: off): from the
    #: first pairing, authority stands only while the drone has heard, within this long, a signed
    #: revision stamp naming the drone from a GS authorized for it other than the owner; else the owner's
    #: authority lapses as if its link were LOST (a covered authorized heir, else the failsafe), on the
    #: ground and in the air
    revision_lease: float = 0.0
    #: seal what the drone says to one GS between two ``flush`` calls (the adapter's pass) as one
    #: envelope (``SecureLink.seal_batch``): one header and tag per radio packet instead of per frame;
    #: off, each message is sealed and put on its own at once (the in-memory fleets; the paper's Fernet)
    batch: bool = False


#: A batch's plaintext at most: with the envelope and the bundle's length it fits one bundle.
BATCH_MAX = MAX_BUNDLE - 64


class _Batch:
    """Plaintexts waiting for one envelope to a GS under ``link``."""

    __slots__ = ("link", "items", "size")

    def __init__(self, link: SecureLink) -> None:
        self.link = link
        self.items: list[bytes] = []
        self.size = 1  # the batch's prefix, then each item and its length


class DroneCore(DroneRevisions, DroneLinks):
    """The companion of drone ``name``: feed it inputs, carry out what they return."""

    def __init__(self, fleet: Fleet, name: str, identity: Identity, opts: DroneCoreOptions = DroneCoreOptions(),
                 started_wall: float | None = None, signing: SigningKey | None = None) -> None:
        """``started_wall``: the time of day the companion started (pairing message 1s stamped
        before it are stale: a restarted companion has forgotten its answers); ``signing``: the
        drone's fleet signing key (its authority status then carries its signed word on who commands
        it, ``zdrone.core.attestation``)."""
        node = fleet.nodes[name]
        self.fleet, self.name, self.opts = fleet, name, opts
        self.uplink = node.uplink
        self.machine = ha.AuthorityMachine(ha.Config(frozenset(node.authorized_gs), opts.handover_timeout,
                                                     opts.failsafe))
        self.responder = PairingResponder(identity, name,
                                          {g: fleet.nodes[g].public_bytes for g in fleet.ground_stations()},
                                          frozenset(node.authorized_gs), not_before=started_wall,
                                          require_hybrid=fleet.pairing_pq)
        self.gs_sysids = {n: fleet.nodes[n].sysid for n in fleet.ground_stations()}
        self.coverage = {n: fleet.nodes[n].coverage.circle() for n in fleet.ground_stations()  # type: ignore[union-attr]
                         if fleet.nodes[n].coverage is not None}
        self._inside_of: tuple[tuple[float, float] | None, dict[str, Circle], frozenset[str]] | None = None  # ``_inside``'s last answer
        self.slots: dict[str, LinkSlot] = {}
        self.links: dict[str, SecureLink] = {}  # the live link of each slot
        self.probation: dict[str, float] = {}  # GS -> until when we listen for its proof of a new pairing key
        self.counters: Counter[str] = Counter()
        self.traffic = LinkTraffic()  # what the GSs' envelopes carried, by kind (bench traffic)
        self.forwarded: Counter[str] = Counter()  # commanding frames forwarded, per GS
        self.forwarded_epochs: Counter[str] = Counter()  # the same per "epoch:gs" (one GS per epoch, always)
        self.standby = StandbyStream()  # what a GS that does not command the drone is sent of its stream
        self._full_stream: set[str] = set()  # the GSs sent the full stream at the last vehicle frame
        self._latest: dict[int, bytes] = {}  # the newest frame of each stream message (a new owner's catch-up)
        self.position: Position | None = None
        self.position_trusted = False  # the position may grant authority (``on_vehicle``)
        self.on_ground = True
        self.fc_signed: bool | None = None  # the adapter's word: the autopilot link is MAVLink-signed (None: unknown)
        self.audit_head: wire.AuditHead | None = None  # the authority record's newest checkpoint (the adapter's)
        self.attester = Attester(name, signing) if signing is not None else None
        self.wall_offset = 0.0  # the time of day minus ``now`` (the adapter's clocks): when an attestation is signed
        self._listening: frozenset[str] = frozenset()
        self._persisted: tuple[str | None, int, str] | None = None
        self._next_beacon = 0.0
        self._timer_handled = float("-inf")
        self.rekey: set[str] = set()  # rotated GSs whose live key predates their new static key
        self.lease = OwnerLease()  # the owner's lease (``zdrone.core.lease``)
        self._queued: dict[str, list[_Batch]] = {}  # GS -> the envelopes of this pass (``batch``)
        self.grace = LinkGrace()  # links that follow the drone: since when each closable link was (``linkplan``)
        self.links_peak = 0  # the most live links held at once

    # ---------------------------------------------------------------- inputs
    def on_envelope(self, gs: str, data: bytes, now: float) -> list[Out]:
        """One uplink envelope on ``up/<gs>`` (the adapter has applied the radio, if any)."""
        out: list[Out] = []
        slot = self.slots.get(gs)
        if slot is None:
            self.counters["no_link"] += 1
            return out
        res, promoted = slot.open(data, now)
        if isinstance(res, Dropped):
            drops = slot.live.drops if slot.live is not None else slot.unlinked
            if drops[res.reason] <= LOGGED_PER_REASON:
                out.append(Emit(rec.Drop(gs=gs, reason=res.reason.value, detail=res.detail)))
            return out + self._effects(now)
        assert isinstance(res, Opened)
        self.traffic.heard(data, res)
        if promoted is not None:
            out += self._on_promoted(gs, promoted, now)
        if res.header is not None:
            uplink = self.uplink.classify(res.header.msgid)
            out += self._handle(ha.Frame(now, gs, uplink), now, res.plaintext)
        else:
            out += self._on_control(gs, res.control, now)
        return out + self._effects(now)

    def on_pair_query(self, gs: str, payload: bytes | None, now: float, secret: bytes,
                      wall: float | None) -> tuple[PairResult, list[Out]]:
        """One pairing query of ``gs`` (``payload`` None: oversized); ``secret``: fresh randomness for
        a new link key; ``wall``: the drone's time of day (message 1's stamp must be fresh). The
        adapter replies with the result's message 2, its error text, or nothing."""
        out: list[Out] = []
        if payload is None:
            ans: PairResult = PairRefused(PairRefusal.OVERSIZE)
        else:
            policy = None if self.responder.admit(gs) else (self.machine.pair_refusal(gs, self.on_ground, now)
                                                            or self._links_full(gs) or self._heard_lately(gs, now))
            # the authority's refusal (first_claim with the seconds left, outside_coverage, ...) tells
            # something: only to a query that passed its tag check; anything else is dropped, counted
            forged = None if policy is None else self._message1_refusal(gs, payload, wall)
            # a rotated GS is told we hold no key of its: it switches to the new pairing's key at once
            # (make-before-break: our live key keeps opening its frames until the new one is proven)
            ans = forged or self.responder.answer(gs, payload, now, secret, policy,
                                                  holds_key=gs in self.links and gs not in self.rekey, wall=wall)
        if isinstance(ans, PairAccepted):
            # a candidate until the GS proves it (the newest pairing replaces an older one)
            link = self._new_link(gs, ans.key, now)
            link.hybrid = payload is not None and is_hybrid(payload)
            if not self._slot(gs).offer(link, now, "pair", self.opts.pairing_ttl):  # (the responder refused it first)
                ans = PairRefused(PairRefusal.DOWNGRADE, "the fleet requires the hybrid (ML-KEM-768) pairing")
        if isinstance(ans, PairAccepted):
            self.probation[gs] = now + self.opts.pairing_ttl
            self.counters["pair_answered"] += 1
            out.append(Emit(rec.PairAnswered(gs=gs)))
        elif isinstance(ans, PairRepeated):
            self.counters["pair_repeated"] += 1  # a replay or a retransmission: the same answer again
        else:
            out += self._pair_refused(gs, ans)
        return ans, out + self._effects(now)

    def _heard_lately(self, gs: str, now: float) -> PairRefused | None:
        """A pairing of ``gs``, our owner, refused as ``linked``: we hold its live key and heard it under
        that key within ``LINKED_HEARD_S``. The owner pairs again when our word has not reached it for a
        second (a restarted companion must have its owner back within the loss threshold); a drone that
        is only late (a loaded companion, a one-way fault) would compute a handshake per try and mend
        nothing: it holds the key. Not for a rotated GS (its new static key needs the pairing) nor a
        classical key the fleet's hybrid rule no longer accepts."""
        link = self.links.get(gs)
        if (gs != self.machine.owner or link is None or gs in self.rekey
                or (self.fleet.pairing_pq and not link.hybrid)):
            return None
        last = link.tbm.last_seen
        if last is None or now - last >= LINKED_HEARD_S:
            return None
        return PairRefused(PairRefusal.LINKED, f"the drone holds your key and heard you {now - last:.1f} s ago")

    def _message1_refusal(self, gs: str, payload: bytes, wall: float | None) -> PairRefused | None:
        """The silent refusal of a message 1 that fails its tag (or its freshness), None if it passes."""
        r = self.responder
        fail = check_message1(r.me, r.ground_stations[gs], pairing_prologue(self.name, gs), payload, wall,
                              None if wall is None else r.max_age)
        return None if fail is None else PairRefused(PairRefusal(fail.value))

    def on_vehicle(self, position: Position | None, on_ground: bool, now: float, trusted: bool = True) -> list[Out]:
        """The vehicle's own position (None while it has no fix: inside no coverage) and whether it
        is on the ground. Updates the coverage circles the drone is inside -- from a ``trusted``
        position only (one that came signed by the autopilot, or the operator opted in for an unsigned
        link): an untrusted one is inside no coverage (no heir, no pairing that needs coverage)."""
        self.position, self.on_ground, self.position_trusted = position, on_ground, trusted
        inside = self._inside(position if trusted else None)
        out: list[Out] = []
        if inside != self.machine.inside:
            out += self._handle(ha.RegionChanged(now, inside), now)
        if on_ground != self.machine.on_ground:  # no link-loss failsafe on the ground (``AuthorityMachine``)
            out += self._handle(ha.GroundChanged(now, on_ground), now)
        return out + self._effects(now)

    def _inside(self, position: Position | None) -> frozenset[str]:
        """The GSs whose coverage circle holds ``position`` (none without one), computed again only
        when the position or the circles changed (the loop asks every pass; a vehicle reports a few
        times a second)."""
        where = None if position is None else (position[0], position[1])
        last = self._inside_of
        if last is not None and last[0] == where and last[1] is self.coverage:
            return last[2]
        inside = frozenset() if where is None else frozenset(
            g for g, circle in self.coverage.items() if circle.contains(GeoPoint(where[0], where[1])))
        self._inside_of = (where, self.coverage, inside)
        return inside

    def on_telemetry(self, frame: bytes, now: float) -> list[Out]:
        """A vehicle frame: sealed to every GS the drone talks to; to a standby GS (not the owner, no
        hand-over pending to it) a stream message at most once a ``StandbyStream`` interval. A GS that
        becomes the owner or heir first gets the newest frame of each stream message, so that it
        never decides from a position up to an interval old."""
        try:
            msgid = read_header(frame).msgid
        except FrameError:
            msgid = -1
        out = self._catch_up()
        for gs in self.machine.telemetry_targets():
            link = self.links.get(gs)
            if link is None or (gs not in self._full_stream and not self.standby.allow(gs, msgid, now)):
                continue
            out += self._send(gs, link, frame)
        if msgid in STREAMED:
            self._latest[msgid] = frame
        return out

    def _catch_up(self) -> list[Out]:
        """A GS that now commands the drone (or is the heir of a pending hand-over) gets the newest
        frame of each stream message at once, before anything the change makes the drone say."""
        m = self.machine
        full = {g for g in (m.owner, m.pending_to) if g is not None}
        out: list[Out] = []
        for gs in sorted(full - self._full_stream):
            link = self.links.get(gs)
            if link is not None:
                for f in self._latest.values():
                    out += self._send(gs, link, f)
                self.counters["catch_up_frames"] += len(self._latest)
            self.standby.forget(gs)
        self._full_stream = full
        return out

    def restore(self, owner: str | None, epoch: int, state: str, now: float) -> list[Out]:
        """At start, the authority saved before: back to it in the air (its owner must re-pair within
        the loss threshold; a failsafe goes on as a failsafe). On the ground the node comes back
        UNPAIRED with the epoch kept (the next authority gets epoch + 1, whoever it is) and the saved
        owner pairing back first for ``first_claim`` seconds; what was saved stays saved until the
        next authority replaces it. With nothing to come back to, a fresh start (the first pairing
        then needs a GS whose coverage holds the vehicle)."""
        if owner is None:
            self._persisted = None
            return [Emit(rec.AuthorityForgotten(owner=owner, epoch=epoch, state=wire.AuthorityState(state))),
                    Persist(None, 0, ha.State.UNPAIRED.value)]
        if self.on_ground:
            log.warning("restarted on the ground: %s (epoch %d) may pair back first for %.1f s",
                        owner, epoch, self.opts.first_claim)
            out = self._apply(self.machine.restore_on_ground(owner, epoch, now, self.opts.first_claim), now)
            return out + self._effects(now)
        out: list[Out] = [Emit(rec.Restarted(owner=owner, epoch=epoch, state=wire.AuthorityState(state),
                                             position=self.position))]
        log.warning("restarted in the air: authority %s (epoch %d); waiting for it to re-pair", owner, epoch)
        failsafe = state == ha.State.FAILSAFE.value  # restarted during the failsafe: it goes on
        out += self._apply(self.machine.restore(owner, epoch, now, self.opts.thresholds.lost, failsafe), now)
        return out + self._effects(now)

    def ready(self, wall: float) -> None:
        """The companion is ready (its vehicle heard, its saved authority restored) at time of day
        ``wall``: pairing message 1s made before it (less the clock skew allowed) are stale."""
        self.responder.not_before = wall

    def get_timer(self) -> float | None:
        """When ``handle_timer`` must next be called if no input comes."""
        due = [self._next_beacon]
        timer = self.machine.get_timer()
        if timer is not None and timer > self._timer_handled:
            due.append(timer)
        due += [t for link in self.links.values() if (t := link.tbm.next_change()) is not None]
        if self.probation:
            due.append(min(self.probation.values()))
        if (lease := self.lease_due()) is not None:
            due.append(lease)
        if (closing := self.grace.next_due()) is not None:
            due.append(closing)
        return min(due)

    def handle_timer(self, now: float) -> list[Out]:
        """What is due at ``now``: the machine's deadlines, the probations' ends, the status beacon, the
        revision lease and the authority's link's silence (``_poll_links``): what time alone decides,
        judged after what was queued (the adapter calls this after its inbox)."""
        out: list[Out] = []
        if now >= self._next_beacon:
            self._next_beacon = now + self.opts.status_beacon
            st = self._stamped(self.machine.status(), now, renew=True)  # one signature for every GS
            plaintext = wire.encode_control(st)
            for gs, link in sorted(self.links.items()):
                out += self._send(gs, link, plaintext)
        for slot in self.slots.values():  # a replaced key is wiped at its grace's end, heard or not
            slot.end_grace(now)
        return out + self._effects(now, timer=True)

    # -------------------------------------------------------------- reports
    def report(self, now: float) -> dict[str, Any]:
        """The core's part of the drone's status record."""
        m = self.machine
        for slot in self.slots.values():
            slot.expire(now)
        return {
            "owner": m.owner, "epoch": m.epoch, "state": m.state.value, "pending_to": m.pending_to,
            "position": list(self.position) if self.position else None,
            "in_region": m.in_region, "subscribed": sorted(m.subscribed),
            "links": {gs: {"state": link.tbm.state(now).value, "since_last": round(link.tbm.since_last(now), 3),
                           "opened": link.opened, "sent": link.sent, "missing": link.missing,
                           "dropped": {r.value: c for r, c in link.drops.items() if c}}
                      for gs, link in self.links.items()},
            "keys": {gs: {"live": slot.live is not None, "candidates": len(slot.candidates), "expired": slot.expired,
                          "dropped_unlinked": {r.value: c for r, c in slot.unlinked.items() if c}}
                     for gs, slot in self.slots.items()},
            "ha_drops": {r.value: c for r, c in m.drops.items()}, "rejects": dict(m.rejects),
            "counters": dict(self.counters) | ({"standby_held": self.standby.held} if self.standby.held else {}), "forwarded_commands": dict(self.forwarded),
            "forwarded_epochs": dict(self.forwarded_epochs), "traffic": self.traffic.report(),
            "links_follow": self._follows(), "links_peak": self.links_peak,
        }

    def failsafe_latency_ms(self, now: float) -> float | None:
        """How long after the loss threshold ``now`` is, for the authority's link (None: never heard)."""
        link = self.links.get(self.machine.owner or "")
        if link is None or link.tbm.last_seen is None:
            return None
        return (now - link.tbm.last_seen - self.opts.thresholds.lost) * 1000.0

    # ------------------------------------------------------------- internals
    def _slot(self, gs: str) -> LinkSlot:
        """``gs``'s slot, made if new: hybrid keys only while the fleet requires the hybrid pairing."""
        slot = self.slots.get(gs)
        if slot is None:
            slot = self.slots[gs] = LinkSlot(hybrid_only=self.fleet.pairing_pq)
        return slot

    def _new_link(self, gs: str, key: LinkKey, now: float) -> SecureLink:
        return SecureLink(
            key=key, role="drone", tx_keyexpr=keyexprs.down(self.name, gs), rx_keyexpr=keyexprs.up(self.name, gs),
            peer_sysid=self.fleet.nodes[gs].sysid, now=now, thresholds=self.opts.thresholds, cipher=self.opts.cipher,
            authorize=lambda g: self.fleet.is_authorized(self.name, g))

    def _control(self, gs: str, msg: wire.Control, now: float) -> list[Out]:
        link = self.links.get(gs)
        return [] if link is None else self._send(gs, link, wire.encode_control(self._stamped(msg, now)))

    def _send(self, gs: str, link: SecureLink, plaintext: bytes) -> list[Out]:
        """Seal ``plaintext`` for ``gs`` now, or (``batch``) queue it for the pass's envelope (``flush``)."""
        if not self.opts.batch:
            return [Put(gs, link.seal(plaintext))]
        batches = self._queued.setdefault(gs, [])
        last = batches[-1] if batches else None
        if last is None or last.link is not link or last.size + len(plaintext) + 2 > BATCH_MAX:
            last = _Batch(link)  # a key replaced within the pass, or a full batch: the next envelope
            batches.append(last)
        last.items.append(plaintext)
        last.size += len(plaintext) + 2
        return []

    def flush(self) -> list[Out]:
        """The end of the adapter's pass (``batch``): what was queued for each GS, sealed as one
        envelope per GS (under the link it was queued for, in order)."""
        if not self._queued:
            return []
        queued, self._queued = self._queued, {}
        return [Put(gs, b.link.seal_batch(b.items)) for gs, batches in queued.items() for b in batches]

    def on_audit_checkpoint(self, seq: int, head: bytes, sig: bytes) -> None:
        """The authority record signed its head (the adapter's log): shown to every GS in the status,
        which countersigns it (``zdrone.core.audit``)."""
        self.audit_head = wire.AuditHead(seq, head, sig)

    def _stamped(self, msg: wire.Control, now: float, renew: bool = False) -> wire.Control:
        """An authority status tells each GS whether the drone's autopilot link is signed, the
        authority record's newest checkpoint, and the drone's signed word on its authority (signed
        anew at every beacon, ``renew``, and at every change of what the status says of it, else
        reused: ``zdrone.core.attestation``)."""
        if isinstance(msg, wire.AuthorityStatus) and self.fc_signed is not None:
            msg = msgspec.structs.replace(msg, fc_signed=self.fc_signed)
        if isinstance(msg, wire.AuthorityStatus) and self.audit_head is not None:
            msg = msgspec.structs.replace(msg, audit=self.audit_head)
        if isinstance(msg, wire.AuthorityStatus) and self.attester is not None:
            signed = self.attester.signed
            msg = msgspec.structs.replace(msg, attest=self.attester.attest(msg, now + self.wall_offset, renew))
            self.counters["attestations_signed"] += self.attester.signed - signed
        return msg

    def _handle(self, event: ha.Event, now: float, frame: bytes | None = None) -> list[Out]:
        owner, epoch = self.machine.owner, self.machine.epoch  # the forward is decided before any switch
        acts = self.machine.handle(event)
        if (frame is not None and isinstance(event, ha.Frame) and event.uplink is UplinkClass.AUTHORITY_ONLY
                and ha.Forward(event.gs) in acts):
            assert event.gs == owner  # the machine forwards commanding frames from the owner only
            self.forwarded[event.gs] += 1
            self.forwarded_epochs[f"{epoch}:{event.gs}"] += 1
        return self._apply(acts, now, frame)

    def _apply(self, actions: list[ha.Action], now: float, frame: bytes | None = None) -> list[Out]:
        out: list[Out] = self._catch_up()  # a new owner or heir: the newest position before the news
        failsafe = False
        for a in actions:
            if isinstance(a, ha.Forward):
                if frame is not None:
                    out.append(ToVehicle(frame))
            elif isinstance(a, ha.DropFrame):
                self.counters[f"ha_drop:{a.reason.value}"] += 1
            elif isinstance(a, ha.SendControl):
                out += self._control(a.gs, a.msg, now)
            elif isinstance(a, ha.FailsafeCommand):
                latency = self.failsafe_latency_ms(now)
                if latency is not None and latency < 0:
                    latency = None  # before the loss threshold: not a link loss (a revocation, a lapsed lease)
                out.append(CommandVehicle(a.command, a.reason, latency))
                out.append(Emit(rec.Failsafe(action=a.command, reason=a.reason, detect_to_command_ms=latency,
                                             position=self.position)))
                log.warning("FAILSAFE: %s (%s), %.1f ms after the threshold", a.command, a.reason, latency or -1)
                failsafe = True
            elif isinstance(a, ha.AuthorityChanged):
                cls = rec.HandoverComplete if a.kind in ("handover", "emergency") else rec.AuthorityChange
                out.append(Emit(cls(from_=a.old, to=a.new, epoch=a.epoch, kind=a.kind, time=0.0,
                                    position=self.position)))
                log.warning("authority %s -> %s (epoch %d, %s)", a.old, a.new, a.epoch, a.kind)
            elif isinstance(a, ha.Note):
                note = _NOTE_RECORDS.get(a.kind)
                if note is not None:
                    out.append(Emit(note(detail=a.detail, position=self.position)))
                log.info("%s: %s", a.kind, a.detail)
            # whom to listen to follows from the state (the machine's ``subscribed``, ``_effects``)
        if failsafe:  # the drone's signed word on its failsafe, to every GS now (the notice is its GSs' alarm)
            status = self.machine.status()
            for gs in sorted(self.links):
                out += self._control(gs, status, now)
        return out

    def _on_control(self, gs: str, msg: wire.Control | None, now: float) -> list[Out]:
        if isinstance(msg, KeyGrant):
            return self._on_grant(gs, msg, now)
        if isinstance(msg, wire.HandoverRelease):
            return self._handle(ha.Release(now, gs, msg.to, msg.epoch), now)
        if isinstance(msg, wire.HandoverRequest):
            return self._handle(ha.AuthorityAsked(now, gs, msg.to, msg.timeout, msg.takeover, msg.ask_id, msg.takeover_to), now)
        if isinstance(msg, wire.AuditOffer):
            return [Countersign(gs, msg.head)]
        if isinstance(msg, wire.SmHeartbeat):
            self.counters["sm_heartbeat"] += 1
        else:
            self.counters[f"control_ignored:{type(msg).__name__}"] += 1
        return []

    def _on_grant(self, sender: str, msg: KeyGrant, now: float) -> list[Out]:
        """A key grant from ``sender``: bad content is counted and rejected; a key the link holds
        already is acknowledged again; else the authority machine accepts or rejects it."""
        bad = ha.check_grant(msg, self.gs_sysids)
        if bad is not None:
            self.counters["bad_grant"] += 1
            return self._control(sender, wire.Reject("key_grant", bad.detail), now)
        carrier = self.links.get(sender)
        if self.fleet.pairing_pq and (carrier is None or not carrier.hybrid):
            # the fleet requires hybrid keys: a key that crossed a classical link is only as strong as it
            self.counters["grant_refused:downgrade"] += 1
            return self._control(sender, wire.Reject("key_grant", "downgrade: the fleet requires hybrid keys and "
                                                                  "this grant came over a classical link"), now)
        key = LinkKey.from_secret(self.name, msg.gs, msg.secret)
        slot = self.slots.get(msg.gs)
        known = [] if slot is None else [slot.live] * (slot.live is not None) + [c.link for c in slot.candidates]
        if any(link.key.same_as(key) for link in known):
            return self._control(sender, KeyGrantAck(msg.gs, msg.grant_id), now)  # a repeated grant
        replace = slot is not None and slot.live is not None and self._lost_notice_holds(msg, slot.live, now)
        out: list[Out] = []
        if self._follows() and msg.gs not in self.links and self.machine.grant_rejection(sender, msg.gs) is None:
            out += self._make_room(msg.gs, now)  # the link left behind longest goes, if one may
            if len(self.links) >= self.fleet.links_max:
                self.counters["grant_refused:links_full"] += 1
                return out + self._control(sender, wire.Reject("key_grant", f"links_full: the drone holds "
                                                               f"{len(self.links)} links and none may close"), now)
        result, actions = self.machine.grant(ha.GrantHeard(now, sender, msg.gs))
        if isinstance(result, ha.GrantAccepted):
            if replace:  # the GS restarted (its own signed word): its old key goes, the granted one is live
                self._wipe_key(result.gs)
                self.counters["keys_lost_replaced"] += 1
            out += self._install(result.gs, key, now, hybrid=carrier is not None and carrier.hybrid,
                                 how="grant:keys_lost" if replace else "grant")
        out += self._apply(actions, now)  # a rejection's Reject is among them
        if isinstance(result, ha.GrantAccepted):
            out += self._control(sender, KeyGrantAck(msg.gs, msg.grant_id), now)
        return out

    def _install(self, gs: str, key: LinkKey, now: float, hybrid: bool = False, how: str = "grant") -> list[Out]:
        """A key granted by the authority: live at once if the link has none, else a candidate that
        GS ``gs`` must prove (and only once its live link is LOST: ``linkslot``). The drone then
        speaks under a new live key once, so the GS can confirm it too."""
        slot = self._slot(gs)
        link = self._new_link(gs, key, now)
        link.hybrid = hybrid
        if slot.live is None:
            slot.install(link, now)
            self.links[gs] = link
            return [Emit(rec.LinkInstalled(gs=gs, how=how)), *self._control(gs, self.machine.status(), now)]
        if not slot.offer(link, now, "grant"):
            self.counters["classical_refused:grant"] += 1  # not reached: ``_on_grant`` refuses it first
            return []
        return [Emit(rec.LinkCandidate(gs=gs, how="grant"))]

    def _on_promoted(self, gs: str, promoted: Promoted, now: float) -> list[Out]:
        """GS ``gs`` proved a candidate key with the frame just opened: it is now the live key."""
        slot = self.slots[gs]
        assert slot.live is not None
        out: list[Out] = []
        if promoted.origin == "pair" and self._follows() and gs not in self.links:
            # a new link by the GS's own pairing counts once proven: room is made now (the link left behind
            # longest goes), or, if none may go or the GS does not cover the drone, the key is dropped
            refused = self._links_full(gs)
            if refused is None:
                out += self._make_room(gs, now)
            if refused is not None or len(self.links) >= self.fleet.links_max:
                self._wipe_key(gs)
                self.counters["pair_refused:links_full"] += 1
                return out + [Emit(rec.PairRefused(gs=gs, reason="links_full: proven with no room"))]
        self.links[gs] = slot.live
        self.probation.pop(gs, None)
        out.append(Emit(rec.LinkConfirmed(gs=gs, how=promoted.origin, replaced=promoted.replaced)))
        log.info("link to %s: new key proven (%s)", gs, promoted.origin)
        if promoted.origin == "pair":
            self.rekey.discard(gs)  # a rotated GS's new key is live: the old one is gone with the slot's swap
            refusal = self.machine.pair_refusal(gs, self.on_ground, now)
            if refusal is not None:  # the authority's state changed since message 1 (e.g. failsafe in the air)
                self.counters["pair_refused"] += 1
                out.append(Emit(rec.PairRefused(gs=gs, reason=refusal.text)))
            else:
                out.append(Emit(rec.Paired(gs=gs)))
                out += self._handle(ha.PairingDone(now, gs, self.on_ground), now)
        return out

    def _pair_refused(self, gs: str, refusal: PairRefused) -> list[Out]:
        key = f"pair_refused:{refusal.reason.value}"
        self.counters[key] += 1
        return [Emit(rec.PairRefused(gs=gs, reason=refusal.text))] if self.counters[key] <= LOGGED_PER_REASON else []

    def _poll_links(self, now: float, timer: bool) -> list[Out]:
        """The links' state changes, the authority's own link last (an heir is chosen among links
        judged at the same instant). After an input (``timer`` False) the authority's link is reported
        only if it got better: its frames may still wait in the adapter's queue behind this input (a
        companion whose loop was late finds all that arrived meanwhile), so its silence, which lands
        the drone or moves authority, is judged by ``handle_timer``, which the adapter calls once what
        was queued is handled. Every other link is judged at once, silences too: a silence judged early
        only holds back a hand-over or an heir until that GS's next frame proves it again."""
        out: list[Out] = []
        owner = self.machine.owner
        for gs, link in sorted(self.links.items(), key=lambda item: item[0] == owner):
            st = link.tbm.poll(now, worsen=timer or gs != owner)
            if st is not None:
                out.append(Emit(rec.LinkStateChanged(gs=gs, state=st)))
                out += self._handle(ha.LinkChanged(now, gs, st), now)
        return out

    def _effects(self, now: float, timer: bool = False) -> list[Out]:
        """What follows from the state after an input, or with ``timer`` after ``handle_timer``:
        link-state changes (``_poll_links``); with ``timer`` only, what time alone decides, after
        what was queued: the machine's expired deadlines and the revision lease; then the uplinks to
        listen to (the machine's plus every GS whose new pairing key waits for its proof) and what to
        persist."""
        out = self._poll_links(now, timer)
        self.lease.owner_is(self.machine.owner, now)  # a new owner's lease runs from its taking over
        if timer:
            out += self._lease(now)
            due = self.machine.get_timer()
            if due is not None and now >= due:  # a hand-over's or a re-pairing's deadline
                self._timer_handled = due
                out += self._apply(self.machine.handle_timer(now), now)
        if self._follows():
            self.grace.update({g for g in self.links if self.machine.may_close(g)}, now)
            if timer:
                for g in self.grace.due(now):
                    out += self._close(g, now, "left behind")
        self.links_peak = max(self.links_peak, len(self.links))
        self.probation = {gs: t for gs, t in self.probation.items() if t > now}
        want = frozenset(self.machine.subscribed) | frozenset(self.probation)
        if want != self._listening:
            out += [Emit(rec.Subscribe(gs=g)) for g in sorted(want - self._listening)]
            out += [Emit(rec.Unsubscribe(gs=g)) for g in sorted(self._listening - want)]
            self._listening = want
            out.append(Listen(want))
        m = self.machine
        kept = (m.owner, m.epoch, m.state.value)
        if m.owner is not None and kept != self._persisted:
            self._persisted = kept
            out.append(Persist(*kept))
        return out
