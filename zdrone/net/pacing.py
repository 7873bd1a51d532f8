"""Per-key pacing of a node's publications: at most one put per key every ``gap`` seconds.

The router limits the rate of each lane of an uplink (Zenoh's downsampling, ``fleet/routerconfig.py``):
a put that follows the previous one on the same lane closer than the router's interval is dropped
there, whoever sent it. A ground station's loop can emit several frames on one uplink at once (a
heartbeat, a command and a control message in the same tick; a GCS application's burst), so it paces
them itself per uplink, and sends them on the uplink's lanes in turn (``NodeRuntime.put_link``): one
lane's frames are then many router intervals apart. The first goes at once, the others wait their
turn in a bounded queue per uplink (the newest refused when full, counted). No clock: ``now`` is
passed in.
"""

from __future__ import annotations

from collections import deque
from typing import Callable

#: Payloads waiting per key at most; beyond it, new ones are refused (``put:pace_full``).
PACE_QUEUE = 256


class Pacer:
    """Which payloads may be published now, one per key every ``gap`` seconds at most."""

    def __init__(self, gap: float, refuse: Callable[[str], None], limit: int = PACE_QUEUE) -> None:
        if gap <= 0:
            raise ValueError("gap must be positive")
        self.gap = gap
        self.limit = limit
        self.refuse = refuse  # counts a refusal by its reason
        self._last: dict[str, float] = {}  # key -> when its last payload went out
        self._waiting: dict[str, deque[bytes]] = {}  # keys with payloads waiting, oldest first

    def offer(self, key: str, payload: bytes, now: float) -> bool:
        """True if ``payload`` may go out now (and it counts as sent); else it waits (or is refused)."""
        q = self._waiting.get(key)
        if q is None and now - self._last.get(key, float("-inf")) >= self.gap:
            self._last[key] = now
            return True
        if q is None:
            q = self._waiting[key] = deque()
        if len(q) >= self.limit:
            self.refuse("put:pace_full")
            return False
        q.append(payload)
        return False

    def due(self, now: float) -> list[tuple[str, bytes]]:
        """The waiting payloads whose turn has come, one per key (they count as sent)."""
        out: list[tuple[str, bytes]] = []
        for key in list(self._waiting):
            if now - self._last[key] >= self.gap:
                q = self._waiting[key]
                out.append((key, q.popleft()))
                self._last[key] = now
                if not q:
                    del self._waiting[key]
        self._forget(now)
        return out

    def next_due(self) -> float | None:
        """When the next waiting payload may go out, or None if nothing waits."""
        if not self._waiting:
            return None
        return min(self._last[key] for key in self._waiting) + self.gap

    def waiting(self) -> int:
        return sum(len(q) for q in self._waiting.values())

    def _forget(self, now: float) -> None:
        """Drop the send times that no longer hold anything back (keeps the table small)."""
        if len(self._last) > 4 * len(self._waiting) + 64:
            self._last = {k: t for k, t in self._last.items() if k in self._waiting or now - t < self.gap}
