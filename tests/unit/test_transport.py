"""UDP listeners cannot be taken over: the simulator's and the GCS gateway's ``udpin:`` sockets
(``MavTransport``) are bound without SO_REUSEADDR, so a second bind of their port fails, even one that
sets it (with it on both, Linux lets the second socket share the port and gives it the unicast
datagrams: a process of the same user absorbed the companion's commands to the autopilot)."""

from __future__ import annotations

import socket

import pytest

from zdrone.core.fleet import ConfigError
from zdrone.sil.ports import free_port
from zdrone.vehicle.transport import MavTransport, bind_udp


def _free_udp() -> int:
    return free_port(socket.SOCK_DGRAM)  # below the ephemeral range: no outgoing socket takes it meanwhile


def test_a_udp_listener_port_cannot_be_bound_a_second_time():
    port = _free_udp()
    t = MavTransport(f"udpin:127.0.0.1:{port}")
    try:
        thief = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        thief.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        with pytest.raises(OSError):
            thief.bind(("127.0.0.1", port))
        thief.close()
        with pytest.raises(ConfigError):
            MavTransport(f"udpin:127.0.0.1:{port}")
        with pytest.raises(OSError):
            bind_udp("127.0.0.1", port)
    finally:
        t.close()


def test_the_control_two_sockets_with_so_reuseaddr_share_a_port_and_the_last_one_takes_it():
    """What the listeners did before: both set SO_REUSEADDR, the second bind succeeds and receives."""
    first = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    second = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        for s in (first, second):
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.settimeout(0.5)
        first.bind(("127.0.0.1", 0))
        second.bind(first.getsockname())  # the takeover
        sender.sendto(b"for the first", first.getsockname())
        assert second.recv(100) == b"for the first"
    finally:
        for s in (first, second, sender):
            s.close()
