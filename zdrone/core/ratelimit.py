"""Per-peer token buckets: bounded work for whatever a peer sends. Pure: ``now`` comes in."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(slots=True)
class _Bucket:
    tokens: float
    stamp: float


class RateLimiter:
    """``allow(peer, now)``: at most ``rate`` events per second per peer, bursts of ``burst``.

    Memory is bounded by the set of peers the caller admits (callers key it by fleet names only,
    which are checked before), so an attacker cannot grow it.
    """

    def __init__(self, rate: float, burst: float) -> None:
        if rate <= 0 or burst < 1:
            raise ValueError("need rate > 0 and burst >= 1")
        self.rate, self.burst = rate, burst
        self._buckets: dict[str, _Bucket] = {}
        self.refused = 0

    def allow(self, peer: str, now: float) -> bool:
        b = self._buckets.get(peer)
        if b is None:
            b = self._buckets[peer] = _Bucket(self.burst, now)
        elif now > b.stamp:
            b.tokens = min(self.burst, b.tokens + (now - b.stamp) * self.rate)
            b.stamp = now
        if b.tokens >= 1.0:
            b.tokens -= 1.0
            return True
        self.refused += 1
        return False
