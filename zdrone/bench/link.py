"""``zdrone bench link``: GS -> vehicle one-way latency and sustained frames/s through the router,
with and without the security module, measured in the same run.

Layout: one router process (the fleet's auth and ACL); a GS process (session user A, spawned); in
this process the drone session (user d1), the drone loop and a UDP socket standing in for the
vehicle. A frame goes: GS seals ->
``session.put`` -> router -> drone subscriber callback -> queue -> drone loop opens and checks it
(envelope, replay window, header, sysid, TBM) -> UDP to the vehicle socket, where it is timestamped.
"Without" skips seal and open and forwards the bytes as they are. Timestamps come from
``time.perf_counter`` (CLOCK_MONOTONIC, one clock for every process on the machine).
"""

from __future__ import annotations

import json
import os
import queue
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import json5
from pymavlink.dialects.v20 import common as mav

from zdrone.core.envelope import Opened, SecureLink
from zdrone.core.errors import ConfigError
from zdrone.core.keys import LinkKey
from zdrone.core.mavlink import FrameCodec
from zdrone.fleet.files import init_fleet, load_secret
from zdrone.fleet import keyexprs
from zdrone.net.session import open_client
from zdrone.sil.launcher import free_port
from zdrone.sil.procs import spawn, wait_line  # the router dies with the bench, however it ends


def _frames(n: int) -> list[bytes]:
    c = FrameCodec(4, 190)
    return [c.encode(mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_REQUEST_MESSAGE, 0, float(i), 0, 0, 0, 0, 0, 0))
            for i in range(n)]


def _sender(router: str, fleet: str, secret: bytes, secure: bool, n: int, rate_hz: float, conn: Any) -> None:
    """GS process: seal and put ``n`` frames (paced at ``rate_hz``, or as fast as possible if 0)."""
    gs = open_client(router, "A", load_secret(fleet, "A").router_password)
    key = LinkKey.from_secret("d1", "A", secret)
    tx = SecureLink(key=key, role="gs", tx_keyexpr=keyexprs.up("d1", "A"), rx_keyexpr=keyexprs.down("d1", "A"), peer_sysid=1, now=0.0)
    frames = _frames(n)
    put, ke = gs.put, keyexprs.up_lane("d1", "A", 0)  # one lane: no per-lane limit in this router
    sent: list[float] = []
    if rate_hz <= 0 and secure:  # throughput: seal ahead, the GS's own CPU is not the path under test
        frames, secure = [tx.seal(f) for f in frames], False
    conn.send("ready")
    conn.recv()
    nxt = time.perf_counter()
    for f in frames:
        if rate_hz > 0:
            delay = nxt - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
            nxt += 1.0 / rate_hz
        sent.append(time.perf_counter())
        put(ke, tx.seal(f) if secure else f)
    conn.send(sent)
    time.sleep(0.2)
    gs.close()


class _Path:
    """GS session -> router -> drone loop -> UDP vehicle, for one variant."""

    def __init__(self, router: str, fleet: Path, secure: bool) -> None:
        self.secure, self.router, self.fleet = secure, router, fleet
        self.secret = os.urandom(32)
        self.dr = open_client(router, "d1", load_secret(fleet, "d1").router_password)
        key = LinkKey.from_secret("d1", "A", self.secret)
        self.rx = SecureLink(key=key, role="drone", tx_keyexpr=keyexprs.down("d1", "A"), rx_keyexpr=keyexprs.up("d1", "A"),
                             peer_sysid=4, now=time.monotonic())
        self.q: queue.SimpleQueue[Any] = queue.SimpleQueue()
        # the bound put itself is the callback: no Python frame runs on Zenoh's thread (as in DroneNode)
        self.sub = self.dr.declare_subscriber(keyexprs.up_lane("d1", "A", 0), self.q.put)
        self.vehicle = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.vehicle.bind(("127.0.0.1", 0))
        self.vehicle.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
        self.out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.vaddr = self.vehicle.getsockname()
        self.arrivals: list[tuple[float, bytes]] = []
        self.dropped = 0
        self._loop = threading.Thread(target=self._drone_loop, daemon=True)
        self._veh = threading.Thread(target=self._vehicle_loop, daemon=True)
        self._loop.start()
        self._veh.start()
        time.sleep(0.5)  # let the subscription reach the router

    def _drone_loop(self) -> None:
        while True:
            sample = self.q.get()
            if sample is None:
                return
            data = sample.payload.to_bytes()
            if self.secure:
                res = self.rx.open(data, time.monotonic())
                if not isinstance(res, Opened):
                    self.dropped += 1
                    continue
                data = res.plaintext
            self.out.sendto(data, self.vaddr)

    def _vehicle_loop(self) -> None:
        self.vehicle.settimeout(0.5)
        while True:
            try:
                data = self.vehicle.recv(2048)
            except socket.timeout:
                continue
            except OSError:
                return
            if data == b"stop":
                return
            self.arrivals.append((time.perf_counter(), data))

    def rekey(self) -> None:
        """A fresh link for each run: a sender restarts its counter at 0."""
        self.secret = os.urandom(32)
        key = LinkKey.from_secret("d1", "A", self.secret)
        self.rx = SecureLink(key=key, role="drone", tx_keyexpr=keyexprs.down("d1", "A"), rx_keyexpr=keyexprs.up("d1", "A"),
                             peer_sysid=4, now=time.monotonic())

    def run_sender(self, n: int, rate_hz: float) -> list[float]:
        import multiprocessing as mp

        self.rekey()
        ctx = mp.get_context("spawn")  # never fork a process that has a Zenoh session
        parent, child = ctx.Pipe()
        p = ctx.Process(target=_sender, args=(self.router, str(self.fleet), self.secret, self.secure, n, rate_hz, child))
        p.start()
        try:
            assert parent.poll(30), "sender did not start"
            parent.recv()
            time.sleep(0.3)
            parent.send("go")
            assert parent.poll(120), "sender did not finish"
            return parent.recv()
        finally:
            p.join(10)
            if p.is_alive():
                p.kill()

    def wait_count(self, n: int, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while len(self.arrivals) < n and time.monotonic() < deadline:
            time.sleep(0.01)

    def close(self) -> None:
        self.q.put(None)
        self.out.sendto(b"stop", self.vaddr)
        self._loop.join(2)
        self._veh.join(2)
        self.sub.undeclare()
        self.dr.close()
        self.vehicle.close()
        self.out.close()


def _latency(path: _Path, n: int, rate_hz: float) -> dict[str, float]:
    path.arrivals.clear()
    sent = path.run_sender(n, rate_hz)
    path.wait_count(n, 5.0)
    index = {f: i for i, f in enumerate(_frames(n))}
    lat = sorted((t - sent[index[d]]) * 1e6 for t, d in path.arrivals if d in index)
    if not lat:
        return {"p50": float("nan"), "p99": float("nan"), "received": 0}
    return {"p50": round(statistics.median(lat), 1), "p99": round(lat[min(len(lat) - 1, int(len(lat) * 0.99))], 1),
            "received": len(lat)}


def _throughput(path: _Path, n: int) -> float:
    path.arrivals.clear()
    sent = path.run_sender(n, 0.0)
    path.wait_count(n, 20.0)
    if not path.arrivals:
        return 0.0
    return round(len(path.arrivals) / (path.arrivals[-1][0] - sent[0]))


#: ports tried before the bench gives up: a port free when chosen may be taken before the router binds
#: it (another bench or test starting beside this one); the router then ends with one error line
ROUTER_TRIES = 3
#: how long a router may take to say it listens (a loaded machine: seconds)
ROUTER_START_S = 30.0


def _start_router(cfg_path: Path) -> tuple[subprocess.Popen, str]:
    """A router listening on a free port, once its ready line is seen (another port if it could not listen)."""
    why = ""
    for _ in range(ROUTER_TRIES):
        router = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
        proc = spawn([sys.executable, "-m", "zdrone", "router", "-c", str(cfg_path), "--listen", router],
                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            wait_line(proc, "listening on", ROUTER_START_S)
            return proc, router
        except RuntimeError as exc:  # it ended (the port taken) or never listened
            why = str(exc)
            proc.kill()
            proc.wait(10)
    raise ConfigError(f"bench link: the router did not start on {ROUTER_TRIES} ports: {why}")


def run(quick: bool = False, progress: bool = False) -> dict[str, Any]:
    tmp = Path(tempfile.mkdtemp(prefix="zdrone-bench-link-"))
    init_fleet(tmp / "fleet")
    # the path's own cost, without the fleet's per-lane ingress limit (UPLINK_MAX_HZ puts/s per uplink, which
    # is a policy against floods, not a property of the path: the throughput run would only measure it)
    cfg_path = tmp / "fleet/router/router.json5"
    cfg = json5.loads(cfg_path.read_text())
    cfg.pop("downsampling", None)
    cfg_path.write_text(json.dumps(cfg, indent=2))
    proc, router = _start_router(cfg_path)
    try:
        n_lat, n_thr = (300, 3000) if quick else (2000, 30000)
        out: dict[str, Any] = {"latency_us": {}, "frames_per_s": {}, "dropped": {}}
        status = None
        if progress:
            from rich.console import Console

            status = Console(stderr=True).status("measuring latency and throughput…")
            status.start()
        variants = (("plain", False), ("zdrone", True))
        rounds = 1 if quick else 3
        samples: dict[str, list[dict[str, float]]] = {n: [] for n, _ in variants}
        for last in [False] * (rounds - 1) + [True]:
            for name, secure in variants:  # alternate, one path at a time (both would share the key)
                path = _Path(router, tmp / "fleet", secure)
                try:
                    samples[name].append(_latency(path, n_lat, 500.0))
                    if last:
                        out["frames_per_s"][name] = _throughput(path, n_thr)
                        out["dropped"][name] = path.dropped
                finally:
                    path.close()
        if status is not None:
            status.stop()
        for name, _ in variants:
            ss = sorted(samples[name], key=lambda x: x["p50"])
            out["latency_us"][name] = ss[len(ss) // 2] | {"rounds": rounds}
        lp, lz = out["latency_us"]["plain"], out["latency_us"]["zdrone"]
        out["added_p50_us"] = round(lz["p50"] - lp["p50"], 1)
        out["added_p99_us"] = round(lz["p99"] - lp["p99"], 1)
        out["throughput_ratio"] = round(out["frames_per_s"]["zdrone"] / max(1, out["frames_per_s"]["plain"]), 3)
        out["targets"] = {"added_p50_us_max": 100.0, "throughput_ratio_min": 0.5}
        out["layout"] = "router, GS sender and drone loop + vehicle socket in three processes"
        return out
    finally:
        proc.terminate()
        proc.wait(10)


def render(r: dict[str, Any]) -> None:
    from zdrone.bench.table import print_table

    rows = [[n, r["latency_us"][n]["p50"], r["latency_us"][n]["p99"], r["frames_per_s"][n]] for n in ("plain", "zdrone")]
    rows.append(["added by zdrone", r["added_p50_us"], r["added_p99_us"], f"ratio {r['throughput_ratio']:.2f}"])
    print_table("GS -> vehicle through the router", ["variant", "p50 µs", "p99 µs", "frames/s"], rows,
                caption="targets: ≤ 100 µs p50 added; throughput with security ≥ 50 % of without")
