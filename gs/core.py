"""The ground station's protocol logic, sans-IO: pairing, key sharing with confirmation, hand-over
coordination and mission stages. ``gs/station.py`` is its thin Zenoh adapter.

Theory of operation
-------------------
``StationCore`` holds one ``DroneView`` per drone the GS serves (its own business: adapters name a
drone and read a ``DroneSeen``). Time comes in as ``now``; bytes and events come in through
``on_*`` methods and ``operator_command``; what the adapter must do comes out as actions
(``gs.actions``, the vocabulary it shares with the drone's core, ``zdrone.core.outputs``): ``Put``
(publish a sealed envelope on the link to a drone), ``Ask`` (send a query; its replies come back
through ``on_pair_reply`` / ``on_linkkey_reply``), ``Emit`` (an event-log record), ``FrameUp`` (a
drone frame for the GCS gateway) and ``ToOperator`` (a line for the operator). An incoming key-sharing
query is answered with a ``QueryAnswer`` value. ``report(now)`` is the core's part of the GS's
status record. Nothing here blocks, reads a clock or touches a socket.

Timers, as the drone's core: the adapter calls ``handle_timer(now)`` when ``now`` reaches
``get_timer()`` and otherwise sleeps until then or until input arrives. The timer is due at once
after any input (what came in may decide something: a status, a position in the overlap), at the
next heartbeat, and at the earliest deadline of the drones' sub-machines (linking, mission,
operator control, hand-over, a hold for a key) and re-sends (``_deadlines``): no timer fires for
nothing to do, and nothing due waits for a poll.

Per drone:

* **Linking** is the sub-machine ``gs.linking.Linking``, tables: pairing (with ``pair``, and again
  when the drone falls silent while we hold its authority: a restarted companion) and, as authority,
  key sharing for every other authorized GS without a link on the drone (one ``KeyShareAsk`` at a
  time; its authentic reply becomes a ``KEY_GRANT`` re-sent each second until the drone acknowledges
  it). A reply proving the drone's static key installs the new link here (our own fresh key: live at
  once, the old one readable for a grace period) and a HEARTBEAT goes out under it, the proof the
  drone waits for. As owner, ``gs.linking.KeyOwner`` answers other GSs' queries: checked against the
  fleet and the asker's rate limit before any crypto; an authentic one gets a fresh secret that
  becomes a *candidate* of our own link (the live link is never touched) until the drone speaks under it.
* **Hand-over**: while it holds authority and the vehicle is inside its and another authorized GS's
  coverage, nearer to the other's centre, the GS releases authority (``HANDOVER_RELEASE``), judged
  from a position reported after the status that made the drone ours (one heard before it may be as
  old as the standby stream's interval: a new owner would hand the drone straight back); if the
  drone reports the release timed out, the GS commands RTL. Where the release stands in the drone's
  epoch (released, confirmed, failed) is the sub-machine ``gs.handover.Handover``, a table. A
  release toward a GS whose key the drone does not hold yet waits for it: while the key is known to
  be coming (a restarted companion), the vehicle is held where it is and its mission resumed just
  before the release (the sub-machine ``gs.keyhold.KeyHold``, a table), so that how fast the vehicle
  flies does not decide whether the hand-over happens inside the overlap.
* **Mission stages** are the sub-machine ``gs.mission.Mission``, a table: it takes events only while
  this GS holds authority and no key grant of its is pending.
"""

from __future__ import annotations

import itertools
import logging
from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Iterator

from pymavlink.dialects.v20 import common as mav

from zdrone.core import bundle
from zdrone.core import records as rec
from zdrone.core import wire
from zdrone.core.authority import RELEASE_NOT_AUTHORITY, RELEASE_STALE_EPOCH
from zdrone.core.authority import State as HaState
from zdrone.core.envelope import Dropped, Opened, SecureLink
from zdrone.core.linktraffic import LinkTraffic
from zdrone.core.fleet import Fleet
from zdrone.core.geometry import Circle, GeoPoint, distance_m
from zdrone.core.keys import Identity, LinkKey
from zdrone.core.kk import is_hybrid
from zdrone.core.linkslot import PREVIOUS_GRACE, LinkSlot
from zdrone.core.mavcontrol import OperatorControlRequest, sysid_as_seen_by
from zdrone.core.mavlink import FrameCodec, read_header
from zdrone.core.opspicture import DroneOps, OpsRequest
from zdrone.core.tbm import LinkState
from zdrone.fleet import keyexprs as kx

from zdrone.vehicle.fix import PositionFix
from zdrone.vehicle.modes import MODE_ROLES, mode_name, set_mode_params
from zdrone.vehicle.report import READ_MSGIDS, AutopilotHeard, PositionReported, TextHeard, VehicleReport

from .actions import Action, Checkpoint, Emit, FrameUp, Put, QueryAnswer, ToOperator
from .handover import Confirmed, Failed, Handover, HandoverPhase, ReleaseSent
from .keyhold import HoldStep, KeyHold, KeyMissing, KeyThere, ModeAck
from .linking import LINKKEY_CANDIDATE_TTL, PAIR_TIMEOUT, RETRY_S, Context, KeyOwner, Linking, PairDue, Reply
from .mission import FlightAck, FlightEvent, FlightParam, FlightTick, Mission
from .opcontrol import Answer, OperatorControl, PendingRequest, Step
from .ownership import owns
from .planner import PlannedItem

log = logging.getLogger(__name__)

GCS_COMPID = mav.MAV_COMP_ID_MISSIONPLANNER
#: the messages the station decodes: the vehicle's report (``VehicleReport``), the mission's and the acks
USED_MSGIDS = READ_MSGIDS | {mav.MAVLINK_MSG_ID_MISSION_CURRENT, mav.MAVLINK_MSG_ID_COMMAND_ACK,
                            mav.MAVLINK_MSG_ID_MISSION_REQUEST_INT, mav.MAVLINK_MSG_ID_MISSION_REQUEST,
                            mav.MAVLINK_MSG_ID_MISSION_ACK, mav.MAVLINK_MSG_ID_PARAM_VALUE,
                            mav.MAVLINK_MSG_ID_MISSION_ITEM_REACHED}
#: An unconfirmed HANDOVER_RELEASE is sent again this often (a lossy radio must not make the
#: drone leave the overlap before it hears one).
RELEASE_RESEND_S = 0.25
#: The authority GS pairs again when the drone has been silent this long (and again as often): a
#: restarted companion has lost every key and must have its owner back within the loss threshold.
SILENT_REPAIR_S = 1.0
#: ... and then tries every this often, each try waiting this long for its answer: a companion that
#: comes back is re-paired within this time of its pairing queryable being up (a query to a drone
#: that is down gets no answer; the drone answers a live one in milliseconds).
SILENT_RETRY_S = 0.2
#: ... for this long of the drone's silence; then every ``SILENT_SLOW_RETRY_S`` (a drone out of reach
#: for good, or one whose authority moved on while we missed its word, is not asked five times a second
#: forever; a companion that takes longer than this to come back is re-paired within a second).
SILENT_FAST_S = 10.0
SILENT_SLOW_RETRY_S = 1.0
#: After this long without a word from the drone (our site cut off, our process hung) our view of the
#: authority may be stale: authority may have moved meanwhile. Until the drone's authority status
#: (a beacon, at least once a second) says who holds it, the GS acts on no authority it thinks it has.
STALE_VIEW_S = 1.0
#: A hand-over that failed (timed out: the target was not heard; refused) is tried again this often
#: while the vehicle is still where it should happen: a target that comes back takes authority.
HANDOVER_RETRY_S = 2.0
#: Toward a GS whose key is still being shared, the hand-over waits while the vehicle is inside this
#: fraction of our coverage radius; past it, the hand-over has failed (the vehicle comes home) ...
KEY_WAIT_RADIUS = 0.9
#: A key known to be coming holds the vehicle flying its mission where it is in the overlap (the
#: autopilot's hold mode) for at most this long; the mission resumes just before the release. A
#: restart of the companion costs a pause of the flight, at any speed, instead of the delivery.
#: Known to be coming: the key is on its way to the drone (the other GS's authenticated reply), or
#: the other GS said its old link still looks alive (``live_link``, an unauthenticated error) within
#: ``KEY_COMING_S`` while our own pairing showed, authenticated, that the companion restarted (it
#: had lost our key) within ``RESTART_EVIDENCE_S``.
#: (The hold itself, its phases and timings: ``gs.keyhold``.)
KEY_COMING_S = 2.0
RESTART_EVIDENCE_S = 30.0
#: A failed hand-over commands RTL only if the vehicle is leaving our coverage: farther from our
#: centre than when we released, by at least this much (else it is flying into our coverage and
#: needs nothing but the retry).
LEAVING_M = 5.0
#: The first mission uploads, and the first take-offs, of a GS's drones are spread over this much time
#: per drone beyond the first (300 drones: 15 s and 6 s), each drone's moment drawn (``gs.mission``).
UPLOAD_SPREAD_PER_DRONE_S = 0.05
TAKEOFF_SPREAD_PER_DRONE_S = 0.02


@dataclass(frozen=True, slots=True)
class CoreOptions:
    """What the GS core needs of the command line."""

    pair: bool = False
    mission: list[PlannedItem] | None = None
    heartbeat_hz: float = 2.0
    command_rate: float = 0.0
    hysteresis_m: float = 20.0
    cipher: str = "zdrone"
    paper_heartbeat: bool = False
    take_control: bool = False  # after a failsafe, ask for control as soon as our link is proven
    allow_takeover: bool = False  # the operator's standing "allow takeover" (MAVLink operator control)
    seed: bytes = b""  # fresh randomness from the adapter: the jitter of retries and spreads (``gs.mission.jitter``)


@dataclass(slots=True)
class DroneView(VehicleReport):
    """What this GS knows of one drone: what its vehicle reports (the base, ``VehicleReport``:
    position fix, armed, mode, autopilot, landed state, pre-arm health, texts) and the rest."""

    name: str
    sysid: int
    link: SecureLink | None = None  # the live link (``slot.live``)
    slot: LinkSlot = field(default_factory=LinkSlot)
    hold: KeyHold | None = None  # the vehicle held for a key (one per epoch, ``gs.keyhold``)
    mission_seq: int | None = None
    owner: str | None = None
    epoch: int = 0
    ha_state: HaState | None = None
    pending_to: str | None = None
    fc_signed: bool | None = None  # the drone's link to its autopilot is MAVLink-signed (None: not said)
    attest: wire.AuthorityAttestation | None = None  # the drone's newest signed word on its authority, as it came
    handover: Handover = field(default_factory=lambda: Handover(""))  # our release, in the current epoch
    stale: bool = False  # the drone was silent: our view of the authority waits for its status
    commands_sent: Counter = field(default_factory=Counter)  # per epoch
    last_command: float | None = None
    last_take_control: float | None = None
    takeover: bool = False  # the owner allows takeover (the drone's AuthorityStatus)
    takeover_to: str | None = None  # ... for this GS only (a consent's window); None: any
    operator: OperatorControl = field(default_factory=lambda: OperatorControl(""))  # set by StationCore
    mission: Mission = field(default_factory=lambda: Mission("", "", 0, None))  # set by StationCore
    linking: "Linking | None" = None  # set by StationCore
    switching: bool = False  # our rotated key's pairing made a new key live: the drone has not spoken under it yet
    position_input: int = 0  # the core's input number of the newest position report (``StationCore._inputs``)
    ours_from_input: int = 0  # ... of the status that made the drone ours (a position before it does not count)

    @property
    def position(self) -> GeoPoint | None:
        """Where the vehicle is, None while its autopilot has no position of its own (``PositionFix``)."""
        return self.fix.position

    @position.setter
    def position(self, value: GeoPoint | None) -> None:
        """A new report of the vehicle's position (heard after whatever came before it)."""
        self.fix = PositionFix()
        self.fix.reported = value
        self.position_input = max(self.position_input, self.ours_from_input) + 1


#: A deadline is looked at this long after it: a rule "past T" holds just after T, and a sum of floats
#: may fall a hair short of it.
DEADLINE_SLACK_S = 0.001


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
    holds_authority: bool  # this GS commands it now (``StationCore.holds_authority``)
    owned: bool  # this GS owns it (``gs.ownership.owns``: what its operator consents as)
    request: PendingRequest | None  # another GS's request for control our operator is asked about
    takeover: bool  # what CONTROL_STATUS says of takeover (``OperatorControl.shown_takeover``)


def _due(last: float | None, now: float, period: float) -> bool:
    return last is None or now - last >= period


def _linking(view: DroneView) -> Linking:
    assert view.linking is not None  # set by StationCore for every view
    return view.linking


class StationCore:
    """The protocol logic of one ground station (see the module docstring)."""

    def __init__(self, name: str, fleet: Fleet, identity: Identity, drones: tuple[str, ...],
                 opts: CoreOptions = CoreOptions()) -> None:
        self.name = name
        self._fleet = fleet
        self.identity = identity
        self.opts = opts
        node = fleet.node(name)
        self.sysid = node.sysid
        self.coverage: Circle | None = node.coverage.circle() if node.coverage else None
        self.counters: Counter[str] = Counter()
        self.traffic = LinkTraffic()  # what the drones' envelopes carried, by kind (bench traffic)
        extra = max(len(drones) - 1, 0)
        spread = {"upload_spread_s": UPLOAD_SPREAD_PER_DRONE_S * extra, "takeoff_spread_s": TAKEOFF_SPREAD_PER_DRONE_S * extra}
        self.views = {d: DroneView(d, fleet.nodes[d].sysid, handover=Handover(d),
                                   operator=OperatorControl(name, allow_takeover=opts.allow_takeover),
                                   mission=Mission(name, d, fleet.nodes[d].sysid, opts.mission, seed=opts.seed,
                                                   counters=self.counters, **spread)) for d in drones}
        self.codec = FrameCodec(self.sysid, GCS_COMPID)
        self.key_owner = KeyOwner(identity, name, fleet, self.counters)
        grant_ids = itertools.count(1)
        for d, view in self.views.items():
            view.linking = Linking(Context(name, d, identity, fleet, self.counters, grant_ids))
        self._sm_seq = 0
        self._hb_due = 0.0
        self._due = 0.0  # the earliest deadline of the drones' sub-machines (``_deadlines``)
        self._input_at: float | None = None  # an input came at this time since ``handle_timer`` last ran
        self._inputs = 0  # envelopes taken so far: orders a position report against an authority change

    @property
    def fleet(self) -> Fleet:
        return self._fleet

    @fleet.setter
    def fleet(self, fleet: Fleet) -> None:
        """A fleet revision took effect: every part reads the new fleet from now on. With the hybrid
        pairing required, a link on a classical key is paired again (hybrid, make-before-break, as
        after a rotation of our key): the drone takes key grants only over hybrid links."""
        self._fleet = self.key_owner.fleet = fleet
        for view in self.views.values():
            linking = _linking(view)
            linking.ctx.fleet = fleet
            if fleet.pairing_pq and view.link is not None and not view.link.hybrid and not linking.rekey_pending:
                linking.rekey(self.identity, linked=True, rotated=False)
                self.counters["repair_hybrid"] += 1

    # --------------------------------------------------------------- by name
    @property
    def drones(self) -> tuple[str, ...]:
        """The drones this GS serves."""
        return tuple(self.views)

    def _view(self, drone: "str | DroneView") -> DroneView:
        return self.views[drone] if isinstance(drone, str) else drone

    def drone_status(self, drone: str, now: float) -> DroneSeen:
        """Drone ``drone`` as this GS sees it at ``now`` (``KeyError``: not one of ``drones``)."""
        v = self.views[drone]
        op = v.operator
        return DroneSeen(name=v.name, sysid=v.sysid, linked=v.link is not None, owner=v.owner, epoch=v.epoch,
                           state=v.ha_state, holds_authority=self.holds_authority(v), owned=owns(v, self.name),
                           request=op.live_request(v, now), takeover=op.shown_takeover(v, now))

    def drone_ops(self, drone: str, now: float) -> DroneOps:
        """Drone ``drone`` as this GS tells the fleet's viewer (``zdrone.core.opspicture``) at ``now``."""
        v = self.views[drone]
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
            holds=self.holds_authority(v), takeover=v.operator.shown_takeover(v, now),
            request=None if req is None else OpsRequest(req.requester, req.to, req.epoch, round(now - req.since, 2),
                                                        req.timeout),
            attest=v.attest)

    def commands_sent(self, drone: str) -> int:
        """Commanding frames sent to ``drone``, all epochs."""
        return sum(self.views[drone].commands_sent.values())

    def describe(self, drone: str, now: float) -> str | None:
        """One line for the operator's console (``view_line``), None while there is no link."""
        v = self.views[drone]
        return None if v.link is None else view_line(self.name, drone, v, now)

    def _input(self, now: float) -> None:
        """An input came: the periodic work looks at what it changed at once (``get_timer``)."""
        if self._input_at is None or now < self._input_at:
            self._input_at = now

    # ------------------------------------------------------------------ sending
    def _new_link(self, view: DroneView, key: LinkKey, now: float) -> SecureLink:
        return SecureLink(key=key, role="gs", tx_keyexpr=kx.up(view.name, self.name),
                          rx_keyexpr=kx.down(view.name, self.name), peer_sysid=view.sysid, now=now,
                          cipher=self.opts.cipher)

    def send_frame(self, drone: "str | DroneView", frame: bytes) -> list[Action]:
        """Seal one MAVLink frame for the drone (nothing without a link). A frame that commands the
        vehicle goes out only while we command the drone (``holds_authority``): from the moment a
        release of ours went out, or we learned that we no longer own it, it is not sent (counted as
        ``command_not_sent``), whichever part of the GS made it; each one sent is counted per epoch."""
        view = self._view(drone)
        if view.link is None:
            return []
        if read_header(frame).commanding:
            if not self.holds_authority(view):
                self.counters["command_not_sent"] += 1
                return []
            view.commands_sent[view.epoch] += 1  # every commanding frame, to check none is lost
        return [Put(view.name, view.link.seal(frame))]

    def send_msg(self, drone: "str | DroneView", msg: Any) -> list[Action]:
        return self.send_frame(drone, self.codec.encode(msg))

    def send_control(self, drone: "str | DroneView", msg: wire.Control) -> list[Action]:
        view = self._view(drone)
        if view.link is None:
            return []
        return [Put(view.name, view.link.seal_control(msg))]

    def request_control(self, view: DroneView, now: float) -> list[Action]:
        """Ask the drone for authority (an operator's request): honoured in its failsafe if our link is
        proven, else passed to the authority. Sent at most once a second."""
        if view.link is None or view.stale or view.owner == self.name and view.ha_state is not HaState.FAILSAFE:
            return []
        if not _due(view.last_take_control, now, 1.0):
            return []
        view.last_take_control = now
        return [Emit(rec.ControlRequested(drone=view.name, state=view.ha_state)),
                *self.send_control(view, wire.HandoverRequest(self.name, view.epoch))]

    def _silent_authority(self, view: DroneView, now: float) -> bool:
        """We hold authority, yet the drone has said nothing for ``SILENT_REPAIR_S``."""
        return (view.link is not None and view.owner == self.name and view.ha_state is not HaState.FAILSAFE
                and view.link.tbm.since_last(now) > SILENT_REPAIR_S and self.fleet.is_authorized(view.name, self.name))

    def holds_authority(self, drone: "str | DroneView") -> bool:
        """We command the drone: we own it (``gs.ownership.owns``), no release of ours stands in its
        epoch, and the fleet in force still authorizes us for it (a revision that revoked us takes
        the drone away: the drone drops our link at once)."""
        view = self._view(drone)
        return (owns(view, self.name) and not view.handover.released_in(view.epoch)
                and self.fleet.is_authorized(view.name, self.name))

    def _mark_stale(self, view: DroneView, now: float) -> None:
        """The drone was silent for ``STALE_VIEW_S`` (once heard): whatever we think of the authority
        waits for its next status."""
        link = view.link
        if (not view.stale and link is not None and link.tbm.last_seen is not None
                and link.tbm.since_last(now) > STALE_VIEW_S):
            view.stale = True
            self.counters["authority_view_stale"] += 1

    def _heartbeat(self, view: DroneView) -> list[Action]:
        return self.send_msg(view, mav.MAVLink_heartbeat_message(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0,
                                                                 mav.MAV_STATE_ACTIVE, 3))

    def _command(self, view: DroneView, command: int, *params: float) -> list[Action]:
        p = list(params) + [0.0] * (7 - len(params))
        return self.send_msg(view, mav.MAVLink_command_long_message(view.sysid, 1, command, 0, *p))

    # -------------------------------------------------------------------- time
    def get_timer(self) -> float:
        """When ``handle_timer`` must next be called if no input comes (see the module docstring)."""
        due = min(self._hb_due, self._due)
        return due if self._input_at is None else min(due, self._input_at)

    def _deadlines(self, view: DroneView, now: float) -> Iterator[float | None]:
        """When the periodic work for ``view``'s drone may next do something without an input: each
        sub-machine's deadline and each re-send's. Early is harmless (the work finds nothing due);
        late is not, so every rule of ``handle_timer`` that reads the time has its moment here."""
        linking = _linking(view)
        if view.link is None:
            yield linking.deadline(now, sharing=False)
            yield linking.pair_retry_due(now, RETRY_S) if self.opts.pair else None
            return
        silence = view.link.tbm.since_last(now)
        if view.owner == self.name and view.ha_state is not HaState.FAILSAFE:  # re-pairing a silent drone
            yield now + SILENT_REPAIR_S - silence
            yield now + SILENT_FAST_S - silence
            yield linking.pair_retry_due(now, SILENT_RETRY_S if silence <= SILENT_FAST_S else SILENT_SLOW_RETRY_S)
        if linking.rekey_pending:
            yield linking.pair_retry_due(now, RETRY_S)
        if not view.stale and view.link.tbm.last_seen is not None:
            yield view.link.tbm.last_seen + STALE_VIEW_S
        yield linking.deadline(now, sharing=view.owner == self.name and not view.stale)
        if self._flies(view):
            yield view.mission.deadline(now, view)
        yield view.operator.deadline(now)
        ho = view.handover
        if ho.epoch == view.epoch:
            yield ho.failed_at + HANDOVER_RETRY_S
            yield ho.sent + RELEASE_RESEND_S
        if view.hold is not None and view.hold.epoch == view.epoch:
            yield from view.hold.deadlines()
        for g in linking.shares:
            refused = linking.live_refused(g)
            yield None if refused is None else refused + KEY_COMING_S
        if self.opts.take_control and view.ha_state is HaState.FAILSAFE and view.last_take_control is not None:
            yield view.last_take_control + 1.0
        if self.opts.command_rate > 0 and view.last_command is not None:
            yield view.last_command + 1.0 / self.opts.command_rate

    def _next_due(self, now: float) -> float:
        later = [d for view in self.views.values() for d in self._deadlines(view, now) if d is not None and d > now]
        return min(later) + DEADLINE_SLACK_S if later else float("inf")

    def handle_timer(self, now: float, wall: float | None = None) -> list[Action]:
        """The GS's periodic work at ``now`` (``wall``: the time of day, for key-sharing stamps):
        whatever is due is done, whenever it is called."""
        self._input_at = None
        out: list[Action] = []
        for view in self.views.values():
            stamp = now if wall is None else wall
            if view.link is None and self.opts.pair:
                out += self._try_pair(view, now, stamp)
            elif self._silent_authority(view, now):  # a restarted companion waits for its owner to re-pair
                assert view.link is not None
                fast = view.link.tbm.since_last(now) <= SILENT_FAST_S
                retry = SILENT_RETRY_S if fast else SILENT_SLOW_RETRY_S
                out += self._try_pair(view, now, stamp, retry=retry, timeout=retry)
            elif view.link is not None and _linking(view).rekey_pending:  # our rotated key's pairing, again
                out += self._try_pair(view, now, stamp)
            if view.link is None:
                continue
            self._mark_stale(view, now)
            if view.owner == self.name and not view.stale:
                out += _linking(view).share_keys(now, now if wall is None else wall, lambda m, v=view: self.send_control(v, m))
            out += self._flight(view, FlightTick(now))
            out += self._operator(view, view.operator.tick(view, now))
            if not view.operator.holds(view):  # an epoch our operator took stays ours until it lets go
                out += self._coordinate(view, now)
            if self.opts.take_control and view.ha_state is HaState.FAILSAFE:
                out += self.request_control(view, now)
            out += self._command_stream(view, now)
        if now >= self._hb_due:
            # the next a period after this one was due (after ``now``, a late pass stretched the period)
            period = 1.0 / self.opts.heartbeat_hz
            nxt = self._hb_due + period
            self._hb_due = nxt if nxt > now else now + period
            for view in self.views.values():
                out += self._heartbeat(view)
                if self.opts.paper_heartbeat:
                    self._sm_seq += 1
                    out += self.send_control(view, wire.SmHeartbeat(self._sm_seq))
        self._due = self._next_due(now)
        return out

    # ------------------------------------------------------------------ linking
    def _try_pair(self, view: DroneView, now: float, stamp: float, retry: float = RETRY_S,
                  timeout: float = PAIR_TIMEOUT) -> list[Action]:
        """Pair (``gs.linking``) unless an exchange is open or the last try was less than ``retry`` ago."""
        out, _ = _linking(view).on_pair(PairDue(now, stamp, retry, timeout))
        return out

    def on_pair_reply(self, drone: str, ok: bytes | None, err: bytes | None, now: float) -> list[Action]:
        """One reply to our pairing query (``ok`` payload, or the drone's error text)."""
        self._input(now)
        view = self.views.get(drone)
        if view is None:
            self.counters["pair_reply_late"] += 1
            return []
        out, paired = _linking(view).on_pair(Reply(now, ok, err))
        if paired is None:
            return out
        # a rotated key's pairing is no restart; a hybrid re-pairing is one only if the drone lost our key
        again = view.link is not None and not (paired.fresh and (paired.rotated or paired.kept))
        if again and paired.kept:
            # the drone still holds our key: its silence was the radio (out of coverage), not a
            # restart; switching to a key it cannot confirm now would cut us off later
            self.counters["pair_not_needed"] += 1
            return [Emit(rec.PairNotNeeded(drone=drone))]
        # our own fresh key, proven by the drone's message 2: live at once; the drone takes it when our
        # first frame under it arrives (a heartbeat now); the old one stays readable a while
        link = self._new_link(view, paired.key, now)
        link.hybrid = paired.hybrid
        view.slot.install(link, now)
        view.link = view.slot.live
        view.switching = paired.fresh  # the old key stays readable until the drone speaks under the new one
        if again:  # the drone may have restarted with no key but ours: share the others' keys again
            _linking(view).keys_lost(now)
        how = " under our new key" if paired.fresh else ""
        return [Emit(rec.GsPaired(drone=drone, again=again)), ToOperator(f"zdrone gs {self.name}: paired with {drone}{how}"),
                *self._heartbeat(view)]

    def adopt_identity(self, identity: Identity, now: float, wall: float) -> list[Action]:
        """Our static key was rotated: key sharing answers under ``identity`` from now on, and every
        drone we hold a link with is re-paired under it at once, as a fresh pairing (``Linking.rekey``;
        tried again every ``RETRY_S`` until one is proven), make-before-break: the live link serves
        until the drone's reply gives the new key, and the old one stays readable while the drone
        switches to it. It is no restart of the drone: the keys it holds for other GSs stand."""
        self._input(now)
        self.identity = identity
        self.key_owner.adopt(identity)
        out: list[Action] = []
        for view in self.views.values():
            _linking(view).rekey(identity, linked=view.link is not None)
            if view.link is not None:
                out += self._try_pair(view, now, wall, retry=0.0)
        return out

    def on_linkkey_query(self, drone: str, payload: bytes, now: float, secret: bytes,
                         wall: float | None = None) -> tuple[QueryAnswer, list[Action]]:
        """Answer one key-sharing query for link (``drone``, us); ``secret`` is fresh randomness
        (``gs.linking.KeyOwner``). The secret handed out never touches the live link: it is a
        candidate until the drone speaks under it (one per asker: the newest replaces an older one)."""
        self._input(now)
        view = self.views.get(drone)
        live = view is not None and view.link is not None and view.link.tbm.state(now) is not LinkState.LOST
        answer, logs, asker = self.key_owner.answer(drone, payload, now, secret, wall, serves=view is not None, live=live)
        if asker is not None:
            assert view is not None
            candidate = self._new_link(view, LinkKey.from_secret(drone, self.name, secret), now)
            candidate.hybrid = is_hybrid(payload)
            view.slot.offer(candidate, now, f"linkkey:{asker}", LINKKEY_CANDIDATE_TTL)
        return answer, logs

    def on_linkkey_reply(self, drone: str, gs: str, ok: bytes | None, err: bytes | None, now: float) -> list[Action]:
        """One reply from ``gs`` to our key-sharing query about ``drone``."""
        self._input(now)
        view = self.views.get(drone)
        if view is None:
            self.counters["linkkey_reply:unknown_drone"] += 1
            return []
        return _linking(view).on_share_reply(gs, ok, err, now)

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
        """One sealed envelope from ``drone``: one message, or a batch of the drone's pass (each
        message taken in order, as if it had come on its own)."""
        self._input(now)
        view = self.views.get(drone)
        if view is None:
            self.counters["down:unknown_drone"] += 1
            return []
        if view.link is None and not view.slot.candidates:
            self.counters["no_link"] += 1
            return []
        self._mark_stale(view, now)  # before the frame counts: a long silence ends here
        if view.switching and view.slot.previous is not None:
            view.slot.previous_until = max(view.slot.previous_until, now + PREVIOUS_GRACE)
        res, promoted = view.slot.open(data, now)
        if view.switching and view.link is not None and view.link.opened:
            view.switching = False  # the drone speaks under our new key: the old one's grace runs out
        if isinstance(res, Dropped):
            return []
        self.traffic.heard(data, res)
        out: list[Action] = []
        if promoted is not None:
            view.link = view.slot.live
            out.append(Emit(rec.GsLinkConfirmed(drone=drone, how=promoted.origin, replaced=promoted.replaced)))
            log.info("link to %s: key confirmed by the drone (%s)", drone, promoted.origin)
        for item in res.items():
            out += self._on_message(view, item, now)
        return out

    def _on_message(self, view: DroneView, res: Opened, now: float) -> list[Action]:
        """One authentic message of the drone: a control message, or a MAVLink frame."""
        self._inputs += 1
        drone = view.name
        if res.control is not None:
            return self._on_control(view, res.control, now)
        out: list[Action] = [FrameUp(drone, res.plaintext)]
        if res.header is None or res.header.msgid not in USED_MSGIDS:
            return out  # a full decode costs ~19 µs: only for what the station uses
        msg = self.codec.decode(res.plaintext)
        if msg is None:
            return out
        t = msg.get_type()
        if t != "HEARTBEAT" or msg.get_srcComponent() == 1:  # the vehicle's heartbeat: its autopilot's
            for change in view.on_message(msg, now):  # the vehicle's report (``VehicleReport``)
                if isinstance(change, PositionReported):
                    view.position_input = self._inputs
                elif isinstance(change, AutopilotHeard):
                    out.append(Emit(rec.AutopilotFound(drone=drone, autopilot=change.autopilot,
                                                       mav_type=change.mav_type)))
                elif isinstance(change, TextHeard):
                    out.append(Emit(rec.VehicleText(drone=drone, text=change.text, severity=change.severity)))
        if t == "PARAM_VALUE":
            name = msg.param_id.rstrip("\x00") if isinstance(msg.param_id, str) else str(msg.param_id)
            out += self._flight(view, FlightParam(now, name, float(msg.param_value)))
        elif t in ("MISSION_CURRENT", "MISSION_ITEM_REACHED"):
            out += self._progress(view, msg.seq, t == "MISSION_ITEM_REACHED")
        out += view.mission.on_message(msg, now, self.sysid, lambda m: self.send_msg(view, m))
        if t == "COMMAND_ACK" and msg.target_system == self.sysid and msg.command == mav.MAV_CMD_DO_SET_MODE:
            self.on_mode_ack(view, msg.result == mav.MAV_RESULT_ACCEPTED, now)
        if t == "COMMAND_ACK" and msg.target_system == self.sysid:
            out += self._flight(view, FlightAck(now, msg.command, msg.result == mav.MAV_RESULT_ACCEPTED, msg.result))
        return out

    def _on_control(self, view: DroneView, msg: wire.Control, now: float) -> list[Action]:
        out: list[Action] = []
        if isinstance(msg, wire.AuthorityStatus):
            state = msg.state  # an enum on the wire: an unknown state does not even decode
            changed = (msg.owner, msg.epoch, state, msg.pending_to) != (view.owner, view.epoch, view.ha_state, view.pending_to)
            was_mine = view.owner == self.name and not view.stale
            if msg.owner == self.name and (not was_mine or msg.epoch != view.epoch):
                view.ours_from_input = self._inputs  # a position heard before this does not decide a release
            view.owner, view.epoch, view.ha_state, view.pending_to = msg.owner, msg.epoch, state, msg.pending_to
            view.stale = False  # the drone's own word: our view is current again
            _linking(view).drone_links = set(msg.linked)
            view.takeover, view.takeover_to = msg.takeover, msg.takeover_to
            if msg.fc_signed is not None and msg.fc_signed != view.fc_signed:
                view.fc_signed = msg.fc_signed
                out.append(Emit(rec.FcSigningHeard(drone=view.name, signed=msg.fc_signed)))
            roles = MODE_ROLES.get(view.autopilot or "")
            if (changed and msg.owner == self.name and not was_mine and roles is not None and view.armed
                    and self._mode(view) == roles["hold"] and view.landed_state == mav.MAV_LANDED_STATE_IN_AIR):
                # e.g. its owner held it for a hand-over to us and fell silent before it resumed: nobody
                # else will move it now
                out.append(ToOperator(f"zdrone gs {self.name}: {view.name} is ours and holds in the air "
                               f"({roles['hold']}): resume its mission or bring it home"))
            if msg.audit is not None:
                out.append(Checkpoint(view.name, msg.audit))
            if msg.attest is not None:  # passed on to the fleet's viewer, which checks it (``drone_ops``)
                view.attest = msg.attest
            if changed:
                out.append(Emit(rec.AuthorityStatus(drone=view.name, owner=msg.owner, epoch=msg.epoch, state=msg.state,
                                                   pending_to=msg.pending_to)))
            ho = self._ho(view)  # of the epoch the drone reports
            if was_mine and msg.owner == self.name and ho.released:
                if state is HaState.HANDOVER_PENDING:
                    ho.handle(Confirmed(now))
                elif state is HaState.LINKED and ho.phase is HandoverPhase.CONFIRMED:
                    out += self._handover_failed(view, "release timed out", now)  # authority stayed here
        elif isinstance(msg, wire.KeyGrantAck):
            out += _linking(view).on_grant_ack(msg.gs, msg.grant_id, now)
        elif isinstance(msg, wire.Reject):
            log.warning("drone %s rejected %s: %s", view.name, msg.what, msg.reason)
            out.append(Emit(rec.Rejected(drone=view.name, what=msg.what, reason=msg.reason)))
            if msg.what == "release" and view.owner == self.name and self._ho(view).released:
                if msg.reason.startswith((RELEASE_NOT_AUTHORITY, RELEASE_STALE_EPOCH)):
                    # the drone holds another GS its authority now (our release's recipient took it): no
                    # failure to retry, and no command of ours until its status says who holds it
                    view.stale = True
                    self.counters["release_after_authority_moved"] += 1
                else:
                    out += self._handover_failed(view, f"release refused: {msg.reason}", now)
        elif isinstance(msg, wire.OperatorRequest):
            out += self._operator(view, view.operator.on_request(view, msg, now))
        elif isinstance(msg, wire.FailsafeNotice):
            view.ha_state = HaState.FAILSAFE  # nobody holds authority until a GS takes control back
            log.warning("drone %s failsafe: %s (%s)", view.name, msg.action, msg.reason)
            out.append(Emit(rec.FailsafeNoticed(drone=view.name, action=msg.action, reason=msg.reason)))
        else:
            self.counters[f"control_ignored:{type(msg).__name__}"] += 1
        return out

    # ---------------------------------------------------------- operator control
    def operator_command(self, drone: "str | DroneView", req: OperatorControlRequest, now: float, app: str = "",
                         app_sysid: int | None = None) -> tuple[Answer, list[Action]]:
        """An application's MAV_CMD_REQUEST_OPERATOR_CONTROL (``gs.opcontrol``): the answer it gets at once.
        ``app`` names the application (its key, or ``unsigned:<peer>``); ``app_sysid`` is its own sysid,
        which the gateway never shows it as another GCS's (``sysid_as_seen_by``): p4 is read the same way."""
        self._input(now)
        view = self._view(drone)
        named = self._gs_named(req.sysid, app_sysid)
        answer, step = view.operator.command(view, req, now, app=app, named=named)
        return answer, self._operator(view, step)

    def _gs_named(self, p4: int, app_sysid: int | None) -> str | None:
        """The fleet GS whose sysid, as application ``app_sysid`` is shown it, is ``p4`` (None: none)."""
        for name in self.fleet.ground_stations():
            sysid = self.fleet.nodes[name].sysid
            if (sysid if app_sysid is None else sysid_as_seen_by(sysid, app_sysid)) == p4:
                return name
        return None

    def _operator(self, view: DroneView, step: Step) -> list[Action]:
        out: list[Action] = [Emit(record) for record in step.logs]
        out += [ToOperator(text) for text in step.say]
        for msg in step.send:
            out += self.send_control(view, msg)
        return out

    def _handover_failed(self, view: DroneView, reason: str, now: float, rtl: bool | None = None) -> list[Action]:
        """The hand-over cannot happen now: authority stays here and the hand-over is tried again
        every ``HANDOVER_RETRY_S`` while the vehicle is in the overlap (a target that comes back takes
        it). If the vehicle is leaving our coverage, it comes home (RTL, once per epoch) rather than
        flying out of it into a failsafe; flying into our coverage, it flies on."""
        ho = self._ho(view)
        first = ho.failures == 0
        ho.handle(Failed(now, reason))
        self.counters["handover_failed"] += 1
        rtl = not ho.rtl_done and (self._leaving(view) if rtl is None else rtl)
        if not rtl and not first:
            return []  # a retry that failed again: counted, not logged
        action = "RTL" if rtl else "retry"
        log.warning("hand-over of %s failed (%s): authority stays here; %s", view.name, reason,
                    "commanding RTL" if rtl else f"trying again every {HANDOVER_RETRY_S:g} s")
        out: list[Action] = [Emit(rec.HandoverFailed(drone=view.name, epoch=view.epoch, action=action, reason=reason)),
                             ToOperator(f"zdrone gs {self.name}: hand-over of {view.name} failed ({reason}); "
                                 + ("commanding RTL" if rtl else "trying again"))]
        if rtl:
            ho.rtl_done = True
            out += self._command(view, mav.MAV_CMD_NAV_RETURN_TO_LAUNCH)
        return out

    def _ho(self, view: DroneView) -> Handover:
        """Our release of ``view``'s drone, in the drone's current epoch (``gs.handover``)."""
        return view.handover.for_epoch(view.epoch)

    def _leaving(self, view: DroneView) -> bool:
        """The vehicle is moving out of our coverage: farther from our centre than at the release (no
        release made, or no position: assume it is)."""
        first = self._ho(view).first_distance
        if self.coverage is None or view.position is None or first is None:
            return True
        here = GeoPoint(view.position.lat, view.position.lon)
        return distance_m(self.coverage.centre, here) > first + LEAVING_M

    # ----------------------------------------------------------------- flying
    def _flies(self, view: DroneView) -> bool:
        """The mission machine takes events: we fly one, hold authority, and no key grant is pending."""
        return self.opts.mission is not None and self.holds_authority(view) and not _linking(view).grants_pending

    def _flight(self, view: DroneView, ev: FlightEvent) -> list[Action]:
        if not self._flies(view):
            return []
        return view.mission.handle(ev, view, lambda m: self.send_msg(view, m))

    def _coordinate(self, view: DroneView, now: float) -> list[Action]:
        """Release authority toward the GS whose coverage the drone is flying into."""
        if view.owner != self.name or view.stale or view.position is None or self.coverage is None:
            return []
        if view.position_input <= view.ours_from_input:
            self.counters["release_waits_position"] += 1  # the position predates our authority: it may be old
            return []
        ho = self._ho(view)
        if ho.retry_waits(now, HANDOVER_RETRY_S):
            return []  # failed a moment ago: the retry waits
        if ho.resend_waits(now, RELEASE_RESEND_S):
            return []  # released: wait for the drone (re-send only if it never confirmed)
        here = GeoPoint(view.position.lat, view.position.lon)
        if not self.coverage.contains(here):
            return []
        mine = distance_m(self.coverage.centre, here)
        for g in self.fleet.nodes[view.name].authorized_gs:
            other = self.fleet.nodes[g]
            if g == self.name or other.coverage is None:
                continue
            circle = other.coverage.circle()
            if circle.contains(here) and distance_m(circle.centre, here) + self.opts.hysteresis_m < mine:
                linking = _linking(view)
                if g not in linking.drone_links and not linking.granted(g):  # the drone holds no key for g
                    held = self._hold_for_key(view, g, mine, now)
                    if held is not None:
                        return held
                    sharing = linking.asking(g) or linking.granting(g)
                    no_hold = view.hold is None or view.hold.epoch != view.epoch
                    if sharing and no_hold and mine < KEY_WAIT_RADIUS * self.coverage.radius_m:
                        self.counters["handover_waiting_key"] += 1  # g's key is on its way: not yet
                        return []
                    return self._handover_failed(view, f"the drone has no link to {g}", now)
                resuming = self._resume(view, g, now)
                if resuming is not None:
                    return resuming  # the release waits for the mission mode
                out: list[Action] = []
                if not ho.released:  # sent for the first time (not again)
                    out.append(Emit(rec.HandoverRelease(drone=view.name, to=g, epoch=view.epoch, position=[here.lat, here.lon])))
                ho.handle(ReleaseSent(now, g, mine))
                return out + self.send_control(view, wire.HandoverRelease(g, view.epoch))
        return []

    def _key_coming(self, view: DroneView, g: str, now: float) -> bool:
        """``g``'s key for the drone is known to be coming (see ``KEY_COMING_S``, ``gs.keyhold``)."""
        linking = _linking(view)
        if linking.granting(g):
            return True
        refused, restarted = linking.live_refused(g), linking.lost_key_at
        return (linking.asking(g) and refused is not None and now - refused < KEY_COMING_S
                and restarted is not None and now - restarted < RESTART_EVIDENCE_S)

    def _mode(self, view: DroneView) -> str:
        return mode_name(view.autopilot, view.custom_mode)

    def _hold_modes(self, view: DroneView) -> tuple[str, str, dict[str, tuple[float, float, float]]] | None:
        """(mission mode, hold mode, their DO_SET_MODE params) if the vehicle flies its mission now."""
        roles = MODE_ROLES.get(view.autopilot or "")
        if roles is None or not view.armed or self._mode(view) != roles["mission"]:
            return None
        params = {m: set_mode_params(view.autopilot, m) for m in (roles["mission"], roles["hold"])}
        if any(v is None for v in params.values()):
            return None
        return roles["mission"], roles["hold"], params  # type: ignore[return-value]

    def on_mode_ack(self, view: DroneView, accepted: bool, now: float) -> None:
        """A COMMAND_ACK of DO_SET_MODE from the vehicle: confirms the hold's current mode change."""
        if view.hold is not None:
            view.hold.handle(ModeAck(now, accepted))

    def _hold_step(self, view: DroneView, hold: KeyHold, step: HoldStep | None, now: float) -> list[Action] | None:
        """Carry out a step of the hold: its record, its mode command, its end (a failed hand-over)."""
        if hold.stands:
            self._ho(view).rtl_done = True  # a mode someone else chose stands: no RTL of ours over it
        if step is None:
            return None
        out: list[Action] = [] if step.log is None else [Emit(step.log)]
        if step.send is not None:
            out += self._command(view, mav.MAV_CMD_DO_SET_MODE, *step.send)
        if step.over is not None:
            out += self._handover_failed(view, f"the drone has no link to {hold.to} ({step.over})", now, rtl=step.rtl)
        return out

    def _hold_for_key(self, view: DroneView, g: str, mine: float, now: float) -> list[Action] | None:
        """Due to release toward ``g`` but its key is still missing on the drone: hold the vehicle (if
        the key is known to be coming and the vehicle flies its mission; once per epoch), keep holding,
        or end the hold (``gs.keyhold``). None: no hold of ours (the caller waits up to
        ``KEY_WAIT_RADIUS`` for a key still asked for, else the hand-over has failed)."""
        hold = view.hold
        if hold is not None and hold.epoch == view.epoch:
            far = mine >= KEY_WAIT_RADIUS * self.coverage.radius_m  # type: ignore[union-attr]
            return self._hold_step(view, hold, hold.handle(KeyMissing(now, self._mode(view), far)), now)
        modes = self._hold_modes(view) if self._key_coming(view, g, now) else None
        if modes is None:
            return None
        mission, hold_mode, params = modes
        view.hold, step = KeyHold.start(view.name, view.epoch, g, now, hold_mode, mission, params, self.counters)
        out = self._hold_step(view, view.hold, step, now)
        assert out is not None
        return [out[0], ToOperator(f"zdrone gs {self.name}: holding {view.name} in the overlap until {g}'s key is there"),
                *out[1:]]

    def _resume(self, view: DroneView, g: str, now: float) -> list[Action] | None:
        """Before releasing toward ``g``: a mission we hold for ``g``'s key goes on first (the release
        waits until the vehicle confirms its mission mode). None: release now."""
        hold = view.hold
        if hold is None or hold.epoch != view.epoch:
            return None
        return self._hold_step(view, hold, hold.handle(KeyThere(now, self._mode(view), g)), now)

    def _command_stream(self, view: DroneView, now: float) -> list[Action]:
        if self.opts.command_rate <= 0 or not self.holds_authority(view) or not view.armed:
            return []
        if not _due(view.last_command, now, 1.0 / self.opts.command_rate):
            return []
        view.last_command = now
        return self._command(view, mav.MAV_CMD_REQUEST_MESSAGE, mav.MAVLINK_MSG_ID_HOME_POSITION)

    def _progress(self, view: DroneView, seq: int, reached: bool) -> list[Action]:
        """The mission's progress (MISSION_CURRENT moving on, MISSION_ITEM_REACHED), logged with where
        the vehicle is and whether it is on the ground: what a delivery is judged by."""
        if not reached and seq == view.mission_seq:
            return []
        if not reached:
            view.mission_seq = seq
        p = view.fix.position
        position = None if p is None else (round(p.lat, 7), round(p.lon, 7), round(p.alt, 2))
        return [Emit(rec.MissionProgress(drone=view.name, seq=seq, reached=reached, landed_state=view.landed_state,
                                        position=position))]

    # ------------------------------------------------------------------ status
    def report(self, now: float) -> dict[str, Any]:
        """The core's part of the GS's status record."""
        out = {}
        for d, v in self.views.items():
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


def view_line(gs: str, drone: str, v: DroneView, now: float) -> str:
    """One drone as this GS sees it: how old its last report is and whether this GS holds its
    authority. A drone not heard for the TBM's DEGRADED threshold is shown as STALE with the age of
    what is shown (its authority, position, state are as of then, not now), never as a live line."""
    assert v.link is not None
    age = v.link.tbm.since_last(now)
    state = v.link.tbm.state(now)
    mine = "this GS" if v.owner == gs else "not this GS"
    authority = f"authority {v.owner} (epoch {v.epoch}, {v.ha_state.value if v.ha_state else 'unknown'}), {mine}"
    pos = (f"{v.position.lat:.6f},{v.position.lon:.6f} alt {v.position.alt:5.1f} m" if v.position
           else f"position unknown ({v.fix.unknown_because})")
    vehicle = f"{'ARMED' if v.armed else 'disarmed'} {mode_name(v.autopilot, v.custom_mode)} | mission item {v.mission_seq}"
    link = f"link rx {v.link.opened} tx {v.link.sent} drops {sum(v.link.drops.values())}"
    if v.link.tbm.last_seen is None:
        return f"gs {gs} | {drone}: nothing heard yet ({age:.1f} s since the link was made) | {link}"
    if state is LinkState.OK:
        return f"gs {gs} | {drone}: report {age:.1f} s old | {authority} | {pos} | {vehicle} | {link}"
    since = "may have moved since" if v.owner == gs else "may have changed"
    return (f"gs {gs} | {drone}: STALE, last report {age:.1f} s ago (link {state.value}): as of then {authority} "
            f"(it {since}) | last position {pos} | was {vehicle} | {link}")
