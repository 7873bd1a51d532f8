"""The hand-off between Zenoh's callback threads and a node's single loop thread.

Callbacks only put ``(kind, peer, data)`` on a bounded queue (envelopes, query replies); the loop
thread drains it. Nothing that arrives is handled on a Zenoh thread, and nothing a sender can do
grows a node's memory or stalls its loop: a payload above its kind's size limit is refused by its
length before it is even copied out of Zenoh, a full queue refuses the newest item, and each drain
handles a bounded batch. Every refusal is counted per reason (``Inbox.dropped``).
"""

from __future__ import annotations

import queue
import threading
import time
from collections import Counter
from typing import Any, Callable

#: Items handled per drain at most, so the rest of the loop still runs under load.
MAX_BATCH = 512
#: Items waiting at most; beyond it, new ones are refused (counted ``<kind>:inbox_full``).
INBOX_SIZE = 4096
#: A sealed envelope carries one MAVLink frame (<= 280 bytes) or one small control message.
MAX_ENVELOPE = 1024
#: A pairing or key-sharing query or reply: a Noise message (<= 512 bytes) and a few names.
MAX_HANDSHAKE = 768


class Inbox:
    """A bounded, thread-safe queue of ``(kind, peer, data)`` with counted refusals."""

    def __init__(self, size: int = INBOX_SIZE) -> None:
        self._q: queue.Queue[tuple[str, str, Any]] = queue.Queue(size)
        self._lock = threading.Lock()
        self.dropped: Counter[str] = Counter()

    def drop(self, reason: str) -> None:
        """Count one refusal (any thread)."""
        with self._lock:
            self.dropped[reason] += 1

    def put(self, kind: str, peer: str, data: Any) -> None:
        try:
            self._q.put_nowait((kind, peer, data))
        except queue.Full:
            self.drop(f"{kind}:inbox_full")

    def put_payload(self, kind: str, peer: str, payload: Any, limit: int = MAX_ENVELOPE) -> None:
        """Queue a Zenoh payload's bytes, unless it is longer than ``limit`` (checked before copying)."""
        if payload is None or len(payload) > limit:
            self.drop(f"{kind}:oversize")
            return
        self.put(kind, peer, payload.to_bytes())

    def stats(self) -> dict[str, int]:
        with self._lock:
            return dict(self.dropped)

    def drain(self, wait: float, handle: Callable[[str, str, Any, float], None]) -> int:
        """Wait up to ``wait`` s for the first item, then handle what is queued (at most
        ``MAX_BATCH``). Return how many were handled."""
        try:
            first = self._q.get(timeout=wait) if wait > 0 else self._q.get_nowait()
        except queue.Empty:
            return 0
        handle(first[0], first[1], first[2], time.monotonic())
        n = 1
        while n < MAX_BATCH:
            try:
                kind, peer, data = self._q.get_nowait()
            except queue.Empty:
                break
            handle(kind, peer, data, time.monotonic())
            n += 1
        return n


def payload_bytes(payload: Any, limit: int = MAX_HANDSHAKE) -> bytes | None:
    """A query's payload, or None when it is missing or longer than ``limit`` (not copied)."""
    if payload is None or len(payload) > limit:
        return None
    return payload.to_bytes()


def reply_bytes(reply: Any, limit: int = MAX_HANDSHAKE) -> tuple[bytes | None, bytes | None]:
    """(ok payload, error payload) of a Zenoh query reply; never raises (runs on a Zenoh thread).
    A payload longer than ``limit`` is not copied: it becomes the error ``oversize``."""
    try:
        if reply.ok is not None:
            data = payload_bytes(reply.ok.payload, limit)
            return (data, None) if data is not None else (None, b"oversize")
        err = reply.err
        if err is None:
            return None, b"error"
        data = payload_bytes(err.payload, limit)
        return None, data if data is not None else b"oversize"
    except Exception:  # a malformed reply must never raise into Zenoh
        return None, b"unreadable reply"
