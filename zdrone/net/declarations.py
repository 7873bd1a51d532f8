"""Zenoh declarations off a node's loop.

Declaring or undeclaring a subscriber is a call into Zenoh that waits on its runtime: 2 ms for a
GS's eight uplink lanes on an idle machine, 50-80 ms under a 300-drone flight, and a drone that
subscribed from its loop (on entering that GS's coverage) heard nothing, stepped nothing and steered
nothing meanwhile (issue 30: a hundred drones enter B's coverage within a second). ``DeclarationThread`` runs such calls in one thread per
process, in the order given; ``settle`` waits until every call given so far has run (a node's
``close`` does, before it undeclares everything). A call that raises is logged and counted, never
lost silently and never raised into the loop.
"""

from __future__ import annotations

import logging
import queue
import threading
from typing import Callable

log = logging.getLogger(__name__)


class DeclarationThread:
    """One thread running declaration calls in order (started on the first call)."""

    def __init__(self) -> None:
        self._q: queue.SimpleQueue[Callable[[], None]] = queue.SimpleQueue()
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self.failed = 0  # calls that raised (logged)

    def submit(self, call: Callable[[], None]) -> None:
        with self._lock:
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="zdrone-declarations", daemon=True)
                self._thread.start()
        self._q.put(call)

    def settle(self, timeout: float) -> bool:
        """Wait until every call submitted before this one has run; False if ``timeout`` ran out."""
        done = threading.Event()
        self.submit(done.set)
        return done.wait(timeout)

    def _run(self) -> None:
        while True:
            call = self._q.get()
            try:
                call()
            except Exception as exc:  # a session closed under it, a router gone: the loop goes on
                self.failed += 1
                log.warning("declaration failed: %s", exc)


#: The process's declaration thread (a host of many nodes shares it).
DECLARATIONS = DeclarationThread()
