"""Per-peer token buckets: bounded work for whatever a peer sends. Pure: ``now`` comes in."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(slots=True)
class TokenBucket:
    """``rate`` tokens a second, at most ``burst`` held; ``take`` spends one if there is one. Time
    never runs back for it (an earlier ``now`` refills nothing)."""

    rate: float
    burst: float
    tokens: float
    stamp: float

    @classmethod
    def full(cls, rate: float, burst: float, now: float) -> "TokenBucket":
        return cls(rate, burst, burst, now)

    def take(self, now: float) -> bool:
        if now > self.stamp:
            self.tokens = min(self.burst, self.tokens + (now - self.stamp) * self.rate)
            self.stamp = now
        if self.tokens >= 1.0:
            self.tokens -= 1.0
            return True
        return False


class RateLimiter:
    """``allow(peer, now)``: at most ``rate`` events per second per peer, bursts of ``burst``.

    Memory is bounded by the set of peers the caller admits (callers key it by fleet names only,
    which are checked before), so an attacker cannot grow it.
    """

    def __init__(self, rate: float, burst: float) -> None:
        if rate <= 0 or burst < 1:
            raise ValueError("need rate > 0 and burst >= 1")
        self.rate, self.burst = rate, burst
        self._buckets: dict[str, TokenBucket] = {}
        self.refused = 0

    def set_burst(self, burst: float) -> None:
        """Buckets hold at most ``burst`` from now on (a bucket holding more keeps ``burst``; none is
        filled by it)."""
        if burst < 1:
            raise ValueError("need burst >= 1")
        self.burst = burst
        for b in self._buckets.values():
            b.burst, b.tokens = burst, min(b.tokens, burst)

    def allow(self, peer: str, now: float) -> bool:
        b = self._buckets.get(peer)
        if b is None:
            b = self._buckets[peer] = TokenBucket.full(self.rate, self.burst, now)
        if b.take(now):
            return True
        self.refused += 1
        return False
