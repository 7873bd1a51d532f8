"""Everything a ground station does for one drone, sans-IO: its ``DroneSession``.

Theory of operation
-------------------
``gs.core.StationCore`` keeps what is the station's own (its keys, the fleet in force, the heartbeat,
answering other GSs' key-sharing queries) and hands each input about a drone to that drone's session.
A session is the GS's view of the drone (``gs.droneview.DroneView``: what the vehicle and the drone's
authority status last said) plus the sub-machines that act on it, each a table:

* **Linking** (``gs.linking.Linking``): pairing (with ``pair``, and again when the drone falls silent
  while we hold its authority: a restarted companion; and after a rotation of our key) and, as the
  authority, key sharing for every other authorized GS without a link on the drone (one
  ``KeyShareAsk`` at a time; its authentic reply becomes a ``KEY_GRANT`` re-sent until the drone
  acknowledges it). A reply proving the drone's static key installs the new link (our own fresh key:
  live at once, the old one readable for a grace period) and a HEARTBEAT goes out under it, the proof
  the drone waits for. Links that follow the drone (what we prepare, when we pair, a link the drone
  closed): ``gs.linkfollow``.
* **Hand-over** (``gs.handover.Handover``, the release in the drone's epoch, and ``release_due`` here,
  the decision): while we hold authority and the vehicle is inside our and another authorized GS's
  coverage, nearer to the other's centre by the hysteresis, we release authority (``HANDOVER_RELEASE``,
  re-sent until the drone confirms), judged from a position reported after the status that made the
  drone ours (an older one may be as old as the standby stream's interval: a new owner would hand the
  drone straight back). A release that timed out or was refused is tried again while the vehicle is
  in the overlap; a vehicle leaving our coverage meanwhile is commanded RTL. Toward a GS whose key the
  drone does not hold yet, the release waits for it; while the key is known to be coming the vehicle
  is held where it is and its mission resumed just before the release (``gs.keyhold.KeyHold``).
* **Mission** (``gs.mission.Mission``): takes events only while we command the drone and no key grant
  of ours is pending.
* **Operator control** (``gs.opcontrol.OperatorControl``): requests, consents and takeover, bound to
  fleet identities. An epoch our operator took stays the operator's: no automatic release in it.

Every input (a sealed envelope's message, a pairing or key-sharing reply, an operator's command)
ends in the session's effects from its facts before and after (``_effects``: the drone became ours,
its autopilot link's signing changed) and marks the session due at once
(``due``); ``tick(now)`` then runs the time rules above, and afterwards ``deadline(now)`` says when a
rule may next do something without an input: each sub-machine's deadline and each re-send's, taken in
one place. The station's timer is the earliest of its sessions' (``StationCore.get_timer``): a
session with nothing due is never looked at, and nothing due waits for a poll.
"""

from __future__ import annotations

import itertools
import logging
from typing import Iterator, NamedTuple

from pymavlink.dialects.v20 import common as mav

from zdrone.core import records as rec
from zdrone.core import wire
from zdrone.core.authority import RELEASE_NOT_AUTHORITY, RELEASE_STALE_EPOCH
from zdrone.core.authority import State as HaState
from zdrone.core.envelope import Dropped, Opened, SecureLink
from zdrone.core.fleet import Fleet
from zdrone.core.geometry import GeoPoint, distance_m
from zdrone.core.keys import Identity, LinkKey
from zdrone.core.kk import is_hybrid
from zdrone.core.linkslot import PREVIOUS_GRACE
from zdrone.core.mavcontrol import OperatorControlRequest
from zdrone.core.mavlink import read_header
from zdrone.fleet import keyexprs
from zdrone.vehicle.modes import MODE_ROLES, mode_name, set_mode_params
from zdrone.vehicle.report import AutopilotHeard, PositionReported, TextHeard

from gs.actions import Action, Checkpoint, Emit, FrameUp, Put, ToOperator
from gs.context import (DEADLINE_SLACK_S, HANDOVER_RETRY_S, KEY_COMING_S, KEY_WAIT_RADIUS, LEAVING_M,
                        RELEASE_RESEND_S, RESTART_EVIDENCE_S, SILENT_FAST_S, SILENT_PAIR_TIMEOUT_S, SILENT_REPAIR_S,
                        SILENT_RETRY_S, SILENT_SLOW_RETRY_S, STALE_VIEW_S, USED_MSGIDS, StationContext)
from gs.droneview import DroneView
from gs.handover import Confirmed, Failed, Handover, HandoverPhase, ReleaseSent
from gs.keyhold import HoldStep, KeyHold, KeyMissing, KeyThere, ModeAck
from gs.linkfollow import PAIR_ON_DEMAND_S, WIPE_SILENT_S, LinkFollow
from gs.linking import PAIR_TIMEOUT, RETRY_S, UNANSWERED_RETRY_S, Context, Linking, PairDue, Reply

from gs.mission import FlightAck, FlightEvent, FlightParam, FlightTick, Mission
from gs.opcontrol import Answer, OperatorControl, Step
from gs.ownership import owns

log = logging.getLogger(__name__)

class Facts(NamedTuple):
    """What a session's effects are computed from, before and after an input (``_effects``)."""

    ours: bool  # the drone's own current word names us its authority (and our view is not stale)
    word: tuple[str | None, int, HaState | None]  # what that word says: owner, epoch, state
    fc_signed: bool | None


def _due(last: float | None, now: float, period: float) -> bool:
    return last is None or now - last >= period


class DroneSession(LinkFollow, DroneView):
    """Everything this GS does for one drone (see the module docstring)."""

    def __init__(self, st: StationContext, name: str, sysid: int, grant_ids: "itertools.count[int]",
                 upload_spread_s: float = 0.0, takeoff_spread_s: float = 0.0) -> None:
        DroneView.__init__(self, name, sysid, handover=Handover(name))
        self.st = st
        self.operator = OperatorControl(st.name, allow_takeover=st.opts.allow_takeover)
        plan = (st.opts.missions or {}).get(name, st.opts.mission)
        self.mission = Mission(st.name, name, sysid, plan, seed=st.opts.seed, counters=st.counters,
                               upload_spread_s=upload_spread_s, takeoff_spread_s=takeoff_spread_s)
        self.check_route()
        self.linking = Linking(Context(st.name, name, st.identity, st.fleet, st.counters, grant_ids, st.asks_out))
        self.inputs = 0  # authentic messages taken: orders a position report against an authority change
        self.due = 0.0  # when ``tick`` must next run (at once: the first pairing)
        self.closed_by_drone = False  # the drone closed our link (links that follow it): no pairing of our own
        self.pair_on_demand_until: float | None = None  # our operator asked for control with no link: pair until then

    # ------------------------------------------------------------------ inputs
    def _facts(self) -> Facts:
        return Facts(self.owner == self.st.name and not self.stale, (self.owner, self.epoch, self.ha_state), self.fc_signed)

    def _input(self, now: float) -> None:
        """An input came at ``now``: the session's rules look at it at once (``tick``)."""
        self.due = min(self.due, now)

    def _effects(self, before: Facts, now: float) -> list[Action]:
        """What follows from the change an input made, and the session is due at once."""
        self._input(now)
        after = self._facts()
        if after == before:
            return []
        out: list[Action] = []
        if after.fc_signed != before.fc_signed and after.fc_signed is not None:
            out.append(Emit(rec.FcSigningHeard(drone=self.name, signed=after.fc_signed)))
        if after.ours and not before.ours and after.word != before.word:
            out += self._ours_in_hold()  # a new word made it ours (not the same word again after a silence)
        return out

    def _ours_in_hold(self) -> list[Action]:
        roles = MODE_ROLES.get(self.autopilot or "")
        if (roles is not None and self.armed and self._mode() == roles["hold"]
                and self.landed_state == mav.MAV_LANDED_STATE_IN_AIR):
            # e.g. its owner held it for a hand-over to us and fell silent before it resumed: nobody
            # else will move it now
            return [ToOperator(f"zdrone gs {self.st.name}: {self.name} is ours and holds in the air "
                               f"({roles['hold']}): resume its mission or bring it home")]
        return []

    def on_envelope(self, data: bytes, now: float) -> list[Action]:
        """One sealed envelope from the drone: one message, or a batch of the drone's pass (each
        message taken in order, as if it had come on its own)."""
        if self.link is None and not self.slot.candidates:
            self.st.counters["no_link"] += 1
            return []
        self._mark_stale(now)  # before the frame counts: a long silence ends here
        before = self._facts()
        if self.switching and self.slot.previous is not None:
            self.slot.previous_until = max(self.slot.previous_until, now + PREVIOUS_GRACE)
        res, promoted = self.slot.open(data, now)
        if self.switching and self.link is not None and self.link.opened:
            self.switching = False  # the drone speaks under our new key: the old one's grace runs out
        if isinstance(res, Dropped):
            return self._effects(before, now)
        self.st.traffic.heard(data, res)
        out: list[Action] = []
        if promoted is not None:
            self.link = self.slot.live
            out.append(Emit(rec.GsLinkConfirmed(drone=self.name, how=promoted.origin, replaced=promoted.replaced)))
            log.info("link to %s: key confirmed by the drone (%s)", self.name, promoted.origin)
            self._repair_hybrid()  # a classical key (shared before the revision) confirmed after it
        for item in res.items():
            out += self._on_message(item, now)
        return out + self._effects(before, now)

    def on_pair_reply(self, ok: bytes | None, err: bytes | None, now: float) -> list[Action]:
        """One reply to our pairing query (``ok`` payload, or the drone's error text)."""
        self._input(now)
        out, paired = self.linking.on_pair(Reply(now, ok, err))
        if paired is None:
            return out
        # a rotated key's pairing is no restart; a hybrid re-pairing is one only if the drone lost our key
        again = self.link is not None and not (paired.fresh and (paired.rotated or paired.kept))
        if again and paired.kept:
            # the drone holds our key: no restart (out of coverage, or late); a key it cannot confirm now
            # would cut us off later, and pairing again within SILENT_REPAIR_S would load a late drone
            self.st.counters["pair_not_needed"] += 1
            self.kept_key_at = now
            return [Emit(rec.PairNotNeeded(drone=self.name))]
        # our own fresh key, proven by the drone's message 2: live at once; the drone takes it when our
        # first frame under it arrives (a heartbeat now); the old one stays readable a while
        link = self.new_link(paired.key, now)
        link.hybrid = paired.hybrid
        self.slot.install(link, now)
        self.link = self.slot.live
        self.switching = paired.fresh  # the old key stays readable until the drone speaks under the new one
        if again:  # the drone may have restarted with no key but ours: share the others' keys again
            self.linking.keys_lost(now)
        how = " under our new key" if paired.fresh else ""
        return [Emit(rec.GsPaired(drone=self.name, again=again)),
                ToOperator(f"zdrone gs {self.st.name}: paired with {self.name}{how}"), *self.heartbeat()]

    def on_pair_done(self, m1: bytes, now: float) -> list[Action]:
        """Our pairing query carrying ``m1`` ended (``Linking.pair_unanswered``)."""
        self._input(now)
        self.linking.pair_unanswered(m1, now)
        return []

    def on_linkkey_reply(self, gs: str, ok: bytes | None, err: bytes | None, now: float) -> list[Action]:
        """One reply from ``gs`` to our key-sharing query about this drone."""
        self._input(now)
        return self.linking.on_share_reply(gs, ok, err, now)

    def offer_candidate(self, asker: str, secret: bytes, payload: bytes, now: float, ttl: float) -> None:
        """The key we handed ``asker`` (``gs.linking.KeyOwner``) is a candidate of our link until the
        drone speaks under it; the live link is never touched."""
        self._input(now)
        candidate = self.new_link(LinkKey.from_secret(self.name, self.st.name, secret), now)
        candidate.hybrid = is_hybrid(payload)
        self.slot.offer(candidate, now, f"linkkey:{asker}", ttl)

    def operator_command(self, req: OperatorControlRequest, now: float, app: str,
                         named: str | None) -> tuple[Answer, list[Action]]:
        """An application's MAV_CMD_REQUEST_OPERATOR_CONTROL (``gs.opcontrol``): the answer it gets at once."""
        before = self._facts()
        if self.link is None and req.request:  # pair on demand (``PAIR_ON_DEMAND_S``): the app asks again
            self.pair_on_demand_until = now + PAIR_ON_DEMAND_S
        answer, step = self.operator.command(self, req, now, app=app, named=named)
        return answer, self._operator(step) + self._effects(before, now)

    def rekey(self, identity: Identity, now: float, wall: float) -> list[Action]:
        """Our static key was rotated: pair again under ``identity`` at once if we hold a link
        (``Linking.rekey``; make-before-break)."""
        self._input(now)
        self.linking.rekey(identity, linked=self.link is not None)
        return self._try_pair(now, wall, retry=0.0) if self.link is not None else []

    def revised(self, fleet: Fleet) -> None:
        """A fleet revision took effect. With the hybrid pairing required, a link on a classical key is
        paired again (hybrid, make-before-break): the drone takes key grants only over hybrid links."""
        self.linking.ctx.fleet = fleet
        self.due = 0.0
        self.linking.drop_classical_shares()  # a classical key not yet granted is never granted now
        # (a classical candidate of ours stays: the drone may have installed it before the revision; once
        # the drone speaks under it, it is paired again hybrid at once, make-before-break: ``_repair_hybrid``)
        self._repair_hybrid()
        self.check_route()  # a GS revoked or moved: the route is checked again against the fleet in force

    def _repair_hybrid(self) -> None:
        """With the hybrid pairing required, a live link on a classical key (whenever it became live)
        is paired again, hybrid, make-before-break (``Linking.rekey``)."""
        if (self.st.fleet.pairing_pq and self.link is not None and not self.link.hybrid
                and not self.linking.rekey_pending):
            self.linking.rekey(self.st.identity, linked=True, rotated=False)
            self.st.counters["repair_hybrid"] += 1

    # ----------------------------------------------------------------- sending
    def new_link(self, key: LinkKey, now: float) -> SecureLink:
        return SecureLink(key=key, role="gs", tx_keyexpr=keyexprs.up(self.name, self.st.name),
                          rx_keyexpr=keyexprs.down(self.name, self.st.name), peer_sysid=self.sysid, now=now,
                          cipher=self.st.opts.cipher)

    def send_frame(self, frame: bytes) -> list[Action]:
        """Seal one MAVLink frame for the drone (nothing without a link). A frame that commands the
        vehicle goes out only while we command the drone (``holds_authority``): from the moment a
        release of ours went out, or we learned that we no longer own it, it is not sent (counted as
        ``command_not_sent``), whichever part of the GS made it; each one sent is counted per epoch."""
        if self.link is None:
            return []
        if read_header(frame).commanding:
            if not self.holds_authority():
                self.st.counters["command_not_sent"] += 1
                return []
            self.commands_sent[self.epoch] += 1  # every commanding frame, to check none is lost
        return [Put(self.name, self.link.seal(frame))]

    def send_msg(self, msg: object) -> list[Action]:
        return self.send_frame(self.st.codec.encode(msg))

    def send_control(self, msg: wire.Control) -> list[Action]:
        if self.link is None:
            return []
        return [Put(self.name, self.link.seal_control(msg))]

    def check_route(self) -> None:
        """The mission's route against the fleet in force (``Mission.check_route``), refused before upload."""
        self.mission.check_route(self.st.fleet, self.name)

    def heartbeat(self) -> list[Action]:
        return self.send_msg(mav.MAVLink_heartbeat_message(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0,
                                                           mav.MAV_STATE_ACTIVE, 3))

    def _command(self, command: int, *params: float) -> list[Action]:
        p = list(params) + [0.0] * (7 - len(params))
        return self.send_msg(mav.MAVLink_command_long_message(self.sysid, 1, command, 0, *p))

    def request_control(self, now: float) -> list[Action]:
        """Ask the drone for authority (an operator's request): honoured in its failsafe if our link is
        proven, else passed to the authority. Sent at most once a second."""
        if self.link is None or self.stale or self.owner == self.st.name and self.ha_state is not HaState.FAILSAFE:
            return []
        if not _due(self.last_take_control, now, 1.0):
            return []
        self.last_take_control = now
        return [Emit(rec.ControlRequested(drone=self.name, state=self.ha_state)),
                *self.send_control(wire.HandoverRequest(self.st.name, self.epoch))]

    # ---------------------------------------------------------------- authority
    def holds_authority(self) -> bool:
        """We command the drone: we own it (``gs.ownership.owns``), no release of ours stands in its
        epoch, and the fleet in force still authorizes us for it (a revision that revoked us takes
        the drone away: the drone drops our link at once)."""
        return (owns(self, self.st.name) and not self.handover.released_in(self.epoch)
                and self.st.fleet.is_authorized(self.name, self.st.name))

    def _silent_authority(self, now: float) -> bool:
        """We hold authority, yet the drone has said nothing for ``SILENT_REPAIR_S``."""
        return (self.link is not None and self.owner == self.st.name and self.ha_state is not HaState.FAILSAFE
                and self._silence(now) > SILENT_REPAIR_S
                and self.st.fleet.is_authorized(self.name, self.st.name))

    def _mark_stale(self, now: float) -> None:
        """The drone was silent for ``STALE_VIEW_S`` (once heard): whatever we think of the authority
        waits for its next status."""
        link = self.link
        if not self.stale and link is not None and link.tbm.last_seen is not None and link.tbm.since_last(now) > STALE_VIEW_S:
            self.stale = True
            self.st.counters["authority_view_stale"] += 1

    # -------------------------------------------------------------------- time
    def tick(self, now: float, wall: float) -> list[Action]:
        """The session's time rules at ``now`` (``wall``: the time of day, for key-sharing stamps):
        whatever is due is done, whenever it is called; then the next deadline (``deadline``)."""
        before = self._facts()
        out: list[Action] = []
        if self.link is None and self._pairs(now):
            out += self._try_pair(now, wall, unanswered=UNANSWERED_RETRY_S)
        elif self._silent_authority(now):  # a restarted companion waits for its owner to re-pair
            assert self.link is not None
            fast = self._silence(now) <= SILENT_FAST_S
            retry = SILENT_RETRY_S if fast else SILENT_SLOW_RETRY_S
            out += self._try_pair(now, wall, retry=retry, timeout=max(retry, SILENT_PAIR_TIMEOUT_S))
        elif self.link is not None and self.linking.rekey_pending:  # our rotated key's pairing, again
            out += self._try_pair(now, wall)
        elif self._left_behind(now):
            out += self._wipe_link("silent: the drone left us behind")
        if self.link is not None:
            self._mark_stale(now)
            if self.owner == self.st.name and not self.stale:
                out += self.linking.share_keys(now, wall, self.send_control, self.links_wanted())
            out += self.flight(FlightTick(now))
            out += self._operator(self.operator.tick(self, now))
            if not self.operator.holds(self):  # an epoch our operator took stays ours until it lets go
                out += self.release_due(now)
            if self.st.opts.take_control and self.ha_state is HaState.FAILSAFE:
                out += self.request_control(now)
            out += self._command_stream(now)
        out += self._effects(before, now)
        self.due = self.deadline(now)
        return out

    def deadline(self, now: float) -> float:
        """When ``tick`` may next do something without an input (``inf``: nothing)."""
        later = [d for d in self._deadlines(now) if d is not None and d > now]
        return min(later) + DEADLINE_SLACK_S if later else float("inf")

    def _deadlines(self, now: float) -> Iterator[float | None]:
        """Each sub-machine's deadline and each re-send's: every rule of ``tick`` that reads the time
        has its moment here. Early is harmless (the rule finds nothing due); late is not."""
        linking = self.linking
        if self.link is None:
            yield linking.deadline(now, sharing=False)
            yield linking.pair_retry_due(now, RETRY_S, UNANSWERED_RETRY_S) if self._pairs(now) else None
            yield self.pair_on_demand_until
            return
        silence = self._silence(now)
        if self.owner == self.st.name and self.ha_state is not HaState.FAILSAFE:  # re-pairing a silent drone
            yield now + SILENT_REPAIR_S - silence
            yield now + SILENT_FAST_S - silence
            yield linking.pair_retry_due(now, SILENT_RETRY_S if silence <= SILENT_FAST_S else SILENT_SLOW_RETRY_S)
        if linking.rekey_pending:
            yield linking.pair_retry_due(now, RETRY_S)
        if self.st.fleet.links_follow(self.name) and self.link.tbm.last_seen is not None:
            yield self.link.tbm.last_seen + WIPE_SILENT_S
        if not self.stale and self.link.tbm.last_seen is not None:
            yield self.link.tbm.last_seen + STALE_VIEW_S
        yield linking.deadline(now, sharing=self.owner == self.st.name and not self.stale)
        if self.flies():
            yield self.mission.deadline(now, self)
        yield self.operator.deadline(now)
        release = self.handover
        if release.epoch == self.epoch:
            yield release.failed_at + HANDOVER_RETRY_S
            yield release.sent + RELEASE_RESEND_S
        if self.hold is not None and self.hold.epoch == self.epoch:
            yield from self.hold.deadlines()
        for g in linking.shares:
            refused = linking.live_refused(g)
            yield None if refused is None else refused + KEY_COMING_S
            restarted = linking.lost_key_at
            yield None if restarted is None else restarted + RESTART_EVIDENCE_S
        if self.st.opts.take_control and self.ha_state is HaState.FAILSAFE and self.last_take_control is not None:
            yield self.last_take_control + 1.0
        if self.st.opts.command_rate > 0 and self.last_command is not None:
            yield self.last_command + 1.0 / self.st.opts.command_rate

    # ------------------------------------------------------------------ linking
    def _try_pair(self, now: float, stamp: float, retry: float = RETRY_S, timeout: float = PAIR_TIMEOUT,
                  unanswered: float | None = None) -> list[Action]:
        """Pair (``gs.linking``) unless an exchange is open or the last try was less than ``retry`` ago
        (``unanswered``, if the last query ended with no reply)."""
        out, _ = self.linking.on_pair(PairDue(now, stamp, retry, timeout, unanswered))
        return out

    # ---------------------------------------------------------------- receiving
    def _on_message(self, res: Opened, now: float) -> list[Action]:
        """One authentic message of the drone: a control message, or a MAVLink frame."""
        self.inputs += 1
        if res.control is not None:
            return self._on_control(res.control, now)
        out: list[Action] = [FrameUp(self.name, res.plaintext)]
        if res.header is None or res.header.msgid not in USED_MSGIDS:
            return out  # a full decode costs ~19 µs: only for what the station uses
        msg = self.st.codec.decode(res.plaintext)
        if msg is None:
            return out
        t = msg.get_type()
        if t != "HEARTBEAT" or msg.get_srcComponent() == 1:  # the vehicle's heartbeat: its autopilot's
            for change in self.on_message(msg, now):  # the vehicle's report (``VehicleReport``)
                if isinstance(change, PositionReported):
                    self.position_input = self.inputs
                elif isinstance(change, AutopilotHeard):
                    out.append(Emit(rec.AutopilotFound(drone=self.name, autopilot=change.autopilot,
                                                       mav_type=change.mav_type)))
                elif isinstance(change, TextHeard):
                    out.append(Emit(rec.VehicleText(drone=self.name, text=change.text, severity=change.severity)))
        if t == "PARAM_VALUE":
            name = msg.param_id.rstrip("\x00") if isinstance(msg.param_id, str) else str(msg.param_id)
            out += self.flight(FlightParam(now, name, float(msg.param_value)))
        elif t in ("MISSION_CURRENT", "MISSION_ITEM_REACHED"):
            out += self._progress(msg.seq, t == "MISSION_ITEM_REACHED")
        out += self.mission.on_message(msg, now, self.st.sysid, self.send_msg)
        if t == "COMMAND_ACK" and msg.target_system == self.st.sysid and msg.command == mav.MAV_CMD_DO_SET_MODE:
            self.on_mode_ack(msg.result == mav.MAV_RESULT_ACCEPTED, now)
        if t == "COMMAND_ACK" and msg.target_system == self.st.sysid:
            out += self.flight(FlightAck(now, msg.command, msg.result == mav.MAV_RESULT_ACCEPTED, msg.result))
        return out

    def on_control(self, msg: wire.Control, now: float) -> list[Action]:
        """One authentic control message of the drone, taken on its own (with its effects)."""
        before = self._facts()
        return self._on_control(msg, now) + self._effects(before, now)

    def _on_control(self, msg: wire.Control, now: float) -> list[Action]:
        if isinstance(msg, wire.AuthorityStatus):
            return self._on_status(msg, now)
        if isinstance(msg, wire.KeyGrantAck):
            return self.linking.on_grant_ack(msg.gs, msg.grant_id, now)
        if isinstance(msg, wire.Reject):
            return self._on_reject(msg, now)
        if isinstance(msg, wire.OperatorRequest):
            return self._operator(self.operator.on_request(self, msg, now))
        if isinstance(msg, wire.LinkClosed):
            return self._on_link_closed(msg, now)
        if isinstance(msg, wire.FailsafeNotice):
            self.ha_state = HaState.FAILSAFE  # nobody holds authority until a GS takes control back
            log.warning("drone %s failsafe: %s (%s)", self.name, msg.action, msg.reason)
            return [Emit(rec.FailsafeNoticed(drone=self.name, action=msg.action, reason=msg.reason))]
        self.st.counters[f"control_ignored:{type(msg).__name__}"] += 1
        return []

    def _on_status(self, msg: wire.AuthorityStatus, now: float) -> list[Action]:
        """The drone's own word on its authority: our view is current again."""
        out: list[Action] = []
        state = msg.state  # an enum on the wire: an unknown state does not even decode
        changed = (msg.owner, msg.epoch, state, msg.pending_to) != (self.owner, self.epoch, self.ha_state, self.pending_to)
        was_ours = self.owner == self.st.name and not self.stale
        if msg.owner == self.st.name and (not was_ours or msg.epoch != self.epoch):
            self.ours_from_input = self.inputs  # a position heard before this does not decide a release
        self.owner, self.epoch, self.ha_state, self.pending_to = msg.owner, msg.epoch, state, msg.pending_to
        self.stale = False
        self.linking.drone_listed(frozenset(msg.linked), now)
        self.takeover, self.takeover_to = msg.takeover, msg.takeover_to
        if msg.fc_signed is not None:
            self.fc_signed = msg.fc_signed
        if msg.audit is not None:
            out.append(Checkpoint(self.name, msg.audit))
        if msg.attest is not None:  # passed on to the fleet's viewer, which checks it (``drone_ops``)
            self.attest = msg.attest
        if changed:
            out.append(Emit(rec.AuthorityStatus(drone=self.name, owner=msg.owner, epoch=msg.epoch, state=msg.state,
                                               pending_to=msg.pending_to)))
        release = self.release()  # of the epoch the drone reports
        if was_ours and msg.owner == self.st.name and release.released:
            if state is HaState.HANDOVER_PENDING:
                release.handle(Confirmed(now))
            elif state is HaState.LINKED and release.phase is HandoverPhase.CONFIRMED:
                out += self._handover_failed("release timed out", now)  # authority stayed here
        return out

    def _on_reject(self, msg: wire.Reject, now: float) -> list[Action]:
        log.warning("drone %s rejected %s: %s", self.name, msg.what, msg.reason)
        out: list[Action] = [Emit(rec.Rejected(drone=self.name, what=msg.what, reason=msg.reason))]
        if msg.what == "release" and self.owner == self.st.name and self.release().released:
            if msg.reason.startswith((RELEASE_NOT_AUTHORITY, RELEASE_STALE_EPOCH)):
                # the drone holds another GS its authority now (our release's recipient took it): no
                # failure to retry, and no command of ours until its status says who holds it
                self.stale = True
                self.st.counters["release_after_authority_moved"] += 1
            else:
                out += self._handover_failed(f"release refused: {msg.reason}", now)
        return out

    def _operator(self, step: Step) -> list[Action]:
        out: list[Action] = [Emit(record) for record in step.logs]
        out += [ToOperator(text) for text in step.say]
        for msg in step.send:
            out += self.send_control(msg)
        return out

    # ----------------------------------------------------------------- hand-over
    def release(self) -> Handover:
        """Our release of the drone, in its current epoch (``gs.handover``)."""
        return self.handover.for_epoch(self.epoch)

    def release_due(self, now: float) -> list[Action]:
        """The GS's hand-over decision: release authority toward the GS whose coverage the drone is
        flying into (see the module docstring); nothing while it is not due."""
        coverage = self.st.coverage
        if self.owner != self.st.name or self.stale or self.position is None or coverage is None:
            return []
        if self.position_input <= self.ours_from_input:
            self.st.counters["release_waits_position"] += 1  # the position predates our authority: it may be old
            return []
        release = self.release()
        if release.retry_waits(now, HANDOVER_RETRY_S):
            return []  # failed a moment ago: the retry waits
        if release.resend_waits(now, RELEASE_RESEND_S):
            return []  # released: wait for the drone (re-send only if it never confirmed)
        here = GeoPoint(self.position.lat, self.position.lon)
        if not coverage.contains(here):
            return []
        ours = distance_m(coverage.centre, here)
        for g in self.st.fleet.nodes[self.name].authorized_gs:
            other = self.st.fleet.nodes[g]
            if g == self.st.name or other.coverage is None:
                continue
            circle = other.coverage.circle()
            if circle.contains(here) and distance_m(circle.centre, here) + self.st.opts.hysteresis_m < ours:
                return self._release_toward(g, here, ours, now)
        return []

    def _release_toward(self, g: str, here: GeoPoint, ours: float, now: float) -> list[Action]:
        """Release toward ``g``, once the drone holds ``g``'s key and a held mission has resumed."""
        linking = self.linking
        if g not in linking.drone_links and not linking.granted(g):  # the drone holds no key for g
            held = self._hold_for_key(g, ours, now)
            if held is not None:
                return held
            sharing = linking.asking(g) or linking.granting(g)
            no_hold = self.hold is None or self.hold.epoch != self.epoch
            if sharing and no_hold and ours < KEY_WAIT_RADIUS * self.st.coverage.radius_m:  # type: ignore[union-attr]
                self.st.counters["handover_waiting_key"] += 1  # g's key is on its way: not yet
                return []
            return self._handover_failed(f"the drone has no link to {g}", now)
        resuming = self._resume(g, now)
        if resuming is not None:
            return resuming  # the release waits for the mission mode
        release = self.release()
        out: list[Action] = []
        if not release.released:  # sent for the first time (not again)
            out.append(Emit(rec.HandoverRelease(drone=self.name, to=g, epoch=self.epoch, position=[here.lat, here.lon])))
        release.handle(ReleaseSent(now, g, ours))
        return out + self.send_control(wire.HandoverRelease(g, self.epoch))

    def _handover_failed(self, reason: str, now: float, rtl: bool | None = None) -> list[Action]:
        """The hand-over cannot happen now: authority stays here and the hand-over is tried again
        every ``HANDOVER_RETRY_S`` while the vehicle is in the overlap (a target that comes back takes
        it). If the vehicle is leaving our coverage, it comes home (RTL, once per epoch) rather than
        flying out of it into a failsafe; flying into our coverage, it flies on."""
        release = self.release()
        first = release.failures == 0
        release.handle(Failed(now, reason))
        self.st.counters["handover_failed"] += 1
        rtl = not release.rtl_done and (self._leaving() if rtl is None else rtl)
        if not rtl and not first:
            return []  # a retry that failed again: counted, not logged
        action = "RTL" if rtl else "retry"
        log.warning("hand-over of %s failed (%s): authority stays here; %s", self.name, reason,
                    "commanding RTL" if rtl else f"trying again every {HANDOVER_RETRY_S:g} s")
        out: list[Action] = [Emit(rec.HandoverFailed(drone=self.name, epoch=self.epoch, action=action, reason=reason)),
                             ToOperator(f"zdrone gs {self.st.name}: hand-over of {self.name} failed ({reason}); "
                                        + ("commanding RTL" if rtl else "trying again"))]
        if rtl:
            release.rtl_done = True
            out += self._command(mav.MAV_CMD_NAV_RETURN_TO_LAUNCH)
        return out

    def _leaving(self) -> bool:
        """The vehicle is moving out of our coverage: farther from our centre than at the release (no
        release made, or no position: assume it is)."""
        first = self.release().first_distance
        coverage = self.st.coverage
        if coverage is None or self.position is None or first is None:
            return True
        here = GeoPoint(self.position.lat, self.position.lon)
        return distance_m(coverage.centre, here) > first + LEAVING_M

    def _key_coming(self, g: str, now: float) -> bool:
        """``g``'s key for the drone is known to be coming (see ``KEY_COMING_S``, ``gs.keyhold``)."""
        linking = self.linking
        if linking.granting(g):
            return True
        refused, restarted = linking.live_refused(g), linking.lost_key_at
        return (linking.asking(g) and refused is not None and now - refused < KEY_COMING_S
                and restarted is not None and now - restarted < RESTART_EVIDENCE_S)

    def _mode(self) -> str:
        return mode_name(self.autopilot, self.custom_mode)

    def _hold_modes(self) -> tuple[str, str, dict[str, tuple[float, float, float]]] | None:
        """(mission mode, hold mode, their DO_SET_MODE params) if the vehicle flies its mission now."""
        roles = MODE_ROLES.get(self.autopilot or "")
        if roles is None or not self.armed or self._mode() != roles["mission"]:
            return None
        params = {m: set_mode_params(self.autopilot, m) for m in (roles["mission"], roles["hold"])}
        if any(v is None for v in params.values()):
            return None
        return roles["mission"], roles["hold"], params  # type: ignore[return-value]

    def on_mode_ack(self, accepted: bool, now: float) -> None:
        """A COMMAND_ACK of DO_SET_MODE from the vehicle: confirms the hold's current mode change."""
        self._input(now)
        if self.hold is not None:
            self.hold.handle(ModeAck(now, accepted))

    def _hold_step(self, hold: KeyHold, step: HoldStep | None, now: float) -> list[Action] | None:
        """Carry out a step of the hold: its record, its mode command, its end (a failed hand-over)."""
        if hold.stands:
            self.release().rtl_done = True  # a mode someone else chose stands: no RTL of ours over it
        if step is None:
            return None
        out: list[Action] = [] if step.log is None else [Emit(step.log)]
        if step.send is not None:
            out += self._command(mav.MAV_CMD_DO_SET_MODE, *step.send)
        if step.over is not None:
            out += self._handover_failed(f"the drone has no link to {hold.to} ({step.over})", now, rtl=step.rtl)
        return out

    def _hold_for_key(self, g: str, ours: float, now: float) -> list[Action] | None:
        """Due to release toward ``g`` but its key is still missing on the drone: hold the vehicle (if
        the key is known to be coming and the vehicle flies its mission; once per epoch), keep holding,
        or end the hold (``gs.keyhold``). None: no hold of ours (the caller waits up to
        ``KEY_WAIT_RADIUS`` for a key still asked for, else the hand-over has failed)."""
        hold = self.hold
        if hold is not None and hold.epoch == self.epoch:
            far = ours >= KEY_WAIT_RADIUS * self.st.coverage.radius_m  # type: ignore[union-attr]
            return self._hold_step(hold, hold.handle(KeyMissing(now, self._mode(), far)), now)
        modes = self._hold_modes() if self._key_coming(g, now) else None
        if modes is None:
            return None
        mission, hold_mode, params = modes
        self.hold, step = KeyHold.start(self.name, self.epoch, g, now, hold_mode, mission, params, self.st.counters)
        out = self._hold_step(self.hold, step, now)
        assert out is not None
        return [out[0], ToOperator(f"zdrone gs {self.st.name}: holding {self.name} in the overlap until {g}'s key is there"),
                *out[1:]]

    def _resume(self, g: str, now: float) -> list[Action] | None:
        """Before releasing toward ``g``: a mission we hold for ``g``'s key goes on first (the release
        waits until the vehicle confirms its mission mode). None: release now."""
        hold = self.hold
        if hold is None or hold.epoch != self.epoch:
            return None
        return self._hold_step(hold, hold.handle(KeyThere(now, self._mode(), g)), now)

    # ------------------------------------------------------------------- flying
    def flies(self) -> bool:
        """The mission machine takes events: we fly one, hold authority, and no key grant is pending."""
        return self.mission.plan is not None and self.holds_authority() and not self.linking.grants_pending

    def flight(self, ev: FlightEvent) -> list[Action]:
        if not self.flies():
            return []
        return self.mission.handle(ev, self, self.send_msg)

    def _command_stream(self, now: float) -> list[Action]:
        if self.st.opts.command_rate <= 0 or not self.holds_authority() or not self.armed:
            return []
        if not _due(self.last_command, now, 1.0 / self.st.opts.command_rate):
            return []
        self.last_command = now
        return self._command(mav.MAV_CMD_REQUEST_MESSAGE, mav.MAVLINK_MSG_ID_HOME_POSITION)

    def _progress(self, seq: int, reached: bool) -> list[Action]:
        """The mission's progress (MISSION_CURRENT moving on, MISSION_ITEM_REACHED), logged with where
        the vehicle is and whether it is on the ground: what a delivery is judged by."""
        if not reached and seq == self.mission_seq:
            return []
        if not reached:
            self.mission_seq = seq
        p = self.fix.position
        position = None if p is None else (round(p.lat, 7), round(p.lon, 7), round(p.alt, 2))
        return [Emit(rec.MissionProgress(drone=self.name, seq=seq, reached=reached, landed_state=self.landed_state,
                                        position=position))]
