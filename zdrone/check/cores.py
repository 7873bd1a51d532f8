"""``zdrone check --cores``: the same bounded exploration, over the shipped cores themselves.

Theory of operation
-------------------
``zdrone.check.abstract`` explores the drone's decision rules inside an abstract world. This module
explores the real thing at a smaller depth: the drone's ``DroneCore`` and the ground stations' A and B
``StationCore``s (``zdrone.bench.fleetnet``: real Noise KK pairing and key sharing, real sealed
envelopes, explicit time), starting from A paired on the ground with B's key shared. Each move is
applied to a deep copy of the whole fleet (the AEAD contexts are stateless and shared between copies),
and states are de-duplicated by a hash of what the nodes know: the authority's state, owner, epoch
and pending recipient, each link's state and whether both ends hold the same live key, each GS's
view of the authority, the position, the radio cuts and hangs.

Moves: time passes half a second (both GSs tick, heartbeats flow, deadlines pass); the drone moves
between A's coverage, the overlap, B's coverage, outside both, and an unknown position; a GS's radio
is cut or comes back; a GS hangs or wakes; the companion restarts in the air; the outsider replays
the last captured envelope of A and A's captured pairing message 1s; the authorized but malicious GS
B re-pairs from wherever the drone is, asks for authority, forges a release, grants a key for A and
proves it as A (when it holds authority), and asks A for A's own key over the backhaul and forges a
frame under it to A; the unauthorized GS X pairs. The network's losses, duplicates and reordering
are the cuts and the replays.

Invariants after every move: the epoch never goes back (a restart included); within its window after
a restart on the ground, authority only to the last owner; commands forwarded only from each epoch's owner; an emergency or
regained authority only to a GS whose coverage holds the drone; no grant replaces a live key on the
drone, and no key another GS learned replaces a GS's live key while it hears the drone; the failsafe
(or an heir) once the owner's link is LOST; and a healthy crossing hands over both ways.
"""

from __future__ import annotations

import contextlib
import copy
import logging
import os
import struct
import tempfile
import time
from collections import deque
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable, Iterator

from cryptography.hazmat.primitives.ciphers.aead import AESGCM, ChaCha20Poly1305
from pymavlink.dialects.v20 import common as mav

from zdrone.bench.fleetnet import WALL0, FleetNet, make_fleet
from zdrone.core import records as rec
from zdrone.core import wire
from zdrone.core.authority import State
from zdrone.core.envelope import SecureLink
from zdrone.core.geometry import GeoPoint, offset
from zdrone.core.keys import LinkKey
from zdrone.core.keyshare import KeyShareAsk, Refused
from zdrone.core.kk import stamp_of
from zdrone.core.mavlink import FrameCodec
from zdrone.core.pairing import PairingInitiator
from zdrone.core.tbm import LinkState
from zdrone.fleet.files import load_secret

# Stateless or immutable objects that deep copies of a fleet may share (they cannot be pickled).
for _shared in (ChaCha20Poly1305, AESGCM, struct.Struct, logging.Logger):
    copy._deepcopy_dispatch[_shared] = lambda x, memo: x  # type: ignore[attr-defined]

Move = tuple[str, Callable[[FleetNet], None]]


class Broken(Exception):
    def __init__(self, invariant: str, detail: str) -> None:
        super().__init__(detail)
        self.invariant, self.detail = invariant, detail


@contextlib.contextmanager
def planted(flaw: str | None) -> Iterator[None]:
    """PLANTED FLAWS, for proving the checker can fail: patch the shipped rule for the run."""
    from zdrone.core import authority, linkslot, pairing

    if flaw is None:
        yield
        return
    if flaw == "heir-without-position":
        target, name, bad = authority.AuthorityMachine, "proven_in_cover", \
            lambda self, gs: self.is_authorized(gs) and self.is_proven(gs)
    elif flaw == "promotion-over-live":
        target, name, bad = linkslot, "replaces_live", lambda origin, live: True
    elif flaw == "pairing-without-position":
        target, name = authority.AuthorityMachine, "pair_refusal"
        original_rule = authority.AuthorityMachine.pair_refusal

        def bad(self, gs, on_ground, now):  # type: ignore[no-untyped-def]
            why = original_rule(self, gs, on_ground, now)
            return None if why is not None and why.reason is pairing.PairRefusal.OUTSIDE_COVERAGE else why
    elif flaw == "unstamped-pairing":
        original = pairing.PairingResponder.answer
        target, name = pairing.PairingResponder, "answer"

        def bad(self, gs, message1, now, secret, policy=None, holds_key=False, wall=None):  # type: ignore[no-untyped-def]
            self.cache = pairing.ResponseCache(0.0)  # and forgets its answers, like a restarted companion
            return original(self, gs, message1, now, secret, policy, holds_key, None)
    elif flaw == "forgetful-ground-restart":
        from zdrone.nodes import drone_actions, drone_core

        target, name = drone_core.DroneCore, "restore"
        original_restore = drone_core.DroneCore.restore

        def bad(self, owner, epoch, state, now):  # type: ignore[no-untyped-def]
            if self.on_ground:  # forgotten on the ground: the epoch starts at 1 again, whoever pairs first
                return [drone_actions.Persist(None, 0, State.UNPAIRED.value)]
            return original_restore(self, owner, epoch, state, now)
    else:
        raise ValueError(f"unknown flaw {flaw!r}")
    saved = getattr(target, name)
    setattr(target, name, bad)
    try:
        yield
    finally:
        setattr(target, name, saved)


class CoreExplorer:
    """Breadth-first over the cores, up to ``depth`` moves."""

    def __init__(self, depth: int, faults: int = 2, max_states: int | None = None, fleet_dir: Path | None = None,
                 flaw: str | None = None) -> None:
        self.depth, self.max_faults, self.max_states, self.flaw = depth, faults, max_states, flaw
        self.fleet_dir = fleet_dir or make_fleet(Path(tempfile.mkdtemp(prefix="zdrone-check-")))
        self.transitions = 0

    # ----------------------------------------------------------------- the world
    def initial(self) -> FleetNet:
        net = FleetNet(self.fleet_dir)
        net.add_gs("A", pair=True)
        net.add_gs("B")
        net.run(4.0)
        assert net.drone is not None and net.drone.machine.owner == "A" and set(net.drone.links) == {"A", "B"}
        net.on_ground = False
        net.faults = 0  # type: ignore[attr-defined]
        a, b = net.centre("A"), net.centre("B")
        net.places = {  # type: ignore[attr-defined]
            # the overlap nearer B's centre: where A releases authority to B
            "A": a, "AB": net.between(a, b, 0.62), "B": b, "none": offset(a, 2000.0, 0.0), "unknown": None}
        return net

    def place(self, net: FleetNet) -> str:
        for name, p in net.places.items():  # type: ignore[attr-defined]
            if p == net.position:
                return name
        return "?"

    def key(self, net: FleetNet) -> tuple:
        d = net.drone
        assert d is not None
        m = d.machine
        now = net.now
        links = []
        for g in ("A", "B", "X"):
            live = d.links.get(g)
            gs = net.gss.get(g)
            gs_live = gs.sessions["d1"].link if gs is not None else None
            same = live is not None and gs_live is not None and live.key.same_as(gs_live.key)
            links.append((g, live.tbm.state(now).value if live else None, same,
                          min(m.links[g].frames_in_cover, 2) if g in m.links else None))
        views = tuple((g, v.owner, v.epoch, v.stale) for g, c in sorted(net.gss.items()) for v in [c.sessions["d1"]])
        return (m.state.value, m.owner, m.epoch, m.pending_to, tuple(links), views, self.place(net), net.on_ground,
                tuple(sorted(net.cut)), tuple(sorted(net.hung)), net.faults,  # type: ignore[attr-defined]
                m.repair_deadline is not None, m.first_claim)

    # -------------------------------------------------------------------- moves
    def moves(self, net: FleetNet) -> Iterator[Move]:
        d = net.drone
        assert d is not None
        yield "time passes 0.5 s", lambda n: n.run(0.5, dt=0.1)
        yield "time passes 3 s", lambda n: n.run(3.0, dt=0.1)
        here = self.place(net)
        for p in net.places:  # type: ignore[attr-defined]
            if p != here:
                yield f"drone moves to {p}", lambda n, p=p: self._move(n, p)
        faults_left = net.faults < self.max_faults  # type: ignore[attr-defined]
        for g in ("A", "B"):
            if g in net.cut:
                yield f"{g}'s radio comes back", lambda n, g=g: n.cut.discard(g)
            elif faults_left:
                yield f"FAULT: {g}'s radio is cut", lambda n, g=g: self._fault(n, lambda: n.cut.add(g))
            if g in net.hung:
                yield f"{g} wakes", lambda n, g=g: n.hung.discard(g)
            elif faults_left:
                yield f"FAULT: {g} hangs", lambda n, g=g: self._fault(n, lambda: n.hung.add(g))
        if faults_left and d.machine.state is not State.UNPAIRED:
            where = "on the ground" if net.on_ground else "in the air"
            yield f"FAULT: the companion restarts {where}", lambda n: self._fault(n, n.restart_drone)
        if d.machine.state is State.FAILSAFE and not net.on_ground:
            yield "the failsafe lands the vehicle", self._land
        yield "outsider replays A's last envelope", self._replay_envelope
        yield "outsider replays A's captured pairing message 1s (those answered, older, or from before a restart)", \
            self._replay_pairings
        yield "B re-pairs", self._b_repairs
        yield "B re-pairs every 0.5 s for 3 s (its link stays proven, wherever the drone is)", self._b_repairs_for_3s
        yield "B asks for authority", lambda n: self._b_control(n, wire.HandoverRequest("B", n.gss["B"].sessions["d1"].epoch))
        yield "B forges a release to itself", lambda n: self._b_control(n, wire.HandoverRelease("B", n.drone.machine.epoch))  # type: ignore[union-attr]
        if d.machine.owner == "B":
            yield "B (owner) grants a key for A and proves it as A", self._b_grant_over_a
        yield "B asks A for A's own key and forges a frame under it to A", self._b_escrow
        yield "X pairs", self._x_pairs

    def _land(self, net: FleetNet) -> None:
        net.on_ground = True
        net.step(0.1)

    def _fault(self, net: FleetNet, do: Callable[[], None]) -> None:
        net.faults += 1  # type: ignore[attr-defined]
        do()

    def _move(self, net: FleetNet, p: str) -> None:
        net.position = net.places[p]  # type: ignore[attr-defined]
        net.step(0.1)

    def _replay_envelope(self, net: FleetNet) -> None:
        data = net.captured_up.get("A")
        if data is not None and net.drone is not None:
            net.drone_outs(net.drone.on_envelope("A", data, net.now))

    def _replay_pairings(self, net: FleetNet) -> None:
        d = net.drone
        assert d is not None
        answered, slot = d.counters["pair_answered"], d.slots.get("A")
        pending = [c.link for c in slot.candidates] if slot is not None else []
        r = d.responder
        newest = r.newest.get("A", float("-inf"))
        for gs, m1 in net.captured_pairings[-3:]:
            # a replay proper: a message 1 the drone answered already, older than the newest it answered,
            # or made before the companion was back (a fresh try of A's that never reached the drone is a
            # late delivery, which any network may make: the drone may answer it)
            stamp = stamp_of(m1)
            if gs == "A" and (r.cache.get(m1, net.now) is not None or stamp <= newest
                              or (r.not_before is not None and stamp < r.not_before)):
                ans, outs = d.on_pair_query("A", m1, net.now, os.urandom(32), WALL0 + net.now)
                net.drone_outs(outs)
        slot = d.slots.get("A")
        if d.counters["pair_answered"] != answered or (slot is not None and pending and
                                                      [c.link for c in slot.candidates] != pending):
            raise Broken("a replay changes nothing", "a replayed pairing message 1 drew a handshake "
                         f"({d.counters['pair_answered'] - answered} answered) or displaced A's pending key")

    def _b_repairs(self, net: FleetNet) -> None:
        b = net.gss["B"]
        b.sessions["d1"].link = None
        b.opts = replace(b.opts, pair=True)
        net.step(0.1)
        b.opts = replace(b.opts, pair=False)

    def _b_repairs_for_3s(self, net: FleetNet) -> None:
        for _ in range(6):
            self._b_repairs(net)
            net.run(0.4, dt=0.1)

    def _b_control(self, net: FleetNet, msg: wire.Control) -> None:
        b = net.gss["B"]
        net.gs_outs("B", b.send_control(b.sessions["d1"], msg))

    def _b_grant_over_a(self, net: FleetNet) -> None:
        b, d = net.gss["B"], net.drone
        assert d is not None
        secret = os.urandom(32)
        net.gs_outs("B", b.send_control(b.sessions["d1"], wire.KeyGrant("A", net.fleet.nodes["A"].sysid, secret, 7)))
        forged = SecureLink(key=LinkKey.from_secret("d1", "A", secret), role="gs", tx_keyexpr="zdrone/d1/up/A",
                            rx_keyexpr="zdrone/d1/down/A", peer_sysid=1, now=net.now)
        hb = FrameCodec(net.fleet.nodes["A"].sysid, 190).encode(mav.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))
        net.drone_outs(d.on_envelope("A", forged.seal(hb), net.now))

    def _b_escrow(self, net: FleetNet) -> None:
        a, b = net.gss["A"], net.gss["B"]
        if "A" in net.hung:
            return
        ask = KeyShareAsk(b.identity, "B", "A", net.fleet.nodes["A"].public_bytes, "d1", net.now, wall=WALL0 + net.now)
        answer, _ = a.on_linkkey_query("d1", ask.payload, net.now, os.urandom(32), WALL0 + net.now)
        if answer.reply is None:
            return
        secret = ask.on_reply(answer.reply, net.now)
        if isinstance(secret, Refused):
            return
        forged = SecureLink(key=LinkKey.from_secret("d1", "A", secret), role="drone", tx_keyexpr="zdrone/d1/down/A",
                            rx_keyexpr="zdrone/d1/up/A", peer_sysid=net.fleet.nodes["A"].sysid, now=net.now)
        net.gs_outs("A", a.on_envelope("d1", forged.seal_control(wire.SmHeartbeat(1)), net.now))

    def _x_pairs(self, net: FleetNet) -> None:
        assert net.drone is not None
        x = load_secret(self.fleet_dir, "X", net.fleet).identity
        m1 = PairingInitiator(x, "X", "d1", net.fleet.nodes["d1"].public_bytes, stamp=WALL0 + net.now).start()
        _, outs = net.drone.on_pair_query("X", m1, net.now, os.urandom(32), WALL0 + net.now)
        net.drone_outs(outs)

    # --------------------------------------------------------------- invariants
    def check(self, before: FleetNet, after: FleetNet) -> None:
        d = after.drone
        assert d is not None
        m = d.machine
        bm = before.drone.machine if before.drone is not None else None
        if bm is not None and m.epoch < bm.epoch:
            raise Broken("the epoch counts up", f"epoch {bm.epoch} -> {m.epoch} ({m.state.value}, owner {m.owner})")
        claim = bm.first_claim if bm is not None else None
        owners = {e: o for _, o, e in m.history}
        for k in d.forwarded_epochs:
            epoch, gs = k.split(":")
            if owners.get(int(epoch)) != gs:
                raise Broken("commands only from the owner", f"{gs}'s command forwarded in epoch {epoch} of {owners.get(int(epoch))}")
        for r in after.records:  # this move's records (``_copy`` starts each move with none)
            if isinstance(r, rec.AuthorityMoved) and r.kind != "handover":  # only a release may go outside
                cov = after.fleet.nodes[r.to].coverage
                inside = r.position is not None and cov is not None and cov.circle().contains(GeoPoint(r.position[0], r.position[1]))
                if not inside:
                    raise Broken("no authority outside coverage without consent",
                                 f"{r.kind} authority to {r.to} at {r.position}")
                if claim is not None and r.to != claim and bm is not None and bm.first_claim_until is not None \
                        and after.now < bm.first_claim_until:  # the whole move inside the window
                    raise Broken("the last owner pairs first after a ground restart",
                                 f"{r.kind} authority to {r.to} while {claim}'s first claim stands")
            if isinstance(r, rec.LinkConfirmed) and r.how == "grant" and r.replaced:
                raise Broken("nobody replaces another's live link", f"a grant replaced {r.gs}'s live key on the drone")
        for g, core in after.gss.items():
            old = before.gss[g].sessions["d1"].link
            link = core.sessions["d1"].link
            if old is not None and link is not None and not link.key.same_as(old.key) and g not in after.hung:
                # heard when the new key was made (a move may span the loss threshold: B's link LOST,
                # then a key shared, within one 3 s move, is no replacement of a live link)
                heard = old.tbm.state(max(before.now, link.tbm.created)) is not LinkState.LOST
                paired = core.counters["pair_sent"] > before.gss[g].counters["pair_sent"]
                # the drone spoke under the key a third party's replaced while it was LOST: the slot took
                # the drone's own key back (``LinkSlot`` revert), which replaces nobody's
                fallback = before.gss[g].sessions["d1"].slot.fallback
                reverted = fallback is not None and link.key.same_as(fallback.key)
                if heard and not paired and not reverted:
                    raise Broken("nobody replaces another's live link", f"{g}'s live key replaced while it heard the drone")
        owner = m.owner
        if owner is not None and m.state is not State.FAILSAFE and m.repair_deadline is None:
            link = d.links.get(owner)
            if link is not None and link.tbm.state(after.now) is LinkState.LOST and m.links[owner].state is not LinkState.LOST:
                raise Broken("failsafe on time", f"{owner}'s link is LOST and the machine has not acted")

    def liveness(self) -> Broken | None:
        net = self.initial()
        a, b = net.centre("A"), net.centre("B")
        net.fly(a, b, 30.0)
        first = net.drone.machine.owner if net.drone else None
        net.fly(b, a, 30.0)
        if first != "B" or net.drone is None or net.drone.machine.owner != "A":
            return Broken("liveness", f"a healthy crossing ended with {first}, then {net.drone.machine.owner if net.drone else None}")
        return None

    @staticmethod
    def _copy(net: FleetNet) -> FleetNet:
        """A deep copy of the fleet's state; the fleet description (immutable) is shared, the records
        and to-vehicle frames of earlier moves are not carried over (each move's are checked alone)."""
        memo: dict[int, Any] = {id(net.fleet): net.fleet}
        keep = net.records, net.to_vehicle, net.captured_pairings
        net.records, net.to_vehicle, net.captured_pairings = [], [], keep[2][-3:]
        try:
            return copy.deepcopy(net, memo)
        finally:
            net.records, net.to_vehicle, net.captured_pairings = keep

    # ------------------------------------------------------------------- search
    def run(self) -> tuple[Broken | None, tuple[str, ...], dict[str, Any]]:
        with planted(self.flaw):
            return self._run()

    def _run(self) -> tuple[Broken | None, tuple[str, ...], dict[str, Any]]:
        for name in ("zdrone", "gs"):
            logging.getLogger(name).setLevel(logging.ERROR)
        t0 = time.perf_counter()
        bad = self.liveness()
        if bad is not None:
            return bad, ("a healthy crossing A -> B -> A",), {}
        start = self.initial()
        seen = {self.key(start)}
        frontier: deque[tuple[FleetNet, tuple[str, ...]]] = deque([(start, ())])
        depth_reached = 0
        found: tuple[Broken | None, tuple[str, ...]] = (None, ())
        while frontier and found[0] is None:
            net, trace = frontier.popleft()
            if len(trace) >= self.depth:
                continue
            for label, move in list(self.moves(net)):
                nxt = self._copy(net)
                self.transitions += 1
                try:
                    move(nxt)
                    self.check(net, nxt)
                except Broken as b:
                    found = (b, trace + (label,))
                    break
                k = self.key(nxt)
                if k in seen:
                    continue
                seen.add(k)
                depth_reached = max(depth_reached, len(trace) + 1)
                frontier.append((nxt, trace + (label,)))
                if self.max_states is not None and len(seen) >= self.max_states:
                    frontier.clear()
                    break
        elapsed = time.perf_counter() - t0
        return found[0], found[1], {"states": len(seen), "transitions": self.transitions, "depth": self.depth,
                                    "depth_reached": depth_reached, "faults": self.max_faults, "seconds": round(elapsed, 2),
                                    "states_per_s": round(len(seen) / elapsed) if elapsed else None}
