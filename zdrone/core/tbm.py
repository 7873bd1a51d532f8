"""Time between messages (TBM): per-link liveness measured from authentic frames only.

Theory of operation: every authentic frame on a link calls ``observe(now)``; ``state(now)`` maps
the time since the last authentic frame to OK / DEGRADED / LOST with two thresholds (defaults
1 s / 3 s). Before the first frame the silence is counted from the moment the monitor was made.
``poll(now)`` reports a state only when it changed, so an adapter can turn it into one event;
``poll(now, worsen=False)`` reports only a better one (after an input: a silence is judged by the
timer, once every input already queued was handled, never while a frame of the link still waits).
Zenoh's own lease (10 s) is far too slow for this; this is the application-level detector.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass


class LinkState(enum.Enum):
    OK = "ok"
    DEGRADED = "degraded"
    LOST = "lost"


_SEVERITY = {LinkState.OK: 0, LinkState.DEGRADED: 1, LinkState.LOST: 2}


@dataclass(frozen=True, slots=True)
class TbmThresholds:
    """Silence (seconds) after which a link is DEGRADED, then LOST."""

    degraded: float = 1.0
    lost: float = 3.0

    def __post_init__(self) -> None:
        if not (0 < self.degraded <= self.lost) or not math.isfinite(self.lost):
            raise ValueError(f"need 0 < degraded <= lost, got {self.degraded} / {self.lost}")


@dataclass(frozen=True, slots=True)
class TbmSnapshot:
    """What the monitor knows at one instant."""

    state: LinkState
    since_last: float
    frames: int
    mean_gap: float | None
    max_gap: float | None
    last_seen: float | None


class TimeBetweenMessages:
    """Liveness monitor of one link. Pure: ``now`` is always passed in."""

    __slots__ = ("thresholds", "created", "last_seen", "frames", "_gap_sum", "max_gap", "_reported")

    def __init__(self, now: float, thresholds: TbmThresholds = TbmThresholds()) -> None:
        self.thresholds = thresholds
        self.created = now
        self.last_seen: float | None = None
        self.frames = 0
        self._gap_sum = 0.0
        self.max_gap: float | None = None
        self._reported = LinkState.LOST

    def observe(self, now: float) -> float | None:
        """Record an authentic frame at ``now``; return the gap since the previous one."""
        gap = None
        last = self.last_seen
        if last is not None:
            gap = now - last if now > last else 0.0
            self._gap_sum += gap
            if self.max_gap is None or gap > self.max_gap:
                self.max_gap = gap
        self.last_seen = now
        self.frames += 1
        return gap

    def since_last(self, now: float) -> float:
        ref = self.last_seen if self.last_seen is not None else self.created
        return max(0.0, now - ref)

    def state(self, now: float) -> LinkState:
        if self.last_seen is None:
            return LinkState.LOST
        silence = self.since_last(now)
        if silence >= self.thresholds.lost:
            return LinkState.LOST
        if silence >= self.thresholds.degraded:
            return LinkState.DEGRADED
        return LinkState.OK

    def deadline(self) -> float | None:
        """The instant the link becomes LOST if nothing arrives (for an adapter's timer)."""
        if self.last_seen is None:
            return None
        return self.last_seen + self.thresholds.lost

    def next_change(self) -> float | None:
        """When ``poll`` will next report a change if nothing arrives (DEGRADED after OK, LOST after
        DEGRADED), or None (LOST reported, or never heard: only a frame changes that)."""
        if self.last_seen is None:
            return None
        if self._reported is LinkState.OK:
            return self.last_seen + self.thresholds.degraded
        if self._reported is LinkState.DEGRADED:
            return self.last_seen + self.thresholds.lost
        return None

    def poll(self, now: float, worsen: bool = True) -> LinkState | None:
        """Return the current state if it differs from the last one polled, else None. With
        ``worsen=False`` only a better state is reported (OK after DEGRADED or LOST, DEGRADED after
        LOST): after one input, while others may still wait in the adapter's queue, a silence is not
        judged yet (the timer judges it once everything queued was handled)."""
        st = self.state(now)
        if st is self._reported or (not worsen and _SEVERITY[st] > _SEVERITY[self._reported]):
            return None
        self._reported = st
        return st

    def carry_over(self, old: "TimeBetweenMessages") -> None:
        """Continue the reporting of ``old`` (a link whose key was replaced): the next ``poll``
        reports a change relative to what ``old`` last reported, so no state change is lost."""
        self._reported = old._reported

    def snapshot(self, now: float) -> TbmSnapshot:
        mean = self._gap_sum / (self.frames - 1) if self.frames > 1 else None
        return TbmSnapshot(self.state(now), self.since_last(now), self.frames, mean, self.max_gap, self.last_seen)
