"""The hand-off between Zenoh's callback threads and a node's single loop thread.

Callbacks only put ``(kind, peer, data)`` on a queue (envelopes, query replies); the loop thread
drains it. Nothing that arrives is handled on a Zenoh thread.
"""

from __future__ import annotations

import queue
import time
from typing import Any, Callable

MAX_BATCH = 512


def drain(inbox: "queue.SimpleQueue[tuple[str, str, Any]]", wait: float,
          handle: Callable[[str, str, Any, float], None]) -> int:
    """Wait up to ``wait`` s for the first item, then handle what is queued (at most ``MAX_BATCH``,
    so the rest of the loop still runs under load). Return how many were handled."""
    try:
        first = inbox.get(timeout=wait) if wait > 0 else inbox.get_nowait()
    except queue.Empty:
        return 0
    handle(first[0], first[1], first[2], time.monotonic())
    n = 1
    while n < MAX_BATCH:
        try:
            kind, peer, data = inbox.get_nowait()
        except queue.Empty:
            break
        handle(kind, peer, data, time.monotonic())
        n += 1
    return n


def reply_bytes(reply: Any) -> tuple[bytes | None, bytes | None]:
    """(ok payload, error payload) of a Zenoh query reply; never raises (runs on a Zenoh thread)."""
    try:
        if reply.ok is not None:
            return reply.ok.payload.to_bytes(), None
        err = reply.err
        return None, (err.payload.to_bytes() if err is not None else b"error")
    except Exception:  # a malformed reply must never raise into Zenoh
        return None, b"unreadable reply"
