"""TESTBED ONLY: outsiders. Attackers that hold stolen router passwords (and what they capture with
them, or a certificate of their own making) but no key of any GS: every attempt must end as a counted
drop at the drone, a refused handshake or a refused connection.

``no-key``: has GS A's *router* password (stolen) but not A's static key nor any link key. It
tries to pair as A with its own key, publishes unsealed MAVLink commands and forged envelopes on
``zdrone/<drone>/up/A``, and replays sealed frames it captured (with the drone's stolen router
password it can listen to ``up/A``; with A's it can publish there). Every attempt must end as a
counted drop at the drone (``unknown_epoch``, ``auth_failed``, ``replay``) or a failed handshake.
It also tries the router with a wrong password (refused at connect).

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

``uplink-unsealed``: A's router password only. Publishes the dangerous ids of ``uplink-sealed``
(``dangerous_messages``) on ``up/A``, unsealed and sealed with a random key: dropped by the security
module before the authority.

``no-cert``: a fleet with mutual TLS (``--tls``, ``--sites``). A's stolen router password, and in
turn: no client certificate at all (its own Zenoh configuration, trusting the fleet CA for the
router), a certificate for "A" from a CA of its own, and X's real certificate and key (a fleet
member, not A). The first two must be refused at connect; with X's certificate the router's ACL
wants CN *and* user to be A, so nothing it publishes on A's keys arrives and its pairing query as A
gets no answer.

``stale-pairing``: the drone's and A's router passwords. From before A starts, a queryable on
``zdrone/<drone>/pair/A`` (the drone's account) records every pairing message 1 A sends, all flight
long (never answered: the real drone answers A); it also holds ``--recorded`` message 1s of A recorded in
earlier flights (made with the genuine pairing code when the attacker starts, i.e. before this
flight, and never made again). When told (right after a companion restart) it replays them as A: a
few every 10 ms until the restarted drone answers one, then each one not yet answered every 0.1 s
(newest first; those A sends meanwhile too), for ``--duration``. A replay must spend none of
A's pairing tokens: the owner re-pairs at once and the drone never goes into its failsafe.
"""

from __future__ import annotations

import json
import logging
import os
import queue
import random
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

import msgspec
import zenoh
from cryptography.hazmat.primitives import serialization

from zdrone.core.envelope import SecureLink
from zdrone.core.fleet import ConfigError
from zdrone.core.keys import Identity, LinkKey
from zdrone.core.keyshare import LinkKeyQuery, _prologue as linkkey_prologue, decode_query
from zdrone.core.kk import KKInitiator, respond as kk_respond
from zdrone.core.mavlink import FrameCodec
from zdrone.core.pairing import PairingInitiator
from zdrone.fleet.files import load_secret
from zdrone.fleet import keyexprs
from zdrone.fleet.tls import issue, make_ca, node_files
from zdrone.sil import testbed_records as trec
from zdrone.net.session import open_client
from zdrone.sil.attackers.common import GO_TIMEOUT, ROGUE_COMPID, UPLINK_GAP_S, Ctx, dangerous_messages, land_frame, next_up, Replies


log = logging.getLogger("zdrone.sil.rogue")


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
            for lane in keyexprs.up_lanes(drone, "A")]
    try:
        c.ready()
        fake = Identity.generate()
        ini = PairingInitiator(fake, "A", drone, fleet.nodes[drone].public_bytes)
        replies = list(s_pub.get(keyexprs.pair(drone, "A"), payload=ini.start(), timeout=3.0))
        c.events.write_record(trec.PairAttempt(answered=sum(1 for r in replies if r.ok is not None)))
        forged = SecureLink(key=LinkKey.from_secret(drone, "A", os.urandom(32)), role="gs", tx_keyexpr=keyexprs.up(drone, "A"),
                            rx_keyexpr=keyexprs.down(drone, "A"), peer_sysid=None, now=0.0)
        sysid_a = fleet.nodes["A"].sysid
        sent = {"plain": 0, "forged": 0, "replayed": 0}
        going = c.attack_window()
        while going():  # each frame spaced above the router's per-key minimum gap: every one reaches the drone
            s_pub.put(next_up(drone, "A"), land_frame(sysid_a))
            sent["plain"] += 1
            time.sleep(UPLINK_GAP_S)
            s_pub.put(next_up(drone, "A"), forged.seal(land_frame(sysid_a)))
            sent["forged"] += 1
            for _ in range(4):
                time.sleep(UPLINK_GAP_S)
                try:
                    frame = captured.get_nowait()
                except queue.Empty:
                    break
                s_pub.put(next_up(drone, "A"), frame)
                sent["replayed"] += 1
            c.stop.wait(0.2)
        c.events.write("attack_done", **sent)
    finally:
        for cap in caps:
            cap.undeclare()
        s_cap.close()
        s_pub.close()


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
    qable = s.declare_queryable(keyexprs.linkkey_all("B"), zenoh.handlers.RingChannel(256))
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
                drone = keyexprs.gs_of(q.key_expr)
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
    replies = Replies()
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
            s.get(keyexprs.linkkey("A", drone), replies, payload=encoder.encode(LinkKeyQuery("B", m1)), timeout=2.0)
            sent["forged_m1"] += 1
            junk = junk_queries(rng)
            s.get(keyexprs.linkkey("A", drone), replies, payload=junk[i % len(junk)], timeout=2.0)
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
    qable = s_cap.declare_queryable(keyexprs.pair(drone, "A"), zenoh.handlers.RingChannel(16))
    s_a = open_client(c.router, "A", c.password("A"))
    captured: list[bytes] = []
    replies = Replies()
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
            s_a.get(keyexprs.pair(drone, "A"), replies, payload=captured[0], timeout=2.0)
            replayed += 1
            c.stop.wait(1.0)
        c.stop.wait(2.0)
        c.events.write("attack_done", replayed=replayed, replies=replies.snapshot())
    finally:
        s_a.close()
        s_cap.close()


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
                                tx_keyexpr=keyexprs.up(drone, "A"), rx_keyexpr=keyexprs.down(drone, "A"), peer_sysid=None, now=0.0)
            for _name, msg in dangerous_messages(target):
                frame = codec.encode(msg)
                s.put(next_up(drone, "A"), frame)
                sent["unsealed"] += 1
                time.sleep(UPLINK_GAP_S)  # under the router's per-key rate: every frame reaches the drone
                s.put(next_up(drone, "A"), forged.seal(frame))
                sent["random_key"] += 1
                time.sleep(UPLINK_GAP_S)
            c.stop.wait(0.5)
        c.events.write("attack_done", ids=len(dangerous_messages(target)), **sent)
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
    sub = s.declare_subscriber(keyexprs.down(drone, "A"), lambda smp: captured.put(b""))
    sent, answered = 0, 0
    try:
        ini = PairingInitiator(Identity.generate(), "A", drone, fleet.nodes[drone].public_bytes)
        answered = sum(1 for r in s.get(keyexprs.pair(drone, "A"), payload=ini.start(), timeout=2.0) if r.ok is not None)
        forged = SecureLink(key=LinkKey.from_secret(drone, "A", os.urandom(32)), role="gs", tx_keyexpr=keyexprs.up(drone, "A"),
                            rx_keyexpr=keyexprs.down(drone, "A"), peer_sysid=None, now=0.0)
        sysid_a = fleet.nodes["A"].sysid
        going = c.attack_window()
        while going():
            s.put(next_up(drone, "A"), land_frame(sysid_a))
            s.put(next_up(drone, "A"), forged.seal(land_frame(sysid_a)))
            sent += 2
            c.stop.wait(0.2)
    finally:
        sub.undeclare()
        s.close()
    c.events.write("attack_done", **outcome, sent=sent, pair_answered=answered, captured=captured.qsize())


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
    qable = s_cap.declare_queryable(keyexprs.pair(drone, "A"), zenoh.handlers.RingChannel(256))
    s_a = open_client(c.router, "A", c.password("A"))
    captured = {"before": 0, "after": 0}
    results: list[Replies] = [Replies() for _ in held]
    seen = set(held)

    def capture(when: str) -> None:
        """Record what A sends (never answered: the genuine drone answers A)."""
        while (q := qable.try_recv()) is not None:
            m1 = q.payload.to_bytes() if q.payload is not None else b""
            q.drop()
            if m1 and m1 not in seen:
                seen.add(m1)
                held.append(m1)
                results.append(Replies())
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
                s_a.get(keyexprs.pair(drone, "A"), results[i], payload=held[i], timeout=1.0)
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
