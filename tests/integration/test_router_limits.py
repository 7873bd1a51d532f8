"""The router's size limit holds for a client on the same host (no shared-memory way around it)."""

from __future__ import annotations

import socket
import threading

from tests.procs import ZDRONE, free_port, spawn
from zdrone.fleet.files import init_fleet, load_secret
from zdrone.fleet import keyexprs as kx
from zdrone.net.session import open_client


def test_a_message_over_64_kib_is_dropped_and_the_sender_stays_connected(tmp_path):
    init_fleet(tmp_path / "fleet")
    port = free_port(socket.SOCK_STREAM)
    ep = f"tcp/127.0.0.1:{port}"
    with spawn(ZDRONE, "router", "-c", str(tmp_path / "fleet" / "router" / "router.json5"), "--listen", ep) as router:
        router.wait_line("listening", 20)
        fleet = tmp_path / "fleet"
        a = open_client(ep, "A", load_secret(fleet, "A").router_password)
        d = open_client(ep, "d1", load_secret(fleet, "d1").router_password)
        got: list[int] = []
        small = threading.Event()
        sub = d.declare_subscriber(kx.up("d1", "A"), lambda s: (got.append(len(s.payload)),
                                                                small.set() if len(s.payload) == 500 else None))
        try:
            for _ in range(50):  # until the route exists
                a.put(kx.up("d1", "A"), b"p" * 10)
                if got:
                    break
                threading.Event().wait(0.1)
            assert got, "no route from A to the drone"
            a.put(kx.up("d1", "A"), b"x" * 70_000)
            a.put(kx.up("d1", "A"), b"y" * 500)
            assert small.wait(10.0), "the small message after the big one never arrived"
            assert 70_000 not in got
        finally:
            sub.undeclare()
            a.close()
            d.close()
