"""``zdrone router``: a Zenoh router in Python (the same config file works with ``zenohd -c``)."""

from __future__ import annotations

import json
import logging
import os
import signal
import threading
import time
from pathlib import Path

import zenoh

from ..core.fleet import ConfigError
from .session import load_router_config
from .shutdown import route_signals

log = logging.getLogger(__name__)


class TrafficTap:
    """Counts every sample that crosses the router, per key expression (the router's own session
    sees them all; the ACL filters remote sessions only)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.lock = threading.Lock()
        self.counts: dict[str, list[int]] = {}
        self.first: float | None = None
        self.last: float | None = None

    def __call__(self, sample: zenoh.Sample) -> None:
        n = len(sample.payload)
        now = time.time()
        with self.lock:
            c = self.counts.setdefault(str(sample.key_expr), [0, 0])
            c[0] += 1
            c[1] += n
            self.first = self.first or now
            self.last = now

    def dump(self) -> None:
        with self.lock:
            data = {"first": self.first, "last": self.last, "keys": {k: list(v) for k, v in self.counts.items()}}
        tmp = self.path.with_suffix(".tmp")
        tmp.write_text(json.dumps(data))
        tmp.replace(self.path)


def run_router(config_path: str | Path, listen: list[str] | None = None, tap: str | None = None,
               connect: list[str] | None = None) -> int:
    """Run until SIGTERM/SIGINT; print one ready line with the listening endpoints. With ``RUST_LOG``
    set, Zenoh logs to stderr at that level."""
    cfg = load_router_config(config_path, listen, connect)
    if os.environ.get("RUST_LOG"):  # Zenoh's own log on stderr, e.g. every put the downsampling drops:
        # RUST_LOG=zenoh::net::routing::interceptor::downsampling=trace
        zenoh.init_log_from_env_or("error")
    stop = threading.Event()
    # taken on a thread of their own (the command line blocked them before any thread started): a
    # handler setting ``stop`` inside ``stop.wait`` can deadlock the main thread (zdrone.net.shutdown)
    route_signals({signal.SIGTERM: stop.set, signal.SIGINT: stop.set})
    try:
        session = zenoh.open(cfg)
    except zenoh.ZError as exc:
        raise ConfigError(f"{config_path}: router did not start: {str(exc).splitlines()[0]}") from None
    try:
        eps = ", ".join(listen) if listen else "(endpoints from config)"
        counter = TrafficTap(tap) if tap else None
        sub = session.declare_subscriber("zdrone/**", counter) if counter else None
        print(f"zdrone router: listening on {eps}, zid {session.info.zid()}", flush=True)
        while not stop.wait(1.0):
            if counter:
                counter.dump()
        if sub is not None:
            sub.undeclare()
        if counter:
            counter.dump()
    finally:
        session.close()
        log.info("router stopped")
    return 0
