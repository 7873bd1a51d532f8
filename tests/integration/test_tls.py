"""Mutual TLS on the router (``zdrone fleet init --tls``), tried from outside: a real router process,
real clients. Only a fleet certificate gets in, and only its own name's keys with it."""

from __future__ import annotations

import socket
import threading

import pytest

from tests.procs import ZDRONE, free_port, spawn
from zdrone.core.errors import ConfigError
from zdrone.fleet import keyexprs
from zdrone.fleet.files import init_fleet, load_secret
from zdrone.fleet.tls import TlsFiles, init_tls, node_files
from zdrone.net.session import open_client


@pytest.fixture()
def tls_router(tmp_path):
    fleet = tmp_path / "fleet"
    init_fleet(fleet, tls=True)
    ep = f"tls/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    with spawn(ZDRONE, "router", "-c", str(fleet / "router" / "router.json5"), "--listen", ep) as router:
        router.wait_line("listening", 20)
        yield fleet, ep


def _password(fleet, name: str) -> str:
    return load_secret(fleet, name).router_password


def _delivered(sender, receiver, key: str) -> bool:
    """Whether a put from ``sender`` on ``key`` reaches ``receiver`` (subscribed to it) within 3 s."""
    got = threading.Event()
    sub = receiver.declare_subscriber(key, lambda s: got.set())
    try:
        for _ in range(30):
            sender.put(key, b"x")
            if got.wait(0.1):
                return True
        return False
    finally:
        sub.undeclare()


def test_a_fleet_node_gets_in_and_reaches_its_peer(tls_router):
    fleet, ep = tls_router
    a = open_client(ep, "A", _password(fleet, "A"), node_files(fleet, "A"))
    d = open_client(ep, "d1", _password(fleet, "d1"), node_files(fleet, "d1"))
    try:
        assert _delivered(a, d, keyexprs.up_lane("d1", "A", 0))
    finally:
        a.close()
        d.close()


def test_no_certificate_or_another_cas_certificate_is_refused(tls_router, tmp_path):
    fleet, ep = tls_router
    with pytest.raises(ConfigError):  # a TLS endpoint without a certificate: refused before connecting
        open_client(ep, "A", _password(fleet, "A"))
    other = tmp_path / "other"
    init_fleet(other)
    init_tls(other, __import__("zdrone.fleet.files", fromlist=["load_fleet"]).load_fleet(other))
    foreign = node_files(other, "A")  # a certificate for "A" from another CA
    mixed = TlsFiles(node_files(fleet, "A").ca, foreign.cert, foreign.key)
    with pytest.raises(ConfigError):
        open_client(ep, "A", _password(fleet, "A"), mixed)


def test_a_stolen_password_with_another_nodes_certificate_speaks_on_no_key(tls_router):
    """X's real certificate with A's stolen password: the router's ACL wants CN A *and* user A."""
    fleet, ep = tls_router
    d = open_client(ep, "d1", _password(fleet, "d1"), node_files(fleet, "d1"))
    try:
        try:
            mallory = open_client(ep, "A", _password(fleet, "A"), node_files(fleet, "X"))
        except ConfigError:
            return  # refused at connect: as good
        try:
            assert not _delivered(mallory, d, keyexprs.up_lane("d1", "A", 0))
        finally:
            mallory.close()
    finally:
        d.close()
