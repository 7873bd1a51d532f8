"""Sliding replay window, as in IPsec (RFC 4303 §3.4.3) and DTLS (RFC 6347 §4.1.2.6).

The window tracks the highest counter accepted and a bitmap of the ``size`` counters below it.
A counter is fresh if it is above the highest, or inside the window and not yet seen. Checking and
marking are separate so that a frame is marked only after it has been authenticated: a forged
frame must never move the window.
"""

from __future__ import annotations


class ReplayWindow:
    """Accepts each counter at most once; tolerates reordering within ``size`` counters."""

    __slots__ = ("size", "highest", "_bits", "_mask", "_limit")

    def __init__(self, size: int = 1024) -> None:
        if size < 1:
            raise ValueError("replay window size must be >= 1")
        self.size = size
        self.highest = -1
        self._bits = 0  # bit i set <=> counter (highest - i) seen; bits beyond ``size`` are ignored
        self._mask = (1 << size) - 1
        self._limit = 2 * size  # trim the bitmap only when it grows past this (cheaper than every time)

    def is_fresh(self, counter: int) -> bool:
        """True if ``counter`` has not been seen and is not older than the window."""
        if counter > self.highest:
            return True
        offset = self.highest - counter
        if offset >= self.size:
            return False
        return not (self._bits >> offset) & 1

    def mark(self, counter: int) -> None:
        """Record ``counter`` as seen. Call only after the frame authenticated."""
        if counter > self.highest:
            shift = counter - self.highest
            if shift < self.size:
                bits = (self._bits << shift) | 1
                self._bits = bits & self._mask if bits.bit_length() > self._limit else bits
            else:
                self._bits = 1
            self.highest = counter
        else:
            self._bits |= 1 << (self.highest - counter)
