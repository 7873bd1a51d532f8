"""``zdrone check --consent``: operator consent explored exhaustively, with the shipped code.

Theory of operation
-------------------
Authority moves by the owner's release, and the owner releases on its operator's consent
(``gs.opcontrol.OperatorControl``, MAVLink operator control bound to fleet identities). This world runs
that class, unchanged, at every ground station, and the drone's ``AuthorityMachine`` between them, and
explores every interleaving of the operators' moves breadth-first up to a depth, de-duplicating states by
what matters (the machine's owner, epoch, state and takeover flag; each station's pending request,
window, takeover setting, holds and standing request, times relative to now).

The world: ground stations A, B and C, all authorized, their links proven, the drone inside every
coverage (so nothing but consent can move authority); A the first owner. Control messages are delivered
at once and in order (the drone's status reaches every station). Every moment, any of these may happen:

* the operator of a GS that does not own the drone asks for control (a new request, p1 = 1);
* the owner's operator answers, naming one of the other GSs in p4: releases to it (p1 = 0), allows it
  takeover for the window (p1 = 1, p2 = 1), or declines it (p1 = 1, p2 = 0); or, as QGroundControl and
  MAVProxy do, naming nobody (p4 = its own sysid): releases or allows takeover to whatever its
  application shows (bound by the shipped ``gs.opcontrol.Prompt`` as the GCS gateway binds it), or
  refuses takeover;
* time passes 1 s or 10 s (every station ticks: requests are sent again, windows and timeouts end).

Each station's application is shown the request pending at its GS after every step (the gateway polls
every loop); the checker keeps its own account of what each application has had on its screen and since
when, apart from the shipped ``Prompt``.

Invariant (a violation prints the shortest trace that reaches it):

* **consent goes to the GS it names, in its epoch**: authority passes from the owner of epoch E to G
  only if, in epoch E, the owner's operator named G in a consent (release or window), or consented naming
  nobody while G's request had stood alone on its application's screen for ``CONSENT_READ_S``. A consent
  made in an earlier epoch, naming another GS, or given to a request shown for less than the read time
  (a third GS's request slipped in as another ended) never moves authority.

Planted flaws (``--flaw``) show the checker can fail: ``consent-to-last-asker`` (a newer request replaces
the pending one, and a consent goes to whatever is pending, whoever p4 names: the behaviour found from
outside), ``window-across-epochs`` (the operator's "allow takeover" outlives the epoch it was given in)
and ``consent-without-reading`` (an unnamed consent binds to whatever request is shown, however briefly:
the behaviour found from outside, a third GS asking as the request the operator was reading expired).
"""

from __future__ import annotations

import logging
import time
from collections import deque
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Iterator

from gs.opcontrol import CONSENT_READ_S, OperatorControl, PendingRequest, Prompt, Step
from zdrone.core import authority as ha
from zdrone.core import wire
from zdrone.core.authority import AuthorityMachine, Config, State
from zdrone.core.mavcontrol import OperatorControlRequest
from zdrone.core.tbm import LinkState
from zdrone.core.uplink import UplinkClass
from zdrone.check.search import _Broken, breadth_first

GSS = ("A", "B", "C")
FLAWS = ("consent-to-last-asker", "window-across-epochs", "consent-without-reading")
INVARIANT = "consent goes to the GS it names, in its epoch"


class _LastAskerControl(OperatorControl):
    """PLANTED FLAW: a newer request replaces the pending one; a consent goes to whatever is pending."""

    def on_request(self, view: Any, msg: wire.OperatorRequest, now: float) -> Step:
        live = self.live_request(view, now)
        if live is not None and live.requester != msg.requester and self.is_owner(view) and msg.epoch == view.epoch:
            self.request = None  # the last asker takes the operator's prompt
        return super().on_request(view, msg, now)

    def command(self, view: Any, req: OperatorControlRequest, now: float, app: str = "",
                named: str | None = None) -> Any:
        live = self.live_request(view, now)
        return super().command(view, req, now, app, live.requester if live is not None else named)


class _EpochlessControl(OperatorControl):
    """PLANTED FLAW: the operator's "allow takeover" holds in every later epoch."""

    def takeover_for(self, view: Any, now: float) -> tuple[bool, str | None]:
        if self.window is not None and now < self.window.until:
            return True, self.window.to
        return self.allow_takeover, None


class _HastyPrompt(Prompt):
    """PLANTED FLAW: an unnamed consent binds to whatever request is shown, however briefly."""

    def binds(self, pending: PendingRequest | None, epoch: int, now: float) -> str | None:
        if pending is None or self.shown != (pending.seq, pending.epoch):
            return "not shown"
        return None


@dataclass
class View:
    """What a station knows of the drone (the attributes ``OperatorControl`` reads)."""

    name: str = "d1"
    link: bool = True
    owner: str | None = None
    epoch: int = 0
    ha_state: State = State.UNPAIRED
    stale: bool = False
    takeover: bool = False
    takeover_to: str | None = None


@dataclass
class ConsentWorld:
    m: AuthorityMachine
    ops: dict[str, OperatorControl]
    views: dict[str, View]
    now: float = 0.0
    prompts: dict[str, Prompt] = field(default_factory=dict)  # each station's application: the shipped binder
    screens: dict[str, tuple[str | None, float]] = field(default_factory=dict)  # the checker's own account
    consents: frozenset[tuple[int, str | None]] = frozenset()  # (epoch, GS named or None: anyone)

    def clone(self) -> "ConsentWorld":
        import copy

        return ConsentWorld(copy.deepcopy(self.m), copy.deepcopy(self.ops),
                            {g: replace(v) for g, v in self.views.items()}, self.now,
                            copy.deepcopy(self.prompts), dict(self.screens), self.consents)

    def key(self) -> tuple:
        m = self.m

        def rel(t: float | None) -> float | None:
            return None if t is None else max(-1.0, round(t - self.now, 1))

        def op_key(o: OperatorControl) -> tuple:
            r = o.request
            w = o.window
            return ((r.requester, r.epoch, rel(r.since + r.timeout), r.ask_id == o.seq) if r else None,
                    (w.to, w.epoch, rel(w.until)) if w else None, o.allow_takeover,
                    tuple(sorted((g, rel(t)) for g, t in o.held_off.items() if t > self.now)),
                    rel(o.asked_until), o.closed is not None and o.closed[1] == m.epoch,
                    (o.release_to, o.release_epoch == m.epoch, rel(o.release_until)) if o.release_to else None,
                    o.held_epoch == m.epoch)
        def screen(g: str) -> tuple:
            p, (who, since) = self.prompts[g], self.screens[g]
            return (p.requester, p.shown is not None and p.shown[1] == m.epoch, rel(p.changed),
                    who, rel(since))

        return (m.state, m.owner, m.epoch, m.pending_to, m.takeover_epoch == m.epoch, m.takeover_to,
                tuple(op_key(self.ops[g]) for g in GSS), tuple(screen(g) for g in GSS),
                frozenset(c for c in self.consents if c[0] == m.epoch))


class ConsentExplorer:
    def __init__(self, depth: int, flaw: str | None = None, max_states: int | None = None) -> None:
        if flaw is not None and flaw not in FLAWS:
            raise ValueError(f"unknown flaw {flaw!r} (one of {', '.join(FLAWS)})")
        self.depth, self.flaw, self.max_states = depth, flaw, max_states
        self.states = self.transitions = self.max_depth_reached = 0

    def initial(self) -> ConsentWorld:
        cls = {"consent-to-last-asker": _LastAskerControl, "window-across-epochs": _EpochlessControl}.get(
            self.flaw or "", OperatorControl)
        m = AuthorityMachine(Config(frozenset(GSS), handover_timeout=5.0))
        m.handle(ha.RegionChanged(0.0, frozenset(GSS)))
        m.handle(ha.PairingDone(0.0, "A"))
        for g in GSS:
            if g != "A":
                m.handle(ha.GrantHeard(0.0, "A", g))
            m.handle(ha.LinkChanged(0.0, g, LinkState.OK))
            for _ in range(ha.PROOF_FRAMES):
                m.handle(ha.Frame(0.0, g, UplinkClass.READ_ONLY))
        prompt = _HastyPrompt if self.flaw == "consent-without-reading" else Prompt
        w = ConsentWorld(m, {g: cls(g) for g in GSS}, {g: View() for g in GSS},
                         prompts={g: prompt() for g in GSS}, screens={g: (None, 0.0) for g in GSS})
        self._status(w)
        return w

    def _observe(self, w: ConsentWorld) -> None:
        """Each application is shown what is pending at its GS now (as the gateway's poll does), and the
        checker notes, on its own, what each one has on its screen and since when."""
        for g in GSS:
            live = w.ops[g].live_request(w.views[g], w.now)
            if live is None:
                w.prompts[g].end(w.now)
            else:
                w.prompts[g].show(live.seq, live.epoch, live.requester, w.now)
            who = None if live is None else (live.requester, live.seq, live.epoch)
            if w.screens[g][0] != who:
                w.screens[g] = (who, w.now)  # type: ignore[assignment]

    # ------------------------------------------------------------------ delivery
    def _status(self, w: ConsentWorld) -> None:
        st = w.m.status()
        for v in w.views.values():
            v.owner, v.epoch, v.ha_state, v.takeover, v.takeover_to = st.owner, st.epoch, st.state, st.takeover, st.takeover_to

    def _drone(self, w: ConsentWorld, actions: list[ha.Action]) -> None:
        queue: deque[tuple[str, wire.Control]] = deque()
        self._check(w, actions)
        self._status(w)
        for a in actions:
            if isinstance(a, ha.SendControl) and isinstance(a.msg, wire.OperatorRequest):
                queue.append((a.gs, a.msg))
        while queue:
            g, msg = queue.popleft()
            self._gs(w, g, w.ops[g].on_request(w.views[g], msg, w.now))  # type: ignore[arg-type]

    def _gs(self, w: ConsentWorld, g: str, step: Step) -> None:
        for msg in step.send:
            if isinstance(msg, wire.HandoverRequest):
                ev: ha.Event = ha.AuthorityAsked(w.now, g, msg.to, msg.timeout, msg.takeover, msg.ask_id, msg.takeover_to)
            elif isinstance(msg, wire.HandoverRelease):
                ev = ha.Release(w.now, g, msg.to, msg.epoch)
            else:
                continue
            self._drone(w, w.m.handle(ev))

    def _check(self, w: ConsentWorld, actions: list[ha.Action]) -> None:
        for a in actions:
            if isinstance(a, ha.AuthorityChanged):
                given_in = a.epoch - 1
                if (given_in, a.new) not in w.consents and (given_in, None) not in w.consents:
                    named = sorted((str(g) for e, g in w.consents if e == given_in), key=str) or ["nobody"]
                    raise _Broken(INVARIANT, f"authority of epoch {given_in} went to {a.new}; the owner's operator "
                                             f"consented in that epoch to {', '.join(named)}")

    # -------------------------------------------------------------------- moves
    def moves(self, w: ConsentWorld) -> Iterator[tuple[str, Callable[[ConsentWorld], None]]]:
        owner = w.m.owner
        assert owner is not None
        for g in GSS:
            if g != owner:
                yield f"{g}'s operator asks for control", lambda x, g=g: self._command(x, g, True, False, None)
        for g in GSS:
            if g == owner:
                continue
            yield f"{owner}'s operator releases to {g} (p4 = {g})", \
                lambda x, o=owner, g=g: self._command(x, o, False, False, g, consent=g)
            yield f"{owner}'s operator allows {g} takeover (p2 = 1, p4 = {g})", \
                lambda x, o=owner, g=g: self._command(x, o, True, True, g, consent=g)
            yield f"{owner}'s operator declines {g} (p2 = 0, p4 = {g})", \
                lambda x, o=owner, g=g: self._command(x, o, True, False, g)
        yield f"{owner}'s operator releases to the request it is shown (p1 = 0, p4 = itself)", \
            lambda x, o=owner: self._unnamed(x, o, False, False)
        yield f"{owner}'s operator allows takeover to the request it is shown (p2 = 1, p4 = itself)", \
            lambda x, o=owner: self._unnamed(x, o, True, True)
        yield f"{owner}'s operator refuses takeover (p2 = 0, p4 = itself)", \
            lambda x, o=owner: self._command(x, o, True, False, o)
        yield "time passes 1 s", lambda x: self._tick(x, 1.0)
        yield "time passes 10 s", lambda x: self._tick(x, 10.0)

    def _command(self, w: ConsentWorld, g: str, request: bool, takeover: bool, named: str | None,
                 consent: str | None | bool = False) -> None:
        op, view = w.ops[g], w.views[g]
        if consent is not False and op.is_owner(view):
            w.consents = w.consents | {(w.m.epoch, consent)}  # the operator's intent, in this epoch (checked, not trusted)
        _, step = op.command(view, OperatorControlRequest(request, takeover, 5.0, 0), w.now, named=named)
        self._gs(w, g, step)
        self._observe(w)

    def _unnamed(self, w: ConsentWorld, g: str, request: bool, takeover: bool) -> None:
        """A consent that names nobody, bound as the gateway binds it; the operator's intent is the request
        that has stood alone on its screen for the read time (the checker's own account)."""
        op, view = w.ops[g], w.views[g]
        pending = op.live_request(view, w.now)
        who, since = w.screens[g]
        if op.is_owner(view) and who is not None and w.now - since >= CONSENT_READ_S:
            w.consents = w.consents | {(w.m.epoch, who[0])}
        named = g  # p4 = its own sysid: names no other GS
        if pending is not None and w.prompts[g].binds(pending, view.epoch, w.now) is None:
            named = pending.requester
        elif pending is not None:
            return  # refused at the gateway: DENIED, shown again
        _, step = op.command(view, OperatorControlRequest(request, takeover, 5.0, 0), w.now, named=named)
        self._gs(w, g, step)
        self._observe(w)

    def _tick(self, w: ConsentWorld, dt: float) -> None:
        for _ in range(int(dt)):
            w.now += 1.0
            self._drone(w, w.m.handle(ha.Tick(w.now)))
            for g in GSS:
                self._gs(w, g, w.ops[g].tick(w.views[g], w.now))
            self._observe(w)

    # -------------------------------------------------------------------- search
    def run(self) -> tuple[tuple[str, str, tuple[str, ...]] | None, dict[str, Any]]:
        for name in ("zdrone.core.authority", "gs.opcontrol"):
            logging.getLogger(name).setLevel(logging.WARNING)
        t0 = time.perf_counter()
        found = breadth_first(self, self.initial())
        elapsed = time.perf_counter() - t0
        violation = None if found is None else (found.invariant, found.detail, found.trace)
        return violation, {"states": self.states, "transitions": self.transitions, "depth": self.depth,
                           "depth_reached": self.max_depth_reached, "faults": 0,
                           "seconds": round(elapsed, 2), "states_per_s": round(self.states / elapsed) if elapsed else None}
