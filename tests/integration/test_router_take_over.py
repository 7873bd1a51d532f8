"""A router restarted the way docs/deploy.md's rolling restart says: ``zdrone router --take-over``
started beside the running one waits for the port while the old one keeps serving, takes it once the
old one ends (SIGTERM), and the clients' sessions come back through it; a router that can never get
the port fails with one line and exit code 2."""

from __future__ import annotations

import itertools
import socket
import threading

from tests.procs import ZDRONE, free_port, spawn, wait_until
from zdrone.fleet import keyexprs
from zdrone.fleet.files import init_fleet, load_secret
from zdrone.fleet.tls import node_files
from zdrone.net.router import TAKE_OVER_LINE
from zdrone.net.session import open_client


def test_a_router_started_beside_the_running_one_takes_its_port_when_it_ends_and_the_clients_come_back(tmp_path):
    fleet = tmp_path / "fleet"
    init_fleet(fleet, tls=True)
    ep = f"tls/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    router = [ZDRONE, "router", "-c", str(fleet / "router" / "router.json5"), "--listen", ep]
    with spawn(*router) as old:
        old.wait_line("listening", 20)
        d, a = (open_client(ep, n, load_secret(fleet, n).router_password, node_files(fleet, n)) for n in ("d1", "A"))
        got: list[int] = []
        sub = d.declare_subscriber(keyexprs.up_lane("d1", "A", 0), lambda s: got.append(int(s.payload.to_bytes())))
        sent = itertools.count()
        last_sent = [0]
        stop = threading.Event()

        def publish() -> None:  # A's uplink, a numbered frame every 20 ms, whatever the router does
            while not stop.wait(0.02):
                last_sent[0] = next(sent)
                a.put(keyexprs.up_lane("d1", "A", 0), str(last_sent[0]).encode())

        pub = threading.Thread(target=publish, daemon=True)
        pub.start()
        try:
            assert wait_until(lambda: got, 10.0), "no route from A to the drone"
            with spawn(*router, "--take-over", "30") as new:
                new.wait_line(TAKE_OVER_LINE, 20)
                n = len(got)
                assert wait_until(lambda: len(got) >= n + 5, 10.0), "the old router stopped serving"
                assert new.p.poll() is None and not any("listening" in line for line in new.lines), \
                    "the new router listens while the old one holds the port"
                assert old.stop() == 0
                mark = last_sent[0]  # sent after the old router was gone: only the new one can carry it
                new.wait_line("listening", 20)
                assert wait_until(lambda: any(x > mark for x in got), 20.0), "the clients did not come back"
                order = [line for line in new.lines if TAKE_OVER_LINE in line or "listening" in line]
                assert TAKE_OVER_LINE in order[0] and "listening" in order[-1]

                with spawn(*router, "--take-over", "1") as third:  # the new one never lets go
                    assert wait_until(lambda: third.p.poll() is not None, 30.0), "a router waiting for ever"
                    assert third.p.returncode == 2
                    errors = [line for line in third.lines if "error" in line.lower()]
                    assert len(errors) == 1 and "could not listen" in errors[0], third.lines
                    assert not any("Traceback" in line for line in third.lines)
                n = len(got)
                assert wait_until(lambda: len(got) > n, 10.0), "the new router stopped serving"
        finally:
            stop.set()
            pub.join(2)
            sub.undeclare()
            a.close()
            d.close()
