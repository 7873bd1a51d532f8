"""Operator control of one drone at one ground station, sans-IO: MAVLink's request / consent /
takeover protocol (MAV_CMD_REQUEST_OPERATOR_CONTROL, CONTROL_STATUS) bound to fleet identities.

Theory of operation
-------------------
Every step is a sealed control message between fleet identities; a MAVLink sysid proves nothing.

* **Requester** (this GS does not hold authority): its operator's request (an application's
  command, p1 = 1) becomes a sealed ``HandoverRequest`` for this GS, sent again every second while
  the request stands (p3 seconds). The drone passes it to the owner as an ``OperatorRequest`` naming
  the sealed sender. The request's p2 is this GS's own "allow takeover" for the epoch it takes.
* **Owner**: one request at a time is *pending* (kept for its timeout and shown to the operator: the
  GCS gateway presents it to its applications with p4 = the requester's fleet sysid). Another GS's
  request while one is pending is not shown (``operator_request_busy``): its GS asks again every
  second and is shown once the pending one is decided. A consent is bound to what the operator saw:
  it must name the pending requester in p4 (else ``operator_consent_refused``, answered DENIED; the
  gateway turns a p4 of 0 or the application's own sysid, as QGroundControl sends it, into the
  requester of the request it showed that application, only once that one request has been on the
  application's screen alone and unchanged for ``CONSENT_READ_S``: ``Prompt``), it holds in the owner's
  epoch only and ends at any authority change.

  - p1 = 0 naming the requester: release to it now (the ordinary ``HandoverRelease``, make-before-break);
  - p1 = 1, p2 = 1 naming the requester: takeover allowed *for that requester* for ``GRANT_WINDOW_S``
    in this epoch (today's flow: TAKEOVER_ALLOWED in every application's CONTROL_STATUS, the requester
    asks again and is granted); the requester's standing request, sent again each second, is its ask;
  - p1 = 1, p2 = 0 naming the requester: declined; that requester is not shown again for
    ``DECLINE_HOLD_S`` (its re-sends are ignored, recorded once; an "allow takeover" does not grant it either). A request stands 3 s at least, so a
    requester causes at most 20 prompts a minute while the operator ignores it, one once declined.

  Without consent nothing moves.
* **Allow takeover** answers the request it was given for, in its epoch, and nothing else: with nothing
  pending an operator's p1 = 1, p2 = 1 is DENIED (``operator_consent_refused``: a consent to a request
  nobody made; a late "allow takeover" must not become a standing setting that the next asker takes),
  and a requester's own p2 is not carried into the epoch it takes. The one standing setting is the
  station's configuration, ``zdrone gs --allow-takeover`` (every epoch; its grants are recorded as the
  station's policy). The owner tells the drone with a ``HandoverRequest`` for itself (naming the one
  requester a window is for); the drone's ``AuthorityStatus`` carries it to every GS.
* **Held control**: an epoch this GS took by its operator's request is the operator's: the station's
  automatic hand-over toward the GS whose coverage the drone flies into stays off in it until the
  operator lets go (p1 = 0 with nobody asking).

Every decision record names the application that made it (``app``: its signing key's name, or
``unsigned:<peer>``); every grant names who decided (``decided_by``: ``operator`` or ``station_policy``). ``OperatorControl`` holds the state; its methods take the station's view of the
drone and ``now`` and return a ``Step``: control messages for the drone, event records and operator
lines (the station core turns them into its actions).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import common as mav

from zdrone.core import records as rec
from zdrone.core import wire
from zdrone.core.authority import State as HaState
from zdrone.core.mavcontrol import (DEFAULT_REQUEST_TIMEOUT_S, REQUEST_TIMEOUT_MAX_S, REQUEST_TIMEOUT_MIN_S,
                                    OperatorControlRequest)

from gs.droneview import DroneView
from gs.ownership import owns

#: After the owner's operator consents with "allow takeover", takeover stays allowed this long (the
#: spec's 10 s in which the requester asks again).
GRANT_WINDOW_S = 10.0
#: A standing request is sent to the drone again this often (a lossy radio must not lose it).
ASK_RESEND_S = 1.0
#: The owner's setting is told to the drone again this often until its status agrees; an operator's
#: release is sent again as often until the drone moves authority.
TELL_RESEND_S = 0.5
#: A requester the operator declined is not shown again for this long (said to the operator).
DECLINE_HOLD_S = 60.0
#: A consent that does not name the requester (p4 = 0 or the application's own sysid, as QGroundControl and
#: MAVProxy send it) binds to the request an application was shown only once that request has stood on its
#: screen, alone and unchanged, this long: long enough to be read. Shorter than the shortest request (3 s).
CONSENT_READ_S = 2.0
#: (A requester whose request expired unanswered may ask again at once: the operator may have missed
#: it. Each request stands REQUEST_TIMEOUT_MIN_S at least, so one requester prompts at most 20 times a
#: minute until the operator declines it.)


class Answer(enum.IntEnum):
    """The MAV_RESULT an application's MAV_CMD_REQUEST_OPERATOR_CONTROL gets at once."""

    ACCEPTED = mav.MAV_RESULT_ACCEPTED  # in control already; or the owner's operator decided
    TEMPORARILY_REJECTED = mav.MAV_RESULT_TEMPORARILY_REJECTED  # no link to the drone
    DENIED = mav.MAV_RESULT_DENIED  # a consent that does not name the pending requester
    FAILED = mav.MAV_RESULT_FAILED  # the owner's operator is asked (the spec's answer)
    IN_PROGRESS = mav.MAV_RESULT_IN_PROGRESS  # takeover allowed (or after a failsafe): control follows


@dataclass(frozen=True, slots=True)
class Step:
    """What a call asks of the station: control messages for the drone, typed event records and
    lines for the operator."""

    send: tuple[wire.Control, ...] = ()
    logs: tuple[rec.Record, ...] = ()
    say: tuple[str, ...] = ()

    def __add__(self, other: "Step") -> "Step":
        return Step(self.send + other.send, self.logs + other.logs, self.say + other.say)


NOTHING = Step()


@dataclass(slots=True)
class PendingRequest:
    """At the owner: a request the drone passed on, waiting for the operator's consent."""

    requester: str
    to: str
    epoch: int
    timeout: float
    since: float
    seq: int  # one number per request shown to the operator
    ask_id: int  # the requester's number for it

    def alive(self, now: float) -> bool:
        return now < self.since + self.timeout


@dataclass(frozen=True, slots=True)
class TakeoverWindow:
    """The owner's operator consented with "allow takeover": ``to`` may take control of ``epoch``
    until ``until`` (``app``: the application that consented)."""

    to: str
    epoch: int
    until: float
    app: str

    def allows(self, view: DroneView, now: float) -> bool:
        return self.epoch == view.epoch and now < self.until


@dataclass(slots=True)
class Prompt:
    """What one operator application is shown of the requests pending at its GS, and since when: the
    request shown (its number and epoch, None: none) and the moment that last changed (a request shown,
    or the one shown ended). An unnamed consent binds to the request shown only when it has stood alone
    and unchanged for ``CONSENT_READ_S`` and is the one pending now (``binds``)."""

    shown: tuple[int, int] | None = None
    requester: str | None = None
    changed: float = -math.inf

    def show(self, seq: int, epoch: int, requester: str, now: float) -> bool:
        """The application is shown request ``seq`` of ``epoch``; True when that is a change."""
        if self.shown == (seq, epoch):
            return False
        self.shown, self.requester, self.changed = (seq, epoch), requester, now
        return True

    def end(self, now: float) -> None:
        """Nothing is pending any more: what the application was shown is gone."""
        if self.shown is not None:
            self.shown, self.requester, self.changed = None, None, now

    def binds(self, pending: "PendingRequest | None", epoch: int, now: float) -> str | None:
        """None when an unnamed consent given now binds to ``pending``; else why it does not."""
        if pending is None:
            return "no request is pending"
        if self.shown != (pending.seq, pending.epoch) or pending.epoch != epoch:
            return f"{pending.requester}'s request was not shown to this application"
        if now - self.changed < CONSENT_READ_S:
            return (f"{pending.requester}'s request was shown {max(0.0, now - self.changed):.1f} s ago "
                    f"(a consent that does not name it needs {CONSENT_READ_S:.0f} s)")
        return None


@dataclass
class OperatorControl:
    """The operator-control state of one GS for one drone (see the module docstring)."""

    gs: str
    allow_takeover: bool = False  # the station's standing policy (``--allow-takeover``), every epoch
    window: TakeoverWindow | None = None  # a consent: one requester may take control for a while
    request: PendingRequest | None = None  # as owner: the request shown to the operator
    closed: tuple[str, int, int] | None = None  # (requester, epoch, ask id) decided: its re-sends ignored
    held_off: dict[str, float] = field(default_factory=dict)  # declined requester -> not shown again until then
    noted: set[tuple[str, str, int]] = field(default_factory=set)  # (why, requester, ask id) ignored, recorded once
    seq: int = 0
    asked_until: float | None = None  # as requester: our operator's request stands until then
    asked_timeout: float = DEFAULT_REQUEST_TIMEOUT_S
    asked_on_takeover: bool = False  # as requester: asked again as soon as the owner allowed us takeover
    ask_id: int = 0  # our operator's requests, numbered
    last_ask: float | None = None
    last_tell: float | None = None
    release_to: str | None = None  # as owner: released by the operator's decision, in ``release_epoch``
    release_epoch: int | None = None
    last_release: float | None = None
    release_until: float | None = None  # the release is sent again until then
    held_epoch: int | None = None  # the epoch we took by our operator's request

    # ------------------------------------------------------------------ queries
    def is_owner(self, view: DroneView) -> bool:
        return owns(view, self.gs)

    def deadline(self, now: float) -> float | None:
        """When, after ``now``, ``tick`` next matters if no input comes (a window or a request ending,
        a re-send due); None: only an input moves this drone's operator control."""
        due: list[float | None] = [None if self.window is None else self.window.until,
                                   None if self.request is None else self.request.since + self.request.timeout,
                                   None if self.last_tell is None else self.last_tell + TELL_RESEND_S,
                                   None if self.last_release is None else self.last_release + TELL_RESEND_S,
                                   self.release_until, self.asked_until,
                                   None if self.last_ask is None else self.last_ask + ASK_RESEND_S]
        later = [d for d in due if d is not None and d > now]
        return min(later) if later else None

    def takeover_for(self, view: DroneView, now: float) -> tuple[bool, str | None]:
        """Our takeover setting now: (allowed, the one requester it is for, or None for any)."""
        if self.window is not None and self.window.allows(view, now):
            return True, self.window.to
        return self.allow_takeover, None

    def takeover_allowed(self, view: DroneView, now: float) -> bool:
        return self.takeover_for(view, now)[0]

    def shown_takeover(self, view: DroneView, now: float) -> bool:
        """What CONTROL_STATUS says about takeover: ours when we own the drone, else the owner's."""
        return self.takeover_allowed(view, now) if self.is_owner(view) else bool(view.takeover)

    def holds(self, view: DroneView) -> bool:
        """Our operator holds control: no automatic hand-over in this epoch."""
        return self.held_epoch == view.epoch and view.owner == self.gs

    def live_request(self, view: DroneView, now: float) -> PendingRequest | None:
        r = self.request
        return r if r is not None and r.alive(now) and r.epoch == view.epoch and self.is_owner(view) else None

    # ------------------------------------------------------------------ operator
    def command(self, view: DroneView, req: OperatorControlRequest, now: float, app: str = "",
                named: str | None = None) -> tuple[Answer, Step]:
        """One MAV_CMD_REQUEST_OPERATOR_CONTROL from application ``app`` of this GS; ``named``: the
        fleet GS its p4 names as that application was shown it (None: no GS)."""
        if view.link is None:
            return Answer.TEMPORARILY_REJECTED, NOTHING
        if self.is_owner(view):
            return self._owner_command(view, req, now, app, named)
        if not req.request:  # withdraw our own request
            was = self.asked_until is not None
            self.asked_until = None
            return Answer.ACCEPTED, self._log(rec.OperatorRequestWithdrawn(drone=view.name, app=app)) if was else NOTHING
        # (its p2 is not carried into the epoch it takes: only the station's configuration is a standing setting)
        self.asked_until, self.asked_timeout, self.last_ask = now + req.timeout, req.timeout, now
        self.ask_id += 1
        for_us = bool(view.takeover) and getattr(view, "takeover_to", None) in (None, self.gs)
        step = self._log(rec.OperatorControlAsked(drone=view.name, owner=view.owner, timeout=req.timeout,
                                                  owner_allows=for_us, app=app))
        step += Step(send=(self._ask(view),))
        if view.ha_state is HaState.FAILSAFE or for_us:
            return Answer.IN_PROGRESS, step
        return Answer.FAILED, step + Step(say=(f"zdrone gs {self.gs}: control of {view.name} requested; "
                                               f"{view.owner}'s operator is asked ({req.timeout:.0f} s)",))

    def _owner_command(self, view: DroneView, req: OperatorControlRequest, now: float, app: str,
                       named: str | None) -> tuple[Answer, Step]:
        pending = self.live_request(view, now)
        if pending is None:
            if named not in (None, self.gs):  # an answer to a request that is not pending (any more)
                if req.request and not req.takeover and self.closed is not None and self.closed[:2] == (named, view.epoch):
                    # the decline of the request just shown, arriving after it ended: it holds all the same
                    self._close(PendingRequest(named, named, view.epoch, 0.0, now, 0, self.closed[2]), now, DECLINE_HOLD_S)
                    return Answer.ACCEPTED, (self._log(rec.OperatorRequestDeclined(
                        drone=view.name, requester=named, hold_s=DECLINE_HOLD_S, app=app)) + Step(say=(
                            f"zdrone gs {self.gs}: {named}'s request for {view.name} declined; its requests are not "
                            f"shown for {DECLINE_HOLD_S:.0f} s",)))
                why = f"p4 names {named}, which has no pending request"  # a consent to a request nobody made
                return Answer.DENIED, (self._log(rec.OperatorConsentRefused(drone=view.name, requester="", named=named,
                                                                           reason=why, app=app))
                                       + Step(say=(f"zdrone gs {self.gs}: consent for {view.name} refused: {why}",)))
            if not req.request:
                held, self.held_epoch = self.held_epoch, None  # let go: automatic hand-overs again
                return Answer.ACCEPTED, (self._log(rec.OperatorControlLetGo(drone=view.name, app=app))
                                         if held == view.epoch else NOTHING)
            if req.takeover:  # "allow takeover" answers a request; with none pending it is no standing setting
                why = "no request is pending to allow (a standing takeover is the station's --allow-takeover)"
                return Answer.DENIED, (self._log(rec.OperatorConsentRefused(drone=view.name, requester="", named=None,
                                                                           reason=why, app=app))
                                       + Step(say=(f"zdrone gs {self.gs}: consent for {view.name} refused: {why}",)))
            if self.window is None:  # "takeover refused" with nothing open: nothing changes
                return Answer.ACCEPTED, NOTHING
            self.window, self.last_tell = None, None  # "takeover refused" ends a consent's window; tell the drone
            return Answer.ACCEPTED, self._log(rec.OperatorTakeoverSetting(drone=view.name, allowed=False,
                                                                          epoch=view.epoch, app=app))
        if named != pending.requester:  # a consent binds to the request the operator was shown
            why = (f"p4 names {named}, not the pending requester {pending.requester}" if named
                   else f"p4 ({req.sysid}) names no ground station; the pending requester is {pending.requester}")
            return Answer.DENIED, (self._log(rec.OperatorConsentRefused(drone=view.name, requester=pending.requester,
                                                                       named=named, reason=why, app=app))
                                   + Step(say=(f"zdrone gs {self.gs}: consent for {view.name} refused: {why}",)))
        if not req.request:  # consent: release to the requester now
            return Answer.ACCEPTED, self._grant(view, pending, now, "released by the operator", app)
        if req.takeover:  # consent by allowing takeover: the requester may take control for the window
            self.window = TakeoverWindow(pending.requester, view.epoch, now + GRANT_WINDOW_S, app)
            self.last_tell = None
            return Answer.ACCEPTED, (self._log(rec.TakeoverWindowOpened(drone=view.name, to=pending.requester,
                                                                        epoch=view.epoch, seconds=GRANT_WINDOW_S, app=app))
                                     + self._tell(view, now))
        self._close(pending, now, DECLINE_HOLD_S)  # declined
        return Answer.ACCEPTED, (self._log(rec.OperatorRequestDeclined(drone=view.name, requester=pending.requester,
                                                                       hold_s=DECLINE_HOLD_S, app=app))
                                 + Step(say=(f"zdrone gs {self.gs}: {pending.requester}'s request for {view.name} "
                                             f"declined; its requests are not shown for {DECLINE_HOLD_S:.0f} s",)))

    # ------------------------------------------------------------------ drone
    def on_request(self, view: DroneView, msg: wire.OperatorRequest, now: float) -> Step:
        """The drone passes on another GS's request for authority."""
        if not self.is_owner(view) or msg.epoch != view.epoch or msg.to != msg.requester:
            # control goes to whoever asks, never to a GS it names; and only ours, in our epoch
            return self._log(rec.OperatorRequestStale(drone=view.name, requester=msg.requester, epoch=msg.epoch))
        until = self.held_off.get(msg.requester)
        if until is not None and now < until:  # declined: not shown, and not granted by an allow-takeover either
            return self._once("held_off", msg, rec.OperatorRequestHeldOff(drone=view.name, requester=msg.requester,
                                                                          seconds_left=round(until - now, 1)))
        allowed, only = self.takeover_for(view, now)
        live = self.live_request(view, now)
        if allowed and only in (None, msg.requester) and (live is None or live.requester == msg.requester):
            req = live or self._pend(view, msg, now)
            step = NOTHING if live is not None else self._received(view, req, True)
            return step + self._grant(view, req, now, "takeover allowed", self.window.app if only else "",
                                      "operator" if only else "station_policy")
        if live is not None:
            if (live.requester, live.ask_id) == (msg.requester, msg.ask_id):
                return NOTHING  # the requester sending its standing request again
            return self._once("busy", msg, rec.OperatorRequestBusy(drone=view.name, requester=msg.requester,
                                                                   pending=live.requester))
        if self.closed == (msg.requester, msg.epoch, msg.ask_id):
            return NOTHING  # re-sends of a request declined or expired: decided already
        req = self._pend(view, msg, now)
        return self._received(view, req, False) + Step(say=(
            f"zdrone gs {self.gs}: {msg.requester} requests control of {view.name} ({req.timeout:.0f} s to consent)",))

    def _pend(self, view: DroneView, msg: wire.OperatorRequest, now: float) -> PendingRequest:
        self.seq += 1
        # the spec's range (3-60 s): a request never stands longer, whatever its sender says
        timeout = min(max(msg.timeout, REQUEST_TIMEOUT_MIN_S), REQUEST_TIMEOUT_MAX_S) if msg.timeout > 0 \
            else DEFAULT_REQUEST_TIMEOUT_S
        self.request = PendingRequest(msg.requester, msg.requester, msg.epoch, timeout, now, self.seq, msg.ask_id)
        return self.request

    def _received(self, view: DroneView, req: PendingRequest, allowed: bool) -> Step:
        return self._log(rec.OperatorRequestReceived(drone=view.name, requester=req.requester, to=req.to,
                                                     epoch=req.epoch, timeout=req.timeout, takeover_allowed=allowed))

    def _once(self, why: str, msg: wire.OperatorRequest, record: rec.OperatorControlEvent) -> Step:
        """An ignored request, recorded once per request (its re-sends come every second)."""
        key = (why, msg.requester, msg.ask_id)
        if key in self.noted:
            return NOTHING
        if len(self.noted) > 256:
            self.noted.clear()
        self.noted.add(key)
        return self._log(record)

    def _grant(self, view: DroneView, req: PendingRequest, now: float, why: str, app: str,
               decided_by: str = "operator") -> Step:
        assert req.to == req.requester  # control goes to the GS that asked (``on_request``)
        self.release_to, self.release_epoch, self.last_release = req.to, view.epoch, now
        self.release_until = now + GRANT_WINDOW_S
        self.request = None
        return (self._log(rec.OperatorRequestGranted(drone=view.name, requester=req.requester, to=req.to, why=why,
                                                     epoch=view.epoch, app=app, decided_by=decided_by))
                + Step(send=(wire.HandoverRelease(req.to, view.epoch),),
                       say=(f"zdrone gs {self.gs}: control of {view.name} goes to {req.to} ({why})",)))

    # ------------------------------------------------------------------- time
    def tick(self, view: DroneView, now: float) -> Step:
        """Deadlines, re-sends, and what follows from the drone's status."""
        step = NOTHING
        w = self.window
        if w is not None and not w.allows(view, now):
            self.window = None  # its time is over, or authority moved on: a consent never outlives its epoch
            step += self._log(rec.TakeoverWindowClosed(drone=view.name))
        if self.request is not None and self.live_request(view, now) is None:
            req = self.request
            self._close(req, now)
            if not req.alive(now):
                step += self._log(rec.OperatorRequestExpired(drone=view.name, requester=req.requester))
        if view.link is None:
            return step
        if self.is_owner(view):
            if self.asked_until is not None:  # ours now: the request succeeded
                self.asked_until, self.held_epoch = None, view.epoch
                step += self._log(rec.OperatorControlTaken(drone=view.name, epoch=view.epoch))
            step += self._tell(view, now)
            if (self.release_to is not None and self.release_epoch == view.epoch and self.release_until is not None
                    and now < self.release_until and _due(self.last_release, now, TELL_RESEND_S)):
                self.last_release = now
                step += Step(send=(wire.HandoverRelease(self.release_to, view.epoch),))
        elif self.asked_until is not None:
            for_us = bool(view.takeover) and getattr(view, "takeover_to", None) in (None, self.gs)
            if now >= self.asked_until:
                self.asked_until = None
                step += self._log(rec.OperatorRequestTimedOut(drone=view.name, owner=view.owner))
            elif _due(self.last_ask, now, ASK_RESEND_S) or (for_us and not self.asked_on_takeover):
                # the owner allowing us takeover is the spec's cue to ask again: at once, not at the next re-send
                self.last_ask, self.asked_on_takeover = now, for_us
                step += Step(send=(self._ask(view),))
            elif not for_us:
                self.asked_on_takeover = False
        if self.release_epoch is not None and self.release_epoch != view.epoch:
            self.release_to = self.release_epoch = self.release_until = None  # authority moved on
        return step

    def _tell(self, view: DroneView, now: float) -> Step:
        """Tell the drone our takeover setting until its status agrees (as owner)."""
        want, to = self.takeover_for(view, now)
        if (bool(view.takeover), getattr(view, "takeover_to", None)) == (want, to if want else None):
            return NOTHING
        if not _due(self.last_tell, now, TELL_RESEND_S):
            return NOTHING
        self.last_tell = now
        return Step(send=(wire.HandoverRequest(self.gs, view.epoch, takeover=want, takeover_to=to if want else None),))

    def _close(self, req: PendingRequest, now: float, hold: float = 0.0) -> None:
        """``req`` is decided (declined, expired): the requester's re-sends of it change nothing, and
        it is not shown again for ``hold`` seconds (a decline's)."""
        self.request = None
        self.closed = (req.requester, req.epoch, req.ask_id)
        if hold > 0:
            self.held_off = {r: t for r, t in self.held_off.items() if t > now}
            self.held_off[req.requester] = now + hold

    def _ask(self, view: DroneView) -> wire.HandoverRequest:
        return wire.HandoverRequest(self.gs, view.epoch, timeout=self.asked_timeout, ask_id=self.ask_id)

    @staticmethod
    def _log(record: rec.OperatorControlEvent) -> Step:
        return Step(logs=(record,))


def _due(last: float | None, now: float, period: float) -> bool:
    return last is None or now - last >= period
