"""Operator control of one drone at one ground station, sans-IO: MAVLink's request / consent /
takeover protocol (MAV_CMD_REQUEST_OPERATOR_CONTROL, CONTROL_STATUS) bound to fleet identities.

Theory of operation
-------------------
Every step is a sealed control message between fleet identities; a MAVLink sysid proves nothing.

* **Requester** (this GS does not hold authority): its operator's request (an application's
  command, p1 = 1) becomes a sealed ``HandoverRequest`` for this GS, sent again every second while
  the request stands (p3 seconds). The drone passes it to the owner as an ``OperatorRequest`` naming
  the sealed sender. The request's p2 is this GS's own "allow takeover" setting once it is in control.
* **Owner**: an ``OperatorRequest`` is kept for its timeout and shown to the operator (the GCS
  gateway presents it to its applications). It is granted — the owner releases authority to the
  requester with the ordinary ``HandoverRelease`` (make-before-break) — when the owner allows
  takeover, or when its operator consents: p1 = 0 (release to the requester), or p1 = 1 with p2 = 1
  (allow takeover for ``GRANT_WINDOW_S``, the window in which the requester asks again). p1 = 1 with
  p2 = 0 declines it. Without consent nothing moves.
* **Allow takeover** is the owner's setting (``zdrone gs --allow-takeover``, p2 of its applications'
  requests); the owner tells the drone with a ``HandoverRequest`` for itself, and the drone's
  ``AuthorityStatus`` carries it to every GS for CONTROL_STATUS. It holds for the owner's epoch only.
* **Held control**: an epoch this GS took by its operator's request is the operator's: the station's
  automatic hand-over toward the GS whose coverage the drone flies into stays off in it until the
  operator lets go (p1 = 0 with nobody asking).

``OperatorControl`` holds the state; its methods take the station's view of the drone and ``now``
and return a ``Step``: control messages for the drone, event records and operator lines (the
station core turns them into its actions).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import common as mav

from zdrone.core import records as rec
from zdrone.core import wire
from zdrone.core.authority import State as HaState
from zdrone.core.mavcontrol import (DEFAULT_REQUEST_TIMEOUT_S, REQUEST_TIMEOUT_MAX_S, REQUEST_TIMEOUT_MIN_S,
                                    OperatorControlRequest)

#: After the owner's operator consents with "allow takeover", takeover stays allowed this long.
GRANT_WINDOW_S = 10.0
#: A standing request is sent to the drone again this often (a lossy radio must not lose it).
ASK_RESEND_S = 1.0
#: The owner's setting is told to the drone again this often until its status agrees; an operator's
#: release is sent again as often until the drone moves authority.
TELL_RESEND_S = 0.5


class Answer(enum.IntEnum):
    """The MAV_RESULT an application's MAV_CMD_REQUEST_OPERATOR_CONTROL gets at once."""

    ACCEPTED = mav.MAV_RESULT_ACCEPTED  # in control already; or the owner's operator decided
    TEMPORARILY_REJECTED = mav.MAV_RESULT_TEMPORARILY_REJECTED  # no link to the drone
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


@dataclass
class OperatorControl:
    """The operator-control state of one GS for one drone (see the module docstring)."""

    gs: str
    allow_takeover: bool = False  # the standing setting
    window_until: float | None = None  # consent: takeover allowed until then
    request: PendingRequest | None = None  # as owner: the request shown to the operator
    closed: tuple[str, int, int] | None = None  # (requester, epoch, ask id) declined or expired: its re-sends ignored
    seq: int = 0
    asked_until: float | None = None  # as requester: our operator's request stands until then
    asked_timeout: float = DEFAULT_REQUEST_TIMEOUT_S
    ask_id: int = 0  # our operator's requests, numbered
    last_ask: float | None = None
    last_tell: float | None = None
    release_to: str | None = None  # as owner: released by the operator's decision, in ``release_epoch``
    release_epoch: int | None = None
    last_release: float | None = None
    release_until: float | None = None  # the release is sent again until then
    held_epoch: int | None = None  # the epoch we took by our operator's request

    # ------------------------------------------------------------------ queries
    def is_owner(self, view: Any) -> bool:
        return bool(view.link is not None and view.owner == self.gs and view.ha_state is not HaState.FAILSAFE
                    and not getattr(view, "stale", False))

    def takeover_allowed(self, now: float) -> bool:
        """Our own setting now: standing, or within a consent's window."""
        return self.allow_takeover or (self.window_until is not None and now < self.window_until)

    def shown_takeover(self, view: Any, now: float) -> bool:
        """What CONTROL_STATUS says about takeover: ours when we own the drone, else the owner's."""
        return self.takeover_allowed(now) if self.is_owner(view) else bool(view.takeover)

    def holds(self, view: Any) -> bool:
        """Our operator holds control: no automatic hand-over in this epoch."""
        return self.held_epoch == view.epoch and view.owner == self.gs

    def live_request(self, view: Any, now: float) -> PendingRequest | None:
        r = self.request
        return r if r is not None and r.alive(now) and r.epoch == view.epoch and self.is_owner(view) else None

    # ------------------------------------------------------------------ operator
    def command(self, view: Any, req: OperatorControlRequest, now: float) -> tuple[Answer, Step]:
        """One MAV_CMD_REQUEST_OPERATOR_CONTROL from an application of this GS."""
        if view.link is None:
            return Answer.TEMPORARILY_REJECTED, NOTHING
        if self.is_owner(view):
            return Answer.ACCEPTED, self._owner_command(view, req, now)
        if not req.request:  # withdraw our own request
            was = self.asked_until is not None
            self.asked_until = None
            return Answer.ACCEPTED, self._log(rec.OperatorRequestWithdrawn(drone=view.name)) if was else NOTHING
        self.allow_takeover = req.takeover  # our setting once in control
        self.asked_until, self.asked_timeout, self.last_ask = now + req.timeout, req.timeout, now
        self.ask_id += 1
        step = self._log(rec.OperatorControlAsked(drone=view.name, owner=view.owner, timeout=req.timeout,
                                                  owner_allows=bool(view.takeover)))
        step += Step(send=(self._ask(view),))
        if view.ha_state is HaState.FAILSAFE or view.takeover:
            return Answer.IN_PROGRESS, step
        return Answer.FAILED, step + Step(say=(f"zdrone gs {self.gs}: control of {view.name} requested; "
                                               f"{view.owner}'s operator is asked ({req.timeout:.0f} s)",))

    def _owner_command(self, view: Any, req: OperatorControlRequest, now: float) -> Step:
        pending = self.live_request(view, now)
        if not req.request:
            if pending is not None:  # consent: release to the requester
                return self._grant(view, pending, now, "released by the operator")
            held, self.held_epoch = self.held_epoch, None  # let go: automatic hand-overs again
            return self._log(rec.OperatorControlLetGo(drone=view.name)) if held == view.epoch else NOTHING
        if pending is None:
            changed = req.takeover != self.allow_takeover
            self.allow_takeover = req.takeover
            return self._log(rec.OperatorTakeoverSetting(drone=view.name, allowed=req.takeover)) if changed else NOTHING
        if req.takeover:  # consent by allowing takeover for the window: granted now, and if asked again
            self.window_until = now + GRANT_WINDOW_S
            return self._grant(view, pending, now, "takeover allowed by the operator")
        self._close(pending)  # declined
        return self._log(rec.OperatorRequestDeclined(drone=view.name, requester=pending.requester))

    # ------------------------------------------------------------------ drone
    def on_request(self, view: Any, msg: wire.OperatorRequest, now: float) -> Step:
        """The drone passes on another GS's request for authority."""
        if not self.is_owner(view) or msg.epoch != view.epoch:
            return self._log(rec.OperatorRequestStale(drone=view.name, requester=msg.requester, epoch=msg.epoch))
        live = self.live_request(view, now)
        if live is not None and (live.requester, live.ask_id) == (msg.requester, msg.ask_id):
            return NOTHING  # the requester sending its standing request again
        if self.closed == (msg.requester, msg.epoch, msg.ask_id):
            return NOTHING  # re-sends of a request declined or expired: decided already
        if msg.to != msg.requester:  # control goes to whoever asks, never to a GS it names
            return self._log(rec.OperatorRequestStale(drone=view.name, requester=msg.requester, epoch=msg.epoch))
        self.seq += 1
        # the spec's range (3-60 s): a request never stands longer, whatever its sender says
        timeout = min(max(msg.timeout, REQUEST_TIMEOUT_MIN_S), REQUEST_TIMEOUT_MAX_S) if msg.timeout > 0 \
            else DEFAULT_REQUEST_TIMEOUT_S
        self.request = PendingRequest(msg.requester, msg.requester, msg.epoch, timeout, now, self.seq, msg.ask_id)
        allowed = self.takeover_allowed(now)
        step = self._log(rec.OperatorRequestReceived(drone=view.name, requester=msg.requester, to=msg.to, epoch=msg.epoch,
                                                     timeout=timeout, takeover_allowed=allowed))
        if allowed:
            return step + self._grant(view, self.request, now, "takeover allowed")
        return step + Step(say=(f"zdrone gs {self.gs}: {msg.requester} requests control of {view.name} "
                                f"({timeout:.0f} s to consent)",))

    def _grant(self, view: Any, req: PendingRequest, now: float, why: str) -> Step:
        assert req.to == req.requester  # control goes to the GS that asked (``on_request``)
        self.release_to, self.release_epoch, self.last_release = req.to, view.epoch, now
        self.release_until = now + GRANT_WINDOW_S
        self.request = None
        return (self._log(rec.OperatorRequestGranted(drone=view.name, requester=req.requester, to=req.to, why=why))
                + Step(send=(wire.HandoverRelease(req.to, view.epoch),),
                       say=(f"zdrone gs {self.gs}: control of {view.name} goes to {req.to} ({why})",)))

    # ------------------------------------------------------------------- time
    def tick(self, view: Any, now: float) -> Step:
        """Deadlines, re-sends, and what follows from the drone's status."""
        step = NOTHING
        if self.window_until is not None and now >= self.window_until:
            self.window_until = None
            step += self._log(rec.TakeoverWindowClosed(drone=view.name))
        if self.request is not None and self.live_request(view, now) is None:
            req = self.request
            self._close(req)
            if not req.alive(now):
                step += self._log(rec.OperatorRequestExpired(drone=view.name, requester=req.requester))
        if view.link is None:
            return step
        if self.is_owner(view):
            if self.asked_until is not None:  # ours now: the request succeeded
                self.asked_until, self.held_epoch = None, view.epoch
                step += self._log(rec.OperatorControlTaken(drone=view.name, epoch=view.epoch))
            want = self.takeover_allowed(now)
            if bool(view.takeover) != want and _due(self.last_tell, now, TELL_RESEND_S):
                self.last_tell = now
                step += Step(send=(wire.HandoverRequest(self.gs, view.epoch, takeover=want),))
            if (self.release_to is not None and self.release_epoch == view.epoch and self.release_until is not None
                    and now < self.release_until and _due(self.last_release, now, TELL_RESEND_S)):
                self.last_release = now
                step += Step(send=(wire.HandoverRelease(self.release_to, view.epoch),))
        elif self.asked_until is not None:
            if now >= self.asked_until:
                self.asked_until = None
                step += self._log(rec.OperatorRequestTimedOut(drone=view.name, owner=view.owner))
            elif _due(self.last_ask, now, ASK_RESEND_S):
                self.last_ask = now
                step += Step(send=(self._ask(view),))
        if self.release_epoch is not None and self.release_epoch != view.epoch:
            self.release_to = self.release_epoch = self.release_until = None  # authority moved on
        return step

    def _close(self, req: PendingRequest) -> None:
        """``req`` is decided (declined, expired): the requester's re-sends of it change nothing."""
        self.request = None
        self.closed = (req.requester, req.epoch, req.ask_id)

    def _ask(self, view: Any) -> wire.HandoverRequest:
        return wire.HandoverRequest(self.gs, view.epoch, timeout=self.asked_timeout, ask_id=self.ask_id)

    @staticmethod
    def _log(record: rec.OperatorControlEvent) -> Step:
        return Step(logs=(record,))


def _due(last: float | None, now: float, period: float) -> bool:
    return last is None or now - last >= period
