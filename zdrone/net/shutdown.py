"""Bounded, clean shutdown of node processes, even if the main thread is stuck inside a Zenoh call.

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
