"""Sessions per credential: what K parallel sessions holding one node's credentials get through the
router toward a drone (a part of ``zdrone bench attack``; ``tests/integration/test_router_limits.py``
flies the same trial).

One trial: a fleet, its router (mutual TLS: a node is its certificate *and* its password; or a
password alone), a session of the drone d1 subscribed to every uplink lane, and a session of GS A
sending a frame every 20 ms on its lanes in turn. A flooder process opens K sessions with ``who``'s
credentials and, for ``seconds``, puts junk on every lane of ``up/<who>`` toward d1 from every
session as fast as it can, a third of it 1 000-byte envelopes (over the uplink's size limit). It
counts what reached d1 of the junk and of A's frames, and the largest envelope that did. Counts, not
speed: how fast the flood went is the machine's.
"""

from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any, Iterator

from zdrone.sil.procs import wait_line

#: The flooder: K sessions as one node, every lane of its uplink to d1, as fast as they can.
FLOODER = """
import sys, time, zenoh
from zdrone.fleet import keyexprs
from zdrone.fleet.files import load_secret
from zdrone.fleet.tls import node_files
from zdrone.net.session import open_client
router, fleet, who, seconds, k = sys.argv[1], sys.argv[2], sys.argv[3], float(sys.argv[4]), int(sys.argv[5])
tls = node_files(fleet, who) if router.startswith("tls/") else None
sessions = [open_client(router, who, load_secret(fleet, who).router_password, tls) for _ in range(k)]
lanes = keyexprs.up_lanes("d1", who)
small, big = b"j" * 40, b"J" * 1000
print("flooding", flush=True)
n, t0 = 0, time.monotonic()
while time.monotonic() - t0 < seconds:
    for i in range(496):
        # every lane from every session; a third of the frames big
        sessions[(i // len(lanes)) % len(sessions)].put(lanes[i % len(lanes)], big if i % 3 == 0 else small,
                                                        congestion_control=zenoh.CongestionControl.DROP)
    n += 496
print("sent", n, round(time.monotonic() - t0, 3), flush=True)
for s in sessions:
    s.close()
"""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def _child(args: list[str]) -> Iterator[subprocess.Popen]:
    from zdrone.sil.procs import forget, spawn

    proc = spawn(args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        yield proc
    finally:
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(5)
        forget(proc)


@contextlib.contextmanager
def router_with_d1_and_a(base: Path, tls: bool = False) -> Iterator[tuple[Path, str, Any, Any]]:
    """A fleet's router on a free port (with ``tls``: mutual TLS), with sessions of the drone d1 and of
    GS A (closed after): (fleet directory, endpoint, d1's session, A's session)."""
    from zdrone.fleet.files import init_fleet, load_secret
    from zdrone.fleet.tls import node_files
    from zdrone.net.session import open_client

    fleet = base / "fleet"
    init_fleet(fleet, tls=tls)
    ep = f"{'tls' if tls else 'tcp'}/127.0.0.1:{_free_port()}"

    def client(name: str) -> Any:
        return open_client(ep, name, load_secret(fleet, name).router_password, node_files(fleet, name) if tls else None)

    with _child([sys.executable, "-m", "zdrone", "router", "-c", str(fleet / "router" / "router.json5"),
                 "--listen", ep]) as router:
        wait_line(router, "listening", 20)
        d, a = client("d1"), client("A")
        try:
            yield fleet, ep, d, a
        finally:
            a.close()
            d.close()


def flood_trial(base: Path, tls: bool, who: str, k: int, seconds: float = 2.0) -> dict[str, Any]:
    """One trial (see the module's text): K sessions of ``who`` flood ``who``'s lanes to d1."""
    import zenoh

    from zdrone.fleet import keyexprs

    base.mkdir(parents=True, exist_ok=True)
    with router_with_d1_and_a(base, tls) as (fleet, ep, d, a):
        got: dict[str, list[tuple[float, bytes]]] = {"A": [], who: []}
        lock = threading.Lock()

        def on_sample(s: Any) -> None:
            with lock:
                got.setdefault(keyexprs.gs_of_uplink(s.key_expr), []).append((time.monotonic(), s.payload.to_bytes()))

        subs = [d.declare_subscriber(lane, on_sample) for lane in keyexprs.up_lanes("d1", "*")]
        lanes = keyexprs.up_lanes("d1", "A")
        tick = threading.Event()
        try:
            deadline = time.monotonic() + 5.0
            while not got["A"]:  # until the route exists
                if time.monotonic() > deadline:
                    raise RuntimeError("no route from A to the drone")
                a.put(lanes[0], b"r")
                tick.wait(0.05)
            with _child([sys.executable, "-c", FLOODER, ep, str(fleet), who, str(seconds), str(k)]) as flooder:
                wait_line(flooder, "flooding", 30)
                t0, sent_a = time.monotonic(), 0
                with lock:
                    for v in got.values():
                        v.clear()
                while flooder.poll() is None and time.monotonic() - t0 < seconds + 10.0:
                    tick.wait(0.02)  # A's pace: a frame every 20 ms while the flood lasts
                    a.put(lanes[sent_a % len(lanes)], b"a" * 40, priority=zenoh.Priority.INTERACTIVE_HIGH)
                    sent_a += 1
                    if time.monotonic() - t0 > seconds:
                        break
                _, n, took = wait_line(flooder, "sent", 20).split()
            last = -1
            while True:  # the last samples in flight: until the count stops growing
                tick.wait(0.15)
                with lock:
                    now = sum(len(v) for v in got.values())
                if now == last:
                    break
                last = now
            with lock:
                frames = [(g, p) for g, v in got.items() for t, p in v if t >= t0]
        finally:
            for sub in subs:
                sub.undeclare()
    junk = [p for _, p in frames if p[:1] in (b"j", b"J")]
    return {"tls": tls, "who": who, "sessions": k, "sent": int(n), "seconds": float(took), "junk_reached": len(junk),
            "junk_per_s": round(len(junk) / float(took), 1), "big_reached": sum(1 for p in junk if len(p) > 40),
            "a_sent": sent_a, "a_reached": sum(1 for g, p in frames if g == "A" and p == b"a" * 40),
            "largest_reached": max((len(p) for _, p in frames), default=0)}


def run(ks: tuple[int, ...] = (1, 4, 16), progress: Any = None) -> list[dict[str, Any]]:
    """K sessions with B's certificate and password (mutual TLS: one budget per credential), and K
    sessions of a thief with A's password alone (no TLS: one budget per session, never A's)."""
    base = Path(tempfile.mkdtemp(prefix="zdrone-bench-sessions-"))
    rows = []
    for tls, who in ((True, "B"), (False, "A")):
        for k in ks:
            if progress is not None:
                progress(f"{k} sessions as {who} ({'TLS' if tls else 'password only'})")
            rows.append(flood_trial(base / f"{'tls' if tls else 'tcp'}-{who}-{k}-{os.getpid()}", tls, who, k))
    return rows
