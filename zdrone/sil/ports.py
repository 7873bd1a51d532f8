"""TESTBED ONLY: ports for the listeners a run starts (routers, simulators, gateways).

A port the kernel hands out (``bind(("127.0.0.1", 0))``) comes from its ephemeral range, the same range
every outgoing connection of every process takes its local port from: between the choice and the
child's own bind, any connection on the machine may take it (the more runs at once, the likelier).
``free_port`` chooses below that range instead, where only another explicit choice can land, and
checks that the port is free now, for TCP and UDP alike (a site router takes both on one port).
"""

from __future__ import annotations

import random
import socket
from pathlib import Path

#: How many ports below the ephemeral range the choice is made from.
SPAN = 12000
#: The lowest port ever chosen (below: well-known and registered services).
LOWEST = 10000
_EPHEMERAL = Path("/proc/sys/net/ipv4/ip_local_port_range")


def _range() -> range | None:
    """Ports to choose from: the SPAN ports below the kernel's ephemeral range (None: unknown)."""
    try:
        low = int(_EPHEMERAL.read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return None
    start = max(LOWEST, low - SPAN)
    return range(start, low) if low - start >= 1000 else None


def _bindable(kind: int, port: int) -> bool:
    with socket.socket(socket.AF_INET, kind) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
        return True


def free_port(kind: int = socket.SOCK_DGRAM) -> int:
    """A port on 127.0.0.1 free now for sockets of type ``kind``, outside the ephemeral range where
    the kernel knows it (else the kernel's own choice)."""
    ports = _range()
    if ports is not None:
        rng = random.SystemRandom()
        for _ in range(100):
            port = rng.choice(ports)
            # free for both kinds: a site router listens on one port for TLS (TCP) and QUIC (UDP), and a
            # simulator's or relay's UDP socket on it made a router fail to start (CI, twice)
            if _bindable(socket.SOCK_STREAM, port) and _bindable(socket.SOCK_DGRAM, port):
                return port
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]
