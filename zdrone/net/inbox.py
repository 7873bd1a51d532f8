"""The hand-off between Zenoh's callback threads and a node's single loop thread."""

from __future__ import annotations

import queue
import time
from typing import Callable

MAX_BATCH = 512


def drain(inbox: "queue.SimpleQueue[tuple[str, bytes]]", wait: float,
          handle: Callable[[str, bytes, float], None]) -> int:
    """Wait up to ``wait`` s for the first (peer, envelope), then handle what is queued (at most
    ``MAX_BATCH``, so the rest of the loop still runs under load). Return how many were handled."""
    try:
        first = inbox.get(timeout=wait) if wait > 0 else inbox.get_nowait()
    except queue.Empty:
        return 0
    handle(first[0], first[1], time.monotonic())
    n = 1
    while n < MAX_BATCH:
        try:
            peer, data = inbox.get_nowait()
        except queue.Empty:
            break
        handle(peer, data, time.monotonic())
        n += 1
    return n
