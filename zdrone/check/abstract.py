"""``zdrone check``: an exhaustive, bounded exploration of the hand-over protocol's decisions.

Theory of operation
-------------------
The drone's decisions are made by pure code that ships: the handover authority
(``zdrone.core.authority.AuthorityMachine``, the very machine ``DroneCore`` drives), the key
confirmation rule (``zdrone.core.linkslot.replaces_live``: which candidate key may replace a live
one) and the pairing freshness rule (``zdrone.core.pairing``: a replayed message 1 spends no
rate-limit token). The checker runs those, unchanged, inside an abstract world and explores every
interleaving of the world's moves breadth-first up to a depth, de-duplicating states by a hash of
what matters (the machine's state, owner, epoch, pending recipient, deadlines relative to now, each
link's state and proof counts clipped at the proof threshold, the subscriptions, the region; the
world's position, faults, keys and rate-limit tokens).

The world: ground stations A and B, both authorized (A the first owner); X, a fleet GS not authorized
for the drone. The drone moves between A's coverage, the overlap, B's coverage, outside both, and an
unknown position (no GPS fix). Every moment, any of these moves may happen:

* honest: a GS whose radio works sends an authentic frame (read-only or commanding); the owner
  releases authority to the other GS (consent); a link whose GS cannot be heard goes LOST; time
  passes one second (deadlines, rate-limit tokens; a restarted companion's owner tries to re-pair);
* network faults (at most ``--faults`` of them in a trace): a GS's radio is cut, or comes back; the
  companion restarts in the air (all keys lost, authority restored, the owner re-pairs at once) or on
  the ground (all keys lost, UNPAIRED with the epoch kept, the last owner holding the first claim);
* the authorized but malicious GS B (its own keys, every router password; its frames reach the drone
  over the backhaul mesh wherever the drone is): asks for authority, forges a release, re-pairs from
  anywhere, grants a key for A when it holds authority and proves it as A, asks A for A's own link
  key over the backhaul and forges a frame under it to A;
* the outsider (every password, every captured byte): replays captured pairing message 1s;
* the unauthorized fleet GS X: pairs and sends frames.

Invariants, checked after every move (a violation prints the shortest trace that reaches it):

1. one owner: outside UNPAIRED, exactly one authorized owner; a pending recipient is not the owner;
2. commands only from the owner: a commanding frame is forwarded only from the epoch's owner, and
   never in FAILSAFE;
3. no authority without consent to a GS outside coverage: an emergency or regained authority goes
   only to a GS whose coverage holds the drone's position at that instant;
4. nobody's action replaces another GS's live link: no key the GS did not make itself becomes live
   on either end while that link is alive;
5. failsafe on time: when the owner's link is LOST the machine is in FAILSAFE or an heir (proven
   inside its coverage) holds authority;
6. the owner, healthy and re-pairing after a restart, is never refused for tokens someone else spent;
7. liveness: a hand-over whose recipient is proven completes at once (make-before-break), and a
   healthy crossing (A -> overlap -> B with A's release) ends with B as owner;
8. the epoch counts up: no move, a companion restart included, makes it go back;
9. first claim: within its window after a restart on the ground, authority goes to the last owner only;
10. closing a link (links that follow the drone: the drone closes one it may, a pairing links it again)
    never removes the owner's, a pending recipient's or an heir's; a closed link carries nothing (its
    GS's frames are not forwarded: 2), and its GS is no heir until it links again (5).

Planted flaws (``--flaw``) show that the checker can fail: ``heir-without-position`` (an heir needs no
coverage), ``promotion-over-live`` (any candidate replaces a live key), ``unstamped-pairing`` (a replayed
message 1 is a fresh handshake and spends the GS's tokens), ``pairing-without-position`` (a pairing that
gives authority needs no coverage), ``forgetful-ground-restart`` (a restart on the ground forgets the
epoch and the last owner, as before), ``close-covering`` (the drone may close any link but the owner's,
the GS covering it included). Each must be found.
"""

from __future__ import annotations

import copy
import logging
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator

from zdrone.core import authority as ha
from zdrone.core.authority import AuthorityMachine, Config, State
from zdrone.core.linkslot import replaces_live
from zdrone.core.tbm import LinkState
from zdrone.core.uplink import UplinkClass
from zdrone.check.search import Violation, _Broken, breadth_first  # noqa: F401  (the explorer runs on them)

AUTHORIZED = ("A", "B")
ROGUE = "X"
INSIDE: dict[str, frozenset[str]] = {
    "A": frozenset({"A"}), "AB": frozenset({"A", "B"}), "B": frozenset({"B"}),
    "none": frozenset(), "unknown": frozenset(),  # no GPS fix: inside no coverage
}
ADJACENT: dict[str, tuple[str, ...]] = {
    "A": ("AB", "none", "unknown"), "AB": ("A", "B", "unknown"), "B": ("AB", "none", "unknown"),
    "none": ("A", "B", "unknown"), "unknown": ("A", "AB", "B", "none"),
}
TOKENS = 3  # the drone's pairing rate limit per GS: a burst of 3, one more per second
GRACE = 3.0
HANDOVER_TIMEOUT = 5.0
FLAWS = ("heir-without-position", "promotion-over-live", "unstamped-pairing", "pairing-without-position",
         "forgetful-ground-restart", "close-covering")
FIRST_CLAIM = ha.FIRST_CLAIM_S


class _NoPositionMachine(AuthorityMachine):
    """PLANTED FLAW: an heir needs no coverage (the rule before issue 18)."""

    def proven_in_cover(self, gs: str) -> bool:
        return self.is_authorized(gs) and self.is_proven(gs)


class _PairAnywhereMachine(AuthorityMachine):
    """PLANTED FLAW: a pairing that gives authority needs no coverage (found by review: a landed
    vehicle, or one whose companion restarted on the ground, went to whoever paired first)."""

    def pair_refusal(self, gs: str, on_ground: bool, now: float) -> Any:
        from zdrone.core.pairing import PairRefusal, PairRefused

        if not self.is_authorized(gs):
            return PairRefused(PairRefusal.UNAUTHORIZED, f"{gs} is not authorized for this drone")
        if self.state is State.FAILSAFE and not on_ground:
            return PairRefused(PairRefusal.FAILSAFE, "re-pair only on the ground")
        return None


class _CloseAnyMachine(AuthorityMachine):
    """PLANTED FLAW: the drone may close any link but the owner's (links that follow the drone, with
    the coverage, the pending recipient and the failsafe left out of the rule)."""

    def may_close(self, gs: str) -> bool:
        return gs in self.links and gs != self.owner


@dataclass
class World:
    """One state of the abstract world around the shipped machine."""

    m: AuthorityMachine
    now: float = 0.0
    pos: str = "A"
    up: dict[str, bool] = field(default_factory=lambda: {"A": True, "B": True})
    drone_key: dict[str, str] = field(default_factory=dict)  # gs -> "own" | "third": the drone's live key of gs
    gs_key_ok: dict[str, bool] = field(default_factory=lambda: {"A": True, "B": True})  # the GS's live key is the drone's
    tokens: dict[str, int] = field(default_factory=lambda: {"A": TOKENS, "B": TOKENS})
    spent_by_others: dict[str, int] = field(default_factory=lambda: {"A": 0, "B": 0})
    faults: int = 0
    restarted: bool = False  # the companion restarted and its owner has not re-paired yet
    ground: bool = False  # the vehicle is on the ground (the failsafe landed it)

    def clone(self) -> "World":
        m = self.m
        n = m.__class__.__new__(m.__class__)
        n.config, n.state, n.owner, n.epoch = m.config, m.state, m.owner, m.epoch
        n.pending_to, n.pending_deadline, n.repair_deadline = m.pending_to, m.pending_deadline, m.repair_deadline
        n.takeover_epoch, n.relay_limit = m.takeover_epoch, copy.deepcopy(m.relay_limit)
        n.takeover_to, n.on_ground = m.takeover_to, m.on_ground
        n.first_claim, n.first_claim_until = m.first_claim, m.first_claim_until
        n.links = {g: ha._Link(l.state, l.frames_since_ok, l.frames_in_cover) for g, l in m.links.items()}
        n.subscribed, n.inside = set(m.subscribed), m.inside
        n.drops, n.rejects = m.drops, m.rejects  # counters only: not part of the state, shared
        n.history = m.history[-1:]
        return World(n, self.now, self.pos, dict(self.up), dict(self.drone_key), dict(self.gs_key_ok),
                     dict(self.tokens), dict(self.spent_by_others), self.faults, self.restarted, self.ground)

    def key(self) -> tuple:
        """What distinguishes this state (time only relative to the deadlines)."""
        m = self.m

        def rel(t: float | None) -> float | None:
            return None if t is None else round(max(-1.0, t - self.now), 3)

        links = tuple(sorted((g, l.state.value, min(l.frames_since_ok, ha.PROOF_FRAMES),
                              min(l.frames_in_cover, ha.PROOF_FRAMES)) for g, l in m.links.items()))
        # the GS-keyed dicts below always hold A then B (made so), so their values are in a fixed order
        return (m.state, m.owner, m.epoch, m.pending_to, rel(m.pending_deadline), rel(m.repair_deadline),
                links, frozenset(m.subscribed), self.pos, tuple(self.up.values()),
                tuple(sorted(self.drone_key.items())), tuple(self.gs_key_ok.values()),
                tuple(self.tokens.values()), tuple(self.spent_by_others.values()),
                self.faults, self.restarted, m.takeover_epoch == m.epoch, self.ground,
                m.first_claim, rel(m.first_claim_until))

    def hears(self, gs: str) -> bool:
        """Frames of ``gs`` open on the drone (and the drone's on ``gs``): radio up, the same key both ends."""
        return self.up.get(gs, False) and self.drone_key.get(gs) == "own" and self.gs_key_ok.get(gs, False)


class Explorer:
    """Breadth-first exploration of every interleaving of the world's moves, up to ``depth``."""

    def __init__(self, depth: int, faults: int = 2, flaw: str | None = None, max_states: int | None = None) -> None:
        if flaw is not None and flaw not in FLAWS:
            raise ValueError(f"unknown flaw {flaw!r} (one of {', '.join(FLAWS)})")
        self.depth, self.max_faults, self.flaw, self.max_states = depth, faults, flaw, max_states
        self.states = 0
        self.transitions = 0
        self.max_depth_reached = 0

    # ------------------------------------------------------------- the rules under test
    def _replaces_live(self, origin: str, live: LinkState | None) -> bool:
        return True if self.flaw == "promotion-over-live" else replaces_live(origin, live)

    def initial(self) -> World:
        cls = {"heir-without-position": _NoPositionMachine,
               "pairing-without-position": _PairAnywhereMachine,
               "close-covering": _CloseAnyMachine}.get(self.flaw or "", AuthorityMachine)
        w = World(cls(Config(frozenset(AUTHORIZED), HANDOVER_TIMEOUT)))
        w.m.handle(ha.RegionChanged(0.0, INSIDE["A"]))
        w.m.handle(ha.PairingDone(0.0, "A", on_ground=True))
        w.drone_key["A"] = "own"
        w.m.handle(ha.GrantHeard(0.0, "A", "B"))  # key sharing on the ground: B's key installed
        w.drone_key["B"] = "own"
        for g in AUTHORIZED:  # both links heard on the ground
            w.m.handle(ha.LinkChanged(0.0, g, LinkState.OK))
        return w

    # -------------------------------------------------------------------- the moves
    def moves(self, w: World) -> Iterator[tuple[str, Callable[[World], None]]]:
        m = w.m
        for p in ADJACENT[w.pos]:
            yield f"drone moves to {p}", lambda x, p=p: self._move(x, p)
        for g in AUTHORIZED:
            if w.hears(g) and g in m.links:
                yield f"{g} sends a read-only frame", lambda x, g=g: self._frame(x, g, UplinkClass.READ_ONLY)
                yield f"{g} sends a command", lambda x, g=g: self._frame(x, g, UplinkClass.AUTHORITY_ONLY)
            link = m.links.get(g)
            if link is not None and link.state is not LinkState.LOST and not w.hears(g):
                yield f"{g}'s link goes LOST", lambda x, g=g: self._lose(x, g)
            if w.faults < self.max_faults and w.up[g]:
                yield f"FAULT: {g}'s radio is cut", lambda x, g=g: self._cut(x, g, False)
            if not w.up[g]:
                yield f"{g}'s radio comes back", lambda x, g=g: self._cut(x, g, True)
        for g in AUTHORIZED:  # links that follow the drone (``zdrone.core.linkplan``); a closed link comes
            if m.may_close(g):  # back by a pairing ("A pairs", "B re-pairs" below)
                yield f"the drone closes {g}'s link (left behind)", lambda x, g=g: self._close(x, g)
        if m.owner is not None and m.state is not State.FAILSAFE and w.hears(m.owner):
            other = "B" if m.owner == "A" else "A"
            yield f"{m.owner} (owner) releases to {other}", lambda x, o=m.owner, t=other: self._release(x, o, t)
        yield "time passes 1 s", lambda x: self._tick(x, replays=0)
        if m.state is State.FAILSAFE and not w.ground:
            yield "the failsafe lands the vehicle", self._land
        if w.faults < self.max_faults and m.state is not State.UNPAIRED and not w.ground:
            yield "FAULT: the companion restarts in the air", lambda x: self._restart(x, replays=0)
            yield "FAULT: the companion restarts; outsider replays 3 captured message 1s of its owner", \
                lambda x: self._restart(x, replays=TOKENS)
        if w.faults < self.max_faults and w.ground and m.state is not State.UNPAIRED:
            yield "FAULT: the companion restarts on the ground (epoch kept, its last owner pairs first)", \
                self._restart_on_ground
        if "A" not in m.links or m.state in (State.UNPAIRED, State.FAILSAFE):
            yield "A pairs", lambda x: self._pair(x, "A")
        if w.restarted:
            yield "time passes 1 s; outsider replays 3 captured message 1s", lambda x: self._tick(x, replays=TOKENS)
        # the malicious authorized GS B
        yield "B asks for authority", lambda x: self._apply(x, ha.AuthorityAsked(x.now, "B", "B", 10.0, False, 1), "B")
        yield "B asks for authority for X", lambda x: self._apply(x, ha.AuthorityAsked(x.now, "B", "A", 10.0, False, 2), "B")
        if m.owner != "B":
            yield "B forges a release of A's epoch to itself", lambda x: self._apply(x, ha.Release(x.now, "B", "B", x.m.epoch), "B")
        yield "B re-pairs (from wherever it is)", lambda x: self._pair(x, "B")
        if m.owner == "B" and "A" in m.links:
            yield "B (owner) grants a key for A and proves it as A", lambda x: self._grant_over(x, "B", "A")
        yield "B asks A for A's link key and forges a frame under it to A", lambda x: self._escrow(x, "B", "A")
        # the unauthorized fleet GS X
        yield "X pairs", lambda x: self._apply(x, ha.PairingDone(x.now, ROGUE, on_ground=False), ROGUE)
        yield "X sends a command", lambda x: self._apply(x, ha.Frame(x.now, ROGUE, UplinkClass.AUTHORITY_ONLY), ROGUE)

    def _apply(self, w: World, ev: ha.Event, actor: str | None = None) -> list[ha.Action]:
        m = w.m
        owner, state, inside = m.owner, m.state, m.inside
        claim = m.first_claim if m.first_claim_until is not None and ev.now < m.first_claim_until else None
        acts = m.handle(ev)
        for a in acts:
            if isinstance(a, ha.Forward) and isinstance(ev, ha.Frame) and ev.uplink is UplinkClass.AUTHORITY_ONLY:
                if a.gs != owner or state is State.FAILSAFE:
                    raise _Broken("commands only from the owner", f"{a.gs}'s command forwarded (owner {owner}, {state.value})")
            if isinstance(a, ha.AuthorityChanged) and a.kind != "handover" and a.new not in inside:
                # only the owner's release (kind "handover") may give authority to a GS outside coverage:
                # a first pairing, a re-pairing after the failsafe, an heir, a GS taking control back
                raise _Broken("no authority outside coverage without consent",
                              f"{a.kind} authority to {a.new} while the drone is inside {sorted(inside) or 'no coverage'}")
            if isinstance(a, ha.AuthorityChanged) and claim is not None and a.new != claim:
                raise _Broken("the last owner pairs first after a ground restart",
                              f"{a.kind} authority to {a.new} while {claim}'s first claim stands")
            if isinstance(a, ha.AuthorityChanged) and a.new in AUTHORIZED and w.drone_key.get(a.new) is None:
                w.drone_key[a.new] = "own"
        return acts

    def _move(self, w: World, p: str) -> None:
        w.pos = p
        self._apply(w, ha.RegionChanged(w.now, INSIDE[p]))

    def _frame(self, w: World, g: str, cls: UplinkClass) -> None:
        m = w.m
        if m.links[g].state is not LinkState.OK:
            self._apply(w, ha.LinkChanged(w.now, g, LinkState.OK))
        pending = m.pending_to
        self._apply(w, ha.Frame(w.now, g, cls), g)
        if pending == g and m.state is State.HANDOVER_PENDING and m.is_proven(g):
            raise _Broken("liveness", f"{g} proved its link but the hand-over did not complete")

    def _lose(self, w: World, g: str) -> None:
        owner, inside = w.m.owner, w.m.inside
        heirs = w.m.heirs() if g == owner else []
        self._apply(w, ha.LinkChanged(w.now, g, LinkState.LOST))
        if g == owner and w.m.state is not State.FAILSAFE and w.m.owner not in heirs and not w.ground:
            raise _Broken("failsafe on time", f"{g}'s authority link is LOST, no heir proven inside its coverage "
                          f"(drone inside {sorted(inside) or 'none'}), and the machine is {w.m.state.value} with {w.m.owner}")

    def _cut(self, w: World, g: str, up: bool) -> None:
        w.up[g] = up
        if not up:
            w.faults += 1

    def _release(self, w: World, owner: str, to: str) -> None:
        self._apply(w, ha.Release(w.now, owner, to, w.m.epoch), owner)

    def _pair(self, w: World, g: str) -> bool:
        """A genuine pairing of ``g`` (fresh message 1, one token); True if it completed."""
        if w.tokens[g] <= 0:
            if w.spent_by_others[g] > 0 and g == w.m.owner and w.restarted:
                raise _Broken("owner re-pairs after a restart",
                              f"{g}'s re-pairing refused: its tokens were spent by {w.spent_by_others[g]} replays")
            return False
        w.tokens[g] -= 1
        if w.m.pair_refusal(g, on_ground=w.ground, now=w.now) is not None:
            return False
        if not self._replaces_live("pair", w.m.links[g].state if g in w.m.links else None):  # a GS's own key: always
            return False
        w.drone_key[g] = "own"
        w.gs_key_ok[g] = True
        self._apply(w, ha.PairingDone(w.now, g, on_ground=w.ground), g)
        if g == w.m.owner:
            w.restarted = False
        return True

    def _replays(self, w: World, g: str, n: int) -> None:
        """The outsider replays ``n`` captured message 1s of ``g``: fresh-checked, they spend nothing."""
        if self.flaw != "unstamped-pairing":
            return  # stale (older than 30 s, or made before the companion started): dropped before any work
        spent = min(n, w.tokens[g])
        w.tokens[g] -= spent
        w.spent_by_others[g] += spent

    def _tick(self, w: World, replays: int) -> None:
        w.now += 1.0
        for g in AUTHORIZED:
            w.tokens[g] = min(TOKENS, w.tokens[g] + 1)
        owner = w.m.owner
        if w.restarted and owner is not None:
            self._replays(w, owner, replays)
            if w.up[owner]:
                self._pair(w, owner)  # the owner tries again (every 0.2 s in the real GS)
        waiting = w.m.repair_deadline is not None and w.now >= w.m.repair_deadline
        owner, heirs = w.m.owner, w.m.heirs()
        self._apply(w, ha.Tick(w.now))
        if waiting and w.m.state is not State.FAILSAFE and w.m.owner not in heirs:
            raise _Broken("failsafe on time", f"the restored owner {owner} did not re-pair in time and "
                          f"the machine is {w.m.state.value} with {w.m.owner}")

    def _land(self, w: World) -> None:
        w.ground = True
        self._apply(w, ha.GroundChanged(w.now, True))

    def _restart_on_ground(self, w: World) -> None:
        """On the ground the companion comes back UNPAIRED with the epoch kept and its last owner
        holding the first claim (``DroneCore.restore``)."""
        owner, epoch = w.m.owner, w.m.epoch
        assert owner is not None
        w.m = w.m.__class__(w.m.config)
        w.faults += 1
        w.drone_key.clear()
        w.restarted = False
        self._apply(w, ha.RegionChanged(w.now, INSIDE[w.pos]))
        self._apply(w, ha.GroundChanged(w.now, True))
        if self.flaw != "forgetful-ground-restart":  # PLANTED FLAW: forgotten on the ground, epoch from 1 again
            w.m.restore_on_ground(owner, epoch, w.now, FIRST_CLAIM)

    def _restart(self, w: World, replays: int) -> None:
        """In the air the companion comes back with the authority it saved (``DroneCore.restore``):
        LINKED(owner, epoch) waiting for the owner to re-pair, or FAILSAFE going on."""
        owner, epoch, failsafe = w.m.owner, w.m.epoch, w.m.state is State.FAILSAFE
        assert owner is not None
        cls = w.m.__class__
        w.m = cls(w.m.config)
        w.faults += 1
        w.drone_key.clear()
        w.m.handle(ha.RegionChanged(w.now, INSIDE[w.pos]))
        w.m.restore(owner, epoch, w.now, GRACE, failsafe=failsafe)
        w.restarted = True
        w.spent_by_others = {g: 0 for g in AUTHORIZED}
        self._replays(w, owner, replays)
        if w.up[owner]:
            self._pair(w, owner)

    def _grant_over(self, w: World, sender: str, g: str) -> None:
        result, _ = w.m.grant(ha.GrantHeard(w.now, sender, g))
        if not isinstance(result, ha.GrantAccepted):
            return
        link = w.m.links.get(g)
        live = link.state if link is not None and w.drone_key.get(g) else None
        if live is None or self._replaces_live("grant", live):
            if live is not None and live is not LinkState.LOST:
                raise _Broken("nobody replaces another's live link",
                              f"{sender}'s key for {g} replaced {g}'s live key (link {live.value}) on the drone")
            w.drone_key[g] = "third"

    def _close(self, w: World, g: str) -> None:
        """The drone closes ``g``'s link (its own decision): both ends wipe the key."""
        m = w.m
        owner, pending = m.owner, m.pending_to
        heirs = [h for h in m.links if h != owner and AuthorityMachine.proven_in_cover(m, h)]  # the shipped rule's
        self._apply(w, ha.LinkClosed(w.now, g, "left behind"))
        if g in m.links:
            return  # kept: some rule may still need it
        if g in (owner, pending) or g in heirs:
            role = "the owner" if g == owner else "the pending recipient" if g == pending else "an heir"
            raise _Broken("closing keeps the owner and every heir", f"{g}'s link closed while {g} was {role} "
                          f"(drone inside {sorted(m.inside) or 'no coverage'}, {m.state.value})")
        w.drone_key.pop(g, None)
        w.gs_key_ok[g] = False

    def _escrow(self, w: World, asker: str, g: str) -> None:
        """``asker`` asks ``g`` for ``g``'s own link key over the backhaul, then forges a frame under it to ``g``."""
        gs_side = LinkState.OK if w.hears(g) else LinkState.LOST
        if w.gs_key_ok[g] and gs_side is not LinkState.LOST:
            return  # ``g`` answers no key-sharing query while its own link is alive (gs.core: live_link)
        if self._replaces_live(f"linkkey:{asker}", gs_side if w.gs_key_ok[g] else None):
            if gs_side is not LinkState.LOST:
                raise _Broken("nobody replaces another's live link",
                              f"{asker}'s forged frame under an escrowed key replaced {g}'s live key on {g}'s side")
            w.gs_key_ok[g] = False

    # -------------------------------------------------------------------- the search
    def run(self) -> tuple[Violation | None, dict[str, Any]]:
        logging.getLogger("zdrone.core.authority").setLevel(logging.WARNING)
        t0 = time.perf_counter()
        violation = self._liveness() or breadth_first(self, self.initial(), self._invariants)
        elapsed = time.perf_counter() - t0
        return violation, {"states": self.states, "transitions": self.transitions, "depth": self.depth,
                           "depth_reached": self.max_depth_reached, "faults": self.max_faults, "flaw": self.flaw,
                           "seconds": round(elapsed, 2), "states_per_s": round(self.states / elapsed) if elapsed else None}

    def _invariants(self, w: World, before: World) -> None:
        m = w.m
        if m.epoch < before.m.epoch:
            raise _Broken("the epoch counts up", f"epoch {before.m.epoch} -> {m.epoch} ({m.state.value}, owner {m.owner})")
        if m.state is not State.UNPAIRED and m.owner not in AUTHORIZED:
            raise _Broken("one owner", f"owner {m.owner!r} in {m.state.value}")
        if m.pending_to is not None and (m.pending_to == m.owner or m.state is not State.HANDOVER_PENDING):
            raise _Broken("one owner", f"pending {m.pending_to} with owner {m.owner} in {m.state.value}")

    def _liveness(self) -> Violation | None:
        """A healthy crossing: A -> overlap (B proves its link) -> A releases -> B owns; and back."""
        w = self.initial()
        trace: list[str] = []
        steps: list[tuple[str, Callable[[World], None]]] = [
            ("drone moves to AB", lambda x: self._move(x, "AB")),
            ("A sends a read-only frame", lambda x: self._frame(x, "A", UplinkClass.READ_ONLY)),
            ("B sends a read-only frame", lambda x: self._frame(x, "B", UplinkClass.READ_ONLY)),
            ("B sends a read-only frame", lambda x: self._frame(x, "B", UplinkClass.READ_ONLY)),
            ("A (owner) releases to B", lambda x: self._release(x, "A", "B")),
            ("drone moves to B", lambda x: self._move(x, "B")),
            ("drone moves to AB", lambda x: self._move(x, "AB")),
            ("A sends a read-only frame", lambda x: self._frame(x, "A", UplinkClass.READ_ONLY)),
            ("A sends a read-only frame", lambda x: self._frame(x, "A", UplinkClass.READ_ONLY)),
            ("B (owner) releases to A", lambda x: self._release(x, "B", "A")),
        ]
        for label, step in steps:
            trace.append(label)
            try:
                step(w)
            except _Broken as b:
                return Violation(b.invariant, b.detail, tuple(trace))
            if label == "A (owner) releases to B" and w.m.owner != "B":
                return Violation("liveness", "a healthy crossing did not hand over to B", tuple(trace))
        if w.m.owner != "A" or w.m.epoch != 3:
            return Violation("liveness", f"the crossing back ended with {w.m.owner} (epoch {w.m.epoch})", tuple(trace))
        return None
