"""What the router's uplink limits cost it: memory and session set-up with one downsampling rule per
uplink lane (as generated: drones x GSs x UP_LANES), one per uplink (drones x GSs, before lanes), or none.

A real router (``zdrone router -c``) with the project's config for a fleet of ``--drones`` drones and
``--stations`` GSs (each authorized for every drone), then one client session per node, opened one
after the other; the router's resident memory before and after, and the time to open them all.

    nice -n 10 .venv/bin/python experiments/router_rules_cost.py --drones 150 --stations 3

Prints one JSON line per variant.
"""

from __future__ import annotations

import argparse
import json
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from zdrone.core.geometry import GeoPoint
from zdrone.fleet import keyexprs as kx
from zdrone.fleet.files import init_fleet, load_fleet, load_secret
from zdrone.fleet.routerconfig import UPLINK_MAX_HZ, router_config
from zdrone.net.session import open_client


def rss_kb(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return 0


def variant_rules(fleet, variant: str) -> list[dict]:
    if variant == "lanes":
        return router_config(fleet, "credentials.txt")["downsampling"]
    if variant == "key":
        rules = [{"key_expr": kx.up(d, g), "freq": UPLINK_MAX_HZ} for d in fleet.drones() for g in fleet.ground_stations()]
        return [{"id": "uplink-rate", "flows": ["ingress"], "messages": ["put"], "rules": rules}]
    return []


def measure(fleet_dir: Path, variant: str) -> dict:
    fleet = load_fleet(fleet_dir)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    ep = f"tcp/127.0.0.1:{port}"
    cfg = router_config(fleet, "credentials.txt", ep)
    cfg["downsampling"] = variant_rules(fleet, variant)
    path = fleet_dir / "router" / f"{variant}.json5"
    path.write_text(json.dumps(cfg))
    router = subprocess.Popen([str(Path(sys.executable).parent / "zdrone"), "router", "-c", str(path)],
                              stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    sessions = []
    try:
        if "listening" not in (router.stdout.readline() if router.stdout else ""):
            return {"variant": variant, "error": "router did not start"}
        time.sleep(0.5)
        before = rss_kb(router.pid)
        t0 = time.monotonic()
        for name in fleet.nodes:
            sessions.append(open_client(ep, name, load_secret(fleet_dir, name).router_password))
        opened = time.monotonic() - t0
        time.sleep(1.0)
        after = rss_kb(router.pid)
        rules = sum(len(item["rules"]) for item in cfg["downsampling"])
        return {"variant": variant, "rules": rules, "sessions": len(sessions), "open_s": round(opened, 2),
                "router_rss_mb": [round(before / 1024, 1), round(after / 1024, 1)],
                "per_session_kb": round((after - before) / max(1, len(sessions)), 1)}
    finally:
        for s in sessions:
            s.close()
        router.terminate()
        try:
            router.wait(10)
        except subprocess.TimeoutExpired:
            router.kill()
            router.wait(5)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--drones", type=int, default=150)
    ap.add_argument("--stations", type=int, default=3)
    ap.add_argument("--variants", default="none,key,lanes")
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="router-rules-"))
    gss = [chr(ord("A") + i) for i in range(args.stations)]
    spec = [(f"d{i + 1}", "drone", 100 + i, None, gss) for i in range(args.drones)]
    spec += [(g, "gs", 10 + i, GeoPoint(47.3977, 8.5456 + 0.01 * i), []) for i, g in enumerate(gss)]
    init_fleet(tmp / "fleet", nodes_spec=spec)
    for v in args.variants.split(","):
        print(json.dumps(measure(tmp / "fleet", v)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
