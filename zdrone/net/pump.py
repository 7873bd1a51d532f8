"""A subscription drained by a thread of its own, in batches: Zenoh's receiving thread never waits for
Python's GIL.

Theory of operation
-------------------
A subscriber with a Python callback (``zenoh.handlers.Callback``) runs it in Zenoh's receiving thread,
which must take the GIL for every sample. In a GS serving hundreds of drones its loop holds the GIL
for most of each pass; a waiting thread gets it only at the interpreter's switch interval (5 ms), and
gives it back after one sample: one sample per switch interval while the loop is busy, the rest queued
behind it in the session (the report's wait that made vehicle -> GS p99 hundreds of ms; ``docs/results.md``).

``PumpedSubscriber`` declares the subscriber with a Rust-side FIFO (``zenoh.handlers.FifoChannel``):
Zenoh's thread queues each sample without the GIL and goes on. One pump thread blocks in the
channel's ``recv`` (the GIL released while it waits), then hands on everything queued meanwhile, up to
``PUMP_BATCH`` samples, in one hold of the GIL. Undeclaring closes the channel, and the pump ends.
The callback is the node's own (``NodeRuntime.subscribe``'s ``on_sample``: bound, counted queues);
what it raises is a programming error, logged and counted, and the pump goes on.

For a subscription with few samples and many siblings (a drone host's 4 600 per-drone subscriptions),
a thread each would cost more than it saves: those keep direct callbacks.
"""

from __future__ import annotations

import logging
import threading
from typing import Any, Callable

import zenoh

log = logging.getLogger(__name__)

#: Samples the channel holds before Zenoh's thread waits for the pump (seconds of a GS's traffic).
PUMP_CAPACITY = 16384
#: Samples handed on per hold of the GIL at most (the loop's turn comes between batches).
PUMP_BATCH = 512


class PumpedSubscriber:
    """A subscriber on ``session`` whose samples reach ``on_sample`` in the pump's thread."""

    def __init__(self, session: Any, keyexpr: str, on_sample: Callable[[Any], None]) -> None:
        self.sub = session.declare_subscriber(keyexpr, zenoh.handlers.FifoChannel(PUMP_CAPACITY))
        self.errors = 0
        self.thread = threading.Thread(target=self._drain, args=(self.sub.handler, on_sample), daemon=True,
                                       name=f"pump {keyexpr}")
        self.thread.start()

    def _drain(self, channel: Any, on_sample: Callable[[Any], None]) -> None:
        while True:
            batch: list[Any] = []
            closed = False
            try:
                batch.append(channel.recv())  # blocks with the GIL released
                while len(batch) < PUMP_BATCH:
                    sample = channel.try_recv()
                    if sample is None:
                        break
                    batch.append(sample)
            except zenoh.ZError:  # closed: undeclared, or the session closed (what was taken is handed on)
                closed = True
            for sample in batch:
                try:
                    on_sample(sample)
                except Exception:  # a programming error: counted and logged, the pump goes on
                    self.errors += 1
                    if self.errors <= 3:
                        log.exception("pump: a sample's handler raised")
            if closed:
                return

    def undeclare(self) -> None:
        self.sub.undeclare()  # closes the channel: the pump's recv ends
