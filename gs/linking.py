"""The GS's links with one drone, sans-IO: pairing, and key sharing as the drone's authority. Tables.

Theory of operation
-------------------
A GS talks to a drone only under a link key. It gets one by **pairing** (a Noise KK exchange over
``pair/<gs>``, ``zdrone.core.pairing``), and, while it holds the drone's authority, it gets the
other authorized GSs their keys by **key sharing** (``zdrone.core.keyshare``): it asks each one for
a fresh key of link (drone, it) over the backhaul and grants that key to the drone inside its own
sealed link (``KEY_GRANT``), re-sent each second until the drone acknowledges it. ``Linking`` keeps,
for one drone, where both exchanges stand; what the key is used for (the link itself, ``LinkSlot``)
stays with the core, which installs the key a reply proves (``PairProven``). As the owner of a link,
answering another GS's key-sharing query, the GS uses ``KeyOwner`` (one per GS, ``gs.keyowner``).

Pairing phases (``PairPhase``): ``IDLE`` (no exchange open) and ``ASKING`` (a message 1 is out; its
reply is taken until ``deadline``). Events: ``PairDue`` (the core's timer: pair now, unless the last
try was less than ``retry`` ago) and ``Reply`` (the drone's answer, or its error). A reply that
does not prove the drone's static key is counted and leaves the exchange open (the genuine one may
still come); the one that does closes it with a ``PairProven`` (the new key, and whether the drone still
held our old one). If we had a link and the drone lost our key, it restarted: ``keys_lost``.
A rotation of our static key (``rekey``) asks for a *fresh* pairing under the new key while the live
link goes on: an exchange started while ``rekey_pending`` is one (``PairProven.fresh``: the drone
answers it as holding no key of ours, which says nothing of a restart), and the core tries again
every ``retry`` until one is proven.

Both exchanges are hybrid (ML-KEM-768 next to X25519) while the fleet in force says ``pairing_pq``:
``ctx.fleet`` is read at each new exchange, so a revision turning it on applies to the next one (and the
reply to a classical one still open gives no key: ``pair_reply_refused:classical``).

Key-sharing phases, per other authorized GS (``SharePhase``): ``NONE`` (nothing asked: the drone may
hold its key already, ``drone_links``), ``ASKED`` (a query is out; a "live link" refusal asks again
after ``LIVE_LINK_RETRY_S``, a query with no answer again after its deadline), ``GRANTING`` (the
reply's key is granted to the drone, re-sent each second) and ``GRANTED`` (the drone acknowledged
it). Events: ``ShareDue`` (the core's timer, while we hold authority), ``Reply``, ``GrantAcked``
``KeysLost`` (the drone restarted: every key we shared for it is gone) and ``PeerKeysLost`` (the other
GS restarted: its signed notice, ``zdrone.core.keyslost``; its share goes back to ``NONE`` once per
start and is asked again even though the drone still lists it, the grant carrying the notice). When the drone's links
follow it (``zdrone.core.linkplan``), only the GSs the owner's plan wants are asked, and a ``GRANTED``
key the drone's status has stopped listing (it closed that link) goes back to ``NONE`` at the next
``ShareDue``, to be asked again when wanted. One new query per
``RETRY_S`` per drone and other GS (a "live link" retry excepted).

``PAIR_TABLE`` and ``SHARE_TABLE`` map (phase, event type) to (handler, the phases it may move to),
tables of the machine engine (``zdrone.core.machine``); the key-sharing table applies to each other
GS apart, its state that GS's ``Share`` (the engine's ``key``: the GS; the pairing exchange is
``key`` None). Pairs not in a table change nothing, a handler moving elsewhere is a programming error
(``_set_state`` raises ``IllegalPhase``), every move is logged ``old -> new (why)``. The pairing
exchange also closes outside its table, to IDLE only (``PAIR_CLOSED``): its deadline passed before the
lookup, or a rotation of our static key abandoned it. ``deadline(now)`` is when the timer next
matters for these exchanges if no input comes.
"""

from __future__ import annotations

import enum
import itertools
import logging
from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Callable, Hashable, Iterator

from zdrone.core import keyslost
from zdrone.core import records as rec
from zdrone.core import wire
from zdrone.core.fleet import Fleet
from zdrone.core.keys import Identity, LinkKey
from zdrone.core.keyshare import KeyShareAsk, Refused, ShareRefusal
from zdrone.core.machine import IllegalTransition, Machine, Table
from zdrone.core.pairing import PairingFailed, PairingInitiator
from zdrone.fleet import keyexprs

from gs.actions import Action, Ask, AskKind, Emit
from gs.keyowner import LINKKEY_BURST, LINKKEY_CANDIDATE_TTL, LINKKEY_RATE, LOGGED, KeyOwner  # noqa: F401 (theirs)

log = logging.getLogger(__name__)

#: Our key-sharing queries out to one owner GS at once at most (each drone's own): the owner's
#: queryable ring holds 256 per path (``zdrone.net.session.QUERY_QUEUE_SIZE``); a query it dropped
#: costs its drone the whole ``ASK_TIMEOUT``. A drone whose query must wait looks again this soon.
ASKS_IN_FLIGHT = 64
ASK_WAIT_S = 0.05
PAIR_TIMEOUT = 3.0
RETRY_S = 2.0
#: A first pairing whose query ended with no reply at all (Zenoh: no queryable of the drone's took it:
#: not up yet) is tried again this soon instead of ``RETRY_S``: the drone never saw it.
UNANSWERED_RETRY_S = 0.5
#: A key grant not yet acknowledged is sent again this often.
GRANT_RESEND_S = 1.0
#: A key-sharing query refused because the answering GS's link still looks alive (a drone that just
#: restarted holds no key for it, but that GS hears the silence only at the loss threshold) is asked
#: again this soon, the first ask still open for the genuine reply.
LIVE_LINK_RETRY_S = 0.5
#: A GS's keys-lost notices send its share back to NONE at most this often (a hostile GS signing a new
#: start in every notice churns its own key at this rate, not at its revision key's budget of 2 a second)
PEER_RESET_GAP_S = 10.0
#: A key we granted that the drone's status no longer lists this long after its acknowledgement was
#: closed by the drone (links that follow it): shared again if still wanted (the status lists the
#: drone's links at least once a second).
REGRANT_AFTER_S = 3.0


def _due(last: float | None, now: float, period: float) -> bool:
    return last is None or now - last >= period


class PairPhase(enum.Enum):
    IDLE = "idle"
    ASKING = "asking"


#: Where the pairing exchange goes when it closes outside its table (deadline passed, abandoned).
PAIR_CLOSED = frozenset({PairPhase.IDLE})


class SharePhase(enum.Enum):
    NONE = "none"
    ASKED = "asked"
    GRANTING = "granting"
    GRANTED = "granted"


# ------------------------------------------------------------------------- events
@dataclass(frozen=True, slots=True)
class PairDue:
    """Pair now (``stamp``: our time of day) unless the last try was less than ``retry`` ago."""

    now: float
    stamp: float
    retry: float = RETRY_S
    timeout: float = PAIR_TIMEOUT
    unanswered: float | None = None  # the retry after a query no drone's queryable answered, if shorter


@dataclass(frozen=True, slots=True)
class Reply:
    """A reply to one of our queries (the drone's to a message 1, another GS's to a key-sharing
    query): its payload ``ok``, or its error text ``err``."""

    now: float
    ok: bytes | None
    err: bytes | None


@dataclass(frozen=True, slots=True)
class ShareDue:
    """As authority: ask for ``gs``'s key if it is due, re-send its grant if that is due."""

    now: float
    wall: float
    follow: bool = False  # the drone's links follow it: a granted key it closed is shared again when wanted


@dataclass(frozen=True, slots=True)
class GrantAcked:
    now: float
    grant_id: int


@dataclass(frozen=True, slots=True)
class KeysLost:
    """The drone restarted: no key we shared for it survives."""

    now: float


@dataclass(frozen=True, slots=True)
class PeerKeysLost:
    """GS ``gs`` restarted: its signed notice (``zdrone.core.keyslost``, checked by the caller) says it
    holds no key made before ``since``. ``notice``: its bytes, carried in the grant to the drone."""

    now: float
    notice: bytes
    since: float


@dataclass(frozen=True, slots=True)
class PairProven:
    """A pairing reply proved the drone's static key: ``key`` is our new link key."""

    key: LinkKey
    kept: bool  # the drone still held our old key (its silence was the radio, not a restart)
    fresh: bool = False  # a pairing under our rotated static key (``Linking.rekey``): not a restart
    hybrid: bool = False  # the exchange was hybrid (ML-KEM-768 next to X25519)
    rotated: bool = True  # a fresh pairing for a rotated static key (False: to make a classical link hybrid)


#: A handler moved to a phase its table row does not allow: a programming error (the engine's one error).
IllegalPhase = IllegalTransition


@dataclass
class Share:
    """Where key sharing for one other GS stands."""

    phase: SharePhase = SharePhase.NONE
    ask: KeyShareAsk | None = None
    grant: wire.KeyGrant | None = None
    ask_again: float | None = None  # a "live link" refusal: ask again then
    last_try: float | None = None  # our last new query to this GS (one per ``RETRY_S``)
    wait_until: float | None = None  # ``ASKS_IN_FLIGHT`` queries to this GS were out: look again then
    live_refused: float | None = None  # its last "live link" refusal
    hybrid: bool = False  # the open exchange (and the key it gave) is hybrid
    granted_at: float | None = None  # the drone acknowledged our grant then
    lost: bytes | None = None  # its newest keys-lost notice, until the drone took a key granted with it
    lost_since: float | None = None  # the start that notice speaks of (each start resets the share once)
    asked_wall: float | None = None  # our time of day at our last query: the key it gave is no older
    reset_at: float | None = None  # when a notice of this GS last sent its share back to NONE


@dataclass
class Context:
    """What the exchanges of one drone need of their GS (set once by the core)."""

    gs: str
    drone: str
    identity: Identity
    fleet: Fleet
    counters: Counter[str]
    grant_ids: Iterator[int] = field(default_factory=lambda: itertools.count(1))
    #: the station's key-sharing queries out, shared by its drones' ``Linking``s: owner GS -> drone -> deadline
    asks_out: dict[str, dict[str, float]] = field(default_factory=dict)


class Linking(Machine):
    """Pairing and key sharing with one drone (see the module docstring)."""

    _log = log
    _log_level = logging.DEBUG

    def __init__(self, ctx: Context) -> None:
        self.ctx = ctx
        self.pair_phase = PairPhase.IDLE
        self.pairing: PairingInitiator | None = None
        self.pairing_deadline = 0.0
        self.last_pair_try: float | None = None
        self._m1: bytes | None = None  # the open exchange's message 1 (``pair_unanswered`` names it)
        self._answered = False  # a reply to the open exchange came (any: refused, bad, or the proof)
        self._unanswered = False  # the last exchange's query ended with no reply at all
        self.lost_key_at: float | None = None  # our pairing found the companion had lost our key (it restarted)
        self.rekey_pending = False  # our static key was rotated: a pairing under the new one is due
        self._rekey_exchange = False  # the open exchange is such a pairing
        self._exchange_hybrid = False  # the open exchange is hybrid
        self._rekey_rotated = True  # the fresh pairing due is for a rotated key (else: a hybrid one)
        self.shares: dict[str, Share] = {}  # other GS -> where its key stands (made when first needed)
        self.drone_links: set[str] = set()  # GSs the drone already holds keys for (its status)
        self.listed_since: dict[str, float] = {}  # since when (our clock) its statuses have listed each
        self.grant_sent: float | None = None

    # ------------------------------------------------------------------ queries
    def asking(self, g: str) -> bool:
        return g in self.shares and self.shares[g].phase is SharePhase.ASKED

    def granting(self, g: str) -> bool:
        return g in self.shares and self.shares[g].phase is SharePhase.GRANTING

    def granted(self, g: str) -> bool:
        return g in self.shares and self.shares[g].phase is SharePhase.GRANTED

    @property
    def grants_pending(self) -> bool:
        """A key grant waits for the drone's acknowledgement."""
        return any(s.phase is SharePhase.GRANTING for s in self.shares.values())

    def live_refused(self, g: str) -> float | None:
        return self.shares[g].live_refused if g in self.shares else None

    def deadline(self, now: float, sharing: bool) -> float | None:
        """When, after ``now``, the timer next matters for these exchanges (``sharing``: we hold the
        drone's authority); None: only an input moves them."""
        due: list[float] = []
        if self.pair_phase is PairPhase.ASKING:
            due.append(self.pairing_deadline)
        if sharing:
            for s in self.shares.values():
                if s.phase is SharePhase.ASKED and s.ask is not None:
                    due.append(s.ask.deadline if s.ask_again is None else min(s.ask.deadline, s.ask_again))
            if self.grants_pending and self.grant_sent is not None:
                due.append(self.grant_sent + GRANT_RESEND_S)
            for g, s in self.shares.items():
                if s.phase is SharePhase.NONE and g not in self.drone_links and s.last_try is not None:
                    due.append(s.last_try + RETRY_S)
                if s.phase is SharePhase.NONE and s.wait_until is not None:
                    due.append(s.wait_until)
        later = [d for d in due if d > now]
        return min(later) if later else None

    def pair_retry_due(self, now: float, retry: float, unanswered: float | None = None) -> float | None:
        """When a ``PairDue`` with ``retry`` (and ``unanswered``) may next start an exchange (None: at once)."""
        due = [self.pairing_deadline] if self.pair_phase is PairPhase.ASKING else []
        if self.last_pair_try is not None:
            due.append(self.last_pair_try + self._retry(retry, unanswered))
        return max(due) if due else None

    def _retry(self, retry: float, unanswered: float | None) -> float:
        """The wait after the last try: ``retry``, or ``unanswered`` if shorter and nothing answered it."""
        return min(retry, unanswered) if self._unanswered and unanswered is not None else retry

    def pair_unanswered(self, m1: bytes, now: float) -> None:
        """Zenoh ended our pairing query carrying ``m1`` (all replies in, or none came): if it is the
        open exchange's and nothing answered it, the exchange is over (no drone's queryable took it:
        the next try may come sooner: ``PairDue.unanswered``). A query that was answered,
        or an older exchange's, changes nothing."""
        if self.pair_phase is not PairPhase.ASKING or m1 != self._m1 or self._answered:
            return
        self.ctx.counters["pair_unanswered"] += 1
        self.pairing, self._unanswered = None, True
        self._set_state(PairPhase.IDLE, "unanswered", allowed=PAIR_CLOSED)

    # ------------------------------------------------------------------ pairing
    def on_pair(self, ev: PairDue | Reply) -> tuple[list[Action], PairProven | None]:
        """Apply a pairing event: the actions, and the new key if a reply proved it."""
        if self.pair_phase is PairPhase.ASKING and isinstance(ev, PairDue) and ev.now >= self.pairing_deadline:
            self._set_state(PairPhase.IDLE, "deadline", allowed=PAIR_CLOSED)  # the exchange expired unanswered
        if self.pair_phase is PairPhase.ASKING and isinstance(ev, Reply) and ev.now >= self.pairing_deadline:
            self._set_state(PairPhase.IDLE, "deadline", allowed=PAIR_CLOSED)
        row = self._row(PAIR_TABLE, ev)
        if row is None:
            return [], None
        return row[0](self, ev)

    def _pair_start(self, ev: PairDue) -> tuple[list[Action], PairProven | None]:
        """Send a message 1 (stamped with our time of day: the drone refuses an old one) unless the
        last try was less than ``retry`` ago."""
        if not _due(self.last_pair_try, ev.now, self._retry(ev.retry, ev.unanswered)):
            return [], None
        c = self.ctx
        self.last_pair_try = ev.now
        self._answered = self._unanswered = False
        c.counters["pair_sent"] += 1
        self.pairing = PairingInitiator(c.identity, c.gs, c.drone, c.fleet.nodes[c.drone].public_bytes, stamp=ev.stamp,
                                        hybrid=c.fleet.pairing_pq)
        self._rekey_exchange = self.rekey_pending
        self._exchange_hybrid = c.fleet.pairing_pq
        self.pairing_deadline = ev.now + ev.timeout
        self._set_state(PairPhase.ASKING, "message 1")
        self._m1 = self.pairing.start()
        return [Ask(AskKind.PAIR, c.drone, c.gs, keyexprs.pair(c.drone, c.gs), self._m1, ev.timeout)], None

    def _pair_late(self, ev: Reply) -> tuple[list[Action], PairProven | None]:
        self.ctx.counters["pair_reply_late"] += 1
        return [], None

    def _pair_reply(self, ev: Reply) -> tuple[list[Action], PairProven | None]:
        c = self.ctx
        self._answered = True
        assert self.pairing is not None
        if ev.ok is None:
            reason = (ev.err or b"error").decode(errors="replace")[:200]
            c.counters["pair_refused"] += 1
            if c.counters["pair_refused"] > LOGGED:
                return [], None
            log.warning("pairing with %s refused: %s", c.drone, reason)
            return [Emit(rec.GsPairRefused(drone=c.drone, reason=reason))], None
        key = self.pairing.finish(ev.ok)
        if isinstance(key, PairingFailed):
            c.counters["pair_bad_reply"] += 1  # forged or stale: the genuine reply may still come
            return ([Emit(rec.PairFailed(drone=c.drone, reason=key.reason))] if c.counters["pair_bad_reply"] <= LOGGED
                    else []), None
        if c.fleet.pairing_pq and not self._exchange_hybrid:
            # begun before the revision requiring hybrid: the drone dropped its candidate; pair again, hybrid
            c.counters["pair_reply_refused:classical"] += 1
            self.pairing = None
            self._set_state(PairPhase.IDLE, "classical")
            return [], None
        kept, fresh = self.pairing.peer_kept_key, self._rekey_exchange
        self.pairing = None
        if fresh:
            self.rekey_pending = False
        self._set_state(PairPhase.IDLE, "paired")
        return [], PairProven(key, kept=kept, fresh=fresh, hybrid=self._exchange_hybrid, rotated=self._rekey_rotated)

    def rekey(self, identity: Identity, linked: bool, rotated: bool = True) -> None:
        """Our static key was rotated: pair under ``identity`` from now on. With a link (``linked``),
        an open exchange is forgotten (its reply could only give a key of the old one) and a fresh
        pairing is due; without one, the next pairing is under the new key anyway."""
        self.ctx.identity = identity
        if not linked:
            return
        self.pairing = None
        self.rekey_pending, self._rekey_rotated = True, rotated
        self._set_state(PairPhase.IDLE, "abandoned", allowed=PAIR_CLOSED)

    # ------------------------------------------------------------------ key sharing
    def keys_lost(self, now: float) -> None:
        """The drone restarted with no key but ours: every key shared for it must be shared again."""
        self.lost_key_at = now  # authenticated: the drone's message 2 said it no longer held our key
        for g in self.shares:
            self._share(g, KeysLost(now))
        self.drone_listed({self.ctx.gs}, now)

    def drone_listed(self, linked: set[str] | frozenset[str] | tuple[str, ...], now: float) -> None:
        """The drone's signed status lists the GSs it holds keys for: since when each has been listed."""
        self.drone_links = set(linked)
        self.listed_since = {g: self.listed_since.get(g, now) for g in self.drone_links}

    def peer_keys_lost(self, g: str, notice: bytes, since: float, now: float, since_here: float) -> None:
        """GS ``g`` (authorized for the drone) restarted holding none of its keys made before ``since``
        (its checked notice; ``since_here``: the same instant on our clock): its key is shared again, once
        per start, the notice going with the grant, if the drone's statuses have listed a key of ``g``
        since before that start (else the drone holds none, or one ``g`` made after it: nothing to replace)."""
        listed = self.listed_since.get(g)
        if g in self.others() and listed is not None and listed < since_here - keyslost.SKEW_S:
            self.shares.setdefault(g, Share())
            self._share(g, PeerKeysLost(now, notice, since))

    def others(self) -> list[str]:
        """The other GSs authorized for the drone, in the fleet as it is now (a revision may change it)."""
        c = self.ctx
        return [g for g in c.fleet.nodes[c.drone].authorized_gs if g != c.gs]

    def share_keys(self, now: float, wall: float, send_control: Callable[[wire.Control], list[Action]],
                   wanted: set[str] | None = None) -> list[Action]:
        """As authority: ask the other authorized GSs for their link keys (only those ``wanted``, if the
        drone's links follow it: ``zdrone.core.linkplan``); grant them to the drone."""
        out: list[Action] = []
        for g in self.others():
            if wanted is not None and g not in wanted and g not in self.shares:
                continue
            share = self.shares.setdefault(g, Share())
            if wanted is not None and g not in wanted and share.phase in (SharePhase.NONE, SharePhase.GRANTED):
                continue  # not (or no longer) prepared: not asked
            out += self._share(g, ShareDue(now, wall, wanted is not None))
        if self.grants_pending and _due(self.grant_sent, now, GRANT_RESEND_S):
            self.grant_sent = now
            for s in self.shares.values():
                if s.phase is SharePhase.GRANTING:
                    assert s.grant is not None
                    out += send_control(s.grant)
        return out

    def drop_classical_shares(self) -> int:
        """The fleet now requires hybrid keys: a classical exchange still open, or its key not yet granted,
        is dropped (asked again, hybrid, at the next share); how many."""
        if not self.ctx.fleet.pairing_pq:
            return 0
        dropped = 0
        for g, s in self.shares.items():
            if s.phase in (SharePhase.ASKED, SharePhase.GRANTING) and not s.hybrid:
                s.ask, s.grant, s.ask_again = None, None, None
                self.ctx.asks_out.get(g, {}).pop(self.ctx.drone, None)
                self._set_state(SharePhase.NONE, "hybrid required", key=g, allowed=frozenset({SharePhase.NONE}))
                dropped += 1
        self.ctx.counters["linkkey_dropped:classical"] += dropped
        return dropped

    def on_share_reply(self, g: str, ok: bytes | None, err: bytes | None, now: float) -> list[Action]:
        if g not in self.shares:
            return self._reply_unasked(g, Reply(now, ok, err))
        return self._share(g, Reply(now, ok, err))

    def on_grant_ack(self, g: str, grant_id: int, now: float) -> list[Action]:
        return self._share(g, GrantAcked(now, grant_id)) if g in self.shares else []

    def _share(self, g: str, ev: Any) -> list[Action]:
        row = self._row(SHARE_TABLE, ev, key=g)
        if row is None:
            return []
        return row[0](self, g, ev)

    def _ask(self, g: str, ev: ShareDue) -> list[Action]:
        s, c = self.shares[g], self.ctx
        if g in self.drone_links and s.lost is None:  # the drone holds its key (unless the GS lost it)
            return []
        if s.ask_again is None and not _due(s.last_try, ev.now, RETRY_S):
            return []
        out = c.asks_out.setdefault(g, {})
        if c.drone not in out and len(out) >= ASKS_IN_FLIGHT:
            for d in [d for d, t in out.items() if t <= ev.now]:  # expired unanswered: their turn is over
                del out[d]
            if len(out) >= ASKS_IN_FLIGHT:
                s.wait_until = ev.now + ASK_WAIT_S
                c.counters["linkkey_ask_waited"] += 1
                return []
        s.ask_again, s.wait_until = None, None
        s.last_try, s.asked_wall = ev.now, ev.wall
        s.ask = KeyShareAsk(c.identity, c.gs, g, c.fleet.nodes[g].public_bytes, c.drone, ev.now, wall=ev.wall,
                            hybrid=c.fleet.pairing_pq)
        s.hybrid = c.fleet.pairing_pq
        out[c.drone] = s.ask.deadline
        self._set_state(SharePhase.ASKED, "asked", key=g)
        return [Ask(AskKind.LINKKEY, c.drone, g, keyexprs.linkkey(g, c.drone), s.ask.payload, s.ask.deadline - ev.now)]

    def _granted_due(self, g: str, ev: ShareDue) -> list[Action]:
        """A key we granted, which the drone no longer holds (it closed that link: links that follow the
        drone): shared again once its status has had time to say so (``REGRANT_AFTER_S``)."""
        s = self.shares[g]
        if (not ev.follow or g in self.drone_links or s.granted_at is None
                or ev.now - s.granted_at < REGRANT_AFTER_S):
            return []
        s.granted_at = None
        self.ctx.counters["linkkey_shared_again"] += 1
        self._set_state(SharePhase.NONE, "the drone closed its link", key=g)
        return self._ask(g, ev)

    def _ask_over(self, g: str, ev: ShareDue) -> list[Action]:
        """An open query: past its deadline (no answer) or its "live link" retry, asked again."""
        s = self.shares[g]
        assert s.ask is not None
        if not s.ask.expired(ev.now) and (s.ask_again is None or ev.now < s.ask_again):
            return []
        self.ctx.counters["linkkey_no_answer" if s.ask_again is None else "linkkey_asked_again"] += 1
        self.ctx.asks_out.get(g, {}).pop(self.ctx.drone, None)
        s.ask = None
        self._set_state(SharePhase.NONE, "ask over", key=g)
        return self._ask(g, ev)

    def _reply(self, g: str, ev: Reply) -> list[Action]:
        s, c = self.shares[g], self.ctx
        if ev.ok is None:
            c.asks_out.get(g, {}).pop(c.drone, None)  # answered: its place is free
            c.counters["linkkey_reply_error"] += 1
            if ev.err == ShareRefusal.LIVE_LINK.value.encode():
                s.ask_again = ev.now + LIVE_LINK_RETRY_S  # soon: its link is about to be LOST
                s.live_refused = ev.now
            return self._reply_error(g, ev)
        assert s.ask is not None
        secret = s.ask.on_reply(ev.ok, ev.now)
        if isinstance(secret, Refused):
            key = f"linkkey_reply:{secret.reason.value}"
            c.counters[key] += 1
            if c.counters[key] > LOGGED:
                return []
            log.warning("key-sharing reply for %s from %s refused: %s", c.drone, g, secret.reason.value)
            return [Emit(rec.LinkkeyBadReply(drone=c.drone, gs=g, reason=secret.reason.value))]
        s.ask, s.ask_again = None, None
        c.asks_out.get(g, {}).pop(c.drone, None)
        if c.fleet.pairing_pq and not s.hybrid:
            # asked before the revision requiring hybrid: a classical key is never granted after it; ask again, hybrid
            c.counters["linkkey_reply_refused:classical"] += 1
            self._set_state(SharePhase.NONE, "classical reply after hybrid required", key=g)
            return []
        s.grant = wire.KeyGrant(g, c.fleet.nodes[g].sysid, secret, next(c.grant_ids), lost=s.lost or b"")
        self.grant_sent = None
        self._set_state(SharePhase.GRANTING, "reply", key=g)
        return [Emit(rec.LinkkeyReceived(drone=c.drone, gs=g))]

    def _reply_error(self, g: str, ev: Reply) -> list[Action]:
        c = self.ctx
        if c.counters["linkkey_reply_error"] > LOGGED:  # the first few in the log; all in the counters
            return []
        return [Emit(rec.LinkkeyError(drone=c.drone, gs=g, reason=(ev.err or b"").decode(errors="replace")[:120]))]

    def _reply_unasked(self, g: str, ev: Reply) -> list[Action]:
        if ev.ok is None:
            self.ctx.counters["linkkey_reply_error"] += 1
            return self._reply_error(g, ev)
        self.ctx.counters["linkkey_reply:not_waiting"] += 1
        return []

    def _acked(self, g: str, ev: GrantAcked) -> list[Action]:
        s = self.shares[g]
        assert s.grant is not None
        if s.grant.grant_id != ev.grant_id:
            return []
        s.grant, s.granted_at, s.lost = None, ev.now, None
        self._set_state(SharePhase.GRANTED, "acknowledged", key=g)
        return [Emit(rec.KeyGranted(drone=self.ctx.drone, gs=g))]

    def _forget(self, g: str, ev: KeysLost) -> list[Action]:
        s = self.shares[g]
        s.grant, s.lost = None, None  # the drone restarted: it holds no key of ``g`` to replace
        self._set_state(SharePhase.NONE, "keys lost", key=g)
        return []

    def _peer_lost(self, g: str, ev: PeerKeysLost) -> list[Action]:
        """``g`` restarted: the key the drone holds (or is being granted) is one it lost. A notice of a
        start already acted on only refreshes the notice the grant will carry."""
        s, c = self.shares[g], self.ctx
        if s.lost_since is not None and ev.since <= s.lost_since:
            if s.lost is not None and ev.since == s.lost_since:
                s.lost = ev.notice  # a fresher copy of the notice for the grant still to come
            return []
        if s.reset_at is not None and ev.now - s.reset_at < PEER_RESET_GAP_S:
            c.counters["linkkey_peer_restart_deferred"] += 1  # a copy after the gap acts (re-published 60 s)
            return []
        s.lost, s.lost_since = ev.notice, ev.since
        if s.phase in (SharePhase.NONE, SharePhase.ASKED):
            return []  # NONE: asked at the next share, past ``drone_links``; ASKED: the query stands or times out
        if s.asked_wall is None or s.asked_wall >= ev.since - keyslost.SKEW_S:
            s.lost = None  # the key we got from it was made after that start (or we never asked): it holds it
            return []
        s.grant, s.last_try, s.reset_at = None, None, ev.now
        c.counters["linkkey_peer_restarted"] += 1
        self._set_state(SharePhase.NONE, f"{g} restarted", key=g)
        return []

    # ------------------------------------------------------------------ engine
    def _machine_name(self, key: Hashable | None = None) -> str:
        return f"{self.ctx.drone}, {'pairing' if key is None else f'key of {key}'}"

    def _get_state(self, key: Hashable | None = None) -> Any:
        """The pairing exchange's phase (``key`` None), or the key sharing's for the GS ``key``."""
        return self.pair_phase if key is None else self.shares[key].phase  # type: ignore[index]

    def _put_state(self, new: Any, key: Hashable | None = None, now: float | None = None) -> None:
        if key is None:
            self.pair_phase = new
        else:
            self.shares[key].phase = new  # type: ignore[index]

P, S = PairPhase, SharePhase
#: The pairing exchange: (phase, event type) -> (handler, the phases it may move to). An exchange
#: past its deadline is IDLE before the table is read.
PAIR_TABLE: Table[PairPhase] = {
    (P.IDLE, PairDue): (Linking._pair_start, frozenset({P.ASKING})),
    (P.IDLE, Reply): (Linking._pair_late, frozenset()),
    (P.ASKING, Reply): (Linking._pair_reply, frozenset({P.IDLE})),
}
# Not listed: PairDue while ASKING (the exchange is open until its deadline).

#: Key sharing for one other GS: (phase, event type) -> (handler, the phases it may move to).
SHARE_TABLE: Table[SharePhase] = {
    (S.NONE, ShareDue): (Linking._ask, frozenset({S.ASKED})),
    (S.ASKED, ShareDue): (Linking._ask_over, frozenset({S.NONE, S.ASKED})),
    (S.ASKED, Reply): (Linking._reply, frozenset({S.GRANTING, S.NONE})),
    (S.NONE, Reply): (Linking._reply_unasked, frozenset()),
    (S.GRANTING, Reply): (Linking._reply_unasked, frozenset()),
    (S.GRANTED, Reply): (Linking._reply_unasked, frozenset()),
    (S.GRANTING, GrantAcked): (Linking._acked, frozenset({S.GRANTED})),
    (S.GRANTING, KeysLost): (Linking._forget, frozenset({S.NONE})),
    (S.GRANTED, KeysLost): (Linking._forget, frozenset({S.NONE})),
    (S.GRANTED, ShareDue): (Linking._granted_due, frozenset({S.NONE, S.ASKED})),
    (S.NONE, PeerKeysLost): (Linking._peer_lost, frozenset({S.NONE})),
    (S.ASKED, PeerKeysLost): (Linking._peer_lost, frozenset({S.ASKED})),
    (S.GRANTING, PeerKeysLost): (Linking._peer_lost, frozenset({S.GRANTING, S.NONE})),
    (S.GRANTED, PeerKeysLost): (Linking._peer_lost, frozenset({S.GRANTED, S.NONE})),
}
# Not listed: ShareDue while GRANTING (the grant is re-sent by share_keys), an acknowledgement of no grant of ours, KeysLost while NONE or ASKED (the query stands).
