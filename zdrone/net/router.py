"""``zdrone router``: a Zenoh router in Python (the same config file works with ``zenohd -c``)."""

from __future__ import annotations

import logging
import signal
import threading
from pathlib import Path

import zenoh

from ..core.fleet import ConfigError
from .session import load_router_config

log = logging.getLogger(__name__)


def run_router(config_path: str | Path, listen: list[str] | None = None) -> int:
    """Run until SIGTERM/SIGINT; print one ready line with the listening endpoints."""
    cfg = load_router_config(config_path, listen)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    try:
        session = zenoh.open(cfg)
    except zenoh.ZError as exc:
        raise ConfigError(f"{config_path}: router did not start: {str(exc).splitlines()[0]}") from None
    try:
        eps = ", ".join(listen) if listen else "(endpoints from config)"
        print(f"zdrone router: listening on {eps}, zid {session.info.zid()}", flush=True)
        stop.wait()
    finally:
        session.close()
        log.info("router stopped")
    return 0
