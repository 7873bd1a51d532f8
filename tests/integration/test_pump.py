"""A pumped subscription (``zdrone.net.pump``) on a real Zenoh session over loopback: every sample
handed on, in order, in the pump's thread, while another thread holds the GIL busy; undeclared, the
pump ends; a handler that raises is counted and the pump goes on."""

from __future__ import annotations

import socket
import threading
import time

import zenoh

from tests.procs import free_port
from zdrone.net.pump import PUMP_BATCH, PumpedSubscriber


def _session() -> zenoh.Session:
    c = zenoh.Config()
    c.insert_json5("mode", '"peer"')
    c.insert_json5("listen/endpoints", f'["tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"]')
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("scouting/gossip/enabled", "false")
    return zenoh.open(c)


def test_every_sample_in_order_in_the_pumps_thread_while_the_loop_is_busy_and_the_pump_ends_when_undeclared():
    s = _session()
    got: list[int] = []
    threads: set[str] = set()
    n = 3 * PUMP_BATCH + 7  # several batches, the last one short
    done = threading.Event()

    def on_sample(smp) -> None:
        got.append(int(smp.payload.to_bytes()))
        threads.add(threading.current_thread().name)
        if int(smp.payload.to_bytes()) == 13:
            raise ValueError("a handler's bug")
        if len(got) == n:
            done.set()

    try:
        pump = PumpedSubscriber(s, "t/**", on_sample)
        busy_until = time.monotonic() + 0.5

        def busy() -> None:  # a node's loop holding the GIL in pure Python
            while time.monotonic() < busy_until:
                pass

        loop = threading.Thread(target=busy)
        loop.start()
        pub = s.declare_publisher("t/x")
        for i in range(n):
            pub.put(str(i).encode())
        loop.join()
        assert done.wait(10), len(got)
        assert got == list(range(n)) and threads == {"pump t/**"} and pump.errors == 1
        pump.undeclare()
        pump.thread.join(5)
        assert not pump.thread.is_alive()
    finally:
        s.close()
