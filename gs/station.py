"""``zdrone gs``: a ground station node.

It pairs with a drone on the ground (Noise KK over ``zdrone/<drone>/pair/<gs>``), shares link keys
over the backhaul (Noise KK as query and reply on ``backhaul/<gs>/linkkey/<drone>``, see
``zdrone.core.keyshare``: the secret it hands out stays a *candidate* of its own link until the drone
proves it; as authority it asks the other authorized GSs and hands their keys to the drone as
KEY_GRANTs), sends a sealed
MAVLink HEARTBEAT at 2 Hz on every link (the drone's TBM liveness signal: no extra packets),
flies a mission (the reference mission or a QGroundControl ``.plan``) when it holds authority, and
coordinates hand-over: while it holds authority and the drone is inside its own and another
authorized GS's coverage, nearer to the other's centre, it releases authority to that GS. If a
hand-over it started fails, it commands RTL so the drone comes back into its coverage.

One thread runs the loop; Zenoh callbacks only queue what they receive. No call in the loop
blocks: pairing and key-sharing queries are asynchronous (their replies come back through the
inbox), and work for incoming key-sharing queries is bounded per turn and rate-limited per asker.
"""

from __future__ import annotations

import logging
import os
import queue
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Callable

import msgspec
import zenoh
from pymavlink.dialects.v20 import common as mav

from zdrone.core import wire
from zdrone.core.envelope import Dropped, SecureLink
from zdrone.core.fleet import ConfigError
from zdrone.core.geometry import GeoPoint, distance_m
from zdrone.core.keys import LinkKey
from zdrone.core.keyshare import KeyShareAsk, Refused, ShareRefusal, answer, decode_query
from zdrone.core.linkslot import LinkSlot, Promoted
from zdrone.core.ratelimit import RateLimiter
from zdrone.core.mavlink import FrameCodec, read_header
from zdrone.core.pairing import PairingFailed, PairingInitiator
from zdrone.fleetfiles import load_fleet, load_secret
from zdrone.net import keyexprs as kx
from zdrone.net.eventlog import EventLog
from zdrone.net.inbox import drain, reply_bytes
from zdrone.net.session import open_client, query_queue

from .planner import MissionUploader, PlannedItem

log = logging.getLogger(__name__)
#: Key-sharing handshakes answered per loop turn at most, and per asker per second.
LINKKEY_PER_TURN = 2
LINKKEY_RATE, LINKKEY_BURST = 1.0, 3.0
#: A secret handed out over the backhaul waits this long for the drone to prove it (the drone
#: first speaks under it when it reaches this GS's coverage).
LINKKEY_CANDIDATE_TTL = 900.0
PAIR_TIMEOUT = 3.0
GCS_COMPID = mav.MAV_COMP_ID_MISSIONPLANNER
USED_MSGIDS = frozenset({mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, mav.MAVLINK_MSG_ID_HEARTBEAT,
                         mav.MAVLINK_MSG_ID_EXTENDED_SYS_STATE, mav.MAVLINK_MSG_ID_MISSION_CURRENT,
                         mav.MAVLINK_MSG_ID_STATUSTEXT, mav.MAVLINK_MSG_ID_COMMAND_ACK,
                         mav.MAVLINK_MSG_ID_MISSION_REQUEST_INT, mav.MAVLINK_MSG_ID_MISSION_REQUEST,
                         mav.MAVLINK_MSG_ID_MISSION_ACK})


@dataclass(frozen=True, slots=True)
class StationOptions:
    gs: str
    fleet: str
    router: str
    drones: tuple[str, ...] = ()
    pair: bool = False
    mission: list[PlannedItem] | None = None
    heartbeat_hz: float = 2.0
    command_rate: float = 0.0
    hysteresis_m: float = 20.0
    events: str | None = None
    gcs: tuple[str, ...] = ()  # local MAVLink endpoints of the GCS gateway
    status_period: float = 1.0
    cipher: str = "zdrone"  # "plain" / "fernet" only for bench traffic
    paper_heartbeat: bool = False  # also send the paper's separate 2 Hz security heartbeat


@dataclass
class DroneView:
    """What this GS knows of one drone."""

    name: str
    sysid: int
    link: SecureLink | None = None  # the live link (``slot.live``)
    slot: LinkSlot = field(default_factory=LinkSlot)
    pairing: PairingInitiator | None = None
    pairing_deadline: float = 0.0
    asks: dict[str, KeyShareAsk] = field(default_factory=dict)  # other GS -> ask in flight
    position: GeoPoint | None = None
    armed: bool = False
    custom_mode: int = 0
    landed_state: int = 0
    mission_seq: int = -1
    owner: str | None = None
    epoch: int = 0
    ha_state: str = "unknown"
    pending_to: str | None = None
    drone_links: set[str] = field(default_factory=set)  # GSs the drone already holds keys for
    grants: dict[str, wire.KeyGrant] = field(default_factory=dict)  # gs -> grant not yet acknowledged
    granted: set[str] = field(default_factory=set)
    grant_sent: float = 0.0
    uploader: MissionUploader | None = None
    flight_stage: str = "idle"  # idle -> uploading -> arming -> starting -> flying
    stage_time: float = 0.0
    released_epoch: int = -1
    release_sent: float = 0.0
    release_confirmed: bool = False  # the drone reported HANDOVER_PENDING for our release
    handover_failed_epoch: int = -1
    commands_sent: Counter = field(default_factory=Counter)  # per epoch
    last_pair_try: float = -1e9
    last_share_try: float = -1e9


class GroundStation:
    """One ground station node."""

    def __init__(self, opts: StationOptions) -> None:
        self.opts = opts
        self.fleet = load_fleet(opts.fleet)
        node = self.fleet.nodes.get(opts.gs)
        if node is None or node.role != "gs":
            raise ConfigError(f"--id {opts.gs}: not a ground station of the fleet ({', '.join(self.fleet.ground_stations())})")
        self.name = opts.gs
        self.sysid = node.sysid
        self.coverage = node.coverage.circle() if node.coverage else None
        self.secret = load_secret(opts.fleet, opts.gs, self.fleet)
        drones = opts.drones or tuple(d for d in self.fleet.drones() if self.fleet.is_authorized(d, self.name))
        for d in drones:
            if d not in self.fleet.nodes or self.fleet.nodes[d].role != "drone":
                raise ConfigError(f"--drone {d}: not a drone of the fleet")
        self.views = {d: DroneView(d, self.fleet.nodes[d].sysid) for d in drones}
        self.codec = FrameCodec(self.sysid, GCS_COMPID)
        self.events = EventLog(opts.events, opts.gs)
        self.counters: Counter[str] = Counter()
        self.rx: queue.SimpleQueue[tuple[str, str, Any]] = queue.SimpleQueue()
        self._running = True
        self._grant_id = 0
        self._sm_seq = 0
        self.frame_listeners: list[Callable[[str, bytes], None]] = []  # e.g. the GCS gateway
        self.loop_hooks: list[Callable[[float], None]] = []  # called once per loop pass with ``now``
        self.status_sources: dict[str, Callable[[], dict[str, Any]]] = {}  # e.g. the gateway's stats
        self.linkkey_limiter = RateLimiter(LINKKEY_RATE, LINKKEY_BURST)
        self.session = open_client(opts.router, opts.gs, self.secret.router_password)
        self.sub = self.session.declare_subscriber(kx.down("*", self.name), self._on_sample)
        self.linkkey_q = self.session.declare_queryable(kx.linkkey_all(self.name), query_queue())

    # ------------------------------------------------------------------ plumbing
    def _on_sample(self, sample: zenoh.Sample) -> None:
        self.rx.put(("down", str(sample.key_expr).split("/")[1], sample.payload.to_bytes()))

    def _new_link(self, view: DroneView, key: LinkKey, now: float) -> SecureLink:
        return SecureLink(key=key, role="gs", tx_keyexpr=kx.up(view.name, self.name),
                          rx_keyexpr=kx.down(view.name, self.name), peer_sysid=view.sysid, now=now,
                          cipher=self.opts.cipher)

    def send_frame(self, view: DroneView, frame: bytes) -> None:
        """Seal and send one MAVLink frame to the drone (no-op without a link)."""
        if view.link is not None:
            if read_header(frame).commanding:
                view.commands_sent[view.epoch] += 1  # every commanding frame, to check none is lost
            self.session.put(kx.up(view.name, self.name), view.link.seal(frame),  # see DroneNode._publish
                             congestion_control=zenoh.CongestionControl.DROP)

    def send_msg(self, view: DroneView, msg: Any) -> None:
        self.send_frame(view, self.codec.encode(msg))

    def send_control(self, view: DroneView, msg: wire.Control) -> None:
        if view.link is not None:
            self.session.put(kx.up(view.name, self.name), view.link.seal_control(msg),
                             congestion_control=zenoh.CongestionControl.DROP)

    def holds_authority(self, view: DroneView) -> bool:
        return view.owner == self.name and view.released_epoch != view.epoch

    # ------------------------------------------------------------------ pairing
    def _try_pair(self, view: DroneView, now: float) -> None:
        """Send message 1 (asynchronous: the reply comes back through the inbox)."""
        if view.pairing is not None and now < view.pairing_deadline:
            return
        if now - view.last_pair_try < 2.0:
            return
        view.last_pair_try = now
        view.pairing = PairingInitiator(self.secret.identity, self.name, view.name, self.fleet.nodes[view.name].public_bytes)
        view.pairing_deadline = now + PAIR_TIMEOUT
        drone = view.name
        self.session.get(kx.pair(drone, self.name), lambda r: self.rx.put(("pair", drone, reply_bytes(r))),
                         payload=view.pairing.start(), timeout=PAIR_TIMEOUT,
                         consolidation=zenoh.ConsolidationMode.NONE)

    def _on_pair_reply(self, view: DroneView, reply: tuple[bytes | None, bytes | None], now: float) -> None:
        ok, err = reply
        ini = view.pairing
        if ini is None or now >= view.pairing_deadline:
            self.counters["pair_reply_late"] += 1
            return
        if ok is None:
            reason = (err or b"error").decode(errors="replace")[:200]
            self.events.write("pair_refused", drone=view.name, reason=reason)
            log.warning("pairing with %s refused: %s", view.name, reason)
            self.counters["pair_refused"] += 1
            return
        key = ini.finish(ok)
        if isinstance(key, PairingFailed):
            self.counters["pair_bad_reply"] += 1  # forged or stale: the genuine reply may still come
            self.events.write("pair_failed", drone=view.name, reason=key.reason)
            return
        view.pairing = None
        # our own fresh key, proven by the drone's message 2: live at once; the drone takes it once
        # our first frame under it arrives (we send a heartbeat now), the old one stays readable a while
        view.slot.install(self._new_link(view, key, now), now)
        view.link = view.slot.live
        self.events.write("paired", drone=view.name)
        print(f"zdrone gs {self.name}: paired with {view.name}", flush=True)
        self._heartbeat(view)

    # --------------------------------------------------------------- key sharing
    def _serve_linkkeys(self, now: float) -> None:
        """Answer key-sharing queries: refusals cost no crypto; ``LINKKEY_PER_TURN`` handshakes at most."""
        handshakes = 0
        while True:
            q = self.linkkey_q.try_recv()
            if q is None:
                return
            try:
                if handshakes >= LINKKEY_PER_TURN:
                    self.counters["linkkey_deferred"] += 1
                    continue
                handshakes += self._answer_linkkey(q, now)
            except zenoh.ZError as exc:
                self.counters["linkkey_reply_error"] += 1
                log.info("linkkey reply failed: %s", exc)
            finally:
                q.drop()

    def _refuse_linkkey(self, q: zenoh.Query, reason: ShareRefusal, drone: str, asker: str, detail: str = "") -> None:
        self.counters[f"linkkey_refused:{reason.value}"] += 1
        if self.counters[f"linkkey_refused:{reason.value}"] <= 5:
            self.events.write("linkkey_refused", drone=drone, asker=asker, reason=reason.value, detail=detail)
        if reason is not ShareRefusal.RATE_LIMITED:
            q.reply_err(reason.value.encode())

    def _answer_linkkey(self, q: zenoh.Query, now: float) -> int:
        """One key-sharing query; return 1 if a handshake was computed."""
        drone = kx.gs_of(q.key_expr)
        req = decode_query(q.payload.to_bytes() if q.payload else b"")
        if isinstance(req, Refused):
            self._refuse_linkkey(q, req.reason, drone, "?", req.detail)
            return 0
        asker = self.fleet.nodes.get(req.asker)
        if asker is None or asker.role != "gs" or req.asker == self.name:
            self._refuse_linkkey(q, ShareRefusal.UNKNOWN_ASKER, drone, req.asker)
            return 0
        if drone not in self.views or not self.fleet.is_authorized(drone, req.asker) or not self.fleet.is_authorized(drone, self.name):
            self._refuse_linkkey(q, ShareRefusal.UNAUTHORIZED, drone, req.asker)
            return 0
        if not self.linkkey_limiter.allow(req.asker, now):
            self._refuse_linkkey(q, ShareRefusal.RATE_LIMITED, drone, req.asker)
            return 0
        secret = os.urandom(32)
        reply = answer(self.secret.identity, self.name, drone, req.asker, asker.public_bytes, req.m1, secret)
        if isinstance(reply, Refused):  # claimed to be an authorized GS without its key
            self._refuse_linkkey(q, reply.reason, drone, req.asker, reply.detail)
            return 1
        view = self.views[drone]
        # Never touch the live link: the secret is a candidate until the drone speaks under it.
        candidate = self._new_link(view, LinkKey.from_secret(drone, self.name, secret), now)
        view.slot.offer(candidate, now, f"linkkey:{req.asker}", LINKKEY_CANDIDATE_TTL)
        q.reply(q.key_expr, reply)
        self.counters["linkkey_shared"] += 1
        self.events.write("linkkey_shared", drone=drone, asker=req.asker)
        log.info("link key for (%s, %s) shared with %s (pending the drone's proof)", drone, self.name, req.asker)
        return 1

    def _share_keys(self, view: DroneView, now: float) -> None:
        """As authority: fetch the other authorized GSs' link keys and grant them to the drone.

        Asynchronous: each ask is one query; its replies come back through the inbox."""
        others = [g for g in self.fleet.nodes[view.name].authorized_gs if g != self.name]
        for g in others:
            ask = view.asks.get(g)
            if ask is not None and not ask.expired(now):
                continue
            if ask is not None:
                del view.asks[g]
                self.counters["linkkey_no_answer"] += 1
            if g in view.drone_links or g in view.granted or g in view.grants or now - view.last_share_try < 2.0:
                continue
            view.last_share_try = now
            ask = KeyShareAsk(self.secret.identity, self.name, g, self.fleet.nodes[g].public_bytes, view.name, now)
            view.asks[g] = ask
            drone = view.name
            self.session.get(kx.linkkey(g, drone), lambda r, g=g: self.rx.put(("linkkey", drone, (g, reply_bytes(r)))),
                             payload=ask.payload, timeout=ask.deadline - now,
                             consolidation=zenoh.ConsolidationMode.NONE)
        if view.grants and now - view.grant_sent >= 1.0:
            view.grant_sent = now
            for grant in view.grants.values():
                self.send_control(view, grant)

    def _on_linkkey_reply(self, view: DroneView, g: str, reply: tuple[bytes | None, bytes | None], now: float) -> None:
        ok, err = reply
        ask = view.asks.get(g)
        if ok is None:
            self.counters["linkkey_reply_error"] += 1
            self.events.write("linkkey_error", drone=view.name, gs=g, reason=(err or b"").decode(errors="replace")[:120])
            return
        if ask is None:
            self.counters["linkkey_reply:not_waiting"] += 1
            return
        secret = ask.on_reply(ok, now)
        if isinstance(secret, Refused):
            self.counters[f"linkkey_reply:{secret.reason.value}"] += 1
            if self.counters[f"linkkey_reply:{secret.reason.value}"] <= 5:
                self.events.write("linkkey_bad_reply", drone=view.name, gs=g, reason=secret.reason.value)
            log.warning("key-sharing reply for %s from %s refused: %s", view.name, g, secret.reason.value)
            return
        del view.asks[g]
        self._grant_id += 1
        view.grants[g] = wire.KeyGrant(g, self.fleet.nodes[g].sysid, secret, self._grant_id)
        view.grant_sent = 0.0
        self.events.write("linkkey_received", drone=view.name, gs=g)

    # ----------------------------------------------------------------- receiving
    def _on_inbox(self, kind: str, drone: str, data: Any, now: float) -> None:
        view = self.views.get(drone)
        if view is None:
            self.counters[f"{kind}:unknown_drone"] += 1
            return
        if kind == "down":
            self._on_envelope(view, data, now)
        elif kind == "pair":
            self._on_pair_reply(view, data, now)
        elif kind == "linkkey":
            self._on_linkkey_reply(view, data[0], data[1], now)

    def _on_envelope(self, view: DroneView, data: bytes, now: float) -> None:
        drone = view.name
        if view.link is None and not view.slot.candidates:
            self.counters["no_link"] += 1
            return
        res, promoted = view.slot.open(data, now)
        if isinstance(res, Dropped):
            return
        if promoted is not None:
            view.link = view.slot.live
            self.events.write("link_confirmed", drone=drone, how=promoted.origin, replaced=promoted.replaced)
            log.info("link to %s: key confirmed by the drone (%s)", drone, promoted.origin)
        if res.control is not None:
            self._on_control(view, res.control, now)
            return
        for listener in self.frame_listeners:
            listener(drone, res.plaintext)
        if res.header is None or res.header.msgid not in USED_MSGIDS:
            return  # a full decode costs ~19 µs: only for what the station uses
        msg = self.codec.decode(res.plaintext)
        if msg is None:
            return
        t = msg.get_type()
        if t == "GLOBAL_POSITION_INT":
            view.position = GeoPoint(msg.lat / 1e7, msg.lon / 1e7, msg.relative_alt / 1000.0)
        elif t == "HEARTBEAT" and msg.get_srcComponent() == 1:
            view.armed = bool(msg.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)
            view.custom_mode = msg.custom_mode
        elif t == "EXTENDED_SYS_STATE":
            view.landed_state = msg.landed_state
        elif t == "MISSION_CURRENT":
            view.mission_seq = msg.seq
        elif t == "STATUSTEXT":
            self.events.write("vehicle_text", drone=drone, text=msg.text)
        if view.uploader is not None:
            for out in view.uploader.on_message(msg, now, self.sysid):
                self.send_msg(view, out)
        if t == "COMMAND_ACK" and msg.target_system == self.sysid:
            self._on_ack(view, msg, now)

    def _on_control(self, view: DroneView, msg: wire.Control, now: float) -> None:
        if isinstance(msg, wire.AuthorityStatus):
            changed = (msg.owner, msg.epoch, msg.state, msg.pending_to) != (view.owner, view.epoch, view.ha_state, view.pending_to)
            was_mine = view.owner == self.name
            view.owner, view.epoch, view.ha_state, view.pending_to = msg.owner, msg.epoch, msg.state, msg.pending_to
            view.drone_links = set(msg.linked)
            if changed:
                self.events.write("authority_status", drone=view.name, owner=msg.owner, epoch=msg.epoch,
                                  state=msg.state, pending_to=msg.pending_to)
            if was_mine and msg.owner == self.name and view.released_epoch == msg.epoch:
                if msg.state == "handover_pending":
                    view.release_confirmed = True
                elif msg.state == "linked" and view.release_confirmed and view.handover_failed_epoch != msg.epoch:
                    self._handover_failed(view, now)  # timed out or aborted: authority stayed here
        elif isinstance(msg, wire.KeyGrantAck):
            if msg.gs in view.grants and view.grants[msg.gs].grant_id == msg.grant_id:
                del view.grants[msg.gs]
                view.granted.add(msg.gs)
                self.events.write("key_granted", drone=view.name, gs=msg.gs)
        elif isinstance(msg, wire.Reject):
            self.events.write("rejected", drone=view.name, what=msg.what, reason=msg.reason)
            log.warning("drone %s rejected %s: %s", view.name, msg.what, msg.reason)
        elif isinstance(msg, wire.FailsafeNotice):
            self.events.write("failsafe_notice", drone=view.name, action=msg.action, reason=msg.reason)
            log.warning("drone %s failsafe: %s (%s)", view.name, msg.action, msg.reason)

    def _handover_failed(self, view: DroneView, now: float) -> None:
        view.handover_failed_epoch = view.epoch
        view.released_epoch = -1
        self.events.write("handover_failed", drone=view.name, epoch=view.epoch, action="RTL")
        log.warning("hand-over of %s failed: authority stays here; commanding RTL", view.name)
        self.send_msg(view, mav.MAVLink_command_long_message(view.sysid, 1, mav.MAV_CMD_NAV_RETURN_TO_LAUNCH, 0, 0, 0, 0, 0, 0, 0, 0))

    def _on_ack(self, view: DroneView, msg: Any, now: float) -> None:
        ok = msg.result == mav.MAV_RESULT_ACCEPTED
        if view.flight_stage == "arming" and msg.command == mav.MAV_CMD_COMPONENT_ARM_DISARM:
            view.flight_stage, view.stage_time = ("starting" if ok else "failed"), now
            if ok:
                self.send_msg(view, mav.MAVLink_command_long_message(view.sysid, 1, mav.MAV_CMD_MISSION_START, 0, 0, 0, 0, 0, 0, 0, 0))
        elif view.flight_stage == "starting" and msg.command == mav.MAV_CMD_MISSION_START:
            view.flight_stage, view.stage_time = ("flying" if ok else "failed"), now
            self.events.write("mission_started" if ok else "mission_start_failed", drone=view.name, result=msg.result)

    # ----------------------------------------------------------------- flying
    def _fly(self, view: DroneView, now: float) -> None:
        if self.opts.mission is None or not self.holds_authority(view) or view.grants:
            return
        if view.flight_stage == "idle":
            view.uploader = MissionUploader(self.opts.mission, target=(view.sysid, 1))
            for m in view.uploader.start(now):
                self.send_msg(view, m)
            view.flight_stage, view.stage_time = "uploading", now
            self.events.write("mission_upload", drone=view.name, items=len(self.opts.mission))
        elif view.flight_stage == "uploading" and view.uploader is not None:
            for m in view.uploader.tick(now):
                self.send_msg(view, m)
            if view.uploader.done:
                if view.uploader.accepted:
                    view.flight_stage, view.stage_time = "arming", now
                    self.send_msg(view, mav.MAVLink_command_long_message(view.sysid, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0))
                else:
                    view.flight_stage = "failed"
                    self.events.write("mission_upload_failed", drone=view.name, result=view.uploader.result)
        elif view.flight_stage in ("arming", "starting") and now - view.stage_time > 3.0:
            view.flight_stage = "idle"  # no answer: start over

    def _coordinate(self, view: DroneView, now: float) -> None:
        """Release authority toward the GS whose coverage the drone is flying into."""
        if view.owner != self.name or view.position is None or self.coverage is None:
            return
        if view.handover_failed_epoch == view.epoch:
            return
        if view.released_epoch == view.epoch and (view.release_confirmed or now - view.release_sent < 1.0):
            return  # released: wait for the drone (re-send only if it never confirmed)
        here = GeoPoint(view.position.lat, view.position.lon)
        if not self.coverage.contains(here):
            return
        mine = distance_m(self.coverage.centre, here)
        for g in self.fleet.nodes[view.name].authorized_gs:
            other = self.fleet.nodes[g]
            if g == self.name or other.coverage is None:
                continue
            circle = other.coverage.circle()
            if circle.contains(here) and distance_m(circle.centre, here) + self.opts.hysteresis_m < mine:
                if view.released_epoch != view.epoch:
                    view.release_confirmed = False
                    self.events.write("handover_release", drone=view.name, to=g, epoch=view.epoch, position=[here.lat, here.lon])
                view.released_epoch, view.release_sent = view.epoch, now
                self.send_control(view, wire.HandoverRelease(g, view.epoch))
                return

    def _command_stream(self, view: DroneView, now: float, last: dict[str, float]) -> None:
        if self.opts.command_rate <= 0 or not self.holds_authority(view) or not view.armed:
            return
        if now - last.get(view.name, 0.0) < 1.0 / self.opts.command_rate:
            return
        last[view.name] = now
        self.send_msg(view, mav.MAVLink_command_long_message(view.sysid, 1, mav.MAV_CMD_REQUEST_MESSAGE, 0,
                                                             mav.MAVLINK_MSG_ID_HOME_POSITION, 0, 0, 0, 0, 0, 0))

    # -------------------------------------------------------------------- loop
    def status(self) -> dict[str, Any]:
        out = {}
        for d, v in self.views.items():
            out[d] = {"linked": v.link is not None, "owner": v.owner, "epoch": v.epoch, "state": v.ha_state,
                      "stage": v.flight_stage, "position": [v.position.lat, v.position.lon, v.position.alt] if v.position else None,
                      "commands_sent": {str(k): c for k, c in v.commands_sent.items()},
                      "link": None if v.link is None else {"opened": v.link.opened, "sent": v.link.sent,
                                                             "dropped": {r.value: c for r, c in v.link.drops.items() if c}},
                      "key_candidates": len(v.slot.candidates),
                      "dropped_unlinked": {r.value: c for r, c in v.slot.unlinked.items() if c}}
        extra = {name: source() for name, source in self.status_sources.items()}
        return {"drones": out, "counters": dict(self.counters), **extra}

    def print_view(self) -> None:
        """The telemetry view: one line per linked drone on stdout."""
        from zdrone.vehicle.px4modes import mode_name

        for d, v in self.views.items():
            if v.link is None:
                continue
            pos = f"{v.position.lat:.6f},{v.position.lon:.6f} alt {v.position.alt:5.1f} m" if v.position else "position ?"
            print(f"gs {self.name} | {d}: authority {v.owner} (epoch {v.epoch}, {v.ha_state}) | {pos} | "
                  f"{'ARMED' if v.armed else 'disarmed'} {mode_name(v.custom_mode)} | mission item {v.mission_seq} | "
                  f"link rx {v.link.opened} tx {v.link.sent} drops {sum(v.link.drops.values())}", flush=True)

    def stop(self, *_: object) -> None:
        self._running = False

    def step(self, now: float, last_cmd: dict[str, float], hb_due: list[float]) -> None:
        """One pass of the loop (also used by the GCS gateway's own loop)."""
        self._serve_linkkeys(now)
        for view in self.views.values():
            if view.link is None and self.opts.pair:
                self._try_pair(view, now)
            if view.link is None:
                continue
            if view.owner == self.name:
                self._share_keys(view, now)
            self._fly(view, now)
            self._coordinate(view, now)
            self._command_stream(view, now, last_cmd)
        if now >= hb_due[0]:
            hb_due[0] = now + 1.0 / self.opts.heartbeat_hz
            for view in self.views.values():
                self._heartbeat(view)
                if self.opts.paper_heartbeat:
                    self._sm_seq += 1
                    self.send_control(view, wire.SmHeartbeat(self._sm_seq))

    def _heartbeat(self, view: DroneView) -> None:
        self.send_msg(view, mav.MAVLink_heartbeat_message(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0,
                                                          mav.MAV_STATE_ACTIVE, 3))

    def drain(self, timeout: float) -> None:
        drain(self.rx, timeout, self._on_inbox)

    def run(self) -> None:
        print(f"zdrone gs {self.name}: sysid {self.sysid}, drones {', '.join(self.views)}, router {self.opts.router}", flush=True)
        self.events.write("start", drones=list(self.views))
        last_cmd: dict[str, float] = {}
        hb_due = [0.0]
        next_status = next_view = 0.0
        try:
            while self._running:
                self.drain(0.005 if self.loop_hooks else 0.01)
                now = time.monotonic()
                self.step(now, last_cmd, hb_due)
                for hook in self.loop_hooks:
                    hook(now)
                if now >= next_status:
                    next_status = now + self.opts.status_period
                    self.events.write("status", **self.status())
                    if now >= next_view:
                        next_view = now + 5.0
                        self.print_view()
        finally:
            self.close()

    def close(self) -> None:
        self.events.write("stop", **self.status())
        for step in (self.sub.undeclare, self.linkkey_q.undeclare, self.session.close):
            try:  # each step on its own: a session the signal thread closed must not stop the rest
                step()
            except Exception as exc:
                log.warning("close: %s", exc)
        self.events.write("closed")
        self.events.close()


def run_station(opts: StationOptions) -> int:
    from zdrone.net.shutdown import block_signals, serve_signals

    block_signals()
    station = GroundStation(opts)
    gateway = None
    if opts.gcs:
        from .gateway import GcsGateway

        try:
            gateway = GcsGateway(station, list(opts.gcs))
        except ConfigError:
            station.close()
            raise
        station.status_sources["gateway"] = gateway.stats
        print(f"zdrone gs {station.name}: GCS gateway on {', '.join(gateway.endpoints())} for {gateway.drone}", flush=True)
    closed = threading.Event()
    serve_signals(station.stop, station.session.close, closed)
    try:
        station.run()
    finally:
        closed.set()
        if gateway is not None:
            gateway.close()
    return 0
