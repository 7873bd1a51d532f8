"""Several ways to the fleet at once: one Zenoh client session per site router (a "path").

Theory of operation
-------------------
A node given several routers (``--router EP1 --router EP2``: one per site whose radio may reach it)
keeps one client session per router, so that losing a site costs no interruption: the other
sessions are already up, with the same subscriptions and queryables declared (make-before-break at
the transport, as the authority does it for the command link).

* A ``SessionPath`` opens its session in the background and keeps trying (a site out of radio
  range at start is normal); once open, Zenoh's client retries its router by itself. The node's
  loop thread adopts the session (``poll``) and only then declares on it, so every declaration
  happens on one thread.
* Everything a node receives arrives once per path that carries it (each site's router delivers
  it). ``RecentPayloads`` lets the first copy through and refuses the others, counted as
  ``duplicate_path`` (they are byte-identical; the envelope's replay window would drop them anyway).
* A node publishes through every path whose session has a router right now (``connected``): a
  site cut off from the others (backhaul down) still hears the drone through its own radio, and a
  path that dies costs nothing, since the others carried the same frames already. A GS in a fleet
  of sites drops the copies the mesh then delivers in the same way.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import OrderedDict
from typing import Any, Callable

import zenoh

log = logging.getLogger(__name__)

#: Payloads remembered per node to recognise the copies other paths deliver, at most.
RECENT_PAYLOADS = 8192
#: ... and for this long at most (s): the other paths' copies come within the mesh's delay. A copy later
#: than this reaches the inbox and is dropped there by the envelope's replay window (counted as a
#: replay, not ``duplicate_path``). Before, a drone kept its last 8 192 payloads whatever their age:
#: about 1 MB a drone once full, 60 % of a zdrone drone's memory in a host of 300.
RECENT_S = 5.0


class RecentPayloads:
    """Thread-safe memory of the payloads seen (per kind and peer) in the last ``window`` s, ``size``
    at most, to drop copies."""

    def __init__(self, size: int = RECENT_PAYLOADS, window: float = RECENT_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.size, self.window, self._clock = size, window, clock
        self._seen: OrderedDict[tuple[str, str, int, int], float] = OrderedDict()  # key -> first seen, oldest first
        self._lock = threading.Lock()

    def first(self, kind: str, peer: str, data: bytes) -> bool:
        """True the first time these bytes are seen from ``peer``; False for a copy."""
        key = (kind, peer, len(data), hash(data))
        now = self._clock()
        with self._lock:
            seen = self._seen
            while seen and (len(seen) >= self.size or next(iter(seen.values())) < now - self.window):
                seen.popitem(last=False)
            if key in seen:
                return False
            seen[key] = now
            return True

    def __len__(self) -> int:
        return len(self._seen)


class SessionPath:
    """One client session to one router, opened in the background until it succeeds."""

    def __init__(self, endpoint: str, opener: Callable[[str], zenoh.Session], background: bool = True) -> None:
        self.endpoint = endpoint
        self._opener = opener
        self.session: zenoh.Session | None = None  # adopted by the loop thread
        self._opened: zenoh.Session | None = None  # set by the opening thread
        self._lock = threading.Lock()
        self._closed = threading.Event()
        self.failures = 0
        if not background:
            self.session = opener(endpoint)  # raises: a single path fails fast with one line
            return
        threading.Thread(target=self._open_loop, name=f"path-{endpoint}", daemon=True).start()

    def _open_loop(self) -> None:
        delay = 0.1
        while not self._closed.is_set():
            try:
                s = self._opener(self.endpoint)
            except Exception as exc:  # out of range, router down: try again
                self.failures += 1
                if self.failures in (1, 10) or self.failures % 100 == 0:
                    log.info("path %s: not open yet (%d tries): %s", self.endpoint, self.failures, exc)
                self._closed.wait(delay)
                delay = min(delay * 1.5, 0.4)
                continue
            with self._lock:
                if not self._closed.is_set():
                    self._opened = s
                    return
            s.close()  # closed while it opened
            return

    def poll(self) -> bool:
        """Adopt a session the background thread opened (loop thread); True if one was adopted."""
        if self.session is not None:
            return False
        with self._lock:
            s, self._opened = self._opened, None
        if s is None:
            return False
        self.session = s
        return True

    def connected(self) -> bool:
        """Whether this path's session reaches a router right now."""
        s = self.session
        if s is None:
            return False
        try:
            return any(True for _ in s.info.routers_zid())
        except Exception:  # a closed session
            return False

    def close(self) -> None:
        with self._lock:
            self._closed.set()
            s, self._opened = self._opened, None
        for sess in (s, self.session):
            if sess is not None:
                try:
                    sess.close()
                except Exception as exc:
                    log.warning("close %s: %s", self.endpoint, exc)
        self.session = None


class PathQueryable:
    """A queryable declared on every adopted path; ``try_recv`` takes from each in turn and hands
    over only the first copy of a query that several paths delivered (the others are dropped)."""

    def __init__(self, keyexpr: str, recent: RecentPayloads | None, on_duplicate: Callable[[], None]) -> None:
        self.keyexpr = keyexpr
        self.per_path: list[Any] = []
        self._recent = recent
        self._on_duplicate = on_duplicate
        self._turn = 0

    def try_recv(self) -> Any:
        n = len(self.per_path)
        for i in range(n):
            q_able = self.per_path[(self._turn + i) % n]
            while True:
                q = q_able.try_recv()
                if q is None:
                    break
                self._turn = (self._turn + i + 1) % n
                if self._recent is not None and not self._is_first(q):
                    self._on_duplicate()
                    q.drop()
                    continue
                return q
        return None

    def _is_first(self, q: Any) -> bool:
        assert self._recent is not None
        payload = q.payload
        data = payload.to_bytes() if payload is not None and len(payload) <= 4096 else b""
        return self._recent.first("query", str(q.key_expr), data)

    def undeclare(self) -> None:
        for q in self.per_path:
            q.undeclare()
        self.per_path.clear()
