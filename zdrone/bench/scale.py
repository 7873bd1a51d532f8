"""``zdrone bench scale``: K drones x G ground stations through one router on this machine.

Layout (three processes plus this one): the router; one process hosting the K drone nodes, each
with its own Zenoh session, authority machine, security module and an in-process simulator (no
sockets; all stepped by one loop); one process hosting the G ground stations, each with its own
session, serving all K drones. GSs stand 500 m apart eastwards (A, B, C, …); every drone is paired
by A, gets the other GSs' keys over the backhaul, and flies a shuttle from A's area to the last
GS's area and back, so it makes 2 x (G - 1) hand-overs; each authority GS sends it a 1 Hz command
stream. A drone is *correct* if it made every hand-over, never had an authority gap, lost no
command, never entered failsafe, and its authority link stayed healthy (TBM never LOST).
"""

from __future__ import annotations

import argparse
import json
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

CROSSINGS = 2
SPEEDUP = 4.0


def _host_drones(args: argparse.Namespace) -> int:
    from ..core.reference import HOME
    from ..core.authority import HaDrop
    from ..core.tbm import LinkState
    from ..fleet.files import load_fleet
    from ..nodes.drone import DroneNode, DroneOptions
    from ..sil.coverage import CoverageGate
    from ..vehicle.inproc import InProcessVehicle

    nodes = []
    for i in range(args.k):
        name = f"d{i + 1}"
        opts = DroneOptions(drone=name, fleet=args.fleet, router=args.router, vehicle="inproc", gate=CoverageGate(load_fleet(args.fleet)),
                            events=str(Path(args.out) / f"{name}.jsonl"), handover_timeout=max(1.5, 5.0 / args.speedup),
                            status_period=2.0)
        nodes.append(DroneNode(opts, vehicle=InProcessVehicle(HOME, sysid=i + 1, speedup=args.speedup, seed=i)))
    print(f"drones host: {args.k} drones ready", flush=True)
    stop = [False]
    signal.signal(signal.SIGTERM, lambda *_: stop.__setitem__(0, True))
    armed_seen = [False] * len(nodes)
    worst_owner_silence = [0.0] * len(nodes)
    owner_lost = [0] * len(nodes)
    deadline = time.monotonic() + args.duration
    loops = 0
    try:
        while not stop[0] and time.monotonic() < deadline:
            for i, n in enumerate(nodes):
                n.step(0.0)
                m = n.machine
                if n.vehicle.armed:
                    armed_seen[i] = True
                    link = n.links.get(m.owner or "")
                    if link is not None:
                        now = time.monotonic()
                        worst_owner_silence[i] = max(worst_owner_silence[i], link.tbm.since_last(now))
                        if link.tbm.state(now) is LinkState.LOST:
                            owner_lost[i] += 1
            loops += 1
            if all(armed_seen) and all(not n.vehicle.armed for n in nodes):
                break
            time.sleep(0.002)
        results = {}
        for i, n in enumerate(nodes):
            m = n.machine
            results[n.name] = {
                "handovers": max(0, m.epoch - 1),  # epoch 1 at pairing, +1 per hand-over
                "owners": [o for _, o, _ in m.history], "state": m.state.value, "flew": armed_seen[i],
                "landed": not n.vehicle.armed and n.vehicle.landed_state == 1,
                "forwarded": dict(n.forwarded), "not_authority": m.drops[HaDrop.NOT_AUTHORITY],
                "worst_owner_silence_s": round(worst_owner_silence[i], 3), "owner_lost_samples": owner_lost[i],
                "security_drops": {gs: {r.value: c for r, c in ln.drops.items() if c} for gs, ln in n.links.items()}}
        Path(args.out, "drones.json").write_text(json.dumps({"results": results, "loops": loops,
                                                              "timed_out": time.monotonic() >= deadline}))
    finally:
        for n in nodes:
            n.close()
    return 0


def _host_stations(args: argparse.Namespace) -> int:
    from gs.planner import shuttle_mission
    from gs.station import GroundStation, StationOptions

    names = [chr(ord("A") + i) for i in range(args.stations)]
    mission = shuttle_mission(CROSSINGS, far_east_m=500.0 * (args.stations - 1) - 60.0)
    stations = [GroundStation(StationOptions(gs=g, fleet=args.fleet, router=args.router, pair=(g == "A"),
                                             mission=mission if g == "A" else None, command_rate=1.0,
                                             events=None)) for g in names]
    print(f"stations host: {len(stations)} stations ready", flush=True)
    # one thread per station: a GS's blocking backhaul query must not wait on another GS's loop
    import threading

    threads = [threading.Thread(target=st.run, daemon=True) for st in stations]
    for t in threads:
        t.start()
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    stop.wait()
    sent = {st.name: {d: sum(v.commands_sent.values()) for d, v in st.views.items()} for st in stations}
    for st in stations:
        st.stop()
    for t in threads:
        t.join(15)
    Path(args.out, "stations.json").write_text(json.dumps({"commands_sent": sent}))
    return 0


def _one(k: int, g: int, base: Path, timeout: float) -> dict[str, Any]:
    from ..fleet.files import init_fleet, scale_nodes
    from ..sil.launcher import free_port

    d = base / f"k{k}"
    d.mkdir(parents=True, exist_ok=True)
    init_fleet(d / "fleet", nodes_spec=scale_nodes(k, g))
    router = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    py = [sys.executable, "-m"]
    logs = {n: open(d / f"{n}.log", "w") for n in ("router", "drones", "stations")}
    procs: dict[str, subprocess.Popen] = {}
    t0 = time.monotonic()
    try:
        procs["router"] = subprocess.Popen(py + ["zdrone", "router", "-c", str(d / "fleet/router/router.json5"), "--listen", router],
                                           stdout=logs["router"], stderr=subprocess.STDOUT)
        time.sleep(1.0)
        common = ["--fleet", str(d / "fleet"), "--router", router, "--out", str(d)]
        procs["drones"] = subprocess.Popen(py + ["zdrone.bench.scale", "host-drones", "--k", str(k), "--speedup", str(SPEEDUP),
                                                 "--duration", str(timeout), *common], stdout=logs["drones"], stderr=subprocess.STDOUT)
        procs["stations"] = subprocess.Popen(py + ["zdrone.bench.scale", "host-stations", "--stations", str(g), *common],
                                             stdout=logs["stations"], stderr=subprocess.STDOUT)
        procs["drones"].wait(timeout + 60)
    finally:
        for name in ("stations", "router", "drones"):
            p = procs.get(name)
            if p is not None and p.poll() is None:
                p.terminate()
                try:
                    p.wait(20)
                except subprocess.TimeoutExpired:
                    p.kill()
        for f in logs.values():
            f.close()
    wall = time.monotonic() - t0
    try:
        drones = json.loads((d / "drones.json").read_text())
        sent = json.loads((d / "stations.json").read_text())["commands_sent"]
    except (OSError, ValueError) as exc:
        return {"k": k, "g": g, "error": f"no results ({exc}); see {d}"}
    expected = 2 * (g - 1)
    per: dict[str, Any] = {}
    for name, r in drones["results"].items():
        s = sum(sent.get(gs, {}).get(name, 0) for gs in sent)
        f = sum(r["forwarded"].values())
        why = []
        if r["handovers"] != expected:
            why.append(f"{r['handovers']}/{expected} hand-overs")
        if r["state"] == "failsafe":
            why.append("failsafe")
        if r["owner_lost_samples"]:
            why.append(f"authority link LOST ({r['worst_owner_silence_s']} s)")
        if s - f:
            why.append(f"{s - f} commands lost")
        if not r["landed"]:
            why.append("not landed")
        per[name] = {"ok": not why, "why": why, "worst_owner_silence_s": r["worst_owner_silence_s"]}
    ok = sum(1 for v in per.values() if v["ok"])
    return {"k": k, "g": g, "correct": ok, "all_correct": ok == k and not drones["timed_out"], "wall_s": round(wall, 1),
            "worst_owner_silence_s": max(v["worst_owner_silence_s"] for v in per.values()),
            "failures": {n: v["why"] for n, v in per.items() if not v["ok"]}, "runs": str(d)}


def run(quick: bool = False, ks: list[int] | None = None, stations: int = 3, progress: bool = True) -> dict[str, Any]:
    ks = ks or ([3] if quick else [10, 25, 50])
    base = Path(tempfile.mkdtemp(prefix="zdrone-bench-scale-"))
    rows = []
    status = None
    if progress:
        from rich.console import Console

        status = Console(stderr=True).status("")
        status.start()
    try:
        for k in ks:
            if status:
                status.update(f"{k} drones x {stations} GSs flying…")
            rows.append(_one(k, stations, base, timeout=150.0))
    finally:
        if status:
            status.stop()
    good = [r["k"] for r in rows if r.get("all_correct")]
    return {"rows": rows, "largest_k_all_correct": max(good) if good else 0, "stations": stations,
            "layout": "router | one process hosting K drone nodes (in-process simulators) | one hosting the G GSs",
            "target": {"k": 50, "g": 3}}


def render(r: dict[str, Any]) -> None:
    from .table import print_table

    rows = [[f"{x['k']} x {x['g']}", x.get("correct", "error"), "yes" if x.get("all_correct") else "no",
             x.get("worst_owner_silence_s", "-"), x.get("wall_s", "-"),
             "; ".join(f"{n}: {', '.join(w)}" for n, w in list(x.get("failures", {}).items())[:3]) or x.get("error", "")]
            for x in r["rows"]]
    print_table("Scale: drones x ground stations through one router", ["drones x GSs", "correct", "all correct",
                "worst authority silence s", "wall s", "first failures"], rows,
                caption=f"largest K with all hand-overs correct and TBM healthy: {r['largest_k_all_correct']} (target 50 x 3)")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m zdrone.bench.scale")
    sub = p.add_subparsers(dest="role", required=True)
    hd = sub.add_parser("host-drones")
    hd.add_argument("--k", type=int, required=True)
    hd.add_argument("--speedup", type=float, default=SPEEDUP)
    hd.add_argument("--duration", type=float, default=150.0)
    hs = sub.add_parser("host-stations")
    hs.add_argument("--stations", type=int, required=True)
    for sp in (hd, hs):
        sp.add_argument("--fleet", required=True)
        sp.add_argument("--router", required=True)
        sp.add_argument("--out", required=True)
    args = p.parse_args(argv)
    return _host_drones(args) if args.role == "host-drones" else _host_stations(args)


if __name__ == "__main__":
    sys.exit(main())
