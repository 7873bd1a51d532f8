"""The node runtime: what every zdrone node needs around its protocol machine.

Theory of operation
-------------------
A node (the drone companion, a ground station) is a pure machine plus this runtime. The runtime owns:

* **identity**: the fleet file, the node's entry (checked for its role) and its secret;
* **the session**: a Zenoh client of the router, authenticated with the node's password;
* **the inbox**: every subscriber and query reply only puts bytes on the bounded, per-sender
  ``Inbox`` (refusing oversized payloads by length); the node's single loop thread drains it;
* **queryables** (bounded rings, drained by the loop) and **subscriptions**, tracked so that
  ``close`` undeclares them all;
* **publishing** (``put``: ``session.put`` with congestion control DROP) and **asking** (``ask``:
  an asynchronous query to every queryable, every reply back through the inbox);
* **the event log**, **stop** (from the signal thread), and **close** (each step on its own, so a
  session the signal thread closed does not stop the rest).

Nothing here knows a protocol: what a node does with what arrives is its own.
"""

from __future__ import annotations

import logging
import threading
from typing import Any, Callable

import zenoh

from ..core.errors import ConfigError
from ..core.fleet import Fleet, Node
from ..fleet.files import NodeSecret, load_fleet, load_secret
from ..fleet.tls import node_files
from .eventlog import EventLog
from .inbox import MAX_ENVELOPE, Inbox, reply_bytes
from .session import open_client, query_queue

log = logging.getLogger(__name__)

ROLE_NAMES = {"drone": "a drone", "gs": "a ground station"}


class NodeRuntime:
    """Identity, session, inbox, queryables, subscriptions, publishing, events, stop and close."""

    def __init__(self, fleet_dir: str, name: str, role: str, router: str, events: str | None) -> None:
        self.fleet: Fleet = load_fleet(fleet_dir)
        node = self.fleet.nodes.get(name)
        if node is None or node.role != role:
            others = [n for n, v in self.fleet.nodes.items() if v.role == role]
            raise ConfigError(f"--id {name}: not {ROLE_NAMES.get(role, role)} of the fleet ({', '.join(others)})")
        self.name = name
        self.node: Node = node
        self.secret: NodeSecret = load_secret(fleet_dir, name, self.fleet)
        self.router = router
        self.events = EventLog(events, name)
        self.inbox = Inbox()
        self.running = True
        self._declared: list[Any] = []  # queryables and subscribers still declared
        tls = node_files(fleet_dir, name).check() if router.startswith("tls/") else None
        self.session = open_client(router, name, self.secret.router_password, tls)

    # ----------------------------------------------------------------- declare
    def queryable(self, keyexpr: str) -> Any:
        """A queryable whose queries wait in a bounded ring for the loop (``try_recv``)."""
        q = self.session.declare_queryable(keyexpr, query_queue())
        self._declared.append(q)
        return q

    def subscribe(self, keyexpr: str, kind: str, peer_of: Callable[[Any], str], limit: int = MAX_ENVELOPE) -> Any:
        """A subscriber that queues each sample's bytes as ``(kind, peer_of(key), data)``."""
        inbox = self.inbox

        def on_sample(sample: zenoh.Sample) -> None:  # a Zenoh thread: hand over and return at once
            inbox.put_payload(kind, peer_of(sample.key_expr), sample.payload, limit)

        sub = self.session.declare_subscriber(keyexpr, on_sample)
        self._declared.append(sub)
        return sub

    def undeclare(self, entity: Any) -> None:
        if entity in self._declared:
            self._declared.remove(entity)
        entity.undeclare()

    # ------------------------------------------------------------------- send
    def put(self, keyexpr: str, payload: bytes) -> None:
        """Publish (``session.put``: through an ACL router, a declared publisher's samples after the
        first are not delivered in zenoh 1.10; ``session.put``'s are). Never blocks: DROP."""
        self.session.put(keyexpr, payload, congestion_control=zenoh.CongestionControl.DROP)

    def ask(self, keyexpr: str, payload: bytes, timeout: float, kind: str, peer: str,
            wrap: Callable[[tuple[bytes | None, bytes | None]], Any] = lambda r: r) -> None:
        """Query every queryable on ``keyexpr`` (ALL: a second queryable declared with a stolen
        password cannot hide the real one); every reply (NONE) comes back through the inbox as
        ``(kind, peer, wrap((ok, err)))``. Asynchronous: never waits."""
        inbox = self.inbox

        def on_reply(reply: Any) -> None:
            inbox.put(kind, peer, wrap(reply_bytes(reply)))

        self.session.get(keyexpr, on_reply, payload=payload, timeout=timeout,
                         target=zenoh.QueryTarget.ALL, consolidation=zenoh.ConsolidationMode.NONE)

    # ------------------------------------------------------------- lifecycle
    def stop(self, *_: object) -> None:
        """Ask the loop to end (from the signal thread or a test)."""
        self.running = False

    def close(self, final: dict[str, Any], extra_steps: tuple[Callable[[], None], ...] = ()) -> None:
        """Write ``stop`` with the final status, undeclare everything, close the session."""
        self.events.write("stop", **final)
        steps: list[Callable[[], None]] = [e.undeclare for e in reversed(self._declared)]
        steps += [self.session.close, *extra_steps]
        self._declared.clear()
        for step in steps:  # each on its own: a session the signal thread closed must not stop the rest
            try:
                step()
            except Exception as exc:
                log.warning("close: %s", exc)
        self.events.write("closed")
        self.events.close()

    def serve(self, run: Callable[[], None]) -> int:
        """Run ``run()`` with SIGTERM/SIGINT turned into ``stop()`` by the signal thread (the command
        line blocked those signals before any thread started: ``cli.run_parsed``)."""
        from .shutdown import serve_signals

        closed = threading.Event()
        serve_signals(self.stop, self.session.close, closed)
        try:
            run()
        finally:
            closed.set()
        return 0
