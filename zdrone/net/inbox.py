"""The hand-off between Zenoh's callback threads and a node's single loop thread.

Callbacks only put ``(kind, peer, data)`` on a bounded queue per (kind, sender) (envelopes, query
replies, and the drone's vehicle messages from its vehicle link's reader thread); the loop thread
drains them in turn, sleeping on the queue until the first item or its own next deadline. Nothing that arrives is handled on a Zenoh thread, and
nothing a sender can do grows a node's memory, stalls its loop or crowds out another sender: a
payload above its kind's size limit is refused by its length before it is even copied out of Zenoh,
a full queue refuses the newest item, and each drain handles a bounded batch, one item per sender in
turn and at most ``MAX_PER_SENDER`` of one sender (a flooded queue cannot fill a whole batch, so a
frame from another sender that arrives meanwhile waits for a few dozen items at most, not hundreds). Every refusal is counted per reason (``Inbox.dropped``).
"""

from __future__ import annotations

import threading
import time
from collections import Counter, deque
from typing import Any, Callable

from zdrone.core.kk import MAX_MESSAGE

#: Items handled per drain at most, so the rest of the loop still runs under load.
MAX_BATCH = 512
#: Items of one (kind, sender) handled per drain at most: the rest waits for the next drain.
MAX_PER_SENDER = 64
#: Items waiting per (kind, sender) at most; beyond it, new ones are refused (``<kind>:inbox_full``).
INBOX_SIZE = 1024
#: (kind, sender) queues holding items at once, at least (senders are node names from key expressions,
#: which the router's ACL ties to the fleet). A queue is freed as soon as it is drained, so this bounds
#: the senders with a backlog, not the senders a node ever hears from. A node's bound grows with its
#: fleet (``senders_bound``): a fixed 256 refused the frames of a GS's 257th drone with a backlog, so a
#: GS serving 300 drones lost 18 000 of their frames in a flight and 227 of them went wrong (issue 30).
MAX_SENDERS = 256
#: Kinds of queue one peer can hold at once (a GS's drone: down, pair, pair_done, linkkey, query).
KINDS_PER_PEER = 5
#: Bytes waiting in all queues together, at most (``<kind>:inbox_bytes``): whatever the fleet's size,
#: what every sender can make a node hold stays bounded (one queue alone: ``INBOX_SIZE`` items).
MAX_BYTES = 64 * 1024 * 1024
#: A sealed envelope carries one MAVLink frame (<= 280 bytes) or one small control message.
MAX_ENVELOPE = 1024
#: A pairing or key-sharing query or reply: a Noise message (classical <= 512 bytes, hybrid with
#: ML-KEM-768 about 1.3 kB: ``kk.MAX_MESSAGE``) and a few names.
MAX_HANDSHAKE = MAX_MESSAGE + 256


class Inbox:
    """Bounded, thread-safe queues of ``(kind, peer, data)``, one per (kind, peer), drained in turn.

    One queue per sender and kind, each at most ``size`` items: a flood on one key (one leaked
    password) fills its own queue only, and the loop takes one item from each non-empty queue in
    turn, so the other senders' frames still get through at their own rate. Refusals are counted."""

    def __init__(self, size: int = INBOX_SIZE, max_senders: int = MAX_SENDERS, max_bytes: int = MAX_BYTES) -> None:
        self.size, self.max_senders, self.max_bytes = size, max_senders, max_bytes
        self._bytes = 0  # bytes waiting, all queues
        self._queues: dict[tuple[str, str], deque[Any]] = {}
        self._order: deque[tuple[str, str]] = deque()  # keys with items, in turn
        self._cond = threading.Condition(threading.Lock())
        self.dropped: Counter[str] = Counter()

    def drop(self, reason: str) -> None:
        """Count one refusal (any thread)."""
        with self._cond:
            self.dropped[reason] += 1

    def put(self, kind: str, peer: str, data: Any) -> None:
        key = (kind, peer)
        with self._cond:
            q = self._queues.get(key)
            if q is None:
                if len(self._queues) >= self.max_senders:
                    self.dropped[f"{kind}:too_many_senders"] += 1
                    return
                q = self._queues[key] = deque()
            if len(q) >= self.size:
                self.dropped[f"{kind}:inbox_full"] += 1
                return
            size = len(data) if isinstance(data, (bytes, bytearray)) else 0
            if self._bytes + size > self.max_bytes:
                self.dropped[f"{kind}:inbox_bytes"] += 1
                return
            self._bytes += size
            if not q:
                self._order.append(key)
            q.append(data)
            self._cond.notify()

    def put_payload(self, kind: str, peer: str, payload: Any, limit: int = MAX_ENVELOPE) -> None:
        """Queue a Zenoh payload's bytes, unless it is longer than ``limit`` (checked before copying)."""
        if payload is None or len(payload) > limit:
            self.drop(f"{kind}:oversize")
            return
        self.put(kind, peer, payload.to_bytes())

    def stats(self) -> dict[str, int]:
        with self._cond:
            return dict(self.dropped)

    def _take(self, n: int) -> list[tuple[str, str, Any]]:
        """Up to ``n`` items, one per sender in turn and ``MAX_PER_SENDER`` of one sender at most
        (the caller holds the lock)."""
        out: list[tuple[str, str, Any]] = []
        rounds: dict[tuple[str, str], int] = {}
        capped: list[tuple[str, str]] = []
        while self._order and len(out) < n:
            key = self._order.popleft()
            q = self._queues[key]
            item = q.popleft()
            if isinstance(item, (bytes, bytearray)):
                self._bytes -= len(item)
            out.append((key[0], key[1], item))
            taken = rounds[key] = rounds.get(key, 0) + 1
            if not q:
                del self._queues[key]  # drained: the sender holds no queue until it sends again
            elif taken >= MAX_PER_SENDER:
                capped.append(key)  # its turn again in the next drain, after the senders still waiting
            else:
                self._order.append(key)
        self._order.extend(capped)
        return out

    def drain(self, wait: float, handle: Callable[[str, str, Any, float], None]) -> int:
        """Wait up to ``wait`` s for the first item, then handle what is queued (at most
        ``MAX_BATCH``, senders in turn). Return how many were handled."""
        with self._cond:
            if not self._order and wait > 0:
                self._cond.wait(wait)
            batch = self._take(MAX_BATCH)
        for kind, peer, data in batch:
            handle(kind, peer, data, time.monotonic())
        return len(batch)


def senders_bound(fleet_nodes: int) -> int:
    """A node's bound on (kind, sender) queues at once: every peer of its fleet with every kind it
    can send (never below ``MAX_SENDERS``)."""
    return max(MAX_SENDERS, KINDS_PER_PEER * fleet_nodes)


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
