"""MAVLink byte transports over UDP and TCP, select()-driven, for the simulator and GCS gateway.

Connection strings (pymavlink style, ``//`` after the colon optional):

* ``udpin:HOST:PORT`` (or ``udp:``): listen; answer every address that has talked to us, and the
  fixed ``peers`` given to ``MavTransport`` (e.g. PX4's onboard link: listen on 14580, send to 14540).
* ``udpout:HOST:PORT``: send to HOST:PORT, receive its answers.
* ``tcpin:HOST:PORT``: listen for TCP clients (several at once).
* ``tcp:HOST:PORT`` (or ``tcpout:``): connect to a TCP server.

A UDP listener is bound without ``SO_REUSEADDR`` (``bind_udp``): on Linux two UDP sockets that both set
it may share a port, and unicast datagrams then go to the one bound last, so any process of the same
user could take the port over from under a listener (the simulator's, the GCS gateway's, the
companion's vehicle link) and absorb what is sent to it. Without it a second bind fails
(``EADDRINUSE``), whatever the second socket sets.
"""

from __future__ import annotations

import logging
import selectors
import socket
import time
from dataclasses import dataclass

from zdrone.core.fleet import ConfigError
from zdrone.core.mavlink import split_frames

log = logging.getLogger(__name__)
PEER_TIMEOUT_S = 30.0


def bind_udp(host: str, port: int) -> socket.socket:
    """A UDP socket bound to ``host:port`` for listening, without ``SO_REUSEADDR`` (nobody else can
    bind the port while it is open). Raises ``OSError`` (``EADDRINUSE``) if the port is taken."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 0)
        s.bind((host, port))
    except OSError:
        s.close()
        raise
    return s


@dataclass(frozen=True, slots=True)
class Endpoint:
    kind: str  # udpin | udpout | tcpin | tcpout
    host: str
    port: int

    def __str__(self) -> str:
        return f"{self.kind}:{self.host}:{self.port}"


def parse_endpoint(text: str) -> Endpoint:
    """Parse a connection string; ``ConfigError`` with one line if it is not one we speak."""
    kinds = {"udpin": "udpin", "udp": "udpin", "udpout": "udpout", "tcpin": "tcpin", "tcp": "tcpout", "tcpout": "tcpout"}
    scheme, sep, rest = text.partition(":")
    rest = rest.removeprefix("//")
    host, _, port = rest.rpartition(":")
    if not sep or scheme not in kinds or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ConfigError(f"connection {text!r}: expected udpin:|udpout:|tcpin:|tcp:HOST:PORT")
    return Endpoint(kinds[scheme], host, int(port))


class MavTransport:
    """One MAVLink endpoint. ``poll`` returns whole frames with an opaque peer id."""

    def __init__(self, conn: str | Endpoint, peers: tuple[tuple[str, int], ...] = ()) -> None:
        self.endpoint = conn if isinstance(conn, Endpoint) else parse_endpoint(conn)
        ep = self.endpoint
        if peers and ep.kind != "udpin":
            raise ConfigError(f"connection {ep}: fixed peers need a udpin: endpoint")
        self.sel = selectors.DefaultSelector()
        self.udp_peers: dict[tuple, float] = {}
        self.tcp_clients: dict[socket.socket, bytes] = {}
        self.listener: socket.socket | None = None
        self.sock: socket.socket | None = None
        self.rx_frames = 0
        self.tx_frames = 0
        self.skipped_bytes = 0  # bytes that were not part of any valid frame (counted, never silent)
        try:
            if ep.kind in ("udpin", "udpout"):
                if ep.kind == "udpin":
                    s = bind_udp(ep.host, ep.port)  # no SO_REUSEADDR: nobody binds the port after us
                    for host, port in peers:  # sent to from the start, whether or not they ever talk
                        self.udp_peers[(socket.gethostbyname(host), port)] = float("inf")
                else:
                    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                    s.bind(("127.0.0.1" if ep.host.startswith("127.") or ep.host == "localhost" else "", 0))
                    self.udp_peers[(socket.gethostbyname(ep.host), ep.port)] = float("inf")
                s.setblocking(False)
                self.sock = s
                self.sel.register(s, selectors.EVENT_READ, "udp")
            elif ep.kind == "tcpin":
                s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
                s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                s.bind((ep.host, ep.port))
                s.listen(8)
                s.setblocking(False)
                self.listener = s
                self.sel.register(s, selectors.EVENT_READ, "accept")
            else:
                s = socket.create_connection((ep.host, ep.port), timeout=5.0)
                s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                s.setblocking(False)
                self.tcp_clients[s] = b""
                self.sel.register(s, selectors.EVENT_READ, "tcp")
        except OSError as exc:
            self.close()
            raise ConfigError(f"connection {ep}: {exc.strerror or exc}") from None

    @property
    def port(self) -> int:
        """The local port (useful with port 0)."""
        s = self.sock or self.listener
        return s.getsockname()[1] if s else self.endpoint.port

    def has_peer(self) -> bool:
        return bool(self.udp_peers) or bool(self.tcp_clients)

    def poll(self, timeout: float) -> list[tuple[bytes, object]]:
        """Wait up to ``timeout`` seconds; return received frames as (frame, peer)."""
        out: list[tuple[bytes, object]] = []
        for key, _ in self.sel.select(timeout):
            tag, s = key.data, key.fileobj
            if tag == "udp":
                for _ in range(256):
                    try:
                        data, addr = s.recvfrom(65535)  # type: ignore[union-attr]
                    except (BlockingIOError, InterruptedError):
                        break
                    except ConnectionRefusedError:  # ICMP port unreachable (a peer not listening): reported
                        continue  # once per error, so read on; the datagrams behind it are still queued
                    except OSError:
                        break
                    self.udp_peers[addr] = max(self.udp_peers.get(addr, 0.0), time.monotonic())
                    frames, rest, skipped = split_frames(data)
                    self.skipped_bytes += skipped + len(rest)
                    out += [(f, addr) for f in frames]
            elif tag == "accept":
                try:
                    conn, addr = s.accept()  # type: ignore[union-attr]
                except OSError:
                    continue
                conn.setblocking(False)
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                self.tcp_clients[conn] = b""
                self.sel.register(conn, selectors.EVENT_READ, "tcp")
                log.info("tcp client %s connected", addr)
            else:
                try:
                    data = s.recv(65536)  # type: ignore[union-attr]
                except (BlockingIOError, InterruptedError):
                    continue
                except OSError:
                    data = b""
                if not data:
                    self._drop_client(s)  # type: ignore[arg-type]
                    continue
                frames, rest, skipped = split_frames(self.tcp_clients.get(s, b"") + data)  # type: ignore[arg-type]
                self.skipped_bytes += skipped
                self.tcp_clients[s] = rest[-4096:]  # type: ignore[index]
                out += [(f, s) for f in frames]
        self.rx_frames += len(out)
        now = time.monotonic()
        for addr, seen in list(self.udp_peers.items()):
            if now - seen > PEER_TIMEOUT_S:
                del self.udp_peers[addr]
        return out

    def _drop_client(self, s: socket.socket) -> None:
        self.tcp_clients.pop(s, None)
        try:
            self.sel.unregister(s)
        except (KeyError, ValueError):
            pass
        s.close()

    def send(self, frame: bytes, peer: object | None = None) -> None:
        """Send one frame to ``peer``, or to every known peer."""
        self.tx_frames += 1
        if self.sock is not None:
            targets = [peer] if peer is not None else list(self.udp_peers)
            for addr in targets:
                try:
                    self.sock.sendto(frame, addr)  # type: ignore[arg-type]
                except OSError:
                    pass
            return
        clients = [peer] if peer is not None else list(self.tcp_clients)
        for c in clients:
            try:
                c.sendall(frame)  # type: ignore[union-attr]
            except OSError:
                self._drop_client(c)  # type: ignore[arg-type]

    def close(self) -> None:
        for s in [self.sock, self.listener, *self.tcp_clients]:
            if s is not None:
                try:
                    self.sel.unregister(s)
                except (KeyError, ValueError):
                    pass
                s.close()
        self.tcp_clients.clear()
        self.sel.close()
