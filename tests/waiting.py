"""Waiting in tests: on an event (a file descriptor readable, a process ended), or by polling a
condition with a deadline — never a bare sleep. One place holds the polling step."""

from __future__ import annotations

import select
import time
from typing import Any, Callable

#: how often a polled condition is looked at
POLL_S = 0.02


def wait_until(pred: Callable[[], Any], timeout: float, step: float = POLL_S) -> bool:
    """Poll ``pred`` until it is true or ``timeout`` seconds pass; whether it became true."""
    deadline = time.monotonic() + timeout
    while True:
        if pred():
            return True
        left = deadline - time.monotonic()
        if left <= 0:
            return False
        time.sleep(min(step, left))


def readable(fds: list[Any], timeout: float) -> bool:
    """Wait until one of ``fds`` (sockets, files) has something to read, at most ``timeout`` s."""
    ready, _, _ = select.select(fds, [], [], max(0.0, timeout))
    return bool(ready)
