"""``zdrone router``: a Zenoh router in Python (the same config file works with ``zenohd -c``).

Taking over from a running router (``--take-over SECONDS``, a rolling restart that costs the clients
well under a second): the new process starts while the old one still holds the port, loads its
config and files, says ``taking over`` and then waits inside Zenoh's own listen retry (every
``TAKE_OVER_RETRY_MS``) for the listening endpoints to be free. The operator (or the testbed) then
ends the old router with SIGTERM: it closes its sessions (its clients start reconnecting at once,
``zdrone.net.session``) and its port, and the new one binds within one retry period and says
``listening``. Two routers never share a port (Zenoh does not set ``SO_REUSEPORT``): the new one
holds nothing until the old one has let go. A router that cannot listen within SECONDS (the old
one never stopped, a bad endpoint or certificate) fails with one line, exit code 2; SIGTERM while
it waits ends it at once (it holds nothing yet).
"""

from __future__ import annotations

import json
import logging
import os
import signal
import threading
import time
from pathlib import Path

import zenoh

from zdrone.core.bundle import unpack

from zdrone.core.fleet import ConfigError
from zdrone.net.session import load_router_config
from zdrone.net.shutdown import route_signals

log = logging.getLogger(__name__)

#: how often a router taking over tries its listening endpoints again (the clients' reconnect is
#: 100-400 ms: the port is back before their next try)
TAKE_OVER_RETRY_MS = 50
#: the line a router taking over prints once everything but the port is ready (then end the old one)
TAKE_OVER_LINE = "taking over"


#: What the tap counts: the links, and the revision pushes every node hears (queries and their replies
#: are not samples: not counted)
TAP_KEYS = ("zdrone/**", "zdrone-fleet/**")


class TrafficTap:
    """Counts every sample that crosses the router, per key expression (the router's own session
    sees them all; the ACL filters remote sessions only): the links (``zdrone/**``) and the fleet's
    revision pushes (``TAP_KEYS``). A drone's publication is a bundle: its envelopes are counted too
    (an envelope holds one message, or a batch of the drone's pass)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.lock = threading.Lock()
        self.counts: dict[str, list[int]] = {}
        self.first: float | None = None
        self.last: float | None = None

    def __call__(self, sample: zenoh.Sample) -> None:
        n = len(sample.payload)
        key = str(sample.key_expr)
        frames = 1
        if "/down/" in key:  # a drone's bundle: the envelopes in it (``zdrone.core.bundle``)
            frames = len(unpack(sample.payload.to_bytes()) or [b""])
        now = time.time()
        with self.lock:
            c = self.counts.setdefault(key, [0, 0, 0])  # samples, bytes, envelopes
            c[0] += 1
            c[1] += n
            c[2] += frames
            if key.startswith("zdrone/"):  # the window: the links' first and last sample
                self.first = self.first or now
                self.last = now

    def dump(self) -> None:
        with self.lock:
            data = {"first": self.first, "last": self.last, "keys": {k: list(v) for k, v in self.counts.items()}}
        tmp = self.path.with_suffix(".tmp")
        tmp.write_text(json.dumps(data))
        tmp.replace(self.path)


def take_over_config(cfg: zenoh.Config, seconds: float) -> None:
    """Make ``cfg``'s session open wait up to ``seconds`` for its listening endpoints (trying again
    every ``TAKE_OVER_RETRY_MS``), then fail, instead of failing at once when one is taken."""
    cfg.insert_json5("listen/timeout_ms", json.dumps(max(1, round(seconds * 1000))))
    cfg.insert_json5("listen/exit_on_failure", "true")
    cfg.insert_json5("listen/retry", json.dumps({"period_init_ms": TAKE_OVER_RETRY_MS,
                                                 "period_max_ms": TAKE_OVER_RETRY_MS,
                                                 "period_increase_factor": 1.0}))
    # the session's open returns as soon as it listens (not 0.5 s later: a scouting delay, and there
    # is nothing to scout, multicast and gossip being off): the ready line says when the port is back
    cfg.insert_json5("scouting/delay", "0")


def run_router(config_path: str | Path, listen: list[str] | None = None, tap: str | None = None,
               connect: list[str] | None = None, take_over: float | None = None) -> int:
    """Run until SIGTERM/SIGINT; print one ready line with the listening endpoints. With
    ``take_over`` (seconds), wait that long for endpoints another router still holds (module
    docstring). With ``RUST_LOG`` set, Zenoh logs to stderr at that level."""
    cfg = load_router_config(config_path, listen, connect)
    if take_over is not None:
        take_over_config(cfg, take_over)
    if os.environ.get("RUST_LOG"):  # Zenoh's own log on stderr, e.g. every put the downsampling drops:
        # RUST_LOG=zenoh::net::routing::interceptor::downsampling=trace
        zenoh.init_log_from_env_or("error")
    stop = threading.Event()
    opened = threading.Event()

    def on_stop() -> None:
        stop.set()
        if take_over is not None and not opened.is_set():  # still waiting for the port: holds nothing
            print("zdrone router: stopped before it took over", flush=True)
            os._exit(0)

    # taken on a thread of their own (the command line blocked them before any thread started): a
    # handler setting ``stop`` inside ``stop.wait`` can deadlock the main thread (zdrone.net.shutdown)
    route_signals({signal.SIGTERM: on_stop, signal.SIGINT: on_stop})
    eps = ", ".join(listen) if listen else "(endpoints from config)"
    if take_over is not None:
        print(f"zdrone router: {TAKE_OVER_LINE} {eps} (waiting up to {take_over:g} s for the port)", flush=True)
    try:
        session = zenoh.open(cfg)
    except zenoh.ZError as exc:
        detail = str(exc).splitlines()[0]
        if take_over is not None:
            raise ConfigError(f"{config_path}: router did not start: could not listen on {eps} within {take_over:g} s "
                              f"(another router still there, or a bad endpoint or certificate): {detail}") from None
        raise ConfigError(f"{config_path}: router did not start: {detail}") from None
    opened.set()
    try:
        counter = TrafficTap(tap) if tap else None
        subs = [session.declare_subscriber(k, counter) for k in TAP_KEYS] if counter else []
        print(f"zdrone router: listening on {eps}, zid {session.info.zid()}", flush=True)
        while not stop.wait(1.0):
            if counter:
                counter.dump()
        for sub in subs:
            sub.undeclare()
        if counter:
            counter.dump()
    finally:
        session.close()
        log.info("router stopped")
    return 0
