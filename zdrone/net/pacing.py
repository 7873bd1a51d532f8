"""Per-key pacing of a node's publications: at most ``burst`` puts per key in any ``gap`` seconds.

The router limits the rate of each lane of an uplink (Zenoh's downsampling, ``fleet/routerconfig.py``):
a put that follows the previous one on the same lane closer than the router's interval is dropped
there, whoever sent it. A ground station's loop can emit several frames on one uplink at once (a
heartbeat, a command and a control message in the same tick; a GCS application's burst), so it paces
them itself per uplink and sends them on the uplink's lanes in turn (``NodeRuntime.put_link``). With
``burst`` = the lanes and ``gap`` = how far apart one lane's frames must be, the rule "this put may go
if the put ``burst`` before it on the key is ``gap`` old" is exactly "the lane it goes on was last used
``gap`` ago or more": a burst of up to one frame per lane goes at once (on different lanes, none is
dropped however the router bunches them), and only what comes beyond it waits its turn, in a bounded
queue per key (the newest refused when full, counted). No clock: ``now`` is passed in.
"""

from __future__ import annotations

from collections import deque
from typing import Callable

#: Payloads waiting per key at most; beyond it, new ones are refused (``put:pace_full``).
PACE_QUEUE = 256


class Pacer:
    """Which payloads may be published now: at most ``burst`` per key in any ``gap`` seconds."""

    def __init__(self, gap: float, refuse: Callable[[str], None], limit: int = PACE_QUEUE, burst: int = 1) -> None:
        if gap <= 0:
            raise ValueError("gap must be positive")
        if burst < 1:
            raise ValueError("burst must be at least 1")
        self.gap = gap
        self.burst = burst
        self.limit = limit
        self.refuse = refuse  # counts a refusal by its reason
        self._sent: dict[str, deque[float]] = {}  # key -> when its last ``burst`` payloads went out
        self._waiting: dict[str, deque[bytes]] = {}  # keys with payloads waiting, oldest first
        self._next_forget = float("-inf")  # the table is swept at most once a ``gap`` (``_forget``)

    def _free_at(self, key: str) -> float:
        """When the next payload on ``key`` may go: once the one ``burst`` before it is ``gap`` old."""
        sent = self._sent.get(key)
        if sent is None or len(sent) < self.burst:
            return float("-inf")
        return sent[0] + self.gap

    def _mark(self, key: str, now: float) -> None:
        sent = self._sent.get(key)
        if sent is None:
            sent = self._sent[key] = deque(maxlen=self.burst)
        sent.append(now)

    def offer(self, key: str, payload: bytes, now: float) -> bool:
        """True if ``payload`` may go out now (and it counts as sent); else it waits (or is refused)."""
        q = self._waiting.get(key)
        if q is None and now >= self._free_at(key):
            self._mark(key, now)
            return True
        if q is None:
            q = self._waiting[key] = deque()
        if len(q) >= self.limit:
            self.refuse("put:pace_full")
            return False
        q.append(payload)
        return False

    def due(self, now: float) -> list[tuple[str, bytes]]:
        """The waiting payloads whose turn has come, in order per key (they count as sent)."""
        out: list[tuple[str, bytes]] = []
        for key in list(self._waiting):
            q = self._waiting[key]
            while q and now >= self._free_at(key):
                out.append((key, q.popleft()))
                self._mark(key, now)
            if not q:
                del self._waiting[key]
        self._forget(now)
        return out

    def next_due(self) -> float | None:
        """When the next waiting payload may go out, or None if nothing waits."""
        if not self._waiting:
            return None
        return min(self._free_at(key) for key in self._waiting)

    def waiting(self) -> int:
        return sum(len(q) for q in self._waiting.values())

    def _forget(self, now: float) -> None:
        """Drop the send times that no longer hold anything back (keeps the table small), at most once a
        ``gap``: a GS of 300 drones calls ``due`` every pass, and a sweep each time was O(drones) a pass.
        A forgotten key's time is one that no longer holds anything back, so the rule is unchanged."""
        if now >= self._next_forget and len(self._sent) > 4 * len(self._waiting) + 64:
            self._next_forget = now + self.gap
            self._sent = {k: t for k, t in self._sent.items() if k in self._waiting or now - t[-1] < self.gap}
