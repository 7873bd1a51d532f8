"""TESTBED ONLY: floods and junk, as much as an account lets through: the router limits them, the
nodes refuse them before any work (by rate, by length, by epoch) and fly on.

``pair-flood``: B's private key and router password (an authorized GS that does not hold authority).
Sends valid Noise KK pairing queries as B as fast as ``--rate`` asks (non-blocking ``session.get``
with a no-op callback, from a pool of pre-computed messages 1) and logs the rate achieved. The
drone must refuse nearly all before any crypto (``pair_refused:rate_limited``) and keep its loop.

``big-flood``: B's router password only. Sends oversized payloads everywhere B's account may:
envelopes on ``zdrone/<drone>/up/B``, pairing queries to the drone as B and key-sharing queries to A
(60 KiB each, ``--rate`` per second of each), and one 4 MiB message of each kind per second. The
router drops messages over 64 KiB; the nodes refuse the rest by their length before copying them
(``up:oversize``, ``pair_refused:oversize``, ``linkkey_refused:oversize``) and fly on.

``junk-flood``: B's router password (with a TLS router, and B's certificate). Publishes junk envelopes on ``zdrone/<drone>/up/B`` as fast
as ``--rate`` asks (default 80 000/s), paced in 5 ms slices: ``--size`` (40) random bytes whose epoch byte is, in
turn, 0 and 1 (the live epoch and the next one of a fresh link: each costs the drone one AEAD
attempt) and any other value (unknown epoch). The router cuts the key to its rate limit; GS A's
link, on its own key, must stay OK.
"""

from __future__ import annotations

import os
import random
import time
from collections import Counter

import zenoh

from zdrone.core.pairing import PairingInitiator
from zdrone.fleet.files import load_secret
from zdrone.fleet import keyexprs
from zdrone.sil import testbed_records as trec
from zdrone.net.session import open_client
from zdrone.sil.attackers.common import Ctx, Replies, next_up, session_as


def pair_flood(c: Ctx) -> None:
    fleet, drone = c.fleet, c.drone
    me = load_secret(c.fleet_dir, "B", fleet)  # B's private key and router password
    s = open_client(c.router, "B", me.router_password)
    replies = Replies()
    key = keyexprs.pair(drone, "B")
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


def big_flood(c: Ctx) -> None:
    drone = c.drone
    s = open_client(c.router, "B", c.password("B"))
    replies = Replies()
    sent: Counter[str] = Counter()
    big, huge = os.urandom(60 * 1024), os.urandom(4 * 1024 * 1024)
    try:
        c.ready()
        if not c.wait_for_go():
            return
        going = c.attack_window()
        period, next_huge = 1.0 / c.rate, 0.0
        while going():
            s.put(next_up(drone, "B"), big, congestion_control=zenoh.CongestionControl.DROP)
            s.get(keyexprs.pair(drone, "B"), replies, payload=big, timeout=1.0)
            s.get(keyexprs.linkkey("A", drone), replies, payload=big, timeout=1.0)
            sent["big"] += 3
            if time.monotonic() >= next_huge:
                next_huge = time.monotonic() + 1.0
                s.put(next_up(drone, "B"), huge, congestion_control=zenoh.CongestionControl.DROP)
                s.get(keyexprs.pair(drone, "B"), replies, payload=huge, timeout=1.0)
                s.get(keyexprs.linkkey("A", drone), replies, payload=huge, timeout=1.0)
                sent["huge"] += 3
            c.stop.wait(period)
        c.stop.wait(1.5)  # the last replies
        c.events.write("attack_done", replies=replies.snapshot(), **sent)
    finally:
        s.close()


def junk_flood(c: Ctx) -> None:
    drone = c.drone
    s = session_as(c, "B", own_site=False)  # B's password (and, with TLS, B's certificate), at --router
    rng = random.Random(19)
    per_epoch = max(1, min(64, (64 << 20) // (3 * c.size)))  # at most 64 MiB of junk in memory
    pool = [bytes([e]) + rng.randbytes(c.size - 1) for e in (0, 1, 7) for _ in range(per_epoch)]  # epochs 0, 1, unknown
    rng.shuffle(pool)
    keys = keyexprs.up_lanes(drone, "B")  # every lane: the most the router lets through
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
