"""TESTBED ONLY: attackers on the fleet's operations picture (``zdrone view``): GSs that tell the
viewer what only the drone may say. Each seals its parts for the viewer as a GS does
(``zdrone.core.opspicture.OpsSealer``), on its own key, with real credentials from the run's fleet
directory, so every part opens at the viewer: what is tested is what the picture makes of them.

``ops-unauthorized``: GS X's own static key and router password (X is in the fleet, authorized for
no drone). Told to attack, it publishes on ``zdrone-ops/X/<lane>`` (the keys the router lets it put its
picture on) at ``--rate`` parts a second, with a burst of ``BURST`` parts at once every
``BURST_EVERY_S``: d1 in its FAILSAFE, held by X at epoch ``LIE_EPOCH``, takeover allowed, a
request pending, its position ``LIE_OFFSET_DEG`` away, the link ``ok`` and heard 0 s ago (a stopped
drone made to look alive); a drone outside the fleet; authority events naming d1, and naming no
drone at all.

``ops-insider``: B's own static key and router password (an authorized GS gone bad), and the
viewer's router password (leaked: the router hop watched). From its start it reads B's own pictures
on their way to the viewer (the key of each is made from B's static key and the viewer's public
one, which B holds) and keeps the drone's signed words on its authority they carry
(``AuthorityAttestation``: genuine, the drone's own signature), logging the first of each owner and
epoch (``word_captured``). Told to attack, it publishes parts as B at ``--rate``: d1 in its
FAILSAFE, held by B at epoch ``LIE_EPOCH``, the link ``ok`` and heard 0 s ago, a position elsewhere,
takeover allowed, a request pending, and, as the drone's word, the *oldest* word it kept of B's
holding authority (captured early; authority moved on since), else the oldest it kept at all.
"""

from __future__ import annotations

import itertools
import os
import queue
import time
from collections import Counter
from typing import Any

from cryptography.exceptions import InvalidTag
from cryptography.hazmat.primitives.ciphers.aead import ChaCha20Poly1305

from zdrone.core import opspicture as op
from zdrone.core.keys import public_key
from zdrone.core.wire import AuthorityAttestation
from zdrone.fleet import keyexprs
from zdrone.fleet.files import load_secret
from zdrone.sil import testbed_records as trec
from zdrone.sil.attackers.common import GO_TIMEOUT, Ctx, session_as

#: The epoch the liars name (far above any the flight reaches).
LIE_EPOCH = 99
#: ops-unauthorized: a burst of this many parts at once ...
BURST = 60
#: ... every this many seconds of the attack (the first one this long after the go).
BURST_EVERY_S = 3.0
#: The position the liars give d1: this far (degrees, ~2 km) north-east of where their own GS stands.
LIE_OFFSET_DEG = 0.02


def _lie(fleet: Any, gs: str, drone: str, attest: AuthorityAttestation | None) -> op.DroneOps:
    """What only the drone may say, said by ``gs``."""
    cov = fleet.nodes[gs].coverage
    lat, lon = (cov.lat, cov.lon) if cov is not None else (0.0, 0.0)
    return op.DroneOps(drone=drone, linked=True, owner=gs, epoch=LIE_EPOCH, state="failsafe", pending_to=gs, link="ok",
                       since_last=0.0, mode="LAND", armed=True, position=(lat + LIE_OFFSET_DEG, lon + LIE_OFFSET_DEG, 60.0),
                       mission_seq=0, stage=f"{gs}'s lie", fc_signed=True, failsafe=True, holds=True,
                       request=op.OpsRequest(gs, gs, LIE_EPOCH, 0.0, 10.0, "allowed"), takeover=True, attest=attest)


def _sealer(c: Ctx, gs: str) -> op.OpsSealer:
    fleet = c.fleet
    viewer = fleet.viewers()[0]
    me = load_secret(c.fleet_dir, gs, fleet)
    return op.OpsSealer(me.identity, gs, viewer, fleet.nodes[viewer].public_bytes, keyexprs.ops(gs), os.urandom(op.SALT_LEN))


_LANE = itertools.count()


def _publish(s: Any, sealer: op.OpsSealer, drones: list[op.DroneOps], events: list[op.OpsEvent]) -> int:
    """Each part on the next of the GS's lanes in turn (the most the router lets one credential through)."""
    parts = op.report_parts(sealer.gs, round(time.time(), 3), drones, events)
    for part in parts:
        s.put(keyexprs.ops_lane(sealer.gs, next(_LANE) % keyexprs.OPS_LANES), sealer.seal(part))
    return len(parts)


def ops_unauthorized(c: Ctx) -> None:
    fleet, drone = c.fleet, c.drone
    s = session_as(c, "X")
    sealer = _sealer(c, "X")
    sent: Counter[str] = Counter()
    try:
        c.ready()
        if not c.wait_for_go():
            return
        going = c.attack_window()
        start = time.monotonic()
        next_burst = start + BURST_EVERY_S
        while going():
            t = round(time.time(), 3)
            drones = [_lie(fleet, "X", drone, None), _lie(fleet, "X", "d99", None)]  # d99: no drone of the fleet
            events = [op.OpsEvent(t, drone, "failsafe_notice", f"{drone} FAILSAFE, X holds authority (X's lie)"),
                      op.OpsEvent(t, "", "authority_status", f"{drone}: owner X, epoch {LIE_EPOCH}, failsafe (X's lie)")]
            n = 1
            if time.monotonic() >= next_burst:
                n, next_burst = BURST, next_burst + BURST_EVERY_S
                sent["bursts"] += 1
            for _ in range(n):
                sent["parts"] += _publish(s, sealer, drones, events)
            c.stop.wait(1.0 / c.rate)
        c.events.write("attack_done", **sent, rate=c.rate, burst=BURST)
    finally:
        s.close()


class _Reader:
    """Opens B's own parts on their way to the viewer, with B's static key (the viewer's public one
    is in the fleet file): one ChaCha20-Poly1305 key per start (salt) of B's."""

    def __init__(self, c: Ctx, gs: str) -> None:
        fleet = c.fleet
        self.gs, self.viewer = gs, fleet.viewers()[0]
        me = load_secret(c.fleet_dir, gs, fleet)
        self.shared = me.identity.private_key().exchange(public_key(fleet.nodes[self.viewer].public_bytes))
        self.keys: dict[bytes, ChaCha20Poly1305] = {}

    def open(self, data: bytes, own_salt: bytes) -> op.OpsReport | None:
        if len(data) < op.HEADER_LEN + op.TAG_LEN:
            return None
        _, salt, _ = op._HEADER.unpack_from(data)
        if salt == own_salt:
            return None
        aead = self.keys.get(salt)
        if aead is None:
            aead = self.keys[salt] = ChaCha20Poly1305(op._key(self.shared, self.gs, self.viewer, salt))
        header = data[:op.HEADER_LEN]
        try:
            part = aead.decrypt(b"\0\0\0\0" + header[-8:], data[op.HEADER_LEN:],
                                op._ad(keyexprs.ops(self.gs), self.gs, self.viewer, header))
        except InvalidTag:
            return None
        try:
            return op._DEC.decode(part)
        except Exception:
            return None


def ops_insider(c: Ctx) -> None:
    fleet, drone = c.fleet, c.drone
    viewer = fleet.viewers()[0]
    s = session_as(c, "B")
    watch = session_as(c, viewer)  # the viewer's leaked password: it may subscribe to the pictures, nothing else
    heard: "queue.SimpleQueue[bytes]" = queue.SimpleQueue()
    sub = watch.declare_subscriber(keyexprs.ops("B") + "/*", lambda smp: heard.put(smp.payload.to_bytes()))
    reader = _Reader(c, "B")
    sealer = _sealer(c, "B")
    kept: dict[tuple[str | None, int], AuthorityAttestation] = {}  # (owner, epoch) -> the first word of it seen
    sent: Counter[str] = Counter()

    def read() -> None:
        while True:
            try:
                data = heard.get_nowait()
            except queue.Empty:
                return
            report = reader.open(data, sealer.salt)
            if report is None:
                continue
            sent["parts_read"] += 1
            for d in report.drones:
                a = d.attest
                if d.drone != drone or a is None or (a.owner, a.epoch) in kept:
                    continue
                kept[(a.owner, a.epoch)] = a
                c.events.write_record(trec.WordCaptured(owner=a.owner, epoch=a.epoch, state=a.state.value, at=a.at,
                                                        seq=a.seq))

    try:
        c.ready()
        deadline = time.monotonic() + GO_TIMEOUT
        while c.wait_go and not c.stop.is_set() and not c.go.is_set() and time.monotonic() < deadline:
            read()  # reading B's pictures until told to attack
            c.stop.wait(0.05)
        if not c.wait_for_go():
            return
        read()
        words = sorted(kept.values(), key=lambda a: (a.at, a.seq))
        replay = next((a for a in words if a.owner == "B"), words[0] if words else None)
        going = c.attack_window()
        while going():
            read()
            t = round(time.time(), 3)
            events = [op.OpsEvent(t, drone, "failsafe_notice", f"{drone} FAILSAFE, B holds authority (B's lie)")]
            sent["parts"] += _publish(s, sealer, [_lie(fleet, "B", drone, replay)], events)
            c.stop.wait(1.0 / c.rate)
        c.events.write("attack_done", **sent, rate=c.rate, words_kept=len(kept),
                       replayed=None if replay is None else {"owner": replay.owner, "epoch": replay.epoch,
                                                             "state": replay.state.value, "at": replay.at,
                                                             "seq": replay.seq})
    finally:
        sub.undeclare()
        watch.close()
        s.close()
