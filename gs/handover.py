"""The GS's side of a hand-over, per drone and per epoch it holds: a table, sans-IO.

Theory of operation
-------------------
While this GS holds a drone's authority, ``DroneSession.release_due`` (``gs.session``) decides
*whether* to release it (the vehicle flies into another authorized GS's coverage) and *to whom*; this
machine keeps *where the release stands* in the drone's current epoch. Phases:

* ``IDLE``: nothing released in this epoch;
* ``RELEASED``: a ``HANDOVER_RELEASE`` went out and the drone has not confirmed it (the core sends it
  again every ``RELEASE_RESEND_S`` until it does);
* ``CONFIRMED``: the drone reports ``HANDOVER_PENDING`` for it: authority moves once the recipient
  proves its link, or the drone's deadline passes (then the drone reports LINKED again, with us);
* ``FAILED``: the hand-over failed in this epoch (the drone had no key for the recipient, the release
  was refused or timed out): authority stays here and the core tries again after ``HANDOVER_RETRY_S``.

Events (``HandoverEvent``, frozen): ``ReleaseSent`` (the core sent a release, first or again),
``Confirmed`` (the drone reports HANDOVER_PENDING for it), ``Failed`` (the hand-over cannot happen
now). ``TABLE`` maps (phase, event type) to (handler, next phase), a table of the machine engine
(``zdrone.core.machine``): the handler keeps the facts, the row says where the phase goes, and the
move is logged ``old -> new``. A pair not in the table changes nothing (``handle`` returns False):
e.g. a confirmation while nothing is released, a status seen after an operator's own release. A new
epoch starts the machine afresh (``for_epoch``): whatever was released or failed belonged to the
epoch before.

Besides the phase, the machine keeps what the epoch's hand-over decisions need: when the release
was last sent, when and how often it failed (the first failure is logged, retries are counted), the
distance from our centre at the epoch's first release (is the vehicle leaving our coverage?) and
whether an RTL of ours, or a mode someone else chose, already stands in this epoch (RTL at most once).
"""

from __future__ import annotations

import enum
import logging
from dataclasses import dataclass

from zdrone.core.machine import Machine, Table

log = logging.getLogger(__name__)


class HandoverPhase(enum.Enum):
    IDLE = "idle"
    RELEASED = "released"
    CONFIRMED = "confirmed"
    FAILED = "failed"


@dataclass(frozen=True, slots=True)
class HandoverEvent:
    now: float


@dataclass(frozen=True, slots=True)
class ReleaseSent(HandoverEvent):
    """A release toward ``to`` went out, at ``distance`` metres from our coverage's centre."""

    to: str
    distance: float


@dataclass(frozen=True, slots=True)
class Confirmed(HandoverEvent):
    """The drone reports HANDOVER_PENDING for our release."""


@dataclass(frozen=True, slots=True)
class Failed(HandoverEvent):
    """The hand-over cannot happen now (``reason`` for the log)."""

    reason: str




class Handover(Machine):
    """Where this GS's release of one drone stands in the drone's current epoch."""

    _state_attr = "phase"
    _log = log

    def __init__(self, drone: str) -> None:
        self.drone = drone
        self.epoch: int | None = None
        self._fresh()

    def _fresh(self) -> None:
        """Nothing released, failed or commanded yet (a new epoch)."""
        self.phase = HandoverPhase.IDLE
        self.to: str | None = None  # the recipient of the last release
        self.sent = 0.0  # the last release went out then
        self.failed_at = 0.0  # the last failure
        self.failures = 0  # in this epoch
        self.first_distance: float | None = None  # from our centre, at the epoch's first release
        self.rtl_done = False  # an RTL of ours, or a mode someone else chose, stands in this epoch

    # ------------------------------------------------------------------ queries
    @property
    def released(self) -> bool:
        """A release of ours stands (sent, confirmed or not): we no longer command the drone."""
        return self.phase in (HandoverPhase.RELEASED, HandoverPhase.CONFIRMED)

    def released_in(self, epoch: int) -> bool:
        return self.epoch == epoch and self.released

    def retry_waits(self, now: float, retry: float) -> bool:
        """Failed less than ``retry`` seconds ago: the next try waits."""
        return self.phase is HandoverPhase.FAILED and now - self.failed_at < retry

    def resend_waits(self, now: float, resend: float) -> bool:
        """Released: wait for the drone (the release is sent again only if it never confirmed)."""
        return self.phase is HandoverPhase.CONFIRMED or self.phase is HandoverPhase.RELEASED and now - self.sent < resend

    # ------------------------------------------------------------------ engine
    def for_epoch(self, epoch: int) -> "Handover":
        """The machine of ``epoch``: a new epoch starts afresh (``IDLE``, nothing failed, no RTL)."""
        if epoch != self.epoch:
            if self.phase is not HandoverPhase.IDLE:
                log.info("hand-over of %s: epoch %s -> %d, %s -> idle", self.drone, self.epoch, epoch, self.phase.value)
            self._fresh()
            self.epoch = epoch
        return self

    def handle(self, ev: HandoverEvent) -> bool:
        """Apply ``ev``; False if the table has no row for it in this phase (nothing changed)."""
        row = self._row(TABLE, ev)
        if row is None:
            return False
        handler, next_phase = row
        handler(self, ev)
        self._set_state(next_phase)
        return True

    def _machine_name(self, key: object = None) -> str:
        return f"hand-over of {self.drone} (epoch {self.epoch})"

    # ------------------------------------------------------------------ handlers
    def _on_release(self, ev: ReleaseSent) -> None:
        if self.first_distance is None:  # the epoch's first release
            self.first_distance = ev.distance
        self.to, self.sent = ev.to, ev.now

    def _on_confirmed(self, ev: Confirmed) -> None:
        pass

    def _on_failed(self, ev: Failed) -> None:
        self.failures += 1
        self.failed_at = ev.now


#: (phase, event type) -> (handler, next phase). Pairs not listed change nothing.
TABLE: Table[HandoverPhase] = {
    (HandoverPhase.IDLE, ReleaseSent): (Handover._on_release, HandoverPhase.RELEASED),
    (HandoverPhase.FAILED, ReleaseSent): (Handover._on_release, HandoverPhase.RELEASED),
    (HandoverPhase.RELEASED, ReleaseSent): (Handover._on_release, HandoverPhase.RELEASED),  # sent again, never confirmed
    (HandoverPhase.RELEASED, Confirmed): (Handover._on_confirmed, HandoverPhase.CONFIRMED),
    (HandoverPhase.CONFIRMED, Confirmed): (Handover._on_confirmed, HandoverPhase.CONFIRMED),
    (HandoverPhase.IDLE, Failed): (Handover._on_failed, HandoverPhase.FAILED),
    (HandoverPhase.RELEASED, Failed): (Handover._on_failed, HandoverPhase.FAILED),
    (HandoverPhase.CONFIRMED, Failed): (Handover._on_failed, HandoverPhase.FAILED),
    (HandoverPhase.FAILED, Failed): (Handover._on_failed, HandoverPhase.FAILED),
}
# Not listed: a release while CONFIRMED (the core waits for the drone), a confirmation while IDLE or
# FAILED (a release that is not ours, e.g. the operator's, or one that failed already).
