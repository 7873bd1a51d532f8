"""The handover authority (HA): which ground station commands the drone, per drone, as a table.

Theory of operation
-------------------
States: ``UNPAIRED -> LINKED(owner, epoch) -> HANDOVER_PENDING(owner -> to) -> LINKED(to, epoch+1)``
and ``FAILSAFE``. The epoch only counts up, across companion restarts too: a restart in the air comes
back in the owner's epoch (``restore``); a restart on the ground comes back UNPAIRED with the epoch
kept, and the next authority, whoever it is, gets epoch+1 (``restore_on_ground``). FAILSAFE ends when a GS whose coverage holds the vehicle re-pairs while it is on the ground, or when an
authorized GS whose link is proven asks to take control (``AuthorityAsked`` for itself: an
operator's explicit request, never automatic) -> ``LINKED(gs, epoch+1)``.

Exactly one GS holds authority in LINKED and HANDOVER_PENDING: ``owner``. Every MAVLink frame a GS
sends up arrives classified by the drone's uplink policy (``zdrone.core.uplink``) and is checked in
this order, each refusal a counted ``DropFrame(reason)``:

1. the sender has no link (not paired, no key installed): ``not_linked``;
2. ``DENIED`` (e.g. SERIAL_CONTROL, SETUP_SIGNING, unless the policy allows them): ``denied_by_policy``,
   whoever sends it, the owner included;
3. ``AUTHORITY_ONLY`` (every id not on the read-only allowlist, unknown ids included): forwarded from
   the owner only, ``not_authority`` from anyone else; in FAILSAFE from nobody (``failsafe``);
4. ``READ_ONLY`` (HEARTBEAT, parameter reads, ...): forwarded from any linked GS, in FAILSAFE too.

Every authentic frame of a linked GS counts towards proving its link, forwarded or not. Telemetry
goes to every linked GS the drone currently listens to.

Hand-over is make-before-break. The owner sends ``Release(to, epoch)``; authority passes to ``to``
in the same step only if ``to``'s link is *proven* (its TBM is OK and at least ``PROOF_FRAMES``
authentic frames arrived since it last was LOST); otherwise the machine waits in
HANDOVER_PENDING, the owner keeping authority, until the proof arrives (switch, epoch+1) or the
timeout passes (authority stays where it was). There is never an instant with no owner or two.

Least privilege. Authority moves only (a) by the owner's release (``Release``, or the owner's own
``AuthorityAsked``: the owner operator's consent to another GS's request travels as the owner's
release), or (b) in an emergency, to an *heir*. When the owner's link becomes LOST, authority
passes to an heir (an emergency hand-over, epoch+1): an authorized GS whose coverage contains the
drone's own position (``RegionChanged``: computed on the drone from the vehicle's GPS; an unknown
position is inside no coverage) and whose link was proven *while the drone was inside that
coverage* (``PROOF_FRAMES`` authentic frames counted only while inside; leaving the coverage or a
LOST link starts the count again). Re-pairing from outside coverage, or frames that arrive over the
backhaul mesh, confirm a key but never make an heir. With no heir the machine enters FAILSAFE and
commands the vehicle to LAND (or RTL); an operator's request to take control back after the
failsafe obeys the same heir rule. A consented release may go to a GS outside coverage (an
operations centre over the backhaul): its proof is that of its link, wherever the drone is.

The machine is pure: every event carries ``now``; ``handle(event)`` returns a list of actions that
the drone node adapter carries out (forward a frame, send a control message, command the vehicle).
One step is three passes, taken by the machine engine (``zdrone.core.machine``: ``_step``):

1. the event's handler, found in the table ``TRANSITIONS``: (state, event type) -> (handler,
   allowed next states). A pair missing from the table is an illegal step: a GS-originated event
   gets a ``Reject`` action, anything else raises ``IllegalTransition`` (a programming error);
2. the rules that follow from the state and the time alone (``SETTLE``: a proven pending recipient
   takes authority, deadlines pass), each a row with the states it applies in and the next states it
   may choose, checked as the handlers' are; at most one fires per step;
3. the effects of the state change, computed once from the state before the step and after it
   (``_effects``), never appended by handlers: the GSs the drone listens to (``subscribed``: in LINKED
   and HANDOVER_PENDING every linked GS whose coverage holds the vehicle, the owner and a pending
   recipient; in FAILSAFE those it listened to when the failsafe began; none in UNPAIRED), and the
   authority status. The status (owner, epoch, state, pending recipient, takeover) goes, as it is
   after the step, to every GS listened to after the step and to the owner before and after it
   whenever it changed -- except in a step that enters FAILSAFE, which every linked GS hears as a
   ``FailsafeNotice`` -- and to whoever a handler asks it for (``_tell``: every listened GS after an
   accepted pairing or a takeover setting, the owner with a relayed request), once per GS.

Handlers return only what is theirs to say: forwards and drops, rejects, the operator's request,
the failsafe's command and notice, and the event-log notes.

The events, the actions, the drops' reasons and the key grants' typed results are the machine's
vocabulary, in ``zdrone.core.authority_events`` (re-exported here). ``pair_refusal`` gives the
machine's rule for pairing as a ``PairRefused`` (the pairing responder's result type), or None.

Fleet revisions (``zdrone.core.revision``). A signed revision may take GSs off the drone's
authorized list (revoked, or de-authorized) or add some: ``Revised(authorized)`` gives the new
list. A GS no longer on it loses its link at once (its proof, its pending hand-over, its takeover
window, its first claim); if it held authority, authority goes as when the owner's link is LOST in
the air: to an heir (an authorized GS proven inside its coverage), else the failsafe. In FAILSAFE
the machine stays there (the revoked owner is only the epoch's name; nobody commands).

Links that follow the drone (``zdrone.core.linkplan``). The drone may close a link it no longer needs
(``LinkClosed``): only one ``may_close`` allows -- not the owner's, a pending recipient's, a consent
window's or a first claim's, not a GS whose coverage holds the drone (so never an heir), never in
FAILSAFE. A closed link is forgotten: its frames are ``not_linked``, it is no heir and no recipient
until the GS links again (a grant of the owner, or its own pairing).

First claim after a restart on the ground. A companion restarted on the ground holds no key and no
owner, yet the GS that held authority never released it: for ``FIRST_CLAIM_S`` after the restart only
that last owner may pair into authority (another authorized GS is refused ``first_claim``), and its
coverage must still hold the vehicle, as for every pairing that gives authority. After the window the
usual rules apply: any authorized GS whose coverage holds the vehicle may pair first.
"""

from __future__ import annotations

import logging
from collections import Counter
from dataclasses import dataclass, replace

from zdrone.core.authority_events import (GS_EVENTS, Action, AuthorityAsked, AuthorityChanged, DropFrame, Event,  # noqa: F401
                               FailsafeCommand, Forward, Frame, GrantAccepted, GrantHeard, GrantRejected,
                               GrantRejection, GrantResult, GroundChanged, HaDrop, LinkChanged, Note, PairingDone,
                               LinkClosed, RegionChanged, Release, Revised, SendControl, Tick, check_grant)
from zdrone.core.machine import IllegalTransition, Machine, SettleRow, Table
from zdrone.core.mavcontrol import REQUEST_TIMEOUT_MAX_S, REQUEST_TIMEOUT_MIN_S
from zdrone.core.pairing import PairRefusal, PairRefused
from zdrone.core.ratelimit import RateLimiter
from zdrone.core.tbm import LinkState
from zdrone.core.uplink import UplinkClass
from zdrone.core.wire import AuthorityState, AuthorityStatus, FailsafeNotice, OperatorRequest, Reject

log = logging.getLogger(__name__)

PROOF_FRAMES = 2
#: A GS's requests for control are passed to the owner at this rate per requester at most (bursts of
#: ``REQUEST_RELAY_BURST``): an operator's request is re-sent once a second while it stands.
REQUEST_RELAY_RATE, REQUEST_RELAY_BURST = 1.0, 3.0
DEFAULT_HANDOVER_TIMEOUT = 5.0
#: After a companion restart on the ground, only the owner it had may pair into authority for this
#: long. That GS never released authority, and it re-pairs by itself within 0.5 s of the node being
#: ready (it tries every 0.2 s once the drone has been silent 1 s): 5 s leaves room for a lossy radio
#: and a GS clock a little behind the drone's, while a vehicle whose owner is gone waits only seconds
#: before another GS covering it may pair.
FIRST_CLAIM_S = 5.0
#: The reasons a release is refused with when authority has moved on from its sender (it is no longer
#: the authority, or the epoch it released is over): the GS that sent it must not command on as if
#: its hand-over had merely failed (``gs.core``: it waits for the drone's status instead).
RELEASE_NOT_AUTHORITY = "not the authority"
RELEASE_STALE_EPOCH = "stale epoch"


State = AuthorityState  # one enum: the machine's states are what the drone reports on the wire


@dataclass(frozen=True, slots=True)
class Config:
    authorized: frozenset[str]
    handover_timeout: float = DEFAULT_HANDOVER_TIMEOUT
    failsafe_action: str = "LAND"


@dataclass(slots=True)
class _Link:
    state: LinkState = LinkState.LOST
    frames_since_ok: int = 0  # authentic frames since the link last was LOST (the proof of a release)
    frames_in_cover: int = 0  # the same, counted only while the drone is inside the GS's coverage (an heir's proof)


class AuthorityMachine(Machine):
    """The HA of one drone. Feed events with ``handle``; carry out the actions it returns."""

    _log = log

    def __init__(self, config: Config) -> None:
        if config.failsafe_action not in ("LAND", "RTL"):
            raise ValueError("failsafe_action must be LAND or RTL")
        self.config = config
        self.state = State.UNPAIRED
        self.owner: str | None = None
        self.epoch = 0
        self.pending_to: str | None = None
        self.pending_deadline: float | None = None
        self.links: dict[str, _Link] = {}
        self.subscribed: set[str] = set()
        self.inside: frozenset[str] = frozenset()
        self.drops: Counter[HaDrop] = Counter()
        self.rejects: Counter[str] = Counter()
        self.history: list[tuple[float, str | None, int]] = []  # (time, owner, epoch) after each change
        self.repair_deadline: float | None = None  # after a restart: the owner must re-pair by then
        self.relay_limit = RateLimiter(REQUEST_RELAY_RATE, REQUEST_RELAY_BURST)  # requests passed to the owner
        self.takeover_epoch: int | None = None  # the epoch whose owner allows takeover (its operator's setting)
        self.on_ground = False  # the vehicle's own word (``GroundChanged``); unknown counts as in the air
        self.takeover_to: str | None = None  # ... for this GS only (a consent's window), None: any
        self.first_claim: str | None = None  # after a restart on the ground: the last owner, pairing back first
        self.first_claim_until: float | None = None  # ... until then
        self._tell: set[str] = set()  # who hears the status after this step whether it changed or not
        self._tell_everyone = False  # ... and every GS listened to after it

    # ------------------------------------------------------------------ queries
    def is_authorized(self, gs: str) -> bool:
        return gs in self.config.authorized

    def is_proven(self, gs: str) -> bool:
        link = self.links.get(gs)
        return link is not None and link.state is LinkState.OK and link.frames_since_ok >= PROOF_FRAMES

    def proven_in_cover(self, gs: str) -> bool:
        """``gs`` is authorized, its coverage holds the drone now, and its link was proven while it did."""
        link = self.links.get(gs)
        return (link is not None and self.is_authorized(gs) and gs in self.inside
                and link.state is LinkState.OK and link.frames_in_cover >= PROOF_FRAMES)

    def is_heir(self, gs: str) -> bool:
        """May ``gs`` take authority from the owner without its consent (its link LOST)? Only a GS
        other than the owner that is ``proven_in_cover``."""
        return gs != self.owner and self.proven_in_cover(gs)

    def may_close(self, gs: str) -> bool:
        """May the drone close its link with ``gs`` (``LinkClosed``: links that follow the drone,
        ``zdrone.core.linkplan``)? Only a link that no rule may need: not the owner's, not a pending
        recipient's, not a consent window's or a first claim's, not a GS whose coverage holds the drone
        (every heir is one), and never in FAILSAFE (whoever may take control back keeps its link)."""
        return (gs in self.links and self.state is not State.FAILSAFE and gs not in self.inside
                and gs not in (self.owner, self.pending_to, self.takeover_to, self.first_claim))

    def heirs(self) -> list[str]:
        """The GSs that may take authority in an emergency, best first (the pending recipient, then by name)."""
        found = sorted(g for g in self.links if self.is_heir(g))
        if self.pending_to in found:
            found.remove(self.pending_to)
            found.insert(0, self.pending_to)
        return found

    @property
    def in_region(self) -> bool:
        """Inside the coverage of two or more authorized GSs: the hand-over region."""
        return len(self.inside & self.config.authorized) >= 2

    def telemetry_targets(self) -> list[str]:
        """The linked GSs the drone currently talks to."""
        return sorted(self.subscribed)

    def status(self) -> AuthorityStatus:
        return AuthorityStatus(self.owner, self.epoch, self.state, self.pending_to, sorted(self.links),
                               takeover=self.takeover_epoch == self.epoch,
                               takeover_to=self.takeover_to if self.takeover_epoch == self.epoch else None)

    def get_timer(self) -> float | None:
        """When the machine must next be woken with ``handle_timer`` (a hand-over's deadline, the
        owner's re-pairing deadline after a restart, the end of a first claim), or None: no deadline pending."""
        times = [t for t in (self.pending_deadline if self.state is State.HANDOVER_PENDING else None,
                             self.repair_deadline, self.first_claim_until) if t is not None]
        return min(times) if times else None

    def handle_timer(self, now: float) -> list[Action]:
        """Time has reached ``get_timer()``: apply what the deadlines decide."""
        return self.handle(Tick(now))

    def grant_rejection(self, sender: str, gs: str) -> GrantRejected | None:
        """Why a key grant from ``sender`` for ``gs`` would be rejected now, or None (a query: the
        ``GrantHeard`` handler applies the same rules)."""
        if (self.state, GrantHeard) not in TRANSITIONS:
            return GrantRejected(gs, GrantRejection.ILLEGAL_STATE, f"illegal in state {self.state.value}")
        if sender != self.owner:
            return GrantRejected(gs, GrantRejection.NOT_AUTHORITY, "not the authority: only the authority grants keys")
        if not self.is_authorized(gs):
            return GrantRejected(gs, GrantRejection.UNAUTHORIZED, f"unauthorized: {gs} is not authorized for this drone")
        return None

    def grant(self, ev: GrantHeard) -> tuple[GrantResult, list[Action]]:
        """Apply a key grant: its result (accepted: the adapter installs the key and acknowledges
        it; rejected: the ``Reject`` is among the actions) and the actions to carry out."""
        result = self.grant_rejection(ev.sender, ev.gs) or GrantAccepted(ev.gs)
        return result, self.handle(ev)

    def restore(self, owner: str, epoch: int, now: float, grace: float, failsafe: bool = False) -> list[Action]:
        """Come back after a companion restart with the authority it had: LINKED(owner, epoch), with
        no key for anyone. ``owner`` must re-pair within ``grace`` seconds (the loss threshold), else
        its link counts as LOST (emergency hand-over if another GS has re-paired and proven its link,
        else the failsafe). With ``failsafe`` (restarted in the air during the failsafe) it comes back
        in FAILSAFE and commands the failsafe action again: only the failsafe's own rules end it. Only
        at start, from UNPAIRED."""
        if self.state is not State.UNPAIRED:
            raise IllegalTransition("restore() after the machine started")
        if not self.is_authorized(owner):
            return [Note("restore_refused", f"{owner} is not authorized")]
        self.owner, self.epoch = owner, epoch
        self.links[owner] = _Link()  # LOST until it re-pairs
        if failsafe:
            self._move("restore", State.FAILSAFE, RESTORED, now)
            action = self.config.failsafe_action
            return [Note("restored", f"authority {owner} epoch {epoch} in failsafe: {action} again"),
                    FailsafeCommand(action, "restarted during the failsafe")]
        self.repair_deadline = now + grace
        self._move("restore", State.LINKED, RESTORED, now)  # no status: nobody holds a key yet
        return [Note("restored", f"authority {owner} epoch {epoch}; waiting {grace:.1f} s for it to re-pair")]

    def restore_on_ground(self, owner: str, epoch: int, now: float, window: float = FIRST_CLAIM_S) -> list[Action]:
        """Come back after a companion restart on the ground: UNPAIRED, no key for anyone, the epoch
        kept (the next authority, whoever it is, gets ``epoch + 1``) and ``owner`` holding the first
        claim for ``window`` seconds: meanwhile only it may pair into authority (its coverage must
        still hold the vehicle); after that, any authorized GS covering the vehicle. An owner no longer
        authorized gets no first claim; the epoch is kept all the same. Only at start, from UNPAIRED."""
        if self.state is not State.UNPAIRED or self.epoch:
            raise IllegalTransition("restore_on_ground() after the machine started")
        self.epoch = epoch
        if not self.is_authorized(owner):
            return [Note("restore_refused", f"{owner} is not authorized: no first claim; the next authority "
                                            f"gets epoch {epoch + 1}")]
        self.first_claim, self.first_claim_until = owner, now + window
        return [Note("first_claim", f"restarted on the ground: {owner} (epoch {epoch}) may pair back first for "
                                    f"{window:.1f} s; the next authority gets epoch {epoch + 1}")]

    # ------------------------------------------------------------------- engine
    def handle(self, event: Event) -> list[Action]:
        """Apply one event; return the actions to carry out. Never raises for GS-sent events."""
        row = self._row(TRANSITIONS, event)
        if row is None:
            if isinstance(event, GS_EVENTS):
                sender = getattr(event, "sender", None) or getattr(event, "gs")
                return self._reject(sender, type(event).__name__, f"illegal in state {self.state.value}")
            raise IllegalTransition(f"{type(event).__name__} in state {self.state.value}")
        return self._step(row, event, SETTLE)

    def _move(self, rule: str, new: State, allowed: frozenset[State], now: float) -> None:
        """Enter the state a handler or a rule chose; the history and whom to listen to follow it."""
        super()._move(rule, new, allowed, now)
        if self.owner is not None and (not self.history or self.history[-1][1:] != (self.owner, self.epoch)):
            self.history.append((now, self.owner, self.epoch))
        self._follow_subscriptions()  # the state's rule, as it stands after this move

    def _machine_name(self, key: object = None) -> str:
        return "authority"

    def _state_note(self) -> str:
        return f"owner {self.owner}, epoch {self.epoch}"

    # the rules of ``SETTLE``: each returns (next state, actions) if it fires, else None
    def _proven_recipient(self, now: float) -> tuple[State, list[Action]] | None:
        """A pending recipient whose link is proven takes authority (make-before-break)."""
        if self.pending_to is None or not self.is_proven(self.pending_to):
            return None
        return State.LINKED, self._switch(self.pending_to, now, "handover")

    def _handover_deadline(self, now: float) -> tuple[State, list[Action]] | None:
        """A hand-over past its deadline ends, authority staying where it was."""
        if self.pending_deadline is None or now < self.pending_deadline:
            return None
        to = self.pending_to
        self.pending_to = self.pending_deadline = None
        return State.LINKED, [Note("handover_timeout", f"{self.owner} -> {to}: authority stays with {self.owner}")]

    def _repair_deadline(self, now: float) -> tuple[State, list[Action]] | None:
        """An owner that has not re-paired by its deadline after a restart has lost its link."""
        if self.repair_deadline is None or now < self.repair_deadline or self.owner is None:
            return None
        self.repair_deadline = None
        return self._on_link(LinkChanged(now, self.owner, LinkState.LOST))

    def _owner_back_on_ground(self, now: float) -> tuple[State, list[Action]] | None:
        """The vehicle is down and its owner's link is back (proven, covering it): the owner has it back."""
        link = self.links.get(self.owner or "")
        if not (self.on_ground and self.owner is not None and link is not None and link.state is LinkState.OK
                and self.proven_in_cover(self.owner)):
            return None
        owner = self.owner
        acts: list[Action] = [Note("failsafe_recovered", f"{owner}'s link is back with the vehicle on the ground")]
        return State.LINKED, acts + self._switch(owner, now, "regained")

    def _first_claim_over(self, now: float) -> tuple[State, list[Action]] | None:
        """A first claim after a restart on the ground ends at its deadline."""
        if self.first_claim_until is None or now < self.first_claim_until:
            return None
        last = self.first_claim
        self.first_claim = self.first_claim_until = None
        return self.state, [Note("first_claim_over", f"{last} did not pair back in time: any authorized GS whose "
                                                     f"coverage holds the vehicle may pair (epoch {self.epoch + 1})")]

    # the effects of a step
    def _status_key(self) -> tuple[object, ...]:
        """What the authority status says (its list of linked GSs aside)."""
        st = self.status()
        return st.owner, st.epoch, st.state, st.pending_to, st.takeover, st.takeover_to

    def _before(self) -> tuple[tuple[object, ...], str | None, State]:
        """The status, the owner and the state before the step; nobody has asked to hear it yet."""
        self._tell, self._tell_everyone = set(), False
        return self._status_key(), self.owner, self.state

    def _effects(self, before: tuple[tuple[object, ...], str | None, State]) -> list[Action]:
        """What follows from the step's state change (the module docstring, pass 3)."""
        key, owner, state = before
        tell, self._tell = self._tell, set()
        if self._tell_everyone:
            tell |= self.subscribed | ({self.owner} if self.owner else set())
            self._tell_everyone = False
        entered_failsafe = self.state is State.FAILSAFE and state is not State.FAILSAFE  # told by its notice
        if key != self._status_key() and not entered_failsafe:
            tell |= self.subscribed | {g for g in (owner, self.owner) if g is not None}
        st = self.status()
        return [SendControl(gs, st) for gs in sorted(tell)]

    def _follow_subscriptions(self) -> None:
        """Listen to every linked GS whose coverage holds the vehicle, and always to the owner and a
        pending recipient, in LINKED and HANDOVER_PENDING (so the old GS is dropped once the vehicle
        leaves its coverage); FAILSAFE keeps the GSs it listened to, UNPAIRED has none."""
        if self.state in (State.LINKED, State.HANDOVER_PENDING):
            self.subscribed = {gs for gs in self.links if gs in self.inside}
            self.subscribed |= {g for g in (self.owner, self.pending_to) if g}

    def _tell_all(self) -> None:
        """The status goes to every GS listened to after this step, changed or not."""
        self._tell_everyone = True

    def _reject(self, gs: str, what: str, reason: str) -> list[Action]:
        self.rejects[reason.split(":")[0]] += 1
        log.info("authority: reject %s from %s: %s", what, gs, reason)
        return [SendControl(gs, Reject(what, reason)), Note("reject", f"{what} from {gs}: {reason}")]

    def _switch(self, to: str, now: float, kind: str) -> list[Action]:
        old = self.owner
        self.owner, self.epoch = to, self.epoch + 1
        self.pending_to = self.pending_deadline = None
        self.first_claim = self.first_claim_until = None  # authority is held again: no claim stands
        return [AuthorityChanged(old, to, self.epoch, kind)]

    # ----------------------------------------------------------------- handlers
    def pair_refusal(self, gs: str, on_ground: bool, now: float) -> PairRefused | None:
        """Why a pairing with ``gs`` would be refused at ``now`` (a query: the adapter asks before any
        crypto, the ``PairingDone`` handlers apply the same rule), or None."""
        if not self.is_authorized(gs):
            return PairRefused(PairRefusal.UNAUTHORIZED, f"{gs} is not authorized for this drone")
        if self.state is State.FAILSAFE and not on_ground:
            return PairRefused(PairRefusal.FAILSAFE, "re-pair only on the ground")
        if self.state in (State.UNPAIRED, State.FAILSAFE) and gs not in self.inside:
            # this pairing would give authority (the first one, or over a vehicle the failsafe landed):
            # least privilege wants the GS to cover where the vehicle is, by its own GPS, as for an heir
            where = "the vehicle's position is unknown" if not self.inside else "its coverage does not hold the vehicle"
            return PairRefused(PairRefusal.OUTSIDE_COVERAGE, where)
        if (self.state is State.UNPAIRED and self.first_claim not in (None, gs) and self.first_claim_until is not None
                and now < self.first_claim_until):
            # restarted on the ground: the owner that never released authority pairs back first
            return PairRefused(PairRefusal.FIRST_CLAIM, f"{self.first_claim} held authority before the restart and "
                                                        f"pairs first ({self.first_claim_until - now:.1f} s left)")
        return None

    def _on_first_pair(self, ev: PairingDone) -> tuple[State, list[Action]]:
        if (why := self.pair_refusal(ev.gs, ev.on_ground, ev.now)) is not None:
            return State.UNPAIRED, self._reject(ev.gs, "pair", why.text)
        self.links[ev.gs] = _Link()
        return State.LINKED, self._switch(ev.gs, ev.now, "paired")

    def _on_pair_linked(self, ev: PairingDone) -> tuple[State, list[Action]]:
        if (why := self.pair_refusal(ev.gs, ev.on_ground, ev.now)) is not None:
            return self.state, self._reject(ev.gs, "pair", why.text)
        if ev.gs == self.owner:
            self.repair_deadline = None  # the owner is back (after a restart, or re-keying)
        self.links.setdefault(ev.gs, _Link())
        self._tell_all()  # every GS learns of the pairing (the links the status lists), changed or not
        return self.state, []

    def _on_pair_failsafe(self, ev: PairingDone) -> tuple[State, list[Action]]:
        if (why := self.pair_refusal(ev.gs, ev.on_ground, ev.now)) is not None:
            return State.FAILSAFE, self._reject(ev.gs, "pair", why.text)
        self.links[ev.gs] = _Link()
        return State.LINKED, self._switch(ev.gs, ev.now, "repaired")

    def _on_key_granted(self, ev: GrantHeard) -> tuple[State, list[Action]]:
        if (why := self.grant_rejection(ev.sender, ev.gs)) is not None:
            return self.state, self._reject(ev.sender, "key_grant", why.detail)
        self.links.setdefault(ev.gs, _Link())  # the adapter installs the key (``grant``: GrantAccepted)
        return self.state, [Note("key_installed", ev.gs)]

    def _on_frame(self, ev: Frame) -> tuple[State, list[Action]]:
        link = self.links.get(ev.gs)
        if link is None:
            self.drops[HaDrop.NOT_LINKED] += 1
            return self.state, [DropFrame(ev.gs, HaDrop.NOT_LINKED)]
        link.frames_since_ok += 1
        if ev.gs in self.inside:
            link.frames_in_cover += 1
        acts: list[Action] = []
        if ev.uplink is UplinkClass.DENIED:
            self.drops[HaDrop.DENIED_BY_POLICY] += 1
            acts.append(DropFrame(ev.gs, HaDrop.DENIED_BY_POLICY))
        elif ev.uplink is UplinkClass.READ_ONLY or ev.gs == self.owner:
            acts.append(Forward(ev.gs))
        else:
            self.drops[HaDrop.NOT_AUTHORITY] += 1
            acts.append(DropFrame(ev.gs, HaDrop.NOT_AUTHORITY))
        return self.state, acts  # a proof of the pending recipient is applied by ``_settle``

    def _on_frame_unpaired(self, ev: Frame) -> tuple[State, list[Action]]:
        self.drops[HaDrop.NOT_LINKED] += 1
        return State.UNPAIRED, [DropFrame(ev.gs, HaDrop.NOT_LINKED)]

    def _on_frame_failsafe(self, ev: Frame) -> tuple[State, list[Action]]:
        if ev.gs in self.links:
            self.links[ev.gs].frames_since_ok += 1  # still proving its link: it may take control back
            if ev.gs in self.inside:
                self.links[ev.gs].frames_in_cover += 1
        if ev.gs not in self.links:
            reason = HaDrop.NOT_LINKED
        elif ev.uplink is UplinkClass.DENIED:
            reason = HaDrop.DENIED_BY_POLICY
        elif ev.uplink is UplinkClass.AUTHORITY_ONLY:
            reason = HaDrop.FAILSAFE
        else:
            return State.FAILSAFE, [Forward(ev.gs)]
        self.drops[reason] += 1
        return State.FAILSAFE, [DropFrame(ev.gs, reason)]

    def _on_release(self, ev: Release) -> tuple[State, list[Action]]:
        if ev.sender != self.owner:
            return self.state, self._reject(ev.sender, "release", RELEASE_NOT_AUTHORITY)
        if ev.epoch != self.epoch:
            return self.state, self._reject(ev.sender, "release", f"{RELEASE_STALE_EPOCH}: {ev.epoch} != {self.epoch}")
        if ev.to == self.owner or not self.is_authorized(ev.to):
            return self.state, self._reject(ev.sender, "release", f"unauthorized: cannot hand over to {ev.to}")
        if ev.to not in self.links:
            return self.state, self._reject(ev.sender, "release", f"no link: no key installed for {ev.to}")
        if self.state is State.HANDOVER_PENDING and ev.to == self.pending_to:
            return self.state, []  # a repeated release
        self.pending_to, self.pending_deadline = ev.to, ev.now + self.config.handover_timeout
        acts: list[Action] = [Note("handover_start", f"{self.owner} -> {ev.to}")]
        # pending; if ``to`` is proven already, ``_settle`` completes it in this same step
        return State.HANDOVER_PENDING, acts

    def _on_request(self, ev: AuthorityAsked) -> tuple[State, list[Action]]:
        if not self.is_authorized(ev.sender):
            return self.state, self._reject(ev.sender, "handover_request", f"unauthorized: {ev.sender} is not authorized")
        if not self.is_authorized(ev.to) or ev.to not in self.links:
            return self.state, self._reject(ev.sender, "handover_request", f"no link: {ev.to} cannot take authority")
        if ev.to == ev.sender and ev.ask_id == 0:  # no operator's request: the owner's "allow takeover" setting
            if ev.sender != self.owner:  # sent while it still was the owner: stale, and never a request
                return self.state, [Note("takeover_setting", f"{ev.sender} is not the owner: setting ignored")]
            self.takeover_epoch = self.epoch if ev.takeover else None
            self.takeover_to = ev.takeover_to if ev.takeover else None  # what the GSs are shown, no more
            self._tell_all()  # the setting's sender hears it stands, changed or not
            return self.state, [Note("takeover_setting", f"{ev.sender}: takeover {'allowed' if ev.takeover else 'refused'}"
                                                         f" in epoch {self.epoch}")]
        if ev.sender == self.owner and ev.to == ev.sender:  # a request that crossed its own success: nothing to do
            return self.state, []
        if ev.sender == self.owner:  # the owner asking is a release
            return self._on_release(Release(ev.now, ev.sender, ev.to, self.epoch))
        if ev.to != ev.sender:  # a GS asks control for itself, never for another it names
            return self.state, self._reject(ev.sender, "handover_request", "a GS may only ask control for itself")
        if not self.relay_limit.allow(ev.sender, ev.now):
            self.rejects["request_rate"] += 1  # counted, not answered: the owner hears one a second at most
            return self.state, []
        note = Note("handover_requested", f"{ev.sender} asks for {ev.to}")
        if not self.owner:
            return self.state, [note]
        # the owner's operator decides (it releases, or lets the request time out): the requester is
        # the sealed request's sender, whatever it claims; its timeout is the spec's 3-60 s
        timeout = min(max(ev.timeout, REQUEST_TIMEOUT_MIN_S), REQUEST_TIMEOUT_MAX_S) if ev.timeout > 0 else 0.0
        ask = OperatorRequest(ev.sender, ev.sender, self.epoch, timeout, ev.ask_id)
        self._tell.add(self.owner)  # with the authority status it is asked in
        return self.state, [note, SendControl(self.owner, ask)]

    def _on_request_failsafe(self, ev: AuthorityAsked) -> tuple[State, list[Action]]:
        """An operator's explicit request to take control back after the failsafe (never automatic):
        the requesting GS must be authorized and its link proven; it becomes the authority of a new
        epoch, and the vehicle goes on with the failsafe action until it commands otherwise."""
        if ev.to != ev.sender:
            return State.FAILSAFE, self._reject(ev.sender, "handover_request", "failsafe: a GS may only take control itself")
        if not self.is_authorized(ev.sender):
            return State.FAILSAFE, self._reject(ev.sender, "handover_request", f"unauthorized: {ev.sender} is not authorized")
        if not self.proven_in_cover(ev.sender):
            why = ("outside coverage: the drone is not inside its coverage" if ev.sender not in self.inside
                   else f"not proven: no live link from {ev.sender} proven inside its coverage")
            return State.FAILSAFE, self._reject(ev.sender, "handover_request", f"{why}")
        acts: list[Action] = [Note("failsafe_recovered", f"{ev.sender} took control after the failsafe")]
        return State.LINKED, acts + self._switch(ev.sender, ev.now, "regained")

    def _on_link(self, ev: LinkChanged) -> tuple[State, list[Action]]:
        link = self.links.get(ev.gs)
        if link is None:
            return self.state, []
        if ev.state is LinkState.LOST:
            link.frames_since_ok = link.frames_in_cover = 0
        link.state = ev.state
        if ev.state is not LinkState.LOST:
            return self.state, []  # a proof of the pending recipient is applied by ``_settle``
        if self.state is State.FAILSAFE:
            return State.FAILSAFE, []
        if ev.gs == self.pending_to:
            self.pending_to = self.pending_deadline = None
            return State.LINKED, [Note("handover_aborted", f"link to {ev.gs} lost")]
        if ev.gs != self.owner:
            return self.state, []
        if self.on_ground:
            # as the autopilots: no link-loss failsafe on the ground; the owner keeps authority and has
            # the vehicle back when its link returns. If the vehicle lifts off first, the rule below
            # applies at that moment (``_on_ground_changed``).
            return self.state, [Note("owner_link_lost_on_ground", f"{ev.gs}: link lost with the vehicle on the "
                                     f"ground: no failsafe; authority stays with {ev.gs} until it is back")]
        return self._owner_lost(ev.now)

    def _owner_lost(self, now: float, why: str = "") -> tuple[State, list[Action]]:
        """The owner's link is LOST with the vehicle in the air (or ``why`` it lost authority
        otherwise): an heir (in coverage, proven there) takes over, else failsafe."""
        ev = LinkChanged(now, self.owner or "", LinkState.LOST)
        heirs = self.heirs()
        lost = f"authority of {ev.gs} lost: {why}" if why else f"authority link to {ev.gs} lost"
        if heirs:
            acts = [Note("authority_link_lost", f"{ev.gs}: authority to {heirs[0]}{f' ({why})' if why else ''}")]
            return State.LINKED, acts + self._switch(heirs[0], ev.now, "emergency")
        action = self.config.failsafe_action
        self.pending_to = self.pending_deadline = None
        notice = FailsafeNotice(action, lost)
        acts = [FailsafeCommand(action, notice.reason), Note("failsafe_entered", notice.reason)]
        acts += [SendControl(g, notice) for g in sorted(self.links)]
        return State.FAILSAFE, acts

    def _on_region(self, ev: RegionChanged) -> tuple[State, list[Action]]:
        was = self.in_region
        for gs in self.inside - ev.inside:  # out of its coverage: its proof as an heir starts again
            if gs in self.links:
                self.links[gs].frames_in_cover = 0
        self.inside = ev.inside
        acts: list[Action] = []
        if self.in_region and not was:
            acts.append(Note("region_entered", ",".join(sorted(ev.inside))))
        elif was and not self.in_region:
            acts.append(Note("region_left", ",".join(sorted(ev.inside))))
        return self.state, acts  # whom to listen to follows (``_follow_subscriptions``)

    def _on_ground_changed(self, ev: GroundChanged) -> tuple[State, list[Action]]:
        was, self.on_ground = self.on_ground, ev.on_ground
        owner = self.links.get(self.owner or "")
        if (was and not ev.on_ground and self.state in (State.LINKED, State.HANDOVER_PENDING) and owner is not None
                and owner.state is LinkState.LOST):
            return self._owner_lost(ev.now)  # lifted off with the owner's link lost: the failsafe rule, now
        return self.state, []

    def _on_revised(self, ev: Revised) -> tuple[State, list[Action]]:
        """A fleet revision: the new authorized list; a GS off it loses its link, and authority if it held it."""
        self.config = replace(self.config, authorized=ev.authorized)
        gone = sorted(g for g in {*self.links, *self.subscribed, self.pending_to, self.owner, self.takeover_to,
                                  self.first_claim} if g is not None and g not in ev.authorized)
        acts: list[Action] = []
        for gs in gone:
            self.links.pop(gs, None)
            self.subscribed.discard(gs)
            acts.append(Note("revoked", f"{gs}: {ev.why}: link dropped" if ev.why else
                             f"{gs}: off the authorized list (revision {ev.revision}): link dropped"))
        if self.takeover_to in gone:
            self.takeover_to = None
        if self.first_claim in gone:
            self.first_claim = self.first_claim_until = None
        if self.pending_to in gone:
            self.pending_to = self.pending_deadline = None
            acts.append(Note("handover_aborted", "the recipient was revoked"))
            if self.state is State.HANDOVER_PENDING and self.owner not in gone:
                return State.LINKED, acts
        if self.state in (State.LINKED, State.HANDOVER_PENDING) and self.owner in gone:
            self.repair_deadline = None
            self.pending_to = self.pending_deadline = None
            next_state, more = self._owner_lost(ev.now, ev.why or f"revoked (revision {ev.revision})")
            return next_state, acts + more
        return self.state, acts

    def _on_link_closed(self, ev: LinkClosed) -> tuple[State, list[Action]]:
        """The drone closes ``gs``'s link: forgotten (its proof, its subscription) if ``may_close``; a
        link some rule may still need is kept and the refusal noted (the core asks only for closable
        ones: this is the rule's own guard, which ``zdrone check`` explores)."""
        if not self.may_close(ev.gs):
            return self.state, [Note("link_kept", f"{ev.gs}: its link may still be needed: not closed")]
        self.links.pop(ev.gs, None)
        self.subscribed.discard(ev.gs)
        return self.state, [Note("link_closed", f"{ev.gs}: {ev.why or 'closed'}")]

    def _ignore(self, ev: Event) -> tuple[State, list[Action]]:
        return self.state, []


#: (state, event type) -> (handler, next states it may choose)
TRANSITIONS: Table[State] = {
    (State.UNPAIRED, PairingDone): (AuthorityMachine._on_first_pair, frozenset({State.UNPAIRED, State.LINKED})),
    (State.UNPAIRED, Frame): (AuthorityMachine._on_frame_unpaired, frozenset({State.UNPAIRED})),
    (State.UNPAIRED, LinkChanged): (AuthorityMachine._ignore, frozenset({State.UNPAIRED})),
    (State.UNPAIRED, RegionChanged): (AuthorityMachine._on_region, frozenset({State.UNPAIRED})),
    (State.UNPAIRED, Tick): (AuthorityMachine._ignore, frozenset({State.UNPAIRED})),
    (State.UNPAIRED, GroundChanged): (AuthorityMachine._on_ground_changed, frozenset({State.UNPAIRED})),
    (State.LINKED, PairingDone): (AuthorityMachine._on_pair_linked, frozenset({State.LINKED})),
    (State.LINKED, GrantHeard): (AuthorityMachine._on_key_granted, frozenset({State.LINKED})),
    (State.LINKED, Frame): (AuthorityMachine._on_frame, frozenset({State.LINKED})),
    (State.LINKED, LinkChanged): (AuthorityMachine._on_link, frozenset({State.LINKED, State.FAILSAFE})),
    (State.LINKED, RegionChanged): (AuthorityMachine._on_region, frozenset({State.LINKED})),
    (State.LINKED, AuthorityAsked): (AuthorityMachine._on_request, frozenset({State.LINKED, State.HANDOVER_PENDING})),
    (State.LINKED, Release): (AuthorityMachine._on_release, frozenset({State.LINKED, State.HANDOVER_PENDING})),
    (State.LINKED, Tick): (AuthorityMachine._ignore, frozenset({State.LINKED, State.FAILSAFE})),
    (State.LINKED, GroundChanged): (AuthorityMachine._on_ground_changed, frozenset({State.LINKED, State.FAILSAFE})),
    (State.HANDOVER_PENDING, PairingDone): (AuthorityMachine._on_pair_linked, frozenset({State.HANDOVER_PENDING})),
    (State.HANDOVER_PENDING, GrantHeard): (AuthorityMachine._on_key_granted, frozenset({State.HANDOVER_PENDING})),
    (State.HANDOVER_PENDING, Frame): (AuthorityMachine._on_frame, frozenset({State.HANDOVER_PENDING, State.LINKED})),
    (State.HANDOVER_PENDING, LinkChanged): (AuthorityMachine._on_link, frozenset({State.HANDOVER_PENDING, State.LINKED, State.FAILSAFE})),
    (State.HANDOVER_PENDING, RegionChanged): (AuthorityMachine._on_region, frozenset({State.HANDOVER_PENDING})),
    (State.HANDOVER_PENDING, AuthorityAsked): (AuthorityMachine._on_request, frozenset({State.HANDOVER_PENDING, State.LINKED})),
    (State.HANDOVER_PENDING, Release): (AuthorityMachine._on_release, frozenset({State.HANDOVER_PENDING, State.LINKED})),
    (State.HANDOVER_PENDING, Tick): (AuthorityMachine._ignore, frozenset({State.HANDOVER_PENDING, State.LINKED, State.FAILSAFE})),
    (State.HANDOVER_PENDING, GroundChanged): (AuthorityMachine._on_ground_changed,
                                          frozenset({State.HANDOVER_PENDING, State.LINKED, State.FAILSAFE})),
    (State.FAILSAFE, PairingDone): (AuthorityMachine._on_pair_failsafe, frozenset({State.FAILSAFE, State.LINKED})),
    (State.FAILSAFE, Frame): (AuthorityMachine._on_frame_failsafe, frozenset({State.FAILSAFE})),
    (State.FAILSAFE, AuthorityAsked): (AuthorityMachine._on_request_failsafe, frozenset({State.FAILSAFE, State.LINKED})),
    (State.FAILSAFE, LinkChanged): (AuthorityMachine._on_link, frozenset({State.FAILSAFE})),
    (State.FAILSAFE, RegionChanged): (AuthorityMachine._on_region, frozenset({State.FAILSAFE})),
    (State.FAILSAFE, Tick): (AuthorityMachine._ignore, frozenset({State.FAILSAFE})),
    (State.FAILSAFE, GroundChanged): (AuthorityMachine._on_ground_changed, frozenset({State.FAILSAFE})),
    (State.UNPAIRED, Revised): (AuthorityMachine._on_revised, frozenset({State.UNPAIRED})),
    (State.LINKED, Revised): (AuthorityMachine._on_revised, frozenset({State.LINKED, State.FAILSAFE})),
    (State.HANDOVER_PENDING, Revised): (AuthorityMachine._on_revised, frozenset({State.HANDOVER_PENDING, State.LINKED, State.FAILSAFE})),
    (State.FAILSAFE, Revised): (AuthorityMachine._on_revised, frozenset({State.FAILSAFE})),
    (State.UNPAIRED, LinkClosed): (AuthorityMachine._on_link_closed, frozenset({State.UNPAIRED})),
    (State.LINKED, LinkClosed): (AuthorityMachine._on_link_closed, frozenset({State.LINKED})),
    (State.HANDOVER_PENDING, LinkClosed): (AuthorityMachine._on_link_closed, frozenset({State.HANDOVER_PENDING})),
    (State.FAILSAFE, LinkClosed): (AuthorityMachine._on_link_closed, frozenset({State.FAILSAFE})),
}
# Missing on purpose (illegal steps, answered with a Reject): GrantHeard, AuthorityAsked and
# Release in UNPAIRED; GrantHeard and Release in FAILSAFE.

#: The rules of state and time alone (``_settle``), in order, the first that fires applies:
#: (states it applies in, rule, next states it may choose)
SETTLE: tuple[SettleRow[State], ...] = (
    (frozenset({State.HANDOVER_PENDING}), AuthorityMachine._proven_recipient, frozenset({State.LINKED})),
    (frozenset({State.HANDOVER_PENDING}), AuthorityMachine._handover_deadline, frozenset({State.LINKED})),
    (frozenset({State.LINKED, State.HANDOVER_PENDING}), AuthorityMachine._repair_deadline,
     frozenset({State.LINKED, State.HANDOVER_PENDING, State.FAILSAFE})),
    (frozenset({State.FAILSAFE}), AuthorityMachine._owner_back_on_ground, frozenset({State.LINKED})),
    (frozenset({State.UNPAIRED}), AuthorityMachine._first_claim_over, frozenset({State.UNPAIRED})),
)
#: A restart's restore (``restore``), outside the table: LINKED(owner, epoch), or FAILSAFE again.
RESTORED = frozenset({State.LINKED, State.FAILSAFE})
