"""``zdrone drone``: the onboard companion node (vehicle link + security module + handover authority).

One thread owns everything: Zenoh callbacks and the vehicle link's reader thread only put what they
received on the inbox (they never block and never call Zenoh); the loop opens envelopes, feeds the
``AuthorityMachine``, carries out its actions and forwards vehicle telemetry to the GSs the machine
talks to.

The loop sleeps until the next input or the next deadline, whichever comes first (``next_deadline``):
the machine's timer (``get_timer``), each link's next TBM threshold (DEGRADED, LOST), the radio's
late frames, a pairing's probation, the status event, the status beacon and the vehicle link's
heartbeat. An envelope or a vehicle frame wakes it at once, and a silent authority link is noticed
at its LOST instant. It never sleeps longer than ``MAX_SLEEP_S``: the pairing queryable's ring and
the paths' state, which nothing wakes the loop for, are looked at on every wake.
"""

from __future__ import annotations

import heapq
import logging
import os
import time
from collections import Counter
from dataclasses import dataclass
from typing import Any, Callable, Protocol

import zenoh
from pymavlink.dialects.v20 import common as mav

from ..core import authority as ha
from ..core.envelope import Dropped, Opened, SecureLink
from ..core.fleet import ConfigError
from ..core.geometry import GeoPoint
from ..core.keys import LinkKey
from ..core.linkslot import LinkSlot, Promoted
from ..core.pairing import PairAccepted, PairingResponder, PairRefusal, PairRefused, PairRepeated, PairResult
from ..core.tbm import TimeBetweenMessages, TbmThresholds
from ..core import wire
from ..core.wire import KeyGrant, KeyGrantAck
from ..vehicle.link import VehicleLink, VehicleState
from ..fleet import keyexprs as kx
from ..net.authstore import AuthorityStore, SavedAuthority
from ..net.inbox import payload_bytes
from ..net.runtime import NodeRuntime

log = logging.getLogger(__name__)

#: Pairing handshakes (X25519 + AEAD work) done per loop turn at most; the rest waits its turn.
PAIRING_PER_TURN = 2
#: Pairing queries looked at per loop turn (no crypto for those refused).
PAIRING_QUERIES_PER_TURN = 256
#: A pairing candidate must be proven by the GS within this time.
PAIRING_TTL = 10.0
#: The authority status goes to every linked GS at least this often (besides every change), so a
#: GS that was hung or missed a change learns who holds authority within a second.
STATUS_BEACON_S = 1.0
#: The loop sleeps at most this long, whatever its deadlines (a safety net, and the bound on how long
#: a pairing query waits in its ring).
MAX_SLEEP_S = 0.05
#: The inbox kind (and sender) of the vehicle link's messages.
VEHICLE = "vehicle"


class LinkGate(Protocol):
    """Whether the (emulated) radio between the vehicle and a GS exists (the testbed's coverage)."""

    blocked: Counter[str]

    def update(self, position: Any) -> None: ...

    def allow(self, gs: str, direction: str) -> bool: ...


class RadioPath(Protocol):
    """When a frame on a GS's (emulated) radio arrives, or None if it is lost (the testbed's radio)."""

    lost: Counter[str]

    def admit(self, gs: str, direction: str, now: float) -> float | None: ...


class Vehicle(Protocol):
    """The flight controller as the node sees it (``VehicleLink``; ``InProcessVehicle`` in benches)."""

    @property
    def sysid(self) -> int | None: ...

    @property
    def position(self) -> Any: ...

    @property
    def armed(self) -> bool: ...

    @property
    def landed_state(self) -> int: ...

    def heartbeat(self, now: float | None = None) -> None: ...

    def next_due(self) -> float: ...

    def recv(self, timeout: float = 0.0) -> list[bytes]: ...

    def start_reader(self, deliver: Callable[[Any], None]) -> bool: ...

    def accept(self, msg: Any, now: float) -> bytes: ...

    def send(self, frame: bytes) -> None: ...

    def state(self) -> VehicleState: ...

    def stream_stats(self) -> dict[str, Any]: ...

    def command_land(self) -> None: ...

    def command_rtl(self) -> None: ...

    def wait_vehicle(self, timeout: float) -> bool: ...

    def close(self) -> None: ...


def next_link_change(tbm: TimeBetweenMessages, now: float) -> float | None:
    """When the link's TBM state next changes if nothing arrives (DEGRADED, then LOST), or None."""
    if tbm.last_seen is None:
        return None
    for threshold in (tbm.thresholds.degraded, tbm.thresholds.lost):
        if tbm.since_last(now) < threshold:  # the comparison ``tbm.state`` makes
            return tbm.last_seen + threshold
    return None


@dataclass(frozen=True, slots=True)
class DroneOptions:
    drone: str
    fleet: str
    router: str | tuple[str, ...]  # one endpoint (or a comma-separated failover list), or one per site (paths)
    vehicle: str
    thresholds: TbmThresholds = TbmThresholds()
    failsafe: str = "LAND"
    handover_timeout: float = 5.0
    gate: Any = None  # TESTBED ONLY: a ``LinkGate`` (radio coverage), handed in by whoever starts the node
    events: str | None = None
    status_period: float = 0.5
    cipher: str = "zdrone"  # "plain" / "fernet" only for bench traffic
    radio: Any = None  # TESTBED ONLY: a ``RadioPath`` (loss, bursts, delay, jitter), handed in likewise


class DroneNode:
    """The companion computer of one drone."""

    def __init__(self, opts: DroneOptions, vehicle: Vehicle | None = None) -> None:
        self.opts = opts
        self.rt = NodeRuntime(opts.fleet, opts.drone, "drone", opts.router, opts.events)
        self.fleet, self.secret, self.events, self.rx = self.rt.fleet, self.rt.secret, self.rt.events, self.rt.inbox
        node = self.rt.node
        self.name = opts.drone
        self.sysid = node.sysid
        self.uplink = node.uplink
        self.machine = ha.AuthorityMachine(ha.Config(frozenset(node.authorized_gs), opts.handover_timeout, opts.failsafe))
        self.store = AuthorityStore(opts.fleet, opts.drone)
        self.gate: LinkGate | None = opts.gate
        self.radio = opts.radio
        self._late: list[tuple[float, int, str, str, bytes]] = []  # (due, seq, direction, gs, bytes): radio delay
        self._late_seq = 0
        self.slots: dict[str, LinkSlot] = {}
        self.links: dict[str, SecureLink] = {}  # the live link of each slot
        self.gs_sysids = {name: n.sysid for name, n in self.fleet.nodes.items() if n.role == "gs"}
        self.probation: dict[str, float] = {}  # GS -> until when we listen for its proof of a new key
        self.responder = PairingResponder(self.secret.identity, self.name,
                                          {g: self.fleet.nodes[g].public_bytes for g in self.fleet.ground_stations()},
                                          frozenset(node.authorized_gs))
        self.subs: dict[str, Any] = {}
        self.counters: Counter[str] = Counter()
        self.forwarded: Counter[str] = Counter()  # commanding frames forwarded, per GS
        self.forwarded_epochs: Counter[str] = Counter()  # the same per "epoch:gs" (one GS per epoch, always)
        self._next_status = 0.0
        self._next_beacon = 0.0
        self._inside: frozenset[str] = frozenset()
        self._last_pass = 0.0  # the ``now`` of the loop's last pass
        self._timer_handled = float("-inf")  # the machine's timer last handled (a stale one never spins the loop)
        self.vehicle: Vehicle = vehicle if vehicle is not None else VehicleLink(opts.vehicle, companion_sysid=self.sysid)
        self._vehicle_pushes = False  # True once the vehicle's frames come through the inbox
        self.pairing = self.rt.queryable(kx.pair_all(self.name))

    # ------------------------------------------------------------------ zenoh
    def _subscribe(self, gs: str) -> None:
        if gs not in self.subs:
            self.subs[gs] = self.rt.subscribe(kx.up(self.name, gs), "up", kx.gs_of)
            self.events.write("subscribe", gs=gs)

    def _unsubscribe(self, gs: str) -> None:
        sub = self.subs.pop(gs, None)
        if sub is not None:
            self.rt.undeclare(sub)
            self.events.write("unsubscribe", gs=gs)

    def _sync_subscriptions(self, now: float) -> None:
        """Listen to what the HA wants plus every GS whose new key waits for its proof."""
        self.probation = {gs: t for gs, t in self.probation.items() if t > now}
        want = set(self.machine.subscribed) | set(self.probation)
        for gs in sorted(want - set(self.subs)):
            self._subscribe(gs)
        for gs in sorted(set(self.subs) - want):
            self._unsubscribe(gs)

    def _publish(self, gs: str, payload: bytes) -> None:
        if self.gate is not None and not self.gate.allow(gs, "down"):
            return
        if self.radio is not None and not self._through_radio("down", gs, payload):
            return
        self._put(gs, payload)

    def _through_radio(self, direction: str, gs: str, data: bytes) -> bool:
        """TESTBED ONLY: True to pass the frame on now; False if the radio lost or delayed it."""
        now = time.monotonic()
        due = self.radio.admit(gs, direction, now)
        if due is None:
            return False
        if due <= now:
            return True
        self._late_seq += 1
        heapq.heappush(self._late, (due, self._late_seq, direction, gs, data))
        return False

    def _release_late(self, now: float) -> None:
        while self._late and self._late[0][0] <= now:
            _, _, direction, gs, data = heapq.heappop(self._late)
            if direction == "down":
                self._put(gs, data)
            else:
                self._open_envelope(gs, data, now)

    def _put(self, gs: str, payload: bytes) -> None:
        self.rt.put(kx.down(self.name, gs), payload)

    # ------------------------------------------------------------------ links
    def _new_link(self, gs: str, key: LinkKey, now: float) -> SecureLink:
        return SecureLink(
            key=key, role="drone", tx_keyexpr=kx.down(self.name, gs), rx_keyexpr=kx.up(self.name, gs),
            peer_sysid=self.fleet.nodes[gs].sysid, now=now, thresholds=self.opts.thresholds, cipher=self.opts.cipher,
            authorize=lambda g: self.fleet.is_authorized(self.name, g))

    def _install(self, gs: str, key: LinkKey, now: float) -> None:
        """A key granted by the authority: live at once if the link has none, else a candidate that
        GS ``gs`` must prove. The drone then speaks under it once, so the GS can confirm it too."""
        slot = self.slots.setdefault(gs, LinkSlot())
        link = self._new_link(gs, key, now)
        if slot.live is None:
            slot.install(link, now)
            self.links[gs] = link
            self.events.write("link_installed", gs=gs, how="grant")
            self._send_control(gs, self.machine.status())  # the drone's proof of the key, for the GS
        else:
            slot.offer(link, now, "grant")
            self.events.write("link_candidate", gs=gs, how="grant")

    def _send_control(self, gs: str, msg: Any) -> None:
        link = self.links.get(gs)
        if link is not None:
            self._publish(gs, link.seal_control(msg))

    def _on_ground(self) -> bool:
        return not self.vehicle.armed or self.vehicle.landed_state == mav.MAV_LANDED_STATE_ON_GROUND

    # ------------------------------------------------------------------ events
    def _apply(self, actions: list[ha.Action], now: float, frame: bytes | None = None) -> None:
        for a in actions:
            if isinstance(a, ha.Forward):
                if frame is not None:
                    self.vehicle.send(frame)
            elif isinstance(a, ha.DropFrame):
                self.counters[f"ha_drop:{a.reason.value}"] += 1
                log.info("HA dropped a frame from %s: %s", a.gs, a.reason.value)
            elif isinstance(a, ha.SendControl):
                self._send_control(a.gs, a.msg)
            elif isinstance(a, (ha.Subscribe, ha.Unsubscribe)):
                self._sync_subscriptions(now)
            elif isinstance(a, ha.CommandVehicle):
                self._failsafe(a, now)
            elif isinstance(a, ha.AuthorityChanged):
                kind = "handover_complete" if a.kind in ("handover", "emergency") else "authority"
                self.events.write(kind, **{"from": a.old, "to": a.new, "epoch": a.epoch, "kind": a.kind,
                                           "time": round(time.time(), 4), "position": self._pos()})
                log.warning("authority %s -> %s (epoch %d, %s)", a.old, a.new, a.epoch, a.kind)
            elif isinstance(a, ha.Note):
                self.events.write(a.kind, detail=a.detail, position=self._pos())
                log.info("%s: %s", a.kind, a.detail)

    def _failsafe(self, a: ha.CommandVehicle, now: float) -> None:
        (self.vehicle.command_land if a.command == "LAND" else self.vehicle.command_rtl)()
        owner_link = self.links.get(self.machine.owner or "")
        latency = None
        if owner_link is not None and owner_link.tbm.last_seen is not None:
            latency = (now - owner_link.tbm.last_seen - self.opts.thresholds.lost) * 1000.0
        self.events.write("failsafe", action=a.command, reason=a.reason, detect_to_command_ms=latency, position=self._pos())
        log.warning("FAILSAFE: %s (%s), %.1f ms after the threshold", a.command, a.reason, latency or -1)

    def _pos(self) -> list[float] | None:
        p = self.vehicle.position
        return [round(p.lat, 7), round(p.lon, 7), round(p.alt, 2)] if p else None

    def _handle(self, event: ha.Event, frame: bytes | None = None) -> None:
        self._apply(self.machine.handle(event), event.now, frame)
        self._save()

    def _save(self) -> None:
        """Persist owner, epoch and state on every change (a restart comes back with them)."""
        m = self.machine
        if m.owner is not None:
            self.store.save(SavedAuthority(m.owner, m.epoch, m.state.value))

    def _restore(self, now: float) -> None:
        """After a restart in the air: the authority it had, waiting for the owner to re-pair."""
        saved = self.store.load()
        if saved is None:
            return
        if saved.owner is None or saved.state == ha.State.FAILSAFE.value or self._on_ground():
            self.store.clear()  # a fresh start on the ground (or nothing to come back to)
            self.events.write("authority_forgotten", owner=saved.owner, epoch=saved.epoch, state=saved.state)
            return
        self.events.write("restarted", owner=saved.owner, epoch=saved.epoch, state=saved.state, position=self._pos())
        log.warning("restarted in the air: authority %s (epoch %d); waiting for it to re-pair", saved.owner, saved.epoch)
        self._apply(self.machine.restore(saved.owner, saved.epoch, now, self.opts.thresholds.lost), now)
        self._sync_subscriptions(now)

    # --------------------------------------------------------------- receiving
    def _on_inbox(self, kind: str, peer: str, data: Any, now: float) -> None:
        if kind == VEHICLE:
            self._telemetry([self.vehicle.accept(data, now)])
        else:
            self._on_envelope(kind, peer, data, now)

    def _on_envelope(self, kind: str, gs: str, data: bytes, now: float) -> None:
        if self.gate is not None and not self.gate.allow(gs, "up"):
            return
        if self.radio is not None and not self._through_radio("up", gs, data):
            return
        self._open_envelope(gs, data, now)

    def _open_envelope(self, gs: str, data: bytes, now: float) -> None:
        slot = self.slots.get(gs)
        if slot is None:
            self.counters["no_link"] += 1
            return
        res, promoted = slot.open(data, now)
        if isinstance(res, Dropped):
            drops = slot.live.drops if slot.live is not None else slot.unlinked
            if drops[res.reason] <= 5:  # the first few of each reason in the log; all of them in the counters
                self.events.write("drop", gs=gs, reason=res.reason.value, detail=res.detail)
            return
        assert isinstance(res, Opened)
        if promoted is not None:
            self._on_promoted(gs, promoted, now)
        if res.header is not None:
            uplink = self.uplink.classify(res.header.msgid)
            if uplink is ha.UplinkClass.AUTHORITY_ONLY and self.machine.owner == gs and self.machine.state is not ha.State.FAILSAFE:
                self.forwarded[gs] += 1
                self.forwarded_epochs[f"{self.machine.epoch}:{gs}"] += 1
            self._handle(ha.Frame(now, gs, uplink), res.plaintext)
            return
        msg = res.control
        if isinstance(msg, KeyGrant):
            self._on_grant(gs, msg, now)
        elif isinstance(msg, wire.HandoverRelease):
            self._handle(ha.Release(now, gs, msg.to, msg.epoch))
        elif isinstance(msg, wire.HandoverRequest):
            self._handle(ha.HandoverRequest(now, gs, msg.to))
        elif isinstance(msg, wire.SmHeartbeat):
            self.counters["sm_heartbeat"] += 1
        else:
            self.counters[f"control_ignored:{type(msg).__name__}"] += 1

    def _on_grant(self, sender: str, msg: KeyGrant, now: float) -> None:
        """A key grant from ``sender``: bad content is counted and rejected; a key the link holds
        already is acknowledged again; else the authority machine accepts or rejects it."""
        bad = ha.check_grant(msg, self.gs_sysids)
        if bad is not None:
            self.counters["bad_grant"] += 1
            self._send_control(sender, wire.Reject("key_grant", bad.detail))
            return
        key = LinkKey.from_secret(self.name, msg.gs, msg.secret)
        slot = self.slots.get(msg.gs)
        known = [] if slot is None else [slot.live] * (slot.live is not None) + [c.link for c in slot.candidates]
        if any(link.key.same_as(key) for link in known):
            self._send_control(sender, KeyGrantAck(msg.gs, msg.grant_id))  # a repeated grant
            return
        result, actions = self.machine.grant(ha.KeyGranted(now, sender, msg.gs))
        if isinstance(result, ha.GrantAccepted):
            self._install(result.gs, key, now)
        self._apply(actions, now)  # a rejection's Reject is among them
        self._save()
        if isinstance(result, ha.GrantAccepted):
            self._send_control(sender, KeyGrantAck(msg.gs, msg.grant_id))

    def _on_promoted(self, gs: str, promoted: Promoted, now: float) -> None:
        """GS ``gs`` proved a candidate key with the frame just opened: it is now the live key."""
        slot = self.slots[gs]
        assert slot.live is not None
        self.links[gs] = slot.live
        self.probation.pop(gs, None)
        self.events.write("link_confirmed", gs=gs, how=promoted.origin, replaced=promoted.replaced)
        log.info("link to %s: new key proven (%s)", gs, promoted.origin)
        if promoted.origin == "pair":
            refusal = self.machine.pair_refusal(gs, self._on_ground())
            if refusal is not None:  # the HA's state changed since message 1 (e.g. failsafe in the air)
                self.counters["pair_refused"] += 1
                self.events.write("pair_refused", gs=gs, reason=refusal.text)
            else:
                self.events.write("paired", gs=gs)
                self._handle(ha.Paired(now, gs, self._on_ground()))
        self._sync_subscriptions(now)

    def _serve_pairing(self, now: float) -> None:
        """Answer pairing queries: refusals cost no crypto; at most ``PAIRING_PER_TURN`` handshakes."""
        handshakes = 0
        for _ in range(PAIRING_QUERIES_PER_TURN):
            q = self.pairing.try_recv()
            if q is None:
                return
            try:
                if handshakes < PAIRING_PER_TURN:
                    handshakes += self._pair(q, now)
                else:
                    self.counters["pair_deferred"] += 1  # over this turn's budget: the GS asks again
            except zenoh.ZError as exc:
                self.counters["pair_reply_error"] += 1
                log.info("pairing reply failed: %s", exc)
            finally:
                q.drop()

    def _pair(self, q: zenoh.Query, now: float) -> int:
        """One pairing query; return 1 if a handshake was computed, else 0."""
        gs = kx.gs_of(q.key_expr)
        payload = payload_bytes(q.payload)
        if payload is None:
            ans: PairResult = PairRefused(PairRefusal.OVERSIZE)
        else:
            policy = None if self.responder.admit(gs) else self.machine.pair_refusal(gs, self._on_ground())
            ans = self.responder.answer(gs, payload, now, os.urandom(32), policy, holds_key=gs in self.links)
        if isinstance(ans, PairAccepted):
            # The key is a candidate until the GS proves it (the newest pairing replaces an older one).
            self.slots.setdefault(gs, LinkSlot()).offer(self._new_link(gs, ans.key, now), now, "pair", PAIRING_TTL)
            self.probation[gs] = now + PAIRING_TTL
            self._sync_subscriptions(now)
            self.counters["pair_answered"] += 1
            self.events.write("pair_answered", gs=gs)
            q.reply(q.key_expr, ans.reply)
        elif isinstance(ans, PairRepeated):
            self.counters["pair_repeated"] += 1  # a replay or a retransmission: the same answer again
            q.reply(q.key_expr, ans.reply)
        else:
            self._pair_refused(gs, ans)
            if not ans.silent:
                q.reply_err(ans.text.encode())
        return int(ans.crypto)

    def _pair_refused(self, gs: str, refusal: PairRefused) -> None:
        key = f"pair_refused:{refusal.reason.value}"
        self.counters[key] += 1
        if self.counters[key] <= 5:  # the first few of each reason in the log; all of them in the counters
            self.events.write("pair_refused", gs=gs, reason=refusal.text)

    # -------------------------------------------------------------------- loop
    def _telemetry(self, frames: list[bytes]) -> None:
        targets = self.machine.telemetry_targets()
        for f in frames:
            for gs in targets:
                link = self.links.get(gs)
                if link is not None:
                    self._publish(gs, link.seal(f))

    def _region(self, now: float) -> None:
        pos = self.vehicle.position
        if self.gate is not None:
            self.gate.update(pos)
        if pos is None:
            return
        inside = frozenset(name for name, n in self.fleet.nodes.items()
                           if n.role == "gs" and n.coverage and n.coverage.circle().contains(GeoPoint(pos.lat, pos.lon)))
        if inside != self._inside:
            self._inside = inside
            self._handle(ha.RegionChanged(now, inside))

    def _poll_links(self, now: float) -> None:
        for gs, link in list(self.links.items()):
            st = link.tbm.poll(now)
            if st is not None:
                self.events.write("link_state", gs=gs, state=st.value)
                self._handle(ha.LinkChanged(now, gs, st))

    def status(self, now: float) -> dict[str, Any]:
        m = self.machine
        for slot in self.slots.values():
            slot.expire(now)
        v = self.vehicle.state()
        return {
            "owner": m.owner, "epoch": m.epoch, "state": m.state.value, "pending_to": m.pending_to,
            "position": self._pos(), "armed": v.armed, "mode": v.mode, "landed_state": v.landed_state,
            "autopilot": getattr(v, "autopilot", None), "vehicle_streams": self.vehicle.stream_stats(),
            "in_region": m.in_region, "subscribed": sorted(m.subscribed),
            "links": {gs: {"state": link.tbm.state(now).value, "since_last": round(link.tbm.since_last(now), 3),
                           "opened": link.opened, "sent": link.sent,
                           "dropped": {r.value: c for r, c in link.drops.items() if c}}
                      for gs, link in self.links.items()},
            "keys": {gs: {"live": slot.live is not None, "candidates": len(slot.candidates), "expired": slot.expired,
                          "dropped_unlinked": {r.value: c for r, c in slot.unlinked.items() if c}}
                     for gs, slot in self.slots.items()},
            "ha_drops": {r.value: c for r, c in m.drops.items()}, "rejects": dict(m.rejects),
            "counters": dict(self.counters), "forwarded_commands": dict(self.forwarded),
            "forwarded_epochs": dict(self.forwarded_epochs),
            "inbox_dropped": self.rx.stats(),
            "paths": self.rt.path_status() if self.rt.multipath else {},
            "out_of_coverage": dict(self.gate.blocked) if self.gate else {},
            "radio_lost": dict(self.radio.lost) if self.radio else {},
        }

    def stop(self, *_: object) -> None:
        self.rt.stop()

    def run(self) -> None:
        print(f"zdrone drone {self.name}: vehicle {self.opts.vehicle}, router {self.rt.router}", flush=True)
        self.events.write("start", vehicle=self.opts.vehicle)
        if not self.vehicle.wait_vehicle(30.0):
            raise ConfigError(f"vehicle {self.opts.vehicle}: no heartbeat within 30 s")
        print(f"zdrone drone {self.name}: vehicle sysid {self.vehicle.sysid} ready", flush=True)
        self._restore(time.monotonic())
        inbox = self.rx
        self._vehicle_pushes = self.vehicle.start_reader(lambda msg: inbox.put(VEHICLE, VEHICLE, msg))
        try:
            while self.rt.running:
                self.step(self.sleep_time())
        finally:
            self.close()

    def next_deadline(self, now: float) -> float:
        """The earliest instant after ``now`` (the last pass) at which something is due if no input
        comes (see the module's docstring)."""
        due = [self._next_status, self._next_beacon, self.vehicle.next_due()]
        timer = self.machine.get_timer()
        if timer is not None and timer > self._timer_handled:
            due.append(timer)
        due += [t for link in self.links.values() if (t := next_link_change(link.tbm, now)) is not None]
        if self._late:
            due.append(self._late[0][0])
        if self.probation:
            due.append(min(self.probation.values()))
        return min(due)

    def sleep_time(self) -> float:
        """How long the loop may wait for input now: until the next deadline (as of the last pass),
        ``MAX_SLEEP_S`` at most."""
        return min(MAX_SLEEP_S, max(0.0, self.next_deadline(self._last_pass) - time.monotonic()))

    def step(self, wait: float) -> None:
        """One pass of the loop: wait up to ``wait`` s for the first input (an envelope, a vehicle
        message), handle what came, then whatever is due. ``step(0.0)`` never waits (benches step
        many nodes in turn); a vehicle without a reader thread is polled here."""
        self.rx.drain(wait, self._on_inbox)
        self.rt.poll_paths()
        now = self._last_pass = time.monotonic()
        if self._late:
            self._release_late(now)
        self._serve_pairing(now)
        self.vehicle.heartbeat(now)
        if not self._vehicle_pushes:
            self._telemetry(self.vehicle.recv(0.0))
        if self.probation and min(self.probation.values()) <= now:
            self._sync_subscriptions(now)
        self._region(now)
        self._poll_links(now)
        timer = self.machine.get_timer()
        if timer is not None and now >= timer:  # a hand-over's or a re-pairing's deadline
            self._timer_handled = timer
            self._apply(self.machine.handle_timer(now), now)
            self._save()
        if now >= self._next_beacon:
            self._next_beacon = now + STATUS_BEACON_S
            st = self.machine.status()
            for gs in sorted(self.links):
                self._send_control(gs, st)
        if now >= self._next_status:
            self._next_status = now + self.opts.status_period
            self.events.write("status", **self.status(now))

    def close(self) -> None:
        now = time.monotonic()
        if self._on_ground():
            self.store.clear()  # stopped on the ground: the next start is a fresh one
        self.rt.close(self.status(now), extra_steps=(self.vehicle.close,))


def run_drone(opts: DroneOptions) -> int:
    node = DroneNode(opts)
    return node.rt.serve(node.run)
