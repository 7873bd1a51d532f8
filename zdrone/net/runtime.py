"""The node runtime: what every zdrone node needs around its protocol machine.

Theory of operation
-------------------
A node (the drone companion, a ground station) is a pure machine plus this runtime. The runtime owns:

* **identity**: the fleet file, the node's entry (checked for its role) and its secret;
* **the session**: a Zenoh client of the router, authenticated with the node's password; or, given
  several routers (one per site, ``paths``), one session per router, every declaration on each,
  publishing through every path that has its router (see ``paths.py``). In a fleet of sites
  anything may arrive more than once (through each path, or through a site router and the mesh):
  the copies are dropped and counted (``duplicate_path``) before the envelope's replay window;
* **the inbox**: every subscriber and query reply only puts bytes on the bounded, per-sender
  ``Inbox`` (refusing oversized payloads by length); the node's single loop thread drains it;
* **queryables** (bounded rings, drained by the loop) and **subscriptions**, tracked so that
  ``close`` undeclares them all;
* **publishing** (``put``: ``session.put`` with congestion control DROP; ``put_link``: a link frame
  from a GS, paced per key to the router's uplink rate limit and sent at a priority above the data
  class, batched: ``LINK_EXPRESS``) and **asking** (``ask``: an asynchronous query to every queryable, every reply back
  through the inbox);
* **the event log**, **stop** (from the signal thread), and **close** (each step on its own, so a
  session the signal thread closed does not stop the rest).

Nothing here knows a protocol: what a node does with what arrives is its own.
"""

from __future__ import annotations

import gc
import itertools
import logging
import os
import threading
from typing import Any, Callable, Iterator

import zenoh

from zdrone.core import records as rec
from zdrone.core.errors import ConfigError
from zdrone.core.fleet import Fleet, Node
from zdrone.fleet import keyexprs
from zdrone.fleet.files import NodeSecret, fleet_path, load_base_fleet, load_fleet, load_secret
from zdrone.fleet.routerconfig import SITE_LEASE_MS, UPLINK_LANE_GAP_S
from zdrone.fleet.tls import node_files
from zdrone.net.declarations import DECLARATIONS
from zdrone.net.eventlog import EventLog
from zdrone.net.inbox import MAX_ENVELOPE, MAX_HANDSHAKE, Inbox, reply_bytes, senders_bound
from zdrone.net.pacing import Pacer
from zdrone.net.paths import PathQueryable, RecentPayloads, SessionPath
from zdrone.net.pump import PumpedSubscriber
from zdrone.net.session import open_client, query_queue

log = logging.getLogger(__name__)

ROLE_NAMES = {"drone": "a drone", "gs": "a ground station", "viewer": "a viewer"}
#: The Zenoh priority of link frames from a GS (heartbeats, commands, control messages): above the
#: data class every other publication uses, so in a router's queue to the drone they pass before
#: bulk traffic (each priority has its own queue).
LINK_PRIORITY = zenoh.Priority.INTERACTIVE_HIGH
#: Link frames are not express. An express message takes a transmission batch of its own, and a
#: session's queue holds 2 batches per priority: a GS that sends one frame to each of its K drones in
#: the same tick (heartbeats, the command stream) outran its own transmission thread, and a DROP
#: message that finds no free batch within 1 ms is dropped by the sender's session, silently (issue
#: 30: 1-3 commands lost per drone at 25-100 drones, A's links LOST on the ground over sites;
#: ``experiments/express_burst.py``). Not express, a burst shares batches (one 64 KiB batch holds
#: hundreds of frames) and waits at most Zenoh's 1 ms batching limit, only under back-pressure.
LINK_EXPRESS = False
#: The put options: every put (DROP: never blocks), and a link frame's.
_QOS: dict[str, Any] = {"congestion_control": zenoh.CongestionControl.DROP}
_LINK_QOS: dict[str, Any] = {**_QOS, "priority": LINK_PRIORITY, "express": LINK_EXPRESS}
#: Subscriber callbacks run in Zenoh's receiving thread instead of a Python thread each (see ``subscribe``).
DIRECT_CALLBACKS = os.environ.get("ZDRONE_INDIRECT_CALLBACKS") != "1"


class NodeRuntime:
    """Identity, session, inbox, queryables, subscriptions, publishing, events, stop and close."""

    def __init__(self, fleet_dir: str, name: str, role: str, router: str | list[str], events: str | None) -> None:
        # parsed once for the node: its revision keeper checks revisions against the same base (at 300
        # drones a parse holds about 0.4 MB; a companion kept two)
        self.base_fleet: Fleet = load_base_fleet(fleet_dir)
        self.fleet: Fleet = load_fleet(fleet_dir, self.base_fleet)
        node = self.fleet.nodes.get(name)
        if node is None or node.role != role:
            others = [n for n, v in self.fleet.nodes.items() if v.role == role]
            raise ConfigError(f"--id {name}: not {ROLE_NAMES.get(role, role)} of the fleet ({', '.join(others)})")
        self.name = name
        self.node: Node = node
        self.secret: NodeSecret = load_secret(fleet_dir, name, self.fleet)
        routers = [router] if isinstance(router, str) else list(router)
        self.router = " + ".join(routers)
        self.events = EventLog(events, name)
        self.inbox = Inbox(max_senders=senders_bound(len(self.fleet.nodes)))
        self.pacer = Pacer(UPLINK_LANE_GAP_S, self.inbox.drop, burst=keyexprs.UP_LANES)  # a lane each, in turn
        self._lanes: dict[str, Iterator[str]] = {}  # uplink -> its lanes' keys, in turn (the next is the next frame's)
        self.running = True
        self._declared: list[Any] = []  # queryables and subscribers still declared
        self._subs: list[tuple[Any, Callable[[Any], Any]]] = []  # (handle, how to declare it on a session)
        self._decl_lock = threading.RLock()  # subscriptions are declared from the loop and ``in_background``
        self._queryables: list[PathQueryable] = []
        self.multipath = len(routers) > 1
        sites = (fleet_path(fleet_dir).parent / "router" / "sites.json").exists()
        self.recent = RecentPayloads() if self.multipath or sites else None
        tls = {r: node_files(fleet_dir, name).check() for r in routers if r.startswith("tls/")}
        password = self.secret.router_password

        lease = SITE_LEASE_MS if self.multipath else None  # a dead path given up well inside the loss threshold

        def opener(r: str) -> zenoh.Session:
            return open_client(r, name, password, tls.get(r), lease)

        self.paths = [SessionPath(r, opener, background=self.multipath) for r in routers]
        self._connected: dict[str, bool] = {}  # the last connectivity seen of each path (for the log)

    @property
    def session(self) -> Any:
        """The first path's session (a single-router node's only one); None while not open."""
        return self.paths[0].session

    def poll_paths(self) -> None:
        """Adopt the sessions opened meanwhile (declaring everything on them) and pick the path to
        publish through. The node's loop calls this every turn (cheap: no I/O)."""
        for p in self.paths:
            if p.poll():
                self._declare_on(p)
                self.events.write_record(rec.PathOpen(router=p.endpoint))
                log.info("path %s open", p.endpoint)
        if self.multipath:
            for p in self.paths:
                up = p.connected()
                if up != self._connected.get(p.endpoint):
                    self._connected[p.endpoint] = up
                    self.events.write_record(rec.PathState(router=p.endpoint, connected=up))
                    log.info("path %s %s", p.endpoint, "connected" if up else "without its router")

    def path_status(self) -> dict[str, dict[str, Any]]:
        """Each path: open, has its router now."""
        return {p.endpoint: {"open": p.session is not None, "connected": p.connected()} for p in self.paths}

    def _declare_on(self, p: SessionPath) -> None:
        assert p.session is not None
        with self._decl_lock:
            for handle, declare in self._subs:
                handle.per_path.append(declare(p.session))
        for q in self._queryables:
            q.per_path.append(p.session.declare_queryable(q.keyexpr, query_queue()))

    def _open_sessions(self) -> list[Any]:
        return [p.session for p in self.paths if p.session is not None]

    # ----------------------------------------------------------------- declare
    def queryable(self, keyexpr: str) -> Any:
        """A queryable whose queries wait in a bounded ring per path for the loop (``try_recv``)."""
        q = PathQueryable(keyexpr, self.recent, lambda: self.inbox.drop("query:duplicate_path"))
        for s in self._open_sessions():
            q.per_path.append(s.declare_queryable(keyexpr, query_queue()))
        self._queryables.append(q)
        self._declared.append(q)
        return q

    def subscribe(self, keyexpr: str, kind: str, peer_of: Callable[[Any], str], limit: int = MAX_ENVELOPE,
                  pumped: bool = False) -> Any:
        """A subscriber (on every path) that queues each sample's bytes as ``(kind, peer_of(key), data)``;
        ``pumped``: drained by a thread of its own from a Rust-side channel (``zdrone.net.pump``: a GS's
        one subscription to all its drones), else in Zenoh's thread."""
        inbox, recent = self.inbox, self.recent

        def on_sample(sample: zenoh.Sample) -> None:  # a Zenoh thread: hand over and return at once
            if recent is None:
                inbox.put_payload(kind, peer_of(sample.key_expr), sample.payload, limit)
                return
            payload = sample.payload
            if payload is None or len(payload) > limit:
                inbox.drop(f"{kind}:oversize")
                return
            peer, data = peer_of(sample.key_expr), payload.to_bytes()
            if recent.first(kind, peer, data):
                inbox.put(kind, peer, data)
            else:
                inbox.drop(f"{kind}:duplicate_path")

        # run in Zenoh's own thread (``indirect=False``): a plain function would get a Python thread of its
        # own per subscriber (4 600 threads in a host of 300 drones); ``on_sample`` only queues and never
        # calls Zenoh, so it cannot wait on Zenoh from inside Zenoh
        callback = zenoh.handlers.Callback(on_sample, indirect=False) if DIRECT_CALLBACKS else on_sample

        def declare(session: Any) -> Any:
            return PumpedSubscriber(session, keyexpr, on_sample) if pumped else session.declare_subscriber(keyexpr, callback)

        handle = _PathSubscriber()
        with self._decl_lock:
            for s in self._open_sessions():
                handle.per_path.append(declare(s))
            self._subs.append((handle, declare))
            self._declared.append(handle)
        return handle

    def undeclare(self, entity: Any) -> None:
        with self._decl_lock:
            if entity in self._declared:
                self._declared.remove(entity)
            self._subs = [e for e in self._subs if e[0] is not entity]
            self._queryables = [q for q in self._queryables if q is not entity]
            entity.undeclare()

    def in_background(self, call: Callable[[], None]) -> None:
        """Run ``call`` (declarations: ``subscribe``, ``undeclare``) in the process's declaration
        thread, in order, so that the loop never waits on Zenoh for it (``DeclarationThread``)."""
        DECLARATIONS.submit(call)

    # ------------------------------------------------------------------- send
    def _out(self) -> list[Any]:
        """The sessions to send through: the only one, or every path's that has its router now."""
        if not self.multipath:
            return [self.paths[0].session]
        return [p.session for p in self.paths if p.connected()]

    def put(self, keyexpr: str, payload: bytes, link: bool = False) -> None:
        """Publish (``session.put``: through an ACL router, a declared publisher's samples after the
        first are not delivered in zenoh 1.10; ``session.put``'s are). Never blocks: DROP. With
        several paths: through every one that has its router, so that losing one costs nothing and
        a site cut off from the others still hears us (none: counted ``put:no_path``). A ``link``
        frame goes at ``LINK_PRIORITY``, batched like any other (``LINK_EXPRESS``)."""
        sessions = self._out()
        if not sessions:
            self.inbox.drop("put:no_path")
        qos = _LINK_QOS if link else _QOS
        for s in sessions:
            s.put(keyexpr, payload, **qos)

    def put_link(self, keyexpr: str, payload: bytes, now: float) -> None:
        """Publish a GS's link frame on uplink ``keyexpr`` (``keyexprs.up``), paced: on the uplink's
        lanes in turn, at once if the lane it goes on was last used ``UPLINK_LANE_GAP_S`` ago or more
        (a burst of up to a frame per lane goes at once), else in its turn (``flush``), so that the
        router's per-lane rate limit never drops it, even when a stall makes the router process
        several back to back. The node's loop calls ``flush`` every pass
        and wakes by ``next_flush``."""
        if self.pacer.offer(keyexpr, payload, now):
            self._put_on_lane(keyexpr, payload)

    def flush(self, now: float) -> None:
        """Publish the paced frames whose turn has come."""
        for keyexpr, payload in self.pacer.due(now):
            self._put_on_lane(keyexpr, payload)

    def _put_on_lane(self, uplink: str, payload: bytes) -> None:
        lanes = self._lanes.get(uplink)
        if lanes is None:
            lanes = self._lanes[uplink] = itertools.cycle([keyexprs.lane_of(uplink, i) for i in range(keyexprs.UP_LANES)])
        self.put(next(lanes), payload, link=True)

    def next_flush(self) -> float | None:
        """When the next paced frame is due, or None if none waits."""
        return self.pacer.next_due()

    def ask(self, keyexpr: str, payload: bytes, timeout: float, kind: str, peer: str,
            wrap: Callable[[tuple[bytes | None, bytes | None]], Any] = lambda r: r, limit: int = MAX_HANDSHAKE,
            on_done: Callable[[], None] | None = None) -> None:
        """Query every queryable on ``keyexpr`` (ALL: a second queryable declared with a stolen
        password cannot hide the real one); every reply (NONE) comes back through the inbox as
        ``(kind, peer, wrap((ok, err)))``, a reply longer than ``limit`` bytes as the error
        ``oversize`` (not copied); ``on_done`` (Zenoh's thread: it must only queue) once the query has
        ended, every reply in or none. Asynchronous: never waits."""
        inbox = self.inbox

        def on_reply(reply: Any) -> None:
            inbox.put(kind, peer, wrap(reply_bytes(reply, limit)))

        sessions = self._out()
        if not sessions:
            self.inbox.drop("ask:no_path")
            return
        # in Zenoh's own thread, as the subscribers' (``subscribe``): a plain function gets a Python thread
        # of its own per query (a pairing round of 300 drones: 300 threads made and ended); ``on_reply``
        # only queues and never calls Zenoh
        handler = zenoh.handlers.Callback(on_reply, on_done, indirect=False) if DIRECT_CALLBACKS else \
            zenoh.handlers.Callback(on_reply, on_done)
        sessions[0].get(keyexpr, handler, payload=payload, timeout=timeout,
              target=zenoh.QueryTarget.ALL, consolidation=zenoh.ConsolidationMode.NONE)

    # ------------------------------------------------------------- lifecycle
    def stop(self, *_: object) -> None:
        """Ask the loop to end (from the signal thread or a test)."""
        self.running = False

    def close(self, final: dict[str, Any], stop: type[rec.Record],
              extra_steps: tuple[Callable[[], None], ...] = ()) -> None:
        """Write ``stop`` (a record of class ``stop``) with the final status, undeclare everything,
        close the session."""
        self.events.write_as(stop, final)
        if not DECLARATIONS.settle(5.0):  # what the loop asked for is declared before everything goes
            log.warning("close: declarations still running after 5 s")
        with self._decl_lock:
            steps: list[Callable[[], None]] = [e.undeclare for e in reversed(self._declared)]
        steps += [p.close for p in self.paths] + list(extra_steps)
        self._declared.clear()
        for step in steps:  # each on its own: a session the signal thread closed must not stop the rest
            try:
                step()
            except Exception as exc:
                log.warning("close: %s", exc)
        self.events.write_record(rec.Closed())
        self.events.close()

    def close_sessions(self) -> None:
        """Close every path's session (from the signal thread when the loop is stuck)."""
        for p in self.paths:
            p.close()

    def serve(self, run: Callable[[], None]) -> int:
        """Run ``run()`` with SIGTERM/SIGINT turned into ``stop()`` by the signal thread (the command
        line blocked those signals before any thread started: ``cli.run_parsed``)."""
        from zdrone.net.shutdown import serve_signals

        closed = threading.Event()
        serve_signals(self.stop, self.close_sessions, closed)
        freeze_start_up()
        try:
            run()
        finally:
            closed.set()
        return 0


def freeze_start_up() -> None:
    """Keep what start-up built (modules, the fleet, keys, each peer's state) out of every later
    garbage collection (``gc.freeze``): a full collection scans every tracked object while holding the
    GIL, and a process serving hundreds of peers stood still for it: 0.64 s in a host of 300 drones
    (issue 30: the drones' passes, and with them their owners' frames, waited for it). What start-up
    built lives as long as the node; a collection still finds what the node makes and drops later."""
    gc.collect()
    gc.freeze()


class _PathSubscriber:
    """A subscription declared on every adopted path."""

    def __init__(self) -> None:
        self.per_path: list[Any] = []

    def undeclare(self) -> None:
        for sub in self.per_path:
            sub.undeclare()
        self.per_path.clear()
