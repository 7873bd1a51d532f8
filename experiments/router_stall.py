"""Does the router's per-key downsampling drop a paced publisher's frames when the router stalls?

A real router (``zdrone router -c``) with the config the project generates for the default fleet
(auth, ACL, the downsampling of every uplink lane on ingress; ``--freq`` changes the uplink's rate,
spread over its lanes, 0 removes it), one client publishing a sequence number every 10 ms on the
uplink's first ``--lanes`` lanes in turn (1: a single key, as before uplinks had lanes) as GS B (express, INTERACTIVE_HIGH, DROP: as ``Runtime.put(link=True)``), the drone d1
subscribed, counting what never arrives. Meanwhile the router is stalled: SIGSTOP/SIGCONT of its
PID (``--stall sigstop``), or starved on one core beside a busy loop (``--stall starve``).

    nice -n 10 .venv/bin/python experiments/router_stall.py --freq 2000 --stall sigstop   # lanes, as a GS
    nice -n 10 .venv/bin/python experiments/router_stall.py --freq 2000 --lanes 1 --stall sigstop
    nice -n 10 .venv/bin/python experiments/router_stall.py --freq 0 --stall sigstop   # no rule

Prints one JSON line: sent, received, lost, and how close together the lost ones' neighbours arrived.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import zenoh

from zdrone.core.fleet import Coverage, Fleet, Node
from zdrone.core.reference import COVERAGE_RADIUS_M, DEFAULT_NODES
from zdrone.fleet import keyexprs as kx
from zdrone.fleet.routerconfig import router_config
from zdrone.sil.ports import free_port


PASSWORDS = {"d1": "pw-d1-experiment", "B": "pw-B-experiment"}


def default_fleet() -> Fleet:
    nodes = {n: Node(role=r, sysid=s, public_key="A" * 43 + "=",  # type: ignore[arg-type]
                     coverage=Coverage(c.lat, c.lon, COVERAGE_RADIUS_M) if c else None, authorized_gs=a)
             for n, r, s, c, a in DEFAULT_NODES}
    return Fleet(version=1, nodes=nodes)


def make_config(port: int, freq: float, lanes: int) -> dict:
    """The fleet's router config as the project generates it; each uplink at ``freq`` over its first
    ``lanes`` lanes (0: no rule)."""
    cfg = router_config(default_fleet(), "credentials.txt", f"tcp/127.0.0.1:{port}")
    if freq <= 0:
        cfg["downsampling"] = []
    else:
        for item in cfg["downsampling"]:
            for rule in item["rules"]:
                rule["freq"] = freq / lanes
    return cfg


def client(port: int, user: str) -> zenoh.Session:
    c = zenoh.Config()
    c.insert_json5("mode", '"client"')
    c.insert_json5("transport/auth/usrpwd", json.dumps({"user": user, "password": PASSWORDS[user]}))
    c.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    c.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(c)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--freq", type=float, default=2000.0, help="an uplink's rate over its lanes (0: no rule)")
    ap.add_argument("--lanes", type=int, default=kx.UP_LANES, help="lanes the publisher uses in turn")
    ap.add_argument("--stall", choices=("none", "sigstop", "starve"), default="sigstop")
    ap.add_argument("--stalls", type=int, default=50)
    ap.add_argument("--stall-ms", type=float, default=30.0)
    ap.add_argument("--gap-ms", type=float, default=10.0, help="the publisher's pace")
    ap.add_argument("--seconds", type=float, default=12.0, help="duration for --stall none/starve")
    ap.add_argument("--cpu", type=int, default=1, help="--stall starve: the core router and busy loop share")
    args = ap.parse_args()

    tmp = Path(tempfile.mkdtemp(prefix="router-stall-"))
    port = free_port(__import__("socket").SOCK_STREAM)
    cfg_path = tmp / "router.json5"
    cfg_path.write_text(json.dumps(make_config(port, args.freq, args.lanes)))
    lanes = kx.up_lanes("d1", "B")[:args.lanes]
    (tmp / "credentials.txt").write_text("".join(f"{u}:{p}\n" for u, p in PASSWORDS.items()))
    cmd = [str(Path(sys.executable).parent / "zdrone"), "router", "-c", str(cfg_path)]
    if args.stall == "starve":
        cmd = ["taskset", "-c", str(args.cpu), "nice", "-n", "19"] + cmd
    router = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    busy: subprocess.Popen | None = None
    try:
        line = router.stdout.readline()
        if "listening" not in line:
            print(json.dumps({"error": "router did not start", "line": line}))
            return 1
        sub_s, pub_s = client(port, "d1"), client(port, "B")
        got: list[tuple[int, float]] = []
        lock = threading.Lock()

        def on_sample(s: zenoh.Sample) -> None:
            seq = struct.unpack_from("!Q", s.payload.to_bytes())[0]
            with lock:
                got.append((seq, time.monotonic()))

        subs = [sub_s.declare_subscriber(lane, on_sample) for lane in kx.up_lanes("d1", "B")]
        time.sleep(0.5)  # subscription reaches the router
        stop = threading.Event()
        sent = [0]
        min_gap = [1e9]

        def publish() -> None:
            gap = args.gap_ms / 1000.0
            last = time.monotonic() - gap
            pad = b"\0" * 150
            while not stop.is_set():
                wait = last + gap - time.monotonic()
                if wait > 0:
                    time.sleep(wait)
                now = time.monotonic()
                min_gap[0] = min(min_gap[0], now - last)
                last = now
                pub_s.put(lanes[sent[0] % len(lanes)], struct.pack("!Q", sent[0]) + pad, congestion_control=zenoh.CongestionControl.DROP,
                          priority=zenoh.Priority.INTERACTIVE_HIGH, express=True)
                sent[0] += 1

        t = threading.Thread(target=publish, daemon=True)
        t.start()
        time.sleep(0.3)
        stalls = 0
        if args.stall == "sigstop":
            rng = random.Random(1)
            for _ in range(args.stalls):
                os.kill(router.pid, signal.SIGSTOP)
                time.sleep(args.stall_ms / 1000.0)
                os.kill(router.pid, signal.SIGCONT)
                stalls += 1
                time.sleep(rng.uniform(0.15, 0.25))
        elif args.stall == "starve":
            busy = subprocess.Popen(["taskset", "-c", str(args.cpu), sys.executable, "-c", "while True: pass"])
            time.sleep(args.seconds)
            busy.terminate()
            busy.wait(5)
            busy = None
        else:
            time.sleep(args.seconds)
        stop.set()
        t.join(2)
        time.sleep(1.0)  # drain
        for sub in subs:
            sub.undeclare()
        with lock:
            seqs = sorted(got)
        seen = {s for s, _ in seqs}
        lost = [i for i in range(sent[0]) if i not in seen]
        arrival = dict(seqs)
        # arrival gap between the lost frame's neighbours: back to back after a stall?
        around = [round((arrival[i + 1] - arrival[i - 1]) * 1000, 3) for i in lost
                  if i - 1 in arrival and i + 1 in arrival]
        inter = sorted(b[1] - a[1] for a, b in zip(seqs, seqs[1:]))
        bunched = sum(1 for g in inter if g < 0.0005)
        print(json.dumps({"freq": args.freq, "lanes": args.lanes, "stall": args.stall, "stalls": stalls, "stall_ms": args.stall_ms,
                          "sent": sent[0], "received": len(seen), "lost": len(lost),
                          "min_send_gap_ms": round(min_gap[0] * 1000, 3),
                          "arrivals_under_0.5ms_apart": bunched,
                          "lost_neighbours_arrival_gap_ms": around[:10]}))
        sub_s.close()
        pub_s.close()
        return 0
    finally:
        if busy is not None:
            busy.kill()
            busy.wait(5)
        os.kill(router.pid, signal.SIGCONT) if router.poll() is None else None
        router.terminate()
        try:
            router.wait(10)
        except subprocess.TimeoutExpired:
            router.kill()
            router.wait(5)


if __name__ == "__main__":
    sys.exit(main())
