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

Each writes a JSON line of its counters to ``--stats`` every second and a last one when it ends
(SIGTERM or ``--duration``).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import random
import signal
import sys
import threading
import time
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
    args = p.parse_args(argv)
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
    else:
        _forge(args, stats)
    return 0


if __name__ == "__main__":
    sys.exit(main())
