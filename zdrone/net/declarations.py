"""Zenoh declarations off a node's loop.

Declaring or undeclaring a subscriber is a call into Zenoh that waits on its runtime: 2 ms for a
GS's eight uplink lanes on an idle machine, 50-80 ms under a 300-drone flight, and a drone that
subscribed from its loop (on entering that GS's coverage) heard nothing, stepped nothing and steered
nothing meanwhile (issue 30: a hundred drones enter B's coverage within a second). ``DeclarationThread`` runs such calls in one thread per
process, in the order given; ``settle`` waits until every call given so far has run (a node's
``close`` does, before it undeclares everything). A call that raises is logged and counted, never
lost silently and never raised into the loop.

The calls a node asks for are also spread in time, ``DECLARE_CALLS_PER_S`` at most, a steady
interval apart: a fleet flying together enters an overlap together (290 drones within one second at
300, each declaring a GS's eight lanes), and those 2 300 declarations reaching the site routers at
once paused another GS's frames across the mesh for 1.08 s. A drone enters an overlap about 10 s
before its hand-over, so hearing the next GS a few seconds later costs it nothing.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from typing import Callable

log = logging.getLogger(__name__)

#: Declaration calls a process runs per second at most (a drone's call declares or undeclares one
#: GS's uplink lanes).
DECLARE_CALLS_PER_S = 100.0


class DeclarationThread:
    """One thread running declaration calls in order (started on the first call), paced calls at
    most ``max_per_s`` a second (None: as fast as they come)."""

    def __init__(self, max_per_s: float | None = None) -> None:
        self._q: queue.SimpleQueue[tuple[Callable[[], None], bool]] = queue.SimpleQueue()
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._interval = 1.0 / max_per_s if max_per_s else 0.0
        self._next = 0.0  # when the next paced call may run
        self.failed = 0  # calls that raised (logged)

    def submit(self, call: Callable[[], None], paced: bool = True) -> None:
        with self._lock:
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="zdrone-declarations", daemon=True)
                self._thread.start()
        self._q.put((call, paced))

    def settle(self, timeout: float) -> bool:
        """Wait until every call submitted before this one has run; False if ``timeout`` ran out."""
        done = threading.Event()
        self.submit(done.set, paced=False)
        return done.wait(timeout)

    def _run(self) -> None:
        while True:
            call, paced = self._q.get()
            if paced and self._interval:
                now = time.monotonic()
                if now < self._next:
                    time.sleep(self._next - now)
                self._next = max(now, self._next) + self._interval
            try:
                call()
            except Exception as exc:  # a session closed under it, a router gone: the loop goes on
                self.failed += 1
                log.warning("declaration failed: %s", exc)


#: The process's declaration thread (a host of many nodes shares it).
DECLARATIONS = DeclarationThread(max_per_s=DECLARE_CALLS_PER_S)
