"""The ground station's protocol logic, sans-IO: what is the station's own, and one session per drone
(``gs.session.DroneSession``). ``gs/station.py`` is its thin Zenoh adapter.

Theory of operation
-------------------
``StationCore`` keeps the station's own state: its identity (rotated by ``adopt_identity``), the fleet
in force (``fleet``: a revision), the heartbeat it sends every drone, and its answers to other GSs'
key-sharing queries (``gs.linking.KeyOwner``: checked against the fleet and the asker's rate limit
before any crypto). Everything about one drone is that drone's session: an input naming a drone
(``on_envelope``, ``on_bundle``, ``on_pair_reply``, ``on_linkkey_reply``, ``operator_command``) goes to
its session and ends there in actions; a key handed to another GS for a drone becomes a candidate of
that drone's link.

Time comes in as ``now``; what the adapter must do comes out as actions (``gs.actions``, the vocabulary
it shares with the drone's core, ``zdrone.core.outputs``): ``Put`` (publish a sealed envelope on the
link to a drone), ``Ask`` (send a query; its replies come back through ``on_pair_reply`` /
``on_linkkey_reply``), ``Emit`` (an event-log record), ``FrameUp`` (a drone frame for the GCS gateway),
``ToOperator`` (a line for the operator) and ``Checkpoint``. An incoming key-sharing query is answered
with a ``QueryAnswer`` value. ``report(now)`` is the core's part of the GS's status record. Nothing
here blocks, reads a clock or touches a socket.

Timers, as the drone's core: the adapter calls ``handle_timer(now)`` when ``now`` reaches
``get_timer()`` and otherwise sleeps until then or until input arrives. ``get_timer`` is the earliest
of the next heartbeat and the sessions' own deadlines (``DroneSession.due``: at once after an input to
it); ``handle_timer`` runs only the sessions that are due.
"""

from __future__ import annotations

import itertools
import logging
from collections import Counter
from dataclasses import dataclass
from typing import Any

from zdrone.core import bundle, keyslost
from zdrone.core import wire
from zdrone.core.authority import State as HaState
from zdrone.core.fleet import Fleet
from zdrone.core.geometry import Circle
from zdrone.core.keys import Identity
from zdrone.core.linktraffic import LinkTraffic
from zdrone.core.mavcontrol import OperatorControlRequest, sysid_as_seen_by
from zdrone.core.mavlink import FrameCodec
from zdrone.core.opspicture import DroneOps, OpsRequest
from zdrone.core.tbm import LinkState
from zdrone.vehicle.modes import mode_name

from gs.actions import Action, QueryAnswer
from gs.droneview import DroneView, view_line
from gs.keyowner import LINKKEY_CANDIDATE_TTL, KeyOwner
from gs.opcontrol import Answer, PendingRequest
from gs.ownership import owns
from gs.context import GCS_COMPID, CoreOptions, StationContext
from gs.session import DroneSession

log = logging.getLogger(__name__)

__all__ = ["CoreOptions", "DroneSeen", "DroneSession", "DroneView", "StationCore", "view_line"]

#: The first mission uploads, and the first take-offs, of a GS's drones are spread over this much time
#: per drone beyond the first (300 drones: 15 s and 6 s), each drone's moment drawn (``gs.mission``).
UPLOAD_SPREAD_PER_DRONE_S = 0.05
TAKEOFF_SPREAD_PER_DRONE_S = 0.02
#: A checkpoint of our record offered to a drone goes out now and at this many heartbeats after
#: (the drone countersigns it once; one that never arrives leaves our decisions ``unwitnessed``).
AUDIT_OFFER_REPEATS = 2
#: The heartbeat period is cut into this many slots (at most one per drone), each drone in one of them
#: (by its place in the station's list): a GS of 300 drones puts 30 heartbeats every 50 ms, not 300
#: at once twice a second, a burst every router on the way queues and every drone's frame waits behind.
HEARTBEAT_SLOTS = 10


@dataclass(frozen=True, slots=True)
class DroneSeen:
    """What an adapter reads of one drone (``StationCore.drone_status``): the drone's authority as
    this GS knows it and what the operator's control shows of it."""

    name: str
    sysid: int
    linked: bool  # this GS holds a live link key for it
    owner: str | None
    epoch: int
    state: HaState | None  # None: no status heard yet
    holds_authority: bool  # this GS commands it now (``DroneSession.holds_authority``)
    owned: bool  # this GS owns it (``gs.ownership.owns``: what its operator consents as)
    request: PendingRequest | None  # another GS's request for control our operator is asked about
    takeover: bool  # what CONTROL_STATUS says of takeover (``OperatorControl.shown_takeover``)


class StationCore:
    """The protocol logic of one ground station (see the module docstring)."""

    def __init__(self, name: str, fleet: Fleet, identity: Identity, drones: tuple[str, ...],
                 opts: CoreOptions = CoreOptions()) -> None:
        self.name = name
        node = fleet.node(name)
        self.sysid = node.sysid
        self.counters: Counter[str] = Counter()
        self.traffic = LinkTraffic()  # what the drones' envelopes carried, by kind (bench traffic)
        self.codec = FrameCodec(self.sysid, GCS_COMPID)
        self.st = StationContext(name=name, sysid=node.sysid, fleet=fleet, identity=identity, opts=opts,
                                 coverage=node.coverage.circle() if node.coverage else None,
                                 counters=self.counters, codec=self.codec, traffic=self.traffic)
        extra = max(len(drones) - 1, 0)
        grant_ids = itertools.count(1)
        self.sessions = {d: DroneSession(self.st, d, fleet.nodes[d].sysid, grant_ids,
                                         upload_spread_s=UPLOAD_SPREAD_PER_DRONE_S * extra,
                                         takeoff_spread_s=TAKEOFF_SPREAD_PER_DRONE_S * extra) for d in drones}
        self.key_owner = KeyOwner(identity, name, fleet, self.counters)
        self._sm_seq = 0
        self._hb_due = 0.0  # the next heartbeat slot's time
        self._hb_slot = 0  # the slot it is
        slots = max(1, min(HEARTBEAT_SLOTS, len(drones)))
        self._hb_groups = [[self.sessions[d] for d in sorted(drones)[i::slots]] for i in range(slots)]
        self._audit_offer: wire.AuditOffer | None = None  # our record's newest checkpoint to countersign
        self._offer_left: dict[str, int] = {}  # drone -> sends left
        self._due = 0.0  # the earliest of the sessions' ``due``, as of the last ``handle_timer``
        self._input_at: float | None = None  # an input came at this time since ``handle_timer`` last ran

    @property
    def opts(self) -> CoreOptions:
        return self.st.opts

    @opts.setter
    def opts(self, opts: CoreOptions) -> None:
        """New options (a test's or a checker's move): every session looks at them at once."""
        self.st.opts = opts
        for session in self.sessions.values():
            session.due = 0.0
        self._due = 0.0

    @property
    def identity(self) -> Identity:
        return self.st.identity

    @property
    def coverage(self) -> Circle | None:
        return self.st.coverage

    @property
    def fleet(self) -> Fleet:
        return self.st.fleet

    @fleet.setter
    def fleet(self, fleet: Fleet) -> None:
        """A fleet revision took effect: every session reads the new fleet from now on (and is due)."""
        self.st.fleet = self.key_owner.fleet = fleet
        for session in self.sessions.values():
            session.revised(fleet)
        self._due = 0.0

    # --------------------------------------------------------------- by name
    @property
    def drones(self) -> tuple[str, ...]:
        """The drones this GS serves."""
        return tuple(self.sessions)

    def session(self, drone: "str | DroneSession") -> DroneSession:
        return self.sessions[drone] if isinstance(drone, str) else drone

    def drone_status(self, drone: str, now: float) -> DroneSeen:
        """Drone ``drone`` as this GS sees it at ``now`` (``KeyError``: not one of ``drones``)."""
        v = self.sessions[drone]
        op = v.operator
        return DroneSeen(name=v.name, sysid=v.sysid, linked=v.link is not None, owner=v.owner, epoch=v.epoch,
                         state=v.ha_state, holds_authority=v.holds_authority(), owned=owns(v, self.name),
                         request=op.live_request(v, now), takeover=op.shown_takeover(v, now))

    def drone_ops(self, drone: str, now: float) -> DroneOps:
        """Drone ``drone`` as this GS tells the fleet's viewer (``zdrone.core.opspicture``) at ``now``."""
        v = self.sessions[drone]
        link, p = v.link, v.position
        req = v.operator.live_request(v, now)
        heard = link is not None and link.tbm.last_seen is not None
        return DroneOps(
            drone=v.name, linked=link is not None, owner=v.owner, epoch=v.epoch,
            state=v.ha_state.value if v.ha_state else "unknown", pending_to=v.pending_to,
            link="none" if link is None else link.tbm.state(now).value,
            since_last=round(link.tbm.since_last(now), 3) if heard and link is not None else None,
            mode=mode_name(v.autopilot, v.custom_mode), armed=v.armed,
            position=None if p is None else (p.lat, p.lon, p.alt), mission_seq=v.mission_seq,
            stage=v.mission.stage.value, fc_signed=v.fc_signed, failsafe=v.ha_state is HaState.FAILSAFE,
            holds=v.holds_authority(), takeover=v.operator.shown_takeover(v, now),
            request=None if req is None else OpsRequest(req.requester, req.to, req.epoch, round(now - req.since, 2),
                                                        req.timeout),
            attest=v.attest)

    def commands_sent(self, drone: str) -> int:
        """Commanding frames sent to ``drone``, all epochs."""
        return sum(self.sessions[drone].commands_sent.values())

    def describe(self, drone: str, now: float) -> str | None:
        """One line for the operator's console (``view_line``), None while there is no link."""
        v = self.sessions[drone]
        return None if v.link is None else view_line(self.name, drone, v, now)

    def holds_authority(self, drone: "str | DroneSession") -> bool:
        """We command ``drone`` (``DroneSession.holds_authority``)."""
        return self.session(drone).holds_authority()

    def _input(self, now: float) -> None:
        """An input came: the sessions it made due are looked at at once (``get_timer``)."""
        if self._input_at is None or now < self._input_at:
            self._input_at = now

    # ------------------------------------------------------------------ sending
    def send_frame(self, drone: "str | DroneSession", frame: bytes) -> list[Action]:
        """Seal one MAVLink frame for ``drone`` (``DroneSession.send_frame``: commands only while we command it)."""
        return self.session(drone).send_frame(frame)

    def send_msg(self, drone: "str | DroneSession", msg: object) -> list[Action]:
        return self.session(drone).send_msg(msg)

    def send_control(self, drone: "str | DroneSession", msg: wire.Control) -> list[Action]:
        return self.session(drone).send_control(msg)

    def offer_checkpoint(self, drones: "frozenset[str] | set[str]", head: wire.AuditHead) -> list[Action]:
        """Our authority record signed a checkpoint that covers decisions about ``drones`` (none named,
        a revision applied: all ours): each of ours among them, and each still owed an earlier one
        (this one covers it), is asked to countersign it (``wire.AuditOffer``), now and at the next
        ``AUDIT_OFFER_REPEATS`` heartbeats."""
        self._audit_offer = wire.AuditOffer(head)
        to = (set(drones) & set(self.sessions)) or set(self.sessions)
        self._offer_left = {d: AUDIT_OFFER_REPEATS + 1 for d in to | set(self._offer_left)}
        return self._send_offer()

    def _send_offer(self) -> list[Action]:
        out: list[Action] = []
        if self._audit_offer is None:
            return out
        for d in sorted(self._offer_left):
            out += self.sessions[d].send_control(self._audit_offer)
            self._offer_left[d] -= 1
            if self._offer_left[d] <= 0:
                del self._offer_left[d]
        return out

    # -------------------------------------------------------------------- time
    def get_timer(self) -> float:
        """When ``handle_timer`` must next be called if no input comes (see the module docstring)."""
        due = min(self._hb_due, self._due)
        return due if self._input_at is None else min(due, self._input_at)

    def handle_timer(self, now: float, wall: float | None = None) -> list[Action]:
        """The GS's periodic work at ``now`` (``wall``: the time of day, for key-sharing stamps): every
        session that is due runs its time rules, and the heartbeat goes out when it is due."""
        self._input_at = None
        stamp = now if wall is None else wall
        out: list[Action] = []
        due = float("inf")  # the sessions' earliest deadline, found in the same walk (300 sessions, every pass)
        for session in self.sessions.values():
            if session.due <= now:
                out += session.tick(now, stamp)
            if session.due < due:
                due = session.due
        if now >= self._hb_due:
            # the slots that are due, each once (a late pass sends every drone one heartbeat, no more); the
            # next slot a slot's time after this one was due (after ``now``, a late pass stretched it)
            step = 1.0 / self.opts.heartbeat_hz / len(self._hb_groups)
            for _ in self._hb_groups:
                if now < self._hb_due:
                    break
                for session in self._hb_groups[self._hb_slot]:
                    out += session.heartbeat()
                    if self.opts.paper_heartbeat:
                        self._sm_seq += 1
                        out += session.send_control(wire.SmHeartbeat(self._sm_seq))
                    due = min(due, session.due)
                if self._hb_slot == 0:
                    offers = self._send_offer()
                    if offers:  # (rare: an audit offer's few sends) every session looked at again
                        out += offers
                        due = min((s.due for s in self.sessions.values()), default=float("inf"))
                self._hb_slot = (self._hb_slot + 1) % len(self._hb_groups)
                self._hb_due += step
            if self._hb_due <= now:
                self._hb_due = now + step
        self._due = due
        return out

    # ------------------------------------------------------------------ linking
    def on_pair_reply(self, drone: str, ok: bytes | None, err: bytes | None, now: float) -> list[Action]:
        """One reply to our pairing query (``ok`` payload, or the drone's error text)."""
        self._input(now)
        session = self.sessions.get(drone)
        if session is None:
            self.counters["pair_reply_late"] += 1
            return []
        return session.on_pair_reply(ok, err, now)

    def on_pair_done(self, drone: str, m1: bytes, now: float) -> list[Action]:
        """Our pairing query to ``drone`` carrying ``m1`` ended: all its replies are in, or none came."""
        self._input(now)
        session = self.sessions.get(drone)
        return [] if session is None else session.on_pair_done(m1, now)

    def adopt_identity(self, identity: Identity, now: float, wall: float) -> list[Action]:
        """Our static key was rotated: key sharing answers under ``identity`` from now on, and every
        drone we hold a link with is re-paired under it at once, as a fresh pairing (``Linking.rekey``;
        tried again every ``RETRY_S`` until one is proven), make-before-break: the live link serves
        until the drone's reply gives the new key, and the old one stays readable while the drone
        switches to it. It is no restart of the drone: the keys it holds for other GSs stand."""
        self._input(now)
        self.st.identity = identity
        self.key_owner.adopt(identity)
        out: list[Action] = []
        for session in self.sessions.values():
            out += session.rekey(identity, now, wall)
        return out

    def on_linkkey_query(self, drone: str, payload: bytes, now: float, secret: bytes,
                         wall: float | None = None) -> tuple[QueryAnswer, list[Action]]:
        """Answer one key-sharing query for link (``drone``, us); ``secret`` is fresh randomness
        (``gs.linking.KeyOwner``). The secret handed out never touches the live link: it is a
        candidate until the drone speaks under it (one per asker: the newest replaces an older one)."""
        self._input(now)
        session = self.sessions.get(drone)
        live = session is not None and session.link is not None and session.link.tbm.state(now) is not LinkState.LOST
        answer, logs, asker = self.key_owner.answer(drone, payload, now, secret, wall, serves=session is not None,
                                                    live=live)
        if asker is not None:
            assert session is not None
            session.offer_candidate(asker, secret, payload, now, LINKKEY_CANDIDATE_TTL)
        return answer, logs

    def on_linkkey_reply(self, drone: str, gs: str, ok: bytes | None, err: bytes | None, now: float) -> list[Action]:
        """One reply from ``gs`` to our key-sharing query about ``drone``."""
        self._input(now)
        session = self.sessions.get(drone)
        if session is None:
            self.counters["linkkey_reply:unknown_drone"] += 1
            return []
        return session.on_linkkey_reply(gs, ok, err, now)

    def on_keys_lost(self, data: bytes, now: float, wall: float) -> None:
        """Another GS's keys-lost notice (``zdrone.core.keyslost``), heard on its revision key: signed by
        it (fleet in force) and fresh by our time of day ``wall``, it has every drone we share with it
        share its key again (``Linking.peer_keys_lost``); otherwise counted and dropped."""
        notice = keyslost.heard(data, self.fleet, wall)
        if isinstance(notice, keyslost.NoticeRefused):
            self.counters[f"keys_lost_refused:{notice.reason}"] += 1
            return
        if notice.gs == self.name:
            return  # our own, heard back
        self.counters["keys_lost_heard"] += 1
        since_here = notice.since - (wall - now)  # its start on our clock
        for session in self.sessions.values():
            session.linking.peer_keys_lost(notice.gs, data, notice.since, now, since_here)

    # ----------------------------------------------------------------- receiving
    def on_bundle(self, drone: str, data: bytes, now: float) -> list[Action]:
        """One publication on our ``down`` key of ``drone``: a bundle of sealed envelopes
        (``zdrone.core.bundle``), each opened on its own; one that does not parse is dropped whole,
        counted (``down:bad_bundle``)."""
        items = bundle.unpack(data)
        if items is None:
            self.counters["down:bad_bundle"] += 1
            return []
        out: list[Action] = []
        for envelope in items:
            out += self.on_envelope(drone, envelope, now)
        return out

    def on_envelope(self, drone: str, data: bytes, now: float) -> list[Action]:
        """One sealed envelope from ``drone`` (``DroneSession.on_envelope``)."""
        self._input(now)
        session = self.sessions.get(drone)
        if session is None:
            self.counters["down:unknown_drone"] += 1
            return []
        return session.on_envelope(data, now)

    # ---------------------------------------------------------- operator control
    def operator_command(self, drone: "str | DroneSession", req: OperatorControlRequest, now: float, app: str = "",
                         app_sysid: int | None = None) -> tuple[Answer, list[Action]]:
        """An application's MAV_CMD_REQUEST_OPERATOR_CONTROL (``gs.opcontrol``): the answer it gets at once.
        ``app`` names the application (its key, or ``unsigned:<peer>``); ``app_sysid`` is its own sysid,
        which the gateway never shows it as another GCS's (``sysid_as_seen_by``): p4 is read the same way."""
        self._input(now)
        return self.session(drone).operator_command(req, now, app, self._gs_named(req.sysid, app_sysid))

    def _gs_named(self, p4: int, app_sysid: int | None) -> str | None:
        """The fleet GS whose sysid, as application ``app_sysid`` is shown it, is ``p4`` (None: none)."""
        for name in self.fleet.ground_stations():
            sysid = self.fleet.nodes[name].sysid
            if (sysid if app_sysid is None else sysid_as_seen_by(sysid, app_sysid)) == p4:
                return name
        return None

    # ------------------------------------------------------------------ status
    def report(self, now: float) -> dict[str, Any]:
        """The core's part of the GS's status record."""
        out = {}
        for d, v in self.sessions.items():
            out[d] = {"linked": v.link is not None, "owner": v.owner, "epoch": v.epoch,
                      "state": v.ha_state.value if v.ha_state else "unknown", "stage": v.mission.stage.value,
                      "position": [v.position.lat, v.position.lon, v.position.alt] if v.position else None,
                      "waiting": v.mission.waiting,
                      "commands_sent": {str(k): c for k, c in v.commands_sent.items()},
                      "link": None if v.link is None else {"opened": v.link.opened, "sent": v.link.sent,
                                                             "dropped": {r.value: c for r, c in v.link.drops.items() if c}},
                      "key_candidates": len(v.slot.candidates),
                      "dropped_unlinked": {r.value: c for r, c in v.slot.unlinked.items() if c},
                      "fc_signed": v.fc_signed}
        return {"drones": out, "counters": dict(self.counters), "traffic": self.traffic.report()}
