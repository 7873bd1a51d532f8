"""TESTBED ONLY: the load of ``zdrone bench view``'s attack part, each in a process of its own (so the
bench process, which drives the real page and samples the view, does not share its interpreter with it):

``python -m zdrone.bench.viewload clients --port P --n N --stats FILE``: ``N`` clients of the view's picture
stream (``GET /api/stream``, the page's own request with the ``Host`` a browser sends to a loopback view),
each on a raw asyncio socket that reads and discards whatever comes. A client whose stream is refused (503:
the server serves ``MAX_STREAMS`` at most), cut (the server holds ``MAX_CONNECTIONS`` at most) or ended tries
again after ``--retry`` seconds (an attacker keeps the pressure on; a browser's ``EventSource`` would retry a
cut stream only). Its own open-file limit is raised to hold them all.

``python -m zdrone.bench.viewload forge --fleet DIR --router EP --rate R --stats FILE``: GS X (in the fleet,
authorized for no drone) with its own static key and router password, as ``ops-unauthorized``
(``zdrone.sil.attackers.ops``): parts sealed for the viewer with X's key (so each opens there), saying d1 is in
its failsafe held by X, and naming ``d99`` (no drone of the fleet: the viewer counts each of X's parts that
reached it as one ``unknown_drone``), ``R`` parts a second, part after part on X's lanes in turn.

``python -m zdrone.bench.viewload halfopen --port P --n N --send head|hello|nothing --stats FILE``: ``N``
connections from one address (``--source``, e.g. 127.0.0.2: another host as the server sees it) that each
send half of something and then nothing more: half a request head (``head``: no token, never ended), half a
TLS ClientHello (``hello``) or nothing at all (``nothing``; ``mixed``: every other one half a ClientHello),
each reopened as soon as the server cuts it (at most ``--rate`` connects a second in all; 0: no limit). It
prints ``viewload halfopen: ready`` once every one of the ``N`` was open and had sent its half.

Each writes a JSON line of its counters to ``--stats`` every second and a last one when it ends
(SIGTERM or ``--duration``).
"""

from __future__ import annotations

import argparse
import asyncio
import errno
import json
import os
import random
import selectors
import signal
import socket
import struct
import sys
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any

#: Seconds a client waits before trying again after its stream was refused, cut or ended.
RETRY_S = 1.0
#: Seconds a client gives the server to accept its connection and to answer its request.
CONNECT_TIMEOUT_S = 10.0
#: The forger publishes what is due every this many seconds.
FORGE_TICK_S = 0.01


class StatsFile:
    """A JSON line of counters appended to ``path`` (the bench reads the last one)."""

    def __init__(self, path: str) -> None:
        self.path = Path(path)
        self.path.write_text("")

    def write(self, stats: dict[str, Any]) -> None:
        with open(self.path, "a") as f:
            f.write(json.dumps({"t": round(time.time(), 3), **stats}) + "\n")


def last_stats(path: Path) -> dict[str, Any] | None:
    """The last whole line of a stats file (None: none yet)."""
    try:
        lines = path.read_text().splitlines()
    except OSError:
        return None
    for line in reversed(lines):
        try:
            return json.loads(line)
        except ValueError:
            continue
    return None


def stats_lines(path: Path) -> list[dict[str, Any]]:
    """Every whole line of a stats file (none yet: empty)."""
    try:
        lines = path.read_text().splitlines()
    except OSError:
        return []
    out = []
    for line in lines:
        try:
            out.append(json.loads(line))
        except ValueError:
            continue
    return out


def raise_nofile(want: int) -> int:
    """This process's soft open-file limit raised to ``want`` (at most the hard one); the limit in force."""
    import resource

    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    target = want if hard == resource.RLIM_INFINITY else min(want, hard)
    if soft != resource.RLIM_INFINITY and soft < target:
        resource.setrlimit(resource.RLIMIT_NOFILE, (target, hard))
        soft = target
    return soft


# ------------------------------------------------------------------ the stream clients
class Clients:
    """``n`` stream clients on ``host:port``; counters of what they got."""

    def __init__(self, host: str, port: int, n: int, retry: float) -> None:
        self.host, self.port, self.n, self.retry = host, port, n, retry
        self.request = (f"GET /api/stream HTTP/1.1\r\nHost: {host}:{port}\r\nAccept: text/event-stream\r\n"
                        f"Cache-Control: no-cache\r\nUser-Agent: zdrone-bench-viewload\r\n\r\n").encode()
        self.open = 0  # connections open now (connected, whatever the server answered or not yet)
        self.streaming = 0  # of which: a 200 stream, receiving
        self.c: dict[str, int] = {"attempts": 0, "connect_failed": 0, "served": 0, "streamed": 0, "refused_503": 0,
                                  "other_status": 0, "cut_before_answer": 0, "stream_ended": 0, "bytes": 0}
        self.first_round = 0  # clients that made their first attempt

    def stats(self) -> dict[str, Any]:
        return {"n": self.n, "open": self.open, "streaming": self.streaming, "first_round": self.first_round, **self.c}

    async def one(self, stopping: asyncio.Event, delay: float) -> None:
        await asyncio.sleep(delay)
        first = True
        while not stopping.is_set():
            self.c["attempts"] += 1
            if first:
                self.first_round += 1
                first = False
            try:
                reader, writer = await asyncio.wait_for(asyncio.open_connection(self.host, self.port), CONNECT_TIMEOUT_S)
            except (OSError, asyncio.TimeoutError):
                self.c["connect_failed"] += 1
                await self._pause(stopping)
                continue
            self.open += 1
            try:
                await self._talk(reader, writer, stopping)
            except (OSError, asyncio.TimeoutError, asyncio.IncompleteReadError, asyncio.LimitOverrunError):
                pass
            finally:
                self.open -= 1
                writer.transport.abort()
            await self._pause(stopping)

    async def _talk(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, stopping: asyncio.Event) -> None:
        writer.write(self.request)
        try:
            head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), CONNECT_TIMEOUT_S)
        except (asyncio.IncompleteReadError, ConnectionError):
            self.c["cut_before_answer"] += 1
            return
        status = head.split(b" ", 2)[1] if head.count(b" ") >= 2 else b""
        if status != b"200":
            self.c["refused_503" if status == b"503" else "other_status"] += 1
            return
        self.c["served"] += 1
        self.streaming += 1
        got = False
        try:
            while not stopping.is_set():
                data = await reader.read(65536)
                if not data:
                    self.c["stream_ended"] += 1
                    return
                self.c["bytes"] += len(data)
                if not got:
                    got = True
                    self.c["streamed"] += 1
        finally:
            self.streaming -= 1

    async def _pause(self, stopping: asyncio.Event) -> None:
        try:
            await asyncio.wait_for(stopping.wait(), self.retry * (0.5 + random.random()))
        except asyncio.TimeoutError:
            pass


async def _run_clients(args: argparse.Namespace, stats: StatsFile) -> None:
    clients = Clients(args.host, args.port, args.n, args.retry)
    stopping = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stopping.set)
    # the clients arrive over ``--ramp`` seconds (not all in one instant: a backlog of SYNs is not the test)
    tasks = [asyncio.create_task(clients.one(stopping, args.ramp * i / max(1, args.n))) for i in range(args.n)]
    end = time.monotonic() + args.duration
    print(f"viewload clients: {args.n} on {args.host}:{args.port}", flush=True)
    while not stopping.is_set() and time.monotonic() < end:
        try:
            await asyncio.wait_for(stopping.wait(), 1.0)
        except asyncio.TimeoutError:
            pass
        stats.write(clients.stats())
    stopping.set()
    for t in tasks:
        t.cancel()
    await asyncio.gather(*tasks, return_exceptions=True)
    stats.write({**clients.stats(), "ended": True})


# ------------------------------------------------------------------ half-open connections
#: What a half-open connection sends once connected (``halfopen --send``).
SENDS = ("head", "hello", "nothing", "mixed")


def half_client_hello(server_name: str = "view.test") -> bytes:
    """The first half of a real TLS ClientHello (this Python's own): the server waits for the rest."""
    import ssl

    ctx = ssl.create_default_context()
    ctx.check_hostname, ctx.verify_mode = False, ssl.CERT_NONE
    out = ssl.MemoryBIO()
    obj = ctx.wrap_bio(ssl.MemoryBIO(), out, server_hostname=server_name)
    try:
        obj.do_handshake()
    except ssl.SSLWantReadError:
        pass
    hello = out.read()
    return hello[: max(6, len(hello) // 2)]


def half_head(host: str) -> bytes:
    """Half a request head, no token, never ended (no blank line)."""
    return f"GET / HTTP/1.1\r\nHost: {host}\r\nUser-Agent: zdrone-bench-viewload\r\nAccept: text/ht".encode()


class HalfOpen:
    """``n`` connections to ``host:port`` from ``source`` that each send ``payloads[i % len]`` once
    connected and then wait; one the server cuts (or answers) is closed (a reset: no TIME_WAIT) and
    opened again at once, at most ``rate`` connects a second in all (0: no limit). One thread, non-blocking
    sockets."""

    def __init__(self, host: str, port: int, n: int, source: str, payloads: list[bytes], rate: float) -> None:
        self.host, self.port, self.n, self.source, self.payloads, self.rate = host, port, n, source, payloads, rate
        self.held = 0  # connected, its half sent, not cut yet
        self.c: dict[str, int] = {"attempts": 0, "connected": 0, "cut": 0, "answered": 0, "connect_failed": 0}
        self.ever: set[int] = set()  # slots that were once connected with their half sent
        self.held_max = 0

    def stats(self) -> dict[str, Any]:
        return {"n": self.n, "held": self.held, "held_max": self.held_max, "first_round": len(self.ever), **self.c}

    def _open(self, sel: selectors.BaseSelector, slot: int) -> bool:
        self.c["attempts"] += 1
        s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        try:
            s.setblocking(False)
            s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))  # close = reset
            if hasattr(socket, "IP_BIND_ADDRESS_NO_PORT"):  # the port chosen at connect, per destination
                s.setsockopt(socket.IPPROTO_IP, socket.IP_BIND_ADDRESS_NO_PORT, 1)
            s.bind((self.source, 0))
            err = s.connect_ex((self.host, self.port))
        except OSError:
            s.close()
            self.c["connect_failed"] += 1
            return False
        if err not in (0, errno.EINPROGRESS):
            s.close()
            self.c["connect_failed"] += 1
            return False
        sel.register(s, selectors.EVENT_WRITE, (slot, False))
        return True

    def _done(self, sel: selectors.BaseSelector, s: socket.socket, held: bool) -> None:
        sel.unregister(s)
        s.close()
        if held:
            self.held -= 1

    def run(self, stop: threading.Event, deadline: float, stats: StatsFile) -> None:
        sel = selectors.DefaultSelector()
        due: deque[int] = deque(range(self.n))  # slots to open (again)
        tokens, last = 1.0, time.monotonic()
        next_stats = last + 1.0
        ready = False
        try:
            while not stop.is_set():
                now = time.monotonic()
                if now >= deadline:
                    break
                if self.rate > 0:
                    tokens = min(max(1.0, self.rate / 10), tokens + (now - last) * self.rate)
                last = now
                failed = 0
                while due and (self.rate <= 0 or tokens >= 1.0) and failed < 8:
                    slot = due.popleft()
                    tokens -= 1.0
                    if not self._open(sel, slot):
                        due.append(slot)
                        failed += 1
                wait = 0.05 if not due else 0.01 if failed or self.rate > 0 else 0.0
                for key, _ in sel.select(wait) if sel.get_map() else ():
                    s, (slot, held) = key.fileobj, key.data
                    if not held:  # connected (or not)
                        if s.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR) != 0:
                            self.c["connect_failed"] += 1
                            self._done(sel, s, False)
                            due.append(slot)
                            continue
                        payload = self.payloads[slot % len(self.payloads)]
                        try:
                            if payload:
                                s.send(payload)
                        except OSError:
                            self.c["cut"] += 1
                            self._done(sel, s, False)
                            due.append(slot)
                            continue
                        self.c["connected"] += 1
                        self.held += 1
                        self.held_max = max(self.held_max, self.held)
                        self.ever.add(slot)
                        sel.modify(s, selectors.EVENT_READ, (slot, True))
                        continue
                    try:  # readable: cut (end of file, a reset) or answered (an HTTP error, a TLS alert)
                        got = s.recv(4096)
                    except OSError:
                        got = b""
                    self.c["answered" if got else "cut"] += 1
                    self._done(sel, s, True)
                    due.append(slot)  # at once: the pressure stays on
                if not ready and len(self.ever) >= self.n:
                    ready = True
                    print(f"viewload halfopen: ready, {self.n} opened from {self.source}", flush=True)
                if now >= next_stats:
                    stats.write(self.stats())
                    next_stats = now + 1.0
        finally:
            for key in list(sel.get_map().values()):
                key.fileobj.close()  # type: ignore[union-attr]
            sel.close()
        stats.write({**self.stats(), "ended": True})


def _halfopen(args: argparse.Namespace, stats: StatsFile) -> None:
    from zdrone.net.shutdown import route_signals

    stop = threading.Event()
    route_signals({signal.SIGTERM: stop.set, signal.SIGINT: stop.set})
    hello = half_client_hello()
    payloads = {"head": [half_head(args.host_header or f"{args.host}:{args.port}")], "hello": [hello],
                "nothing": [b""], "mixed": [b"", hello]}[args.send]
    h = HalfOpen(args.host, args.port, args.n, args.source, payloads, args.rate)
    print(f"viewload halfopen: {args.n} on {args.host}:{args.port} from {args.source}, {args.send}", flush=True)
    h.run(stop, time.monotonic() + args.duration, stats)


# ------------------------------------------------------------------ the forger
def _forge(args: argparse.Namespace, stats: StatsFile) -> None:
    from zdrone.core import opspicture as op
    from zdrone.fleet import keyexprs
    from zdrone.net.shutdown import route_signals
    from zdrone.sil.attackers.common import Ctx, session_as
    from zdrone.sil.attackers.ops import _lie, _sealer

    stop = threading.Event()
    route_signals({signal.SIGTERM: stop.set, signal.SIGINT: stop.set})
    c = Ctx(args.fleet, args.router, "d1", None, args.duration, args.rate, None, False)  # type: ignore[arg-type]
    s = session_as(c, "X")
    sealer = _sealer(c, "X")
    # plain session puts, as ops-unauthorized sends (through declared publishers none of X's parts reached the
    # view in a trial: X, which may not subscribe there, is likely told of no subscriber to send to)
    lanes = keyexprs.ops_lanes("X")
    sent, lane, ticks = 0, 0, 0
    print(f"viewload forge: X at {args.rate:g} parts/s", flush=True)
    try:
        start = time.monotonic()
        next_stats = start + 1.0
        while not stop.is_set():
            now = time.monotonic()
            if now - start >= args.duration:
                break
            due = int(args.rate * (now - start)) - sent
            if due > 0:
                t = round(time.time(), 3)
                drones = [_lie(c.fleet, "X", "d1", None), _lie(c.fleet, "X", "d99", None)]  # d99: no drone of the fleet
                events = [op.OpsEvent(t, "d1", "failsafe_notice", "d1 FAILSAFE, X holds authority (X's lie)")]
                part = op.report_parts("X", t, drones, events)[0]
                for _ in range(due):
                    s.put(lanes[lane], sealer.seal(part))
                    lane = (lane + 1) % keyexprs.OPS_LANES
                sent += due
            ticks += 1
            if now >= next_stats:
                stats.write({"sent": sent, "rate": args.rate, "elapsed_s": round(now - start, 2)})
                next_stats += 1.0
            stop.wait(FORGE_TICK_S)
        stats.write({"sent": sent, "rate": args.rate, "elapsed_s": round(time.monotonic() - start, 2), "ended": True})
    finally:
        s.close()


def main(argv: list[str] | None = None) -> int:
    from zdrone.crashes import stacks_on_crash

    stacks_on_crash()
    p = argparse.ArgumentParser(prog="python -m zdrone.bench.viewload", description="TESTBED ONLY: bench view's load")
    sub = p.add_subparsers(dest="what", required=True)
    pc = sub.add_parser("clients", help="N clients of the view's picture stream")
    pc.add_argument("--host", default="127.0.0.1")
    pc.add_argument("--port", type=int, required=True)
    pc.add_argument("--n", type=int, default=1000)
    pc.add_argument("--retry", type=float, default=RETRY_S, help=f"seconds before a refused client tries again ({RETRY_S:g})")
    pc.add_argument("--ramp", type=float, default=2.0, help="seconds over which the clients first connect (2)")
    pc.add_argument("--duration", type=float, default=600.0)
    pc.add_argument("--stats", required=True)
    pf = sub.add_parser("forge", help="X's sealed parts for the viewer at --rate")
    pf.add_argument("--fleet", required=True)
    pf.add_argument("--router", required=True)
    pf.add_argument("--rate", type=float, default=1000.0)
    pf.add_argument("--duration", type=float, default=600.0)
    pf.add_argument("--stats", required=True)
    ph = sub.add_parser("halfopen", help="N connections from one address, each half a head or handshake, reopened as cut")
    ph.add_argument("--host", default="127.0.0.1")
    ph.add_argument("--port", type=int, required=True)
    ph.add_argument("--n", type=int, default=300)
    ph.add_argument("--source", default="127.0.0.2", help="the address connected from (127.0.0.2)")
    ph.add_argument("--send", choices=SENDS, default="head", help="what each sends: half a request head, half a "
                    "ClientHello, nothing, or mixed (nothing / half a ClientHello)")
    ph.add_argument("--host-header", default=None, help="the Host of the half head (default HOST:PORT)")
    ph.add_argument("--rate", type=float, default=0.0, help="connects a second at most, in all (0: no limit)")
    ph.add_argument("--duration", type=float, default=600.0)
    ph.add_argument("--stats", required=True)
    args = p.parse_args(argv)
    if args.what == "halfopen" and not (1 <= args.n <= 20_000 and args.rate >= 0):
        print("viewload: --n 1..20000, --rate >= 0", file=sys.stderr)
        return 2
    if args.what == "clients" and not (1 <= args.n <= 20_000 and args.retry > 0 and args.ramp >= 0):
        print("viewload: --n 1..20000, --retry > 0, --ramp >= 0", file=sys.stderr)
        return 2
    if args.what == "forge" and not 0 < args.rate <= 100_000:
        print("viewload: --rate 0..100000", file=sys.stderr)
        return 2
    if args.duration <= 0:
        print("viewload: --duration > 0", file=sys.stderr)
        return 2
    stats = StatsFile(args.stats)
    if args.what == "clients":
        limit = raise_nofile(args.n + 256)
        if limit < args.n + 16:
            print(f"viewload: only {limit} files may be open for {args.n} clients", file=sys.stderr)
        asyncio.run(_run_clients(args, stats))
    elif args.what == "halfopen":
        limit = raise_nofile(args.n + 256)
        if limit < args.n + 16:
            print(f"viewload: only {limit} files may be open for {args.n} connections", file=sys.stderr)
        _halfopen(args, stats)
    else:
        _forge(args, stats)
    return 0


if __name__ == "__main__":
    sys.exit(main())
