"""A hold of the vehicle while a hand-over waits for the drone's key to the next GS: a table, sans-IO.

Theory of operation
-------------------
When this GS is due to release a drone toward GS ``to`` (the vehicle flies into ``to``'s coverage)
but the drone holds no key for ``to`` yet, and that key is known to be coming (a restarted
companion: ``StationCore._key_coming``), the GS holds the vehicle where it is in the overlap (the
autopilot's hold mode), at most ``HOLD_FOR_KEY_S``, and resumes its mission just before the release:
how fast the vehicle flies then does not decide whether the hand-over happens inside the overlap.
One hold per epoch at most (``KeyHold.start`` makes it; the core keeps it with the epoch).

Phases (``HoldPhase``): ``HOLDING`` (the hold mode asked for, re-sent every ``HOLD_RESEND_S`` until
the vehicle confirms it: a COMMAND_ACK, or its HEARTBEAT in that mode), ``RESUMING`` (the key is
there: the mission mode asked for, re-sent likewise; the release waits for it) and ``OVER``
(resumed, expired, or someone else changed the mode: nothing more of ours in this epoch).

Events (frozen): ``KeyMissing`` (the core's look while the release is due and the key is still
missing), ``KeyThere`` (the key reached the drone: the release is due), ``ModeAck`` (a COMMAND_ACK of
DO_SET_MODE). ``TABLE`` maps (phase, event type) to (handler, the phases it may move to), a table of
the machine engine (``zdrone.core.machine``); a pair not in it returns None, which the core reads as
"no hold of ours" (it then waits for the key or fails the hand-over; or releases). A handler's answer
is a ``HoldStep``: a mode command to send, and whether the hold ended without the hand-over (``over``,
with an RTL or not). A handler moves by ``_set_state`` (the engine's: checked against its row, logged
``old -> new (why)``); a move its row does not allow raises ``IllegalHold``.
"""

from __future__ import annotations

import enum
import logging
from collections import Counter
from dataclasses import dataclass

from zdrone.core import records as rec
from zdrone.core.machine import IllegalTransition, Machine, Table

log = logging.getLogger(__name__)

#: A key known to be coming holds the vehicle for at most this long; the mission resumes just before
#: the release (a resume not confirmed ``RESUME_GRACE_S`` later has failed).
HOLD_FOR_KEY_S = 15.0
RESUME_GRACE_S = 5.0
#: A mode change of the hold (to hold, back to the mission) is sent again this often until the
#: vehicle confirms it; a hold not confirmed this long after it was asked, with the vehicle past
#: ``gs.context.KEY_WAIT_RADIUS``, has failed: RTL.
HOLD_RESEND_S = 0.5


class HoldPhase(enum.Enum):
    HOLDING = "holding"  # hold mode asked for (confirmed or not), waiting for the key
    RESUMING = "resuming"  # the key is there: the mission mode asked for; the release waits for it
    OVER = "over"  # resumed, expired (RTL), or someone else changed the mode: nothing more of ours


@dataclass(frozen=True, slots=True)
class KeyMissing:
    """The release toward the hold's GS is due and the drone still has no key for it."""

    now: float
    mode: str  # the vehicle's mode now
    far: bool  # the vehicle is past the radius up to which the GS waits for a key


@dataclass(frozen=True, slots=True)
class KeyThere:
    """The drone holds the key of ``to`` now: the release toward it is due (the mission goes on first)."""

    now: float
    mode: str
    to: str


@dataclass(frozen=True, slots=True)
class ModeAck:
    now: float
    accepted: bool


@dataclass(frozen=True, slots=True)
class HoldStep:
    """What the core does for the hold: send ``send`` (DO_SET_MODE params 1-3) if given; if ``over``,
    the hold ended without the hand-over (for that reason), commanding RTL if ``rtl``."""

    send: tuple[float, float, float] | None = None
    over: str | None = None
    rtl: bool = False
    log: rec.Record | None = None


WAIT = HoldStep()


#: A handler moved to a phase its table row does not allow: a programming error (the engine's one error).
IllegalHold = IllegalTransition


class KeyHold(Machine):
    """The hold of one epoch (see the module docstring)."""

    _state_attr = "phase"
    _log = log

    def __init__(self, drone: str, epoch: int, to: str, since: float, hold_mode: str, mission_mode: str,
                 params: dict[str, tuple[float, float, float]], counters: Counter[str]) -> None:
        self.drone, self.epoch, self.to, self.since = drone, epoch, to, since
        self.hold_mode, self.mission_mode = hold_mode, mission_mode
        self.params = params  # DO_SET_MODE params 1-3 of each mode
        self.counters = counters
        self.phase = HoldPhase.HOLDING
        self.sent = 0.0  # the current phase's mode command, last sent
        self.confirmed = False  # the current phase's mode confirmed by the vehicle
        self.seen = False  # the vehicle's HEARTBEAT showed the hold mode
        self.stands = False  # a mode someone else chose (not the mission's) stands for the epoch

    @classmethod
    def start(cls, drone: str, epoch: int, to: str, now: float, hold_mode: str, mission_mode: str,
              params: dict[str, tuple[float, float, float]], counters: Counter[str]) -> tuple["KeyHold", HoldStep]:
        """Hold the vehicle now: the hold and its first step (the hold mode asked for)."""
        hold = cls(drone, epoch, to, now, hold_mode, mission_mode, params, counters)
        counters["handover_hold"] += 1
        log.warning("hand-over of %s to %s waits for its key: holding the vehicle (%s) for at most %g s",
                    drone, to, hold_mode, HOLD_FOR_KEY_S)
        return hold, HoldStep(send=hold._command(hold_mode, now), log=rec.HandoverHold(drone=drone, to=to, epoch=epoch,
                                                                                       mode=hold_mode))

    @property
    def active(self) -> bool:
        return self.phase is not HoldPhase.OVER

    def deadlines(self) -> tuple[float, ...]:
        """When a look at the hold may next do something (re-send, expiry, resume's end)."""
        if not self.active:
            return ()
        return (self.sent + HOLD_RESEND_S, self.since + HOLD_RESEND_S, self.since + HOLD_FOR_KEY_S,
                self.since + HOLD_FOR_KEY_S + RESUME_GRACE_S)

    # ------------------------------------------------------------------ engine
    def handle(self, ev: KeyMissing | KeyThere | ModeAck) -> HoldStep | None:
        """Apply ``ev``; None: the table has no row for it (no hold of ours in this phase)."""
        row = self._row(TABLE, ev)
        if row is None:
            return None
        return row[0](self, ev)

    def _machine_name(self, key: object = None) -> str:
        return f"hold of {self.drone} (epoch {self.epoch}, for {self.to})"

    def _command(self, mode: str, now: float) -> tuple[float, float, float]:
        self.sent = now
        return self.params[mode]

    def _overridden(self, mode: str) -> bool:
        """The vehicle is in a mode neither we nor its mission chose, or left the hold it was seen in."""
        return mode not in (self.hold_mode, self.mission_mode) or (self.seen and mode != self.hold_mode)

    def _end(self, why: str, mode: str) -> None:
        """Nothing more of the hold: counted by why. A mode someone else chose (other than the
        mission's) stands for the rest of the epoch: no RTL of ours over it."""
        self._set_state(HoldPhase.OVER, why)
        self.counters[f"handover_hold_over:{why}"] += 1
        if why == "mode changed" and mode != self.mission_mode:
            self.stands = True

    def _over(self, why: str, mode: str, rtl: bool) -> HoldStep:
        self._end(why, mode)
        return HoldStep(over=why, rtl=rtl)

    # ------------------------------------------------------------------ handlers
    def _holding(self, ev: KeyMissing) -> HoldStep:
        """Keep holding (the mode re-sent until confirmed), or end the hold."""
        if ev.mode == self.hold_mode:
            self.confirmed = self.seen = True
        elif self._overridden(ev.mode):  # someone else (its operator, the autopilot) changed the mode
            return self._over("mode changed", ev.mode, rtl=False)
        if ev.now - self.since >= HOLD_FOR_KEY_S:  # RTL wherever it holds
            return self._over("expired", ev.mode, rtl=ev.mode == self.hold_mode)
        if not self.confirmed:
            if ev.far and ev.now - self.since >= HOLD_RESEND_S:  # the vehicle does not hold and is leaving
                return self._over("not confirmed", ev.mode, rtl=True)
            if ev.now - self.sent >= HOLD_RESEND_S:
                self.counters["handover_hold_resent"] += 1
                return HoldStep(send=self._command(self.hold_mode, ev.now))
        self.counters["handover_holding_for_key"] += 1
        return WAIT

    def _resume(self, ev: KeyThere) -> HoldStep | None:
        """The key is there: the mission goes on first (None: someone else changed the mode: release)."""
        if self._overridden(ev.mode):  # theirs stands
            self._end("mode changed", ev.mode)
            return None
        self._set_state(HoldPhase.RESUMING, "key there")
        self.confirmed = False
        self.counters["handover_resume"] += 1
        return HoldStep(send=self._command(self.mission_mode, ev.now),
                        log=rec.HandoverResume(drone=self.drone, to=ev.to, epoch=self.epoch,
                                               held_s=round(ev.now - self.since, 2)))

    def _resuming(self, ev: KeyThere) -> HoldStep | None:
        """Wait for the mission mode (None: confirmed: release now)."""
        if self.confirmed or ev.mode == self.mission_mode and ev.now - self.sent >= HOLD_RESEND_S:
            self._set_state(HoldPhase.OVER, "resumed")
            return None
        if ev.now - self.since >= HOLD_FOR_KEY_S + RESUME_GRACE_S:  # the vehicle never took its mission back
            return self._over("resume not confirmed", ev.mode, rtl=ev.mode == self.hold_mode)
        if ev.now - self.sent >= HOLD_RESEND_S:
            self.counters["handover_resume_resent"] += 1
            return HoldStep(send=self._command(self.mission_mode, ev.now))
        return WAIT

    def _acked(self, ev: ModeAck) -> HoldStep:
        if ev.accepted and ev.now >= self.sent:
            self.confirmed = True
        return WAIT


H = HoldPhase
#: (phase, event type) -> (handler, the phases it may move to). Pairs not listed: no hold of ours.
TABLE: Table[HoldPhase] = {
    (H.HOLDING, KeyMissing): (KeyHold._holding, frozenset({H.OVER})),
    (H.HOLDING, KeyThere): (KeyHold._resume, frozenset({H.RESUMING, H.OVER})),
    (H.RESUMING, KeyThere): (KeyHold._resuming, frozenset({H.OVER})),
    (H.HOLDING, ModeAck): (KeyHold._acked, frozenset()),
    (H.RESUMING, ModeAck): (KeyHold._acked, frozenset()),
}
# Not listed: KeyMissing while RESUMING (the key was there: the core waits or fails as without a
# hold), anything while OVER.
