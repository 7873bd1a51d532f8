"""Bounded, clean shutdown of node processes, even if the main thread is stuck inside a Zenoh call.

No Python signal handler here sets an ``Event``: a handler runs in the main thread between two
bytecodes, and if that thread is inside the same event's ``wait`` at that moment (holding the
condition's lock), ``set`` waits for a lock its own thread holds: the process hangs and no later
SIGTERM ends it. Signals are taken on a thread of their own with ``sigwait`` instead
(``serve_signals``, ``route_signals``).

SIGTERM/SIGINT are blocked in every thread before the Zenoh session starts its own threads
(``block_signals``); a dedicated thread receives them with ``sigwait`` (``serve_signals``), asks the
node's loop to stop, and if the loop has not finished closing within the grace period, prints every
thread's stack (to diagnose) and closes the session from outside, which unblocks the stuck call.
"""

from __future__ import annotations

import faulthandler
import logging
import signal
import sys
import threading
from typing import Callable

log = logging.getLogger(__name__)
SIGNALS = {signal.SIGTERM, signal.SIGINT}


def block_signals() -> None:
    """Call before opening a Zenoh session: threads created afterwards inherit the mask."""
    signal.pthread_sigmask(signal.SIG_BLOCK, SIGNALS)


def serve_signals(stop: Callable[[], None], force_close: Callable[[], None], done: threading.Event,
                  grace: float = 4.0) -> threading.Thread:
    """Start the thread that turns SIGTERM/SIGINT into ``stop()`` (and ``force_close()`` if stuck)."""

    def wait() -> None:
        signal.sigwait(SIGNALS)
        stop()
        if done.wait(grace):
            return
        log.error("shutdown: the main loop is stuck; its stacks follow; closing the session from outside")
        faulthandler.dump_traceback(file=sys.stderr, all_threads=True)
        try:
            force_close()
        except Exception:  # the process is ending: report, never hang
            log.exception("shutdown: forced close failed")

    t = threading.Thread(target=wait, name="signals", daemon=True)
    t.start()
    return t


def route_signals(actions: dict[int, Callable[[], None]]) -> threading.Thread:
    """From now on, run ``actions[signum]()`` on a thread of its own each time one of these signals
    comes: they are blocked in this thread (and in the threads it starts later: call this before
    any library starts one) and taken with ``sigwait``. An action may set events, take locks."""
    signals = set(actions)
    signal.pthread_sigmask(signal.SIG_BLOCK, signals)

    def serve() -> None:
        while True:
            actions[signal.sigwait(signals)]()

    t = threading.Thread(target=serve, name="signals", daemon=True)
    t.start()
    return t
