"""TESTBED ONLY: an authorized GS gone bad (malicious or compromised): B's own private key and router
password (and certificate), so that the drone and the other GSs take its frames as B's. What it must
not get is what B itself may not: authority without a hand-over, a command forwarded without
authority, another GS's live link.

``uplink-sealed``: B's private key and router password. When told to attack (after both hand-overs,
authority back with A), it pairs with the drone as B, proves the new key with sealed HEARTBEATs, and
sends every dangerous message id sealed on its link. The handover authority must drop them
(``not_authority``, ``denied_by_policy``): B is linked but not the authority.

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
"""

from __future__ import annotations

import queue
import time
from collections import Counter
from typing import Any, Callable

import zenoh
from pymavlink.dialects.v20 import common as mav

from zdrone.core.bundle import pack, unpack
from zdrone.core.envelope import Opened, SecureLink
from zdrone.core.fleet import ConfigError
from zdrone.core.keys import LinkKey
from zdrone.core.keyshare import KeyShareAsk
from zdrone.core.mavlink import FrameCodec
from zdrone.core.pairing import PairingInitiator
from zdrone.core import wire
from zdrone.fleet.files import load_secret
from zdrone.fleet import keyexprs
from zdrone.sil import testbed_records as trec
from zdrone.net.session import open_client
from zdrone.sil.attackers.common import ROGUE_COMPID, UPLINK_GAP_S, Ctx, dangerous_messages, gcs_heartbeat, next_up, session_as



def _envelopes_to(q: "queue.SimpleQueue[bytes]") -> Callable[[Any], None]:
    """A subscriber callback putting each envelope of a drone's bundle on ``q`` (as a GS reads them)."""
    def on_sample(smp: Any) -> None:
        for envelope in unpack(smp.payload.to_bytes()) or ():
            q.put(envelope)
    return on_sample

def uplink_sealed(c: Ctx) -> None:
    fleet, drone = c.fleet, c.drone
    me = load_secret(c.fleet_dir, "B", fleet)
    s = open_client(c.router, "B", me.router_password)
    down: queue.SimpleQueue[bytes] = queue.SimpleQueue()
    sub = s.declare_subscriber(keyexprs.down(drone, "B"), _envelopes_to(down))
    codec = FrameCodec(fleet.nodes["B"].sysid, ROGUE_COMPID)
    target = fleet.nodes[drone].sysid
    try:
        c.ready()
        if not c.wait_for_go():
            return
        ini = PairingInitiator(me.identity, "B", drone, fleet.nodes[drone].public_bytes, stamp=time.time())
        key = None
        refusals = []
        for r in s.get(keyexprs.pair(drone, "B"), payload=ini.start(), timeout=2.0):
            if r.ok is not None and key is None:
                out = ini.finish(r.ok.payload.to_bytes())
                key = out if isinstance(out, LinkKey) else None
            elif r.err is not None:
                refusals.append(r.err.payload.to_bytes().decode(errors="replace")[:80])
        if key is None:
            c.events.write_record(trec.RoguePairFailed(refusals=refusals))
            return
        now = time.monotonic()
        link = SecureLink(key=key, role="gs", tx_keyexpr=keyexprs.up(drone, "B"), rx_keyexpr=keyexprs.down(drone, "B"),
                          peer_sysid=target, now=now)
        c.events.write_record(trec.PairedAs(gs="B"))
        for _ in range(3):  # the proof of the new key: authentic, read-only frames
            s.put(next_up(drone, "B"), link.seal(codec.encode(gcs_heartbeat())))
            time.sleep(UPLINK_GAP_S)
        sent: Counter[str] = Counter()
        going = c.attack_window()
        while going():
            for name, msg in dangerous_messages(target):
                s.put(next_up(drone, "B"), link.seal(codec.encode(msg)))
                sent[name] += 1
                time.sleep(UPLINK_GAP_S)  # under the router's per-key rate: every frame reaches the drone
            s.put(next_up(drone, "B"), link.seal(codec.encode(gcs_heartbeat())))
            c.stop.wait(0.1)
        opened = 0
        while True:
            try:
                data = down.get_nowait()
            except queue.Empty:
                break
            res = link.open(data, time.monotonic())
            opened += len(res.items()) if isinstance(res, Opened) else 0  # a batch: each frame in it
        c.events.write("attack_done", sealed=dict(sent), total=sum(sent.values()), drone_frames_opened=opened)
    finally:
        sub.undeclare()
        s.close()


#: insider-heir: how often the attacker pairs again: the drone stops listening to B once a new key is
#: proven (outside the overlap), so each pairing brings a few frames, and B's link stays OK (< 1 s
#: of silence) only if it pairs about once a second (its allowance: 1/s, bursts of 3)
PAIR_EVERY_S = 1.0


#: insider-heir: HEARTBEATs sent at once under each new key (they reach the drone before it stops listening)
PROOF_BURST = 5


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
    s = session_as(c, "B")
    down: queue.SimpleQueue[bytes] = queue.SimpleQueue()
    sub = s.declare_subscriber(keyexprs.down(drone, "B"), _envelopes_to(down))
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
                        links = (links + [SecureLink(key=out, role="gs", tx_keyexpr=keyexprs.up(drone, "B"),
                                                     rx_keyexpr=keyexprs.down(drone, "B"), peer_sysid=target, now=now)])[-3:]
                        sent["pairings"] += 1
                        for _ in range(PROOF_BURST):  # the proof, and frames towards "proven"
                            s.put(next_up(drone, "B"), links[-1].seal(codec.encode(gcs_heartbeat())))
                        sent["heartbeats"] += PROOF_BURST
                        c.events.write_record(trec.PairedAs(gs="B"))
            if now >= next_pair:
                next_pair = now + PAIR_EVERY_S
                pairing = _Pairing(PairingInitiator(me.identity, "B", drone, fleet.nodes[drone].public_bytes,
                                                     stamp=time.time()))
                s.get(keyexprs.pair(drone, "B"), pairing, payload=pairing.ini.start(), timeout=2.0)
                sent["pair_queries"] += 1
            if links and now >= next_beat:
                next_beat = now + 0.2
                s.put(next_up(drone, "B"), links[-1].seal(codec.encode(gcs_heartbeat())))
                sent["heartbeats"] += 1
            if links and now >= next_cmd:
                next_cmd = now + 0.5
                s.put(next_up(drone, "B"), links[-1].seal(codec.encode(rtl)))
                sent["commands"] += 1
                if owner_at is not None or failsafe_at is not None:  # and ask for control, for itself
                    s.put(next_up(drone, "B"), links[-1].seal_control(wire.HandoverRequest("B", epoch)))
                    sent["control_requests"] += 1
                if owner_at is not None:  # in command: a landed vehicle is armed and taken off again
                    for msg in (arm, takeoff):
                        s.put(next_up(drone, "B"), links[-1].seal(codec.encode(msg)))
                        sent["commands"] += 1
            while True:  # what the drone says to B: who holds authority, the vehicle's answers
                try:
                    data = down.get_nowait()
                except queue.Empty:
                    break
                for link in reversed(links):
                    opened = link.open(data, now)
                    if not isinstance(opened, Opened):
                        continue
                    for res in opened.items():  # a batch of the drone's pass: each message
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
    s_b = session_as(c, "B")
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
            for r in s_b.get(keyexprs.linkkey("A", drone), payload=ask.payload, timeout=3.0):
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
            as_drone = SecureLink(key=key, role="drone", tx_keyexpr=keyexprs.down(drone, "A"), rx_keyexpr=keyexprs.up(drone, "A"),
                                  peer_sysid=fleet.nodes["A"].sysid, now=now)
            as_a = SecureLink(key=key, role="gs", tx_keyexpr=keyexprs.up(drone, "A"), rx_keyexpr=keyexprs.down(drone, "A"),
                              peer_sysid=fleet.nodes[drone].sysid, now=now)
            for _ in range(3):
                seq += 1
                s_d.put(keyexprs.down(drone, "A"), pack([as_drone.seal_control(wire.SmHeartbeat(seq))]))  # to A, as the drone
                s_a.put(next_up(drone, "A"), as_a.seal(FrameCodec(fleet.nodes["A"].sysid, ROGUE_COMPID).encode(gcs_heartbeat())))
                sent["injected_down"] += 1
                sent["injected_up"] += 1
                c.stop.wait(0.05)
            c.stop.wait(1.5)  # A's rate limit for B: 1/s, bursts of 3
        c.events.write("attack_done", **sent, refused=dict(refused))
    finally:
        s_a.close()
        s_d.close()
        s_b.close()
