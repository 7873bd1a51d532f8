"""``zdrone view``'s web server in-process against a fake follower (no Zenoh, no fleet): what the
server and the page do with a picture given, on a real socket (uvicorn on a thread)."""

from __future__ import annotations

import contextlib
import dataclasses
import threading
from typing import Any, Iterator

from tests.procs import free_port, wait_until
from zdrone.view.server import ViewOptions, build_app, server_config


class FakeFleet:
    """What the stream's geometry reads of a fleet: no home, no GS."""

    home = None
    nodes: dict[str, Any] = {}


def row(name: str, **kw: Any) -> dict[str, Any]:
    """One drone's row as ``FleetPicture.drone`` makes it: live, verified, owned by A."""
    r = {"drone": name, "owner": "A", "epoch": 1, "state": "linked", "pending_to": None, "verified": True,
         "attested_age": 0.4, "unverified": [], "disputed": [], "failsafe": False, "reports_failsafe": [],
         "stale": False, "age": 0.1, "mode": "AUTO", "armed": True, "position": [47.0, 8.0, 30.0],
         "position_from": "A", "mission_seq": 2, "stage": "", "fc_signed": True,
         "links": {"A": {"link": "ok", "age": 0.1, "holds": True, "says": "A", "epoch": 1, "silent": False}},
         "requests": [], "takeover": False, "takeover_to": None}
    r.update(kw)
    return r


class FakeFollower:
    """A follower whose picture is ``drones`` (rows); counts the snapshots made."""

    fleet = FakeFleet()

    def __init__(self, drones: list[dict[str, Any]] | None = None) -> None:
        self.drones = drones or []
        self.stopping = threading.Event()
        self.version = 1
        self.snapshots = 0
        self.lock = threading.Lock()

    def snapshot(self) -> dict[str, Any]:
        with self.lock:
            self.snapshots += 1
            return {"drones": list(self.drones), "stations": {"A": {"age": 0.1, "silent": False}}, "feed": [],
                    "drops": {}, "opened": 1}

    def tracks(self) -> dict[str, Any]:
        return {}


@contextlib.contextmanager
def serving(follower: Any, opts: ViewOptions | None = None, host: str = "127.0.0.1") -> Iterator[int]:
    """The view's app for ``follower`` (built as for ``--listen host``) on 127.0.0.1, its port."""
    import uvicorn

    port = free_port()
    opts = dataclasses.replace(opts or ViewOptions(fleet="-", router="-"), port=port)
    server = uvicorn.Server(server_config(build_app(follower, opts, host), opts, "127.0.0.1"))
    thread = threading.Thread(target=server.run, name="view-under-test", daemon=True)
    thread.start()
    try:
        assert wait_until(lambda: server.started or not thread.is_alive(), 10) and server.started
        yield port
    finally:
        follower.stopping.set()
        server.should_exit = True
        thread.join(10)
