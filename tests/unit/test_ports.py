"""The testbed's listener ports come from below the kernel's ephemeral range, free when chosen."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

from zdrone.sil import ports
from zdrone.sil.ports import free_port


@pytest.mark.parametrize("kind", [socket.SOCK_STREAM, socket.SOCK_DGRAM])
def test_a_port_below_the_ephemeral_range_free_to_bind(kind):
    low = int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    chosen = {free_port(kind) for _ in range(20)}
    assert all(max(ports.LOWEST, low - ports.SPAN) <= p < low for p in chosen) and len(chosen) > 10
    for p in chosen:
        with socket.socket(socket.AF_INET, kind) as s:
            s.bind(("127.0.0.1", p))


def test_a_port_held_is_never_chosen_and_without_the_range_the_kernel_chooses(monkeypatch):
    held = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    held.bind(("127.0.0.1", 0))
    try:
        port = held.getsockname()[1]
        monkeypatch.setattr(ports, "_range", lambda: range(port, port + 1))  # only the held one to choose
        other = free_port(socket.SOCK_STREAM)
        assert other != port and other > 0
        monkeypatch.undo()
        monkeypatch.setattr(ports, "_EPHEMERAL", Path("/nonexistent"))
        assert ports._range() is None and free_port(socket.SOCK_STREAM) > 0
    finally:
        held.close()


def test_a_port_held_by_udp_is_never_chosen_for_tcp(monkeypatch):
    """A site router listens for TLS (TCP) and QUIC (UDP) on one port: a TCP choice must be free for UDP too
    (a simulator's UDP socket on the port a router was given stopped it starting: ``Address already in use``)."""
    held = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    held.bind(("127.0.0.1", 0))
    try:
        port = held.getsockname()[1]
        monkeypatch.setattr(ports, "_range", lambda: range(port, port + 1))
        assert free_port(socket.SOCK_STREAM) != port
    finally:
        held.close()
