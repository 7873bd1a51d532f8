"""``zdrone drone``: the onboard companion node — the thin adapter of ``drone_core.DroneCore``.

The protocol logic (link keys, pairing answers, key grants, the handover authority, the region,
forwarding) is the pure ``DroneCore``; this module owns the Zenoh session (subscriptions of the
GSs' uplinks, the pairing queryable), the vehicle link, the clock, the event log and the saved
authority, and carries out the core's outputs. The testbed's emulated radio (coverage gate, loss,
delay) sits here too, between the session and the core, handed in by whoever starts the node.

The vehicle's position reaches the core with whether it may grant authority: only if it came signed
by the autopilot (``VehicleLink.position_signed``), or the operator opted in for an unsigned link
(``--trust-unsigned-position``); an untrusted position is inside no coverage. What became of a
commanded failsafe (confirmed by the autopilot, sent again, given up) goes to the event log.

One thread owns everything: Zenoh callbacks and the vehicle link's reader thread only put what they
received on the inbox. The loop sleeps until the next input or the core's timer (``get_timer``), the
status event or the vehicle link's heartbeat, whichever comes first, ``MAX_SLEEP_S`` at most (the
pairing queryable's ring and the paths' state, which nothing wakes the loop for, are looked at on
every wake).
"""

from __future__ import annotations

import collections
import functools
import heapq
import logging
import os
import time
from collections import Counter
from dataclasses import dataclass
from typing import Any, Callable, Protocol

import msgspec
import zenoh
from pymavlink.dialects.v20 import common as mav

from zdrone.core import authority as ha
from zdrone.core import records as rec
from zdrone.core.audit import Witnessing
from zdrone.core.bundle import BundleWriter
from zdrone.core.fleet import ConfigError, Fleet
from zdrone.core.outputs import Emit, Handlers, Put, dispatch
from zdrone.core.pairing import query_answer
from zdrone.core.revision import RevisionAccepted
from zdrone.core.tbm import TbmThresholds
from zdrone.fleet import keyexprs
from zdrone.fleet import revisions
from zdrone.fleet.routerconfig import UPLINK_MAX_BYTES
from zdrone.net.authstore import AuthorityStore, SavedAuthority
from zdrone.net.inbox import payload_bytes
from zdrone.net.runtime import NodeRuntime
from zdrone.nodes.drone_actions import CommandVehicle, Countersign, Listen, Out, Persist, ToVehicle
from zdrone.nodes.drone_core import DroneCore, DroneCoreOptions
from zdrone.vehicle.fcsigning import FcKeyStore, FcSigning
from zdrone.vehicle.link import VehicleLink, VehicleState

__all__ = ["DroneNode", "DroneOptions", "run_drone"]

log = logging.getLogger(__name__)

#: Pairing handshakes (X25519 + AEAD work) done per loop turn at most; the rest waits its turn.
PAIRING_PER_TURN = 2
#: Pairing queries looked at per loop turn (no crypto for those refused).
PAIRING_QUERIES_PER_TURN = 256
#: Queries over a turn's handshake budget held for the next turns, at most, and for this long at most
#: (within the GS's wait for its answer: ``gs.context.SILENT_PAIR_TIMEOUT_S``, 1 s). A few: a burst of
#: the GSs' queries waits for the next turn (on a companion, within ``MAX_SLEEP_S``); a drone whose turns
#: come late drops the rest as before (at 32, a testbed host of 300 late drones held 9 600 queries and
#: their Zenoh state, 1.4 GB, and let nearly all of them expire).
PAIRING_HELD = 4
PAIRING_HOLD_S = 0.8
#: The loop sleeps at most this long, whatever its deadlines (a safety net, and the bound on how long
#: a pairing query waits in its ring).
MAX_SLEEP_S = 0.05
#: The inbox kind (and sender) of the vehicle link's messages.
VEHICLE = "vehicle"
#: The record of each outcome of a commanded failsafe (``VehicleTracker.failsafe_outcomes``).
_FAILSAFE_RECORDS: dict[str, type[rec.Record]] = {"confirmed": rec.FailsafeConfirmed, "retried": rec.FailsafeRetried,
                                                   "unconfirmed": rec.FailsafeUnconfirmed}


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

    @property
    def position_signed(self) -> bool: ...

    def failsafe_outcomes(self) -> list[Any]: ...

    def stream_stats(self) -> dict[str, Any]: ...

    def command_land(self) -> None: ...

    def command_rtl(self) -> None: ...

    def wait_vehicle(self, timeout: float) -> bool: ...

    def close(self) -> None: ...


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
    fc_signing: str = "prefer"  # MAVLink signing of the flight controller's link: require | prefer | off
    rotate_fc_key: bool = False  # install a new signing key in the flight controller (on the ground)
    # the operator's opt-in for this drone: a position that did not come over a signed autopilot link
    # may grant authority (an heir, a pairing that needs coverage); off, only signed positions do
    trust_unsigned_position: bool = False
    revision_lease: float = 0.0  # DroneCoreOptions.revision_lease (0: off)


#: The drone countersigns a GS's checkpoints at most this often (a GS sends each offer three times, 0.5 s apart).
COUNTERSIGN_EVERY_S = 0.4


class DroneNode:
    """The companion computer of one drone: Zenoh, the vehicle and the clock around a ``DroneCore``."""

    def __init__(self, opts: DroneOptions, vehicle: Vehicle | None = None) -> None:
        self.opts = opts
        self.rt = NodeRuntime(opts.fleet, opts.drone, "drone", opts.router, opts.events)
        self.fleet, self.secret, self.events, self.rx = self.rt.fleet, self.rt.secret, self.rt.events, self.rt.inbox
        self.name = opts.drone
        self.sysid = self.rt.node.sysid
        self.core = DroneCore(self.fleet, self.name, self.secret.identity,
                              DroneCoreOptions(opts.thresholds, opts.failsafe, opts.handover_timeout, opts.cipher,
                                               revision_lease=opts.revision_lease,
                                               # a pass's messages to a GS under one envelope (the paper's
                                               # Fernet layer, measured by bench traffic, seals per frame)
                                               batch=opts.cipher != "fernet"),
                              started_wall=time.time(), signing=self.secret.signing)
        self.core.wall_offset = time.time() - time.monotonic()  # the time of day its attestations name
        self.witnessing: Witnessing | None = None  # it countersigns its GSs' checkpoints (zdrone.core.audit)
        if self.secret.signing is not None:  # the signed authority record beside the event log (zdrone.core.audit)
            self.events.start_audit(self.secret.signing, on_checkpoint=lambda cp: self.core.on_audit_checkpoint(*cp.raw()))
            self.witnessing = Witnessing(self.name, self.secret.signing, self._gs_keys(self.fleet),
                                         every=COUNTERSIGN_EVERY_S)
        self.store = AuthorityStore(opts.fleet, opts.drone)
        self.gate: LinkGate | None = opts.gate
        self.radio = opts.radio
        self._late: list[tuple[float, int, str, str, bytes]] = []  # (due, seq, direction, gs, bytes): radio delay
        self._late_seq = 0
        self.bundles = BundleWriter()  # the envelopes of this pass per GS, published at its end (``flush_down``)
        self.subs: dict[str, list[Any]] = {}  # GS -> a subscriber per lane of its uplink (declaration thread)
        self._listening: set[str] = set()  # the GSs whose uplinks the loop asked to hear
        self.listen_total_s = self.listen_worst_s = 0.0  # time spent declaring and undeclaring them
        self._next_status = 0.0
        self._last_pass = 0.0  # the ``now`` of the loop's last pass
        self.vehicle: Vehicle = vehicle if vehicle is not None else VehicleLink(
            opts.vehicle, companion_sysid=self.sysid,
            signing=FcSigning(FcKeyStore.for_node(opts.fleet, opts.drone), opts.fc_signing, opts.rotate_fc_key))
        self._vehicle_pushes = False  # True once the vehicle's frames come through the inbox
        self.pairing = self.rt.queryable(keyexprs.pair_all(self.name))
        self._held_pairing: collections.deque[tuple[float, Any]] = collections.deque()  # (since, query)
        # fleet revisions: heard and kept, asked for on coming back in reach (a drone never answers)
        self.revision = revisions.RevisionChannel(self.rt, opts.fleet, publisher=False, in_reach=self._hears_a_gs)

    @property
    def machine(self) -> ha.AuthorityMachine:
        """The handover authority (read-only use: benches and tests)."""
        return self.core.machine

    # ------------------------------------------------------------- outputs
    def _do(self, outs: list[Out], now: float) -> None:
        """Carry out the core's outputs."""
        dispatch(outs, self._handlers)

    @functools.cached_property
    def _handlers(self) -> Handlers:
        return {Put: lambda o: self._publish(o.peer, o.payload), ToVehicle: lambda o: self.vehicle.send(o.frame),
                Emit: lambda o: self._emit(o.record), Listen: lambda o: self._listen(o.gss),
                CommandVehicle: lambda o: (self.vehicle.command_land if o.command == "LAND" else self.vehicle.command_rtl)(),
                Persist: self._persist, Countersign: self._countersign}

    def _gs_keys(self, fleet: Fleet) -> dict[str, bytes | None]:
        """The GSs whose checkpoints it countersigns, under their keys in force (a revoked GS's: none)."""
        return {g: None if fleet.is_revoked(g) else fleet.signing_public(g)
                for g in fleet.ground_stations() if fleet.is_authorized(self.name, g)}

    def _countersign(self, o: Countersign) -> None:
        """A GS's checkpoint from its authentic offer: countersigned once, an entry of this drone's
        record; one whose signature fails is counted, never countersigned."""
        if self.witnessing is not None and not self.events.countersign(self.witnessing, o.gs, o.head, time.time()):
            self.core.counters["audit_bad_checkpoint"] += 1

    def _persist(self, o: Persist) -> None:
        if o.owner is None:
            self.store.clear()
        else:
            self.store.save(SavedAuthority(o.owner, o.epoch, o.state))

    def _emit(self, record: rec.Record) -> None:
        if isinstance(record, rec.AuthorityMoved) and not record.time:
            record = msgspec.structs.replace(record, time=round(time.time(), 4))
        self.events.write_record(record)

    def _listen(self, gss: frozenset[str]) -> None:
        """Listen to exactly ``gss``'s uplinks: the subscriptions are declared and undeclared in the
        process's declaration thread, in order (``NodeRuntime.in_background``): a declaration waits on
        Zenoh (50-80 ms each under a 300-drone flight), and the loop must not."""
        for gs in sorted(gss - self._listening):
            self._listening.add(gs)
            self.rt.in_background(functools.partial(self._declare_uplink, gs))
        for gs in sorted(self._listening - gss):
            self._listening.discard(gs)
            self.rt.in_background(functools.partial(self._undeclare_uplink, gs))

    def _declare_uplink(self, gs: str) -> None:  # the declaration thread
        started = time.monotonic()
        try:
            if gs not in self.subs:  # the router's size limit, held here too
                self.subs[gs] = [self.rt.subscribe(lane, "up", keyexprs.gs_of_uplink, limit=UPLINK_MAX_BYTES)
                                 for lane in keyexprs.up_lanes(self.name, gs)]
        finally:
            self._declared_in(time.monotonic() - started)

    def _undeclare_uplink(self, gs: str) -> None:  # the declaration thread
        started = time.monotonic()
        try:
            for handle in self.subs.pop(gs, []):
                self.rt.undeclare(handle)
        finally:
            self._declared_in(time.monotonic() - started)

    def _declared_in(self, took: float) -> None:
        self.listen_total_s += took  # Zenoh declarations, now off the loop (bench scale reports them)
        self.listen_worst_s = max(self.listen_worst_s, took)

    def _publish(self, gs: str, payload: bytes) -> None:
        if self.gate is not None and not self.gate.allow(gs, "down"):
            return
        if self.radio is not None and not self._through_radio("down", gs, payload):
            return
        self.bundles.add(gs, payload)

    def flush_down(self, now: float) -> None:
        """Publish the pass's envelopes: the core seals what it queued for each GS as one envelope
        (``DroneCore.flush``), then one bundle per GS (``zdrone.core.bundle``)."""
        self._do(self.core.flush(), now)
        if self.bundles.pending():
            for gs, bundle in self.bundles.take():
                self.rt.put(keyexprs.down(self.name, gs), bundle)

    # -------------------------------------------------- the testbed's radio
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
                self.bundles.add(gs, data)
            else:
                self._do(self.core.on_envelope(gs, data, now), now)

    # -------------------------------------------------------------- inputs
    def _on_ground(self) -> bool:
        return not self.vehicle.armed or self.vehicle.landed_state == mav.MAV_LANDED_STATE_ON_GROUND

    def _position_trusted(self) -> bool:
        """The vehicle's position may grant authority: it came signed by the autopilot, or the operator
        opted in for an unsigned link (``--trust-unsigned-position``)."""
        return self.opts.trust_unsigned_position or bool(self.vehicle.position_signed)

    def _pos(self) -> tuple[float, float, float] | None:
        p = self.vehicle.position
        return (round(p.lat, 7), round(p.lon, 7), round(p.alt, 2)) if p else None

    def _on_inbox(self, kind: str, peer: str, data: Any, now: float) -> None:
        if kind == VEHICLE:
            self._do(self.core.on_telemetry(self.vehicle.accept(data, now), now), now)
            return
        if kind in revisions.KINDS:
            self._on_revision(kind, peer, data, now)
            return
        if self.gate is not None and not self.gate.allow(peer, "up"):
            return
        if self.radio is not None and not self._through_radio("up", peer, data):
            return
        self._do(self.core.on_envelope(peer, data, now), now)

    def _on_revision(self, kind: str, peer: str, data: Any, now: float) -> None:
        """A fleet revision heard (published, or a query's reply): applied live if it is the next one;
        a GS's signed stamp may renew the owner's lease (``DroneCore.on_revision_stamp``). TESTBED: out of every GS's radio
        (the coverage gate), the drone hears none."""
        if not self._hears_a_gs():
            return
        got = self.revision.on_inbox(kind, data)
        if isinstance(got, RevisionAccepted):
            self.fleet = got.fleet
            self._rekey_audit(got.fleet)  # before the revision's own entry: that one is signed under the new key
            if self.witnessing is not None:
                self.witnessing.set_node_keys(self._gs_keys(got.fleet))
            self._do(self.core.on_revision(got.fleet, now), now)
        if (stamp := self.revision.take_stamp()) is not None:  # checked by the core against the fleet in force
            self._do(self.core.on_revision_stamp(stamp, now, carrier=peer), now)

    def _rekey_audit(self, fleet: Fleet) -> None:
        """A revision that changed this drone's own keys: its authority record goes on under the new
        signing key from its bundle (``EventLog.rekey_audit``), its word on its authority is signed
        with it and pairing answers under the new static key (``DroneCore.adopt_own_keys``); if the
        bundle does not hold them yet, nothing is signed (counted: ``audit_rotation_pending``), never
        under a retired key."""
        node = fleet.nodes.get(self.name)
        if node is None:
            return
        held = self.core.responder.me.public, (self.core.attester.key.public if self.core.attester else None)
        if (node.public_bytes, node.signing_public_bytes) == held:
            return
        from zdrone.fleet.files import load_secret

        try:
            secret = load_secret(self.opts.fleet, self.name, fleet)
        except ConfigError as exc:
            log.warning("own keys rotated by the fleet, but the bundle does not hold the new ones: %s", exc)
            self.core.counters["audit_rotation_pending"] += 1
            if self.events.audit is not None:
                self.events.rekey_audit(None)
            if self.witnessing is not None:
                self.witnessing.rekey(None)
            self.core.adopt_own_keys(None, None)
            return
        log.warning("own keys rotated by the fleet: pairing, attestations and the record under the new keys")
        self.core.counters["own_keys_rotated"] += 1
        if self.events.audit is not None:
            self.events.rekey_audit(secret.signing)
        if self.witnessing is not None:
            self.witnessing.rekey(secret.signing)
        self.core.adopt_own_keys(secret.identity, secret.signing)

    def _hears_a_gs(self) -> bool:
        """TESTBED: whether the coverage gate lets any GS's traffic through now (True without one)."""
        return self.gate is None or any(self.gate.allow(g, "up") for g in self.core.gs_sysids)  # the fleet's GSs

    def _restore(self, now: float) -> None:
        """At start: back to the authority saved before a restart (in the air: its owner re-pairs; on
        the ground: the epoch goes on and the saved owner pairs back first), or a fresh start."""
        saved = self.store.load()
        self._do(self.core.on_vehicle(self._pos(), self._on_ground(), now, self._position_trusted()), now)
        if saved is not None:
            self._do(self.core.restore(saved.owner, saved.epoch, saved.state, now), now)

    def _serve_pairing(self, now: float) -> None:
        """Answer pairing queries: refusals cost no crypto; at most ``PAIRING_PER_TURN`` handshakes a
        turn. A query over the turn's budget is held for the next turns (``PAIRING_HELD``, at most
        ``PAIRING_HOLD_S``), oldest first, not dropped: a dropped query ends unanswered at the GS,
        which then asks again at once (an owner re-pairing a silent drone, every 0.2 s), so a drone too
        busy to answer got more questions, each a handshake once answered."""
        handshakes, held = 0, self._held_pairing
        for _ in range(PAIRING_QUERIES_PER_TURN):
            if held and handshakes < PAIRING_PER_TURN:
                since, q = held.popleft()
                if now - since > PAIRING_HOLD_S:
                    self.core.counters["pair_held_expired"] += 1  # the GS has given up on it: it asks again
                    q.drop()
                    continue
            else:
                q = self.pairing.try_recv()
                if q is None:
                    return
                if handshakes >= PAIRING_PER_TURN:
                    if len(held) < PAIRING_HELD:
                        self.core.counters["pair_held"] += 1  # answered in a later turn
                        held.append((now, q))
                    else:
                        self.core.counters["pair_deferred"] += 1  # over the budget and the hold: the GS asks again
                        q.drop()
                    continue
            try:
                gs = keyexprs.gs_of(q.key_expr)
                ans, outs = self.core.on_pair_query(gs, payload_bytes(q.payload), now, os.urandom(32), time.time())
                self._do(outs, now)
                handshakes += int(ans.crypto)
                answer = query_answer(ans)
                if answer is not None and answer[0] is not None:
                    q.reply(q.key_expr, answer[0])
                elif answer is not None and answer[1] is not None:
                    q.reply_err(answer[1])
            except zenoh.ZError as exc:
                self.core.counters["pair_reply_error"] += 1
                log.info("pairing reply failed: %s", exc)
            finally:
                q.drop()

    # ---------------------------------------------------------------- loop
    def status(self, now: float) -> dict[str, Any]:
        v = self.vehicle.state()
        return {
            **self.core.report(now), "position": list(self._pos() or ()) or None,
            "armed": v.armed, "mode": v.mode, "landed_state": v.landed_state,
            "autopilot": getattr(v, "autopilot", None), "vehicle_streams": self.vehicle.stream_stats(),
            "inbox_dropped": self.rx.stats(),
            "paths": self.rt.path_status() if self.rt.multipath else {},
            "out_of_coverage": dict(self.gate.blocked) if self.gate else {},
            "radio_lost": dict(self.radio.lost) if self.radio else {},
            "fc_signing": self._fc_signing(),
            "revision": self.revision.keeper.stats(),
        }

    def _fc_signing(self) -> dict[str, Any]:
        """The autopilot link's MAVLink signing (``FcSigning.status``); the core tells the GSs whether it is signed."""
        st: dict[str, Any] = getattr(self.vehicle, "signing_status", dict)()
        self.core.fc_signed = bool(st.get("signed")) if st else None
        if st:
            st = {**st, "position_trusted": self.core.position_trusted,
                  "trust_unsigned_position": self.opts.trust_unsigned_position}
        return st

    def _found(self) -> None:
        """Say which vehicle the link found and, if its link is not signed, that every GS is told so and
        what its positions are worth."""
        endpoint = (self.vehicle.stream_stats().get("endpoint") or {})
        self._emit(rec.VehicleFound(sysid=self.vehicle.sysid or 0, autopilot=self.vehicle.state().autopilot,
                                    endpoint=endpoint.get("address"), how=endpoint.get("how")))
        st = self._fc_signing()
        if st and not st.get("signed"):
            trust = self.opts.trust_unsigned_position
            self._emit(rec.FcUnsigned(mode=str(st.get("mode")), state=str(st.get("state")), reason=str(st.get("reason") or ""),
                                      trust_unsigned_position=trust))
            log.warning("the autopilot's link is NOT signed (--fc-signing %s, %s): every GS is told so; %s", st.get("mode"),
                        st.get("state"), "its positions are trusted for authority (--trust-unsigned-position)" if trust
                        else "its positions grant no authority (no heir, no pairing that needs coverage)")
            print(f"zdrone drone {self.name}: autopilot link unsigned ({st.get('mode')}): positions "
                  f"{'trusted (--trust-unsigned-position)' if trust else 'grant no authority'}", flush=True)

    def stop(self, *_: object) -> None:
        self.rt.stop()

    def run(self) -> None:
        print(f"zdrone drone {self.name}: vehicle {self.opts.vehicle}, router {self.rt.router}", flush=True)
        self.events.write_record(rec.Start(vehicle=self.opts.vehicle))
        if not self.vehicle.wait_vehicle(30.0):
            raise ConfigError(f"vehicle {self.opts.vehicle}: no heartbeat within 30 s")
        print(f"zdrone drone {self.name}: vehicle sysid {self.vehicle.sysid} ready", flush=True)
        self._found()
        self._restore(time.monotonic())
        self.core.ready(time.time())
        inbox = self.rx
        self._vehicle_pushes = self.vehicle.start_reader(lambda msg: inbox.put(VEHICLE, VEHICLE, msg))
        try:
            while self.rt.running:
                self.step(self.sleep_time())
        finally:
            self.close()

    def next_deadline(self, now: float) -> float:
        """The earliest instant at which something is due if no input comes: the core's timer, the
        radio's late frames, the status event, the vehicle link's heartbeat."""
        due = [self._next_status, self.vehicle.next_due()]
        timer = self.core.get_timer()
        if timer is not None:
            due.append(timer)
        if self._late:
            due.append(self._late[0][0])
        if self._held_pairing:  # pairing queries held over the last turn's budget: the next turn answers them
            due.append(now)
        return min(due)

    def sleep_time(self) -> float:
        """How long the loop may wait for input now: until the next deadline, ``MAX_SLEEP_S`` at most."""
        return min(MAX_SLEEP_S, max(0.0, self.next_deadline(self._last_pass) - time.monotonic()))

    def take_inputs(self) -> None:
        """Handle what came, without waiting and without the rest of a pass: a host that steps many
        drones in turn calls it between their steps, so that a GS's frame does not wait for its
        drone's turn (a drone on its own companion wakes on it: ``step``'s wait)."""
        self.rx.drain(0.0, self._on_inbox)

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
        self.revision.serve(now)
        self.vehicle.heartbeat(now)
        if not self._vehicle_pushes:
            for frame in self.vehicle.recv(0.0):
                self._do(self.core.on_telemetry(frame, now), now)
        pos, trusted = self._pos(), self._position_trusted()
        if self.gate is not None:  # the testbed's radio follows the vehicle, never a position it cannot vouch for
            self.gate.update(self.vehicle.position if trusted else None)
        self._do(self.core.on_vehicle(pos, self._on_ground(), now, trusted), now)
        for outcome in self.vehicle.failsafe_outcomes():
            self._emit(_FAILSAFE_RECORDS[outcome.outcome](action=outcome.action, attempts=outcome.attempts,
                                                          after_s=outcome.after_s, seen=outcome.seen))
        timer = self.core.get_timer()
        if timer is not None and now >= timer:
            self._do(self.core.handle_timer(now), now)
        if now >= self._next_status:
            self._next_status = now + self.opts.status_period
            self.events.write_as(rec.DroneStatus, self.status(now))
        self.flush_down(now)

    def close(self) -> None:
        now = time.monotonic()  # the saved authority stays, on the ground too: the epoch goes on after a restart
        self.flush_down(now)
        self.rt.close(self.status(now), rec.DroneStop, extra_steps=(self.vehicle.close,))


def run_drone(opts: DroneOptions) -> int:
    node = DroneNode(opts)
    return node.rt.serve(node.run)
