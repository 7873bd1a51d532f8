"""``zdrone gs``: a ground station node — the Zenoh adapter of ``gs.core.StationCore``.

The protocol logic (pairing, key sharing with confirmation, hand-over coordination, mission stages)
is the pure ``StationCore``; this module owns the Zenoh session, the subscriber of the drones'
``down/<gs>`` keys, the ``backhaul/<gs>/linkkey/*`` queryable, the clock and the event log, and
carries out the core's actions. It sends a sealed MAVLink HEARTBEAT at 2 Hz on every link (the
drone's TBM liveness signal: no extra packets) and flies a mission (the reference mission or a
QGroundControl ``.plan``) when it holds authority.

One thread runs the loop; Zenoh callbacks only queue what they receive. No call in the loop
blocks: pairing and key-sharing queries are asynchronous (their replies come back through the
inbox), and the handshakes for incoming key-sharing queries are bounded per loop turn
(``LINKKEY_PER_TURN``) and rate-limited per asker in the core.

The loop sleeps until input arrives (an envelope, a query reply) or the core's timer is due
(``StationCore.get_timer``: at once after an input, the next heartbeat, the next look at its
periodic work), and calls ``handle_timer`` only then; the status event has its own time. The
key-sharing queryable's ring is looked at on every wake, at least every ``MAX_SLEEP_S``; loop hooks
that poll sockets (the GCS gateway) keep the loop at ``HOOK_POLL_S``. The adapter names drones and
reads ``DroneSeen``es (``drone_status``) and ``commands_sent``: the core's ``DroneView``s are its own.
If the fleet has a viewer, the station publishes its operations picture for it
(``zdrone.net.opspublish.OpsPublisher``: ``StationCore.drone_ops`` and the authority events it logs).
"""

from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass
from typing import Any, Callable

import zenoh

from zdrone.core import keyslost
from zdrone.core import records as rec
from zdrone.core.audit import Witnessing
from zdrone.core import wire
from zdrone.core.bundle import MAX_BUNDLE
from zdrone.core.errors import ConfigError
from zdrone.core.fleet import Fleet
from zdrone.core.keys import SigningKey
from zdrone.core.mavcontrol import OperatorControlRequest
from zdrone.fleet import keyexprs
from zdrone.fleet import revisions
from zdrone.net.eventlog import EventLog
from zdrone.net.inbox import payload_bytes
from zdrone.net.runtime import NodeRuntime

from zdrone.core.outputs import Handlers, dispatch

from gs.actions import Action, Ask, AskKind, Checkpoint, Emit, FrameUp, Put, ToOperator
from gs.core import GCS_COMPID, CoreOptions, DroneSeen, StationCore, view_line
from gs.planner import PlannedItem
from zdrone.net.opspublish import OpsPublisher

log = logging.getLogger(__name__)
#: Key-sharing handshakes answered per loop turn at most (the rest wait in the bounded query queue).
LINKKEY_PER_TURN = 2
#: Key-sharing queries looked at per loop turn (refusals cost microseconds each).
LINKKEY_QUERIES_PER_TURN = 256
#: While key-sharing queries wait in the ring for a turn's handshakes, the loop looks again this soon.
LINKKEY_BACKLOG_POLL_S = 0.005
#: The loop sleeps at most this long without input (the key-sharing queryable's ring is looked at
#: on every wake).
MAX_SLEEP_S = 0.05
#: The loop's period while a hook polls sockets of its own (the GCS gateway's endpoints).
HOOK_POLL_S = 0.005

__all__ = ["GCS_COMPID", "DroneSeen", "GroundStation", "StationOptions", "audit_on_revision", "run_station",
           "view_line"]


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
    take_control: bool = False  # take control back after a failsafe (the operator's standing request)
    allow_takeover: bool = False  # MAVLink operator control: another GS's request takes authority at once
    gcs_signing: str | None = None  # the gateway's MAVLink signing: off | prefer | require (None: require with keys)
    gcs_keys: str | None = None  # the gateway's application key file (``gs.appkeys``)
    pair_drones: frozenset[str] | None = None  # with ``pair``: only these drones (None: every one)
    missions: dict[str, list[PlannedItem]] | None = None  # a drone's own mission, over ``mission``


def audit_on_revision(events: EventLog, witnessing: Witnessing | None, fleet: Fleet, own: str,
                      old_signing: bytes | None, signing: SigningKey | None) -> bool:
    """A fleet revision applied at GS ``own`` (``fleet``: the new effective fleet): the drones it
    witnesses are countersigned under their keys in force now (a revoked drone's under none); if
    ``own``'s signing key in the fleet is not ``old_signing`` (the public key its record is signed
    under until now, None: none), its authority record and its countersignatures go on under
    ``signing`` if that is the key in force, else under none (unsigned, never under a retired key).
    Returns whether its own key changed."""
    if witnessing is not None:
        witnessing.set_node_keys({d: None if d not in fleet.nodes or fleet.is_revoked(d) else fleet.signing_public(d)
                                  for d in witnessing.node_keys})
    new = fleet.nodes[own].signing_public_bytes if own in fleet.nodes else None
    if new == old_signing:
        return False
    key = signing if signing is not None and signing.public == new else None
    events.rekey_audit(key)
    if witnessing is not None:
        witnessing.rekey(key)
    return True


class GroundStation:
    """One ground station node."""

    def __init__(self, opts: StationOptions) -> None:
        self.opts = opts
        self.started_wall = time.time()  # no link key of ours is older: our keys-lost notice's ``since``
        self.rt = NodeRuntime(opts.fleet, opts.gs, "gs", opts.router, opts.events)
        self.fleet, self.secret, self.events, self.rx = self.rt.fleet, self.rt.secret, self.rt.events, self.rt.inbox
        self.name = opts.gs
        self.sysid = self.rt.node.sysid
        drones = opts.drones or tuple(d for d in self.fleet.drones() if self.fleet.is_authorized(d, self.name))
        for d in drones:
            if d not in self.fleet.nodes or self.fleet.nodes[d].role != "drone":
                raise ConfigError(f"--drone {d}: not a drone of the fleet")
        self.core = StationCore(self.name, self.fleet, self.secret.identity, tuple(drones), CoreOptions(
            pair=opts.pair, mission=opts.mission, heartbeat_hz=opts.heartbeat_hz, command_rate=opts.command_rate,
            hysteresis_m=opts.hysteresis_m, cipher=opts.cipher, paper_heartbeat=opts.paper_heartbeat,
            take_control=opts.take_control, allow_takeover=opts.allow_takeover, seed=os.urandom(32),
            pair_drones=opts.pair_drones, missions=opts.missions))
        self.witnessing: Witnessing | None = None
        self.audit_key: bytes | None = None  # the public half of the key its record is signed under now
        self._offered: object = None  # the record's checkpoint last offered to its drones (``AuditChain.offer``)
        if self.secret.signing is not None:  # its own authority record; it countersigns the drones' checkpoints
            self.events.start_audit(self.secret.signing)
            self.witnessing = Witnessing(self.name, self.secret.signing, {d: self.fleet.signing_public(d) for d in drones})
            self.audit_key = self.secret.signing.public
        self.counters = self.core.counters
        self.frame_listeners: list[Callable[[str, bytes], None]] = []  # e.g. the GCS gateway
        self.loop_hooks: list[Callable[[float], None]] = []  # called once per loop pass with ``now``
        self.status_sources: dict[str, Callable[[], dict[str, Any]]] = {}  # e.g. the gateway's stats
        self.session = self.rt.session
        self.sub = self.rt.subscribe(keyexprs.down("*", self.name), "down", keyexprs.drone_of, limit=MAX_BUNDLE,
                                     pumped=True)  # every drone's reports: never a GIL wait in Zenoh's thread
        self.linkkey_q = self.rt.queryable(keyexprs.linkkey_all(self.name))
        self._linkkey_backlog = False  # the last turn left key-sharing queries in the ring (``_serve_linkkeys``)
        self.revision = revisions.RevisionChannel(self.rt, opts.fleet, publisher=True, write_applied=True,
                                                  signing=lambda: self.secret.signing, wall=time.time,
                                                  drones=self._vouched, notice=self._keys_lost_notice)
        # the operations picture for the fleet's viewer (``zdrone view``), if the fleet has one
        self.ops = OpsPublisher.for_station(self.name, self.fleet, self.secret.identity, self.core, self.rt.put)
        self._handlers: Handlers = {Put: self._put, FrameUp: self._frame_up, Ask: self._ask, Emit: self._emit,
                                    ToOperator: lambda a: print(a.text, flush=True), Checkpoint: self._countersign}

    def _vouched(self) -> list[str]:
        """The drones this GS's revision stamps name: those it is authorized for in the fleet in force."""
        return [d for d in self.fleet.drones() if self.fleet.is_authorized(d, self.name)]

    # ------------------------------------------------------------------ plumbing

    def _do(self, actions: list[Action]) -> None:
        """Carry out the core's actions."""
        dispatch(actions, self._handlers)

    def _put(self, a: Put) -> None:
        """A link frame on the drone's uplink key: paced, priority, express."""
        self.rt.put_link(keyexprs.up(a.peer, self.name), a.payload, time.monotonic())

    def _emit(self, a: Emit) -> None:
        self.events.write_record(a.record)
        if self.ops is not None:
            self.ops.on_record(a.record, time.time())

    def _frame_up(self, a: FrameUp) -> None:
        for listener in self.frame_listeners:
            listener(a.drone, a.frame)

    def _ask(self, a: Ask) -> None:
        if a.kind is AskKind.PAIR:
            rx, drone, m1 = self.rx, a.drone, a.payload  # the query's end names its exchange by its message 1
            self.rt.ask(a.keyexpr, a.payload, a.timeout, "pair", a.drone, on_done=lambda: rx.put("pair_done", drone, m1))
        else:
            gs = a.gs
            self.rt.ask(a.keyexpr, a.payload, a.timeout, "linkkey", a.drone, wrap=lambda r: (gs, r))

    @property
    def drones(self) -> tuple[str, ...]:
        return self.core.drones

    def drone_status(self, drone: str, now: float) -> DroneSeen:
        return self.core.drone_status(drone, now)

    def commands_sent(self, drone: str) -> int:
        """Commanding frames this GS sent the drone, all epochs (``zdrone.bench.scale`` counts them)."""
        return self.core.commands_sent(drone)

    def send_frame(self, drone: str, frame: bytes) -> None:
        """Seal and send one MAVLink frame to the drone (no-op without a link)."""
        self._do(self.core.send_frame(drone, frame))

    def send_msg(self, drone: str, msg: Any) -> None:
        self._do(self.core.send_msg(drone, msg))

    def send_control(self, drone: str, msg: wire.Control) -> None:
        self._do(self.core.send_control(drone, msg))

    def holds_authority(self, drone: str) -> bool:
        return self.core.holds_authority(drone)

    def operator_command(self, drone: str, req: OperatorControlRequest, now: float, app: str = "",
                         app_sysid: int | None = None) -> int:
        """An application's MAV_CMD_REQUEST_OPERATOR_CONTROL: carried out; the MAV_RESULT it gets at once
        (``app``: the application's name, ``app_sysid``: its own sysid; see ``StationCore.operator_command``)."""
        answer, actions = self.core.operator_command(drone, req, now, app=app, app_sysid=app_sysid)
        self._do(actions)
        return int(answer)

    def _countersign(self, a: Checkpoint) -> None:
        """Countersign a drone's authority-record checkpoint from its authentic status
        (``zdrone.core.audit``; logged in this GS's record)."""
        if self.witnessing is not None and not self.events.countersign(self.witnessing, a.drone, a.head, time.time()):
            self.counters["audit_bad_checkpoint"] += 1

    # ------------------------------------------------------------------ inbox
    def _on_inbox(self, kind: str, drone: str, data: Any, now: float) -> None:
        if kind in revisions.KINDS:
            self._on_revision(kind, data, now)
        elif kind == "down":
            self._do(self.core.on_bundle(drone, data, now))
        elif kind == "pair_done":
            self._do(self.core.on_pair_done(drone, data, now))
        elif kind == "pair":
            self._do(self.core.on_pair_reply(drone, data[0], data[1], now))
        elif kind == "linkkey":
            gs, (ok, err) = data
            self._do(self.core.on_linkkey_reply(drone, gs, ok, err, now))

    def _on_revision(self, kind: str, data: Any, now: float) -> None:
        """A fleet revision heard: the next one is applied live (the core reads the new fleet: revoked
        nodes are on no authorized list); the drones' checkpoints are countersigned under their keys
        in force from now on (``audit_on_revision``). If this GS's keys in the fleet are not those of
        the secret it holds (a rotation, or one whose new secret was not on this host yet), the new
        secret is taken from the bundle: its record, its countersignatures and its revision stamps go on
        under the new signing key, and if its identity changed every linked drone is re-paired under
        it (``StationCore.adopt_identity``); if it rotated ours or the viewer's, the operations picture
        is sealed under the new keys."""
        got = self.revision.on_inbox(kind, data)
        notice = self.revision.take_notice()
        if notice is not None:  # another GS restarted: the drones we own share its key again
            self.core.on_keys_lost(notice, now, time.time())
        if isinstance(got, revisions.RevisionAccepted):
            self.fleet = self.core.fleet = got.fleet
            mine, held = got.fleet.nodes[self.name], self.secret
            if (mine.public_bytes, mine.signing_public_bytes) != (
                    held.identity.public, held.signing.public if held.signing is not None else None):
                self._adopt_own_key(now)
            else:
                audit_on_revision(self.events, self.witnessing, self.fleet, self.name, self.audit_key, None)
            if self.ops is not None and self.ops.reseal(got.fleet, self.core.identity):
                log.warning("operations picture sealed anew (a key rotated: ours or the viewer's)")

    def _keys_lost_notice(self) -> bytes | None:
        """Our keys-lost notice while we publish one (``keyslost.NOTICE_FOR_S`` after our start): we keep
        no link key across a restart, so every drone's owner shares our key again."""
        wall = time.time()
        if self.secret.signing is None or wall - self.started_wall > keyslost.NOTICE_FOR_S:
            return None
        return keyslost.make_notice(self.name, self.started_wall, wall, self.secret.signing)

    def _adopt_own_key(self, now: float) -> None:
        from zdrone.fleet.files import load_secret

        try:
            secret = load_secret(self.opts.fleet, self.name, self.fleet)
        except ConfigError as exc:  # the new bundle is not on this host yet: nothing more signed with a retired key
            log.warning("own key rotated by the fleet, but the bundle does not hold the new one: %s", exc)
            self.counters["rotation_pending"] += 1
            audit_on_revision(self.events, self.witnessing, self.fleet, self.name, self.audit_key, None)
            self.audit_key = None
            return
        audit_on_revision(self.events, self.witnessing, self.fleet, self.name, self.audit_key, secret.signing)
        self.audit_key = secret.signing.public if secret.signing is not None else None
        renewed = secret.identity.public != self.secret.identity.public
        self.secret = secret  # the revision stamps (``RevisionChannel``'s ``signing``) follow
        if renewed:
            log.warning("own key rotated by the fleet: re-pairing every linked drone under the new key")
            self.counters["rotated"] += 1
            self._do(self.core.adopt_identity(secret.identity, now, time.time()))

    def _serve_linkkeys(self, now: float) -> None:
        """Answer key-sharing queries: refusals cost no crypto; ``LINKKEY_PER_TURN`` handshakes at most."""
        handshakes = 0
        self._linkkey_backlog = False
        for _ in range(LINKKEY_QUERIES_PER_TURN):
            if handshakes >= LINKKEY_PER_TURN:
                # the turn's handshakes are spent: what is left stays in the bounded ring for the next
                # turn (soon: ``poll_period``), unanswered queries would cost the asker its whole timeout
                self.counters["linkkey_deferred"] += 1
                self._linkkey_backlog = True
                return
            q = self.linkkey_q.try_recv()
            if q is None:
                return
            try:
                payload = payload_bytes(q.payload)
                if payload is None:
                    self.counters["linkkey_refused:oversize"] += 1
                    continue
                ans, actions = self.core.on_linkkey_query(keyexprs.gs_of(q.key_expr), payload, now, os.urandom(32), time.time())
                handshakes += ans.crypto
                if ans.reply is not None:
                    q.reply(q.key_expr, ans.reply)
                elif ans.error is not None:
                    q.reply_err(ans.error)
                self._do(actions)
            except zenoh.ZError as exc:
                self.counters["linkkey_reply_error"] += 1
                log.info("linkkey reply failed: %s", exc)
            except Exception:  # last resort: no query may end the GS (counted, logged with its stack)
                self.counters["linkkey_internal_error"] += 1
                log.exception("linkkey query")
            finally:
                q.drop()

    # -------------------------------------------------------------------- loop
    def status(self) -> dict[str, Any]:
        extra = {name: source() for name, source in self.status_sources.items()}
        return {**self.core.report(time.monotonic()), "inbox_dropped": self.rx.stats(), **extra}

    def print_view(self, now: float) -> None:
        """The telemetry view: one line per linked drone on stdout (``view_line``)."""
        for d in self.core.drones:
            line = self.core.describe(d, now)
            if line is not None:
                print(line, flush=True)

    def stop(self, *_: object) -> None:
        self.rt.stop()

    killed = False

    def kill(self) -> None:
        """A testbed's crash of this GS in a host shared with others (``bench scale --layout corridor``'s
        ``--kill-owner``): its loop ends now and its Zenoh session closes; nothing more is sent."""
        self.killed = True
        self.rt.stop()

    def _offer_checkpoint(self) -> None:
        """Our record's newest checkpoint that covers a decision, not offered yet: to the drones its
        decisions name, to countersign (``StationCore.offer_checkpoint``)."""
        offer = self.events.audit.offer if self.events.audit is not None else None
        if offer is not None and offer is not self._offered:
            self._offered = offer
            cp, drones = offer
            self._do(self.core.offer_checkpoint(drones, wire.AuditHead(*cp.raw())))

    def step(self, now: float) -> None:
        """One pass of the loop."""
        self._serve_linkkeys(now)
        self.revision.serve(now)
        self._offer_checkpoint()
        if now >= self.core.get_timer():
            self._do(self.core.handle_timer(now, time.time()))
        self.rt.flush(now)

    def wait_time(self, until: float) -> float:
        """How long the loop may wait for input: until ``until``, the core's timer, the next paced
        frame or the next look at the key-sharing ring (``poll_period``), whichever comes first."""
        now = time.monotonic()
        due = [until - now, self.core.get_timer() - now, self.poll_period()]
        if self.ops is not None:
            due.append(self.ops.next_due() - now)
        paced = self.rt.next_flush()
        if paced is not None:
            due.append(paced - now)
        return max(0.0, min(due))

    def drain(self, timeout: float) -> None:
        self.rx.drain(timeout, self._on_inbox)

    def poll_period(self) -> float:
        """How long the loop sleeps at most without input, for what wakes nobody: the key-sharing
        queryable's ring (``MAX_SLEEP_S``), the sockets a loop hook polls (``HOOK_POLL_S``)."""
        if self._linkkey_backlog:
            return LINKKEY_BACKLOG_POLL_S
        return HOOK_POLL_S if self.loop_hooks else MAX_SLEEP_S

    def run(self) -> None:
        print(f"zdrone gs {self.name}: sysid {self.sysid}, drones {', '.join(self.drones)}, router {self.opts.router}", flush=True)
        self.events.write_record(rec.GsStart(drones=list(self.drones)))
        next_status = next_view = 0.0
        try:
            while self.rt.running:
                self.drain(self.wait_time(next_status))
                now = time.monotonic()
                self.step(now)
                if self.ops is not None:
                    self.ops.publish(now, time.time())
                for hook in self.loop_hooks:
                    hook(now)
                self.rt.flush(now)
                if now >= next_status:
                    next_status = now + self.opts.status_period
                    self.events.write_as(rec.GsStatus, self.status())
                    if now >= next_view:
                        next_view = now + 5.0
                        self.print_view(now)
        finally:
            self.close()

    def close(self) -> None:
        self.rt.close(self.status(), rec.GsStop)


def run_station(opts: StationOptions) -> int:
    station = GroundStation(opts)
    gateway = None
    if opts.gcs:
        from gs.gateway import GcsGateway

        from gs.appkeys import load_gs_keys, signing_state_path

        try:
            keys = load_gs_keys(opts.gcs_keys, station.name, others=station.fleet.ground_stations()) if opts.gcs_keys else ()
            mode = opts.gcs_signing or ("require" if opts.gcs_keys else "prefer")
            state = signing_state_path(opts.gcs_keys, station.name) if opts.gcs_keys else None
            gateway = GcsGateway(station, list(opts.gcs), signing=mode, keys=keys, state_path=state)
        except ConfigError:
            station.close()
            raise
        station.status_sources["gateway"] = gateway.stats
        print(f"zdrone gs {station.name}: GCS gateway on {', '.join(gateway.endpoints())} for {gateway.drone}", flush=True)
        print(f"zdrone gs {station.name}: GCS signing {mode}, {len(keys)} application key(s)"
              + {"require": ": only signed applications may command or speak for the operator",
                 "prefer": ": unsigned applications may command and speak for the operator (any local process)",
                 "off": ": any local process may command and speak for the operator"}[mode], flush=True)
    try:
        return station.rt.serve(station.run)
    finally:
        if gateway is not None:
            gateway.close()
