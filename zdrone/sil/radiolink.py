"""TESTBED ONLY: radio coverage as real links, on loopback.

Theory of operation
-------------------
Each (drone, site) radio is a ``RadioLink``: a TCP relay on a loopback port in front of the site's
router. The drone's per-site Zenoh session connects to the relay, never to the router itself, so
the bytes of that session (TLS included) pass through it untouched. While the link is **up** the
relay accepts connections and pumps bytes both ways; taking it **down** closes every connection it
carries and refuses new ones at once, exactly what the drone's Zenoh session sees when the vehicle
flies out of the site's radio range: its transport to that router ends, and its retries fail until
the link is up again. The backhaul between two sites' routers is a ``RadioLink`` too (always up
unless a scenario cuts it).

``SiteCoverage`` decides, from the vehicle's true position (the simulator's ``--truth`` datagrams),
which sites' radios reach it: a site reaches the vehicle when the vehicle is inside the coverage
circle of any of the site's ground stations (fleet.json5). It brings each site's link up or down
and logs every change. No frame filter is involved: what does not reach a site's router simply
does not arrive. With network namespaces (root) the same links would be veth pairs; on loopback
the relay plays that part. Site routers mesh over QUIC (UDP): their backhaul is a
``DatagramLink``, a UDP relay with the same switch (down drops every datagram, both ways, and
forgets the flows, so the routers' QUIC connection dies of silence as over a cut backhaul).
"""

from __future__ import annotations

import json
import logging
import socket
import threading
from collections import Counter
from collections.abc import Mapping
from typing import Any, Callable, Protocol

from zdrone.core.fleet import Fleet
from zdrone.core.geometry import Circle, GeoPoint

log = logging.getLogger(__name__)

CHUNK = 65536


class SwitchedLink(Protocol):
    """A testbed link the testbed brings up and down: a loopback relay here, a veth pair in ``netns``."""

    name: str

    @property
    def up(self) -> bool: ...

    def set_up(self, up: bool) -> bool: ...

    def close(self) -> None: ...


class _Relay:
    """What both relays share: a name, a target, an up/down switch (thread-safe, counted), and the
    loopback endpoint the node connects to instead of the target."""

    port: int

    def __init__(self, name: str, target: tuple[str, int], up: bool) -> None:
        self.name = name
        self.target = target
        self._up = up
        self._lock = threading.Lock()
        self.counters: Counter[str] = Counter()
        self._closed = threading.Event()

    @property
    def endpoint(self) -> str:
        return f"127.0.0.1:{self.port}"

    @property
    def up(self) -> bool:
        return self._up

    def set_up(self, up: bool) -> bool:
        """Bring the link up or down; True if that changed it. Down cuts everything it carries at once."""
        with self._lock:
            if up == self._up:
                return False
            self._up = up
            doomed = self._cut() if not up else []
        for s in doomed:
            _hang_up(s)
        self.counters["up" if up else "down"] += 1
        return True

    def _cut(self) -> list[socket.socket]:
        """Under the lock: forget what the link carries; the sockets to close."""
        raise NotImplementedError


class RadioLink(_Relay):
    """One emulated link: a loopback TCP relay to ``target`` that can be brought up and down."""

    def __init__(self, name: str, target: tuple[str, int], up: bool = True) -> None:
        super().__init__(name, target, up)
        self._conns: set[socket.socket] = set()
        self._listener = socket.create_server(("127.0.0.1", 0))
        self._listener.settimeout(0.2)
        self.port = self._listener.getsockname()[1]
        self._thread = threading.Thread(target=self._accept_loop, name=f"radio-{name}", daemon=True)
        self._thread.start()

    def _cut(self) -> list[socket.socket]:
        doomed = list(self._conns)
        self._conns.clear()
        return doomed

    def close(self) -> None:
        self._closed.set()
        self.set_up(False)
        self._listener.close()
        self._thread.join(2.0)

    # ------------------------------------------------------------------ relay
    def _accept_loop(self) -> None:
        while not self._closed.is_set():
            try:
                client, _ = self._listener.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            if not self._up:
                self.counters["refused"] += 1
                _hang_up(client)
                continue
            try:
                server = socket.create_connection(self.target, timeout=2.0)
            except OSError:
                self.counters["target_unreachable"] += 1
                _hang_up(client)
                continue
            for s in (client, server):
                s.settimeout(None)
                s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            with self._lock:
                if not self._up:  # went down meanwhile
                    _hang_up(client)
                    _hang_up(server)
                    continue
                self._conns.update((client, server))
            self.counters["connections"] += 1
            for a, b in ((client, server), (server, client)):
                threading.Thread(target=self._pump, args=(a, b), name=f"radio-{self.name}-pump", daemon=True).start()

    def _pump(self, src: socket.socket, dst: socket.socket) -> None:
        try:
            while True:
                data = src.recv(CHUNK)
                if not data:
                    break
                dst.sendall(data)
        except OSError:
            pass
        with self._lock:
            self._conns.discard(src)
            self._conns.discard(dst)
        _hang_up(src)
        _hang_up(dst)


class DatagramLink(_Relay):
    """One emulated datagram link: a loopback UDP relay to ``target`` that can be brought up and
    down. Each client address gets its own socket toward the target (a flow); replies go back to
    the client it belongs to."""

    def __init__(self, name: str, target: tuple[str, int], up: bool = True) -> None:
        super().__init__(name, target, up)
        self._flows: dict[tuple[str, int], socket.socket] = {}
        self._front = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._front.bind(("127.0.0.1", 0))
        self._front.settimeout(0.2)
        self.port = self._front.getsockname()[1]
        self._thread = threading.Thread(target=self._front_loop, name=f"radio-{name}", daemon=True)
        self._thread.start()

    def _cut(self) -> list[socket.socket]:
        doomed = list(self._flows.values())
        self._flows.clear()
        return doomed

    def close(self) -> None:
        self._closed.set()
        self.set_up(False)
        self._front.close()
        self._thread.join(2.0)

    def _front_loop(self) -> None:
        while not self._closed.is_set():
            try:
                data, client = self._front.recvfrom(CHUNK)
            except TimeoutError:
                continue
            except OSError:
                return
            with self._lock:
                if not self._up:
                    self.counters["dropped"] += 1
                    continue
                back = self._flows.get(client)
                if back is None:
                    back = self._flows[client] = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                    back.connect(self.target)
                    threading.Thread(target=self._back_loop, args=(back, client), name=f"radio-{self.name}-back",
                                     daemon=True).start()
                    self.counters["flows"] += 1
            try:
                back.send(data)
            except OSError:
                self.counters["target_unreachable"] += 1

    def _back_loop(self, back: socket.socket, client: tuple[str, int]) -> None:
        while True:
            try:
                data = back.recv(CHUNK)
            except OSError:  # closed by set_up(False) / close, or the target refused
                return
            if not self._up:
                self.counters["dropped"] += 1
                continue
            try:
                self._front.sendto(data, client)
            except OSError:
                return


def _hang_up(s: socket.socket) -> None:
    try:
        s.shutdown(socket.SHUT_RDWR)
    except OSError:
        pass
    try:
        s.close()
    except OSError:
        pass


def site_circles(fleet: Fleet, sites: Mapping[str, Mapping[str, Any]]) -> dict[str, list[Circle]]:
    """Each site's radio coverage: the circles of its ground stations."""
    out: dict[str, list[Circle]] = {}
    for site, info in sites.items():
        out[site] = [fleet.nodes[g].coverage.circle() for g in info.get("ground_stations", ())
                     if g in fleet.nodes and fleet.nodes[g].coverage is not None]
    return out


class SiteCoverage:
    """Brings each site's radio link up or down from the vehicle's true position."""

    def __init__(self, circles: Mapping[str, list[Circle]], links: Mapping[str, SwitchedLink],
                 on_change: Callable[[str, bool, GeoPoint], None] | None = None) -> None:
        self.circles = dict(circles)
        self.links = dict(links)
        self.on_change = on_change
        self.position: GeoPoint | None = None
        self.updates = 0
        self.jammed: set[str] = set()  # sites whose radio is held down whatever the position (a flap)
        self._lock = threading.Lock()

    def reaches(self, site: str, pos: GeoPoint) -> bool:
        return any(c.contains(pos) for c in self.circles.get(site, ()))

    def update(self, pos: GeoPoint) -> None:
        with self._lock:
            self.position = pos
            self.updates += 1
            self._apply(pos)

    def jam(self, site: str, jammed: bool) -> None:
        """Hold ``site``'s radio down (a radio-link flap), or let the position decide again."""
        with self._lock:
            (self.jammed.add if jammed else self.jammed.discard)(site)
            if self.position is not None:
                self._apply(self.position)
            elif jammed and site in self.links:
                self.links[site].set_up(False)

    def _apply(self, pos: GeoPoint) -> None:
        for site, link in self.links.items():
            inside = self.reaches(site, pos) and site not in self.jammed
            if link.set_up(inside):
                log.info("radio %s %s at %.6f,%.6f", site, "up" if inside else "down", pos.lat, pos.lon)
                if self.on_change is not None:
                    self.on_change(site, inside, pos)


class TruthReceiver:
    """Receives the simulator's true position (``zdrone sim --truth``) on a UDP port (loopback, or the
    host's end of the control link with ``--netns``) and
    hands each one to ``on_position`` (from its own thread). Undecodable datagrams are counted."""

    def __init__(self, on_position: Callable[[GeoPoint], None], host: str = "127.0.0.1") -> None:
        self.on_position = on_position
        self.host = host
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((host, 0))
        self.sock.settimeout(0.2)
        self.port: int = self.sock.getsockname()[1]
        self.counters: Counter[str] = Counter()
        self._closed = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="truth", daemon=True)
        self._thread.start()

    def _loop(self) -> None:
        while not self._closed.is_set():
            try:
                data = self.sock.recv(512)
            except TimeoutError:
                continue
            except OSError:
                return
            try:
                d = json.loads(data)
                pos = GeoPoint(float(d["lat"]), float(d["lon"]), float(d.get("alt", 0.0)))
            except (ValueError, KeyError, TypeError):
                self.counters["malformed"] += 1
                continue
            self.counters["positions"] += 1
            self.on_position(pos)

    def close(self) -> None:
        self._closed.set()
        self.sock.close()
        self._thread.join(2.0)
