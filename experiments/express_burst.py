"""Does a client session drop its own puts when it sends a burst of them express?

What a ground station does every heartbeat tick: one put per drone it serves, back to back, on K
different keys (``zdrone/d<i>/up/A/<lane>``), congestion control DROP, priority INTERACTIVE_HIGH,
express or not. A plain Zenoh router (no ACL, no downsampling) in another process, one subscriber
session counting what arrives. Zenoh's transmission queue holds 2 batches per priority by default
(``transport.link.tx.queue.size``); an express message is sent in a batch of its own, and a DROP
message that finds no free batch within ``wait_before_drop`` (1 ms) is dropped, and the priority is
then marked congested (the next DROP messages are dropped at once until a batch is free). So a
burst of express puts is lost in the sender's own session whenever its transmission thread falls
behind by 2 batches for 1 ms: nothing is counted anywhere (no ``stats`` feature in the Python build).

    .venv/bin/python experiments/express_burst.py --drones 100 --express 1
    .venv/bin/python experiments/express_burst.py --drones 100 --express 0
    .venv/bin/python experiments/express_burst.py --drones 100 --express 1 --busy 2   # two busy loops beside it
    .venv/bin/python experiments/express_burst.py --drones 100 --express 1 --queue 16

Prints one JSON line: puts sent, received, lost, the bursts that lost any, the losses by place in the burst.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import threading
import time

import zenoh

from zdrone.sil.ports import free_port

ROUTER = """
import sys, time, zenoh
c = zenoh.Config()
c.insert_json5("mode", '"router"')
c.insert_json5("listen/endpoints", '["tcp/127.0.0.1:%s"]' % sys.argv[1])
c.insert_json5("scouting/multicast/enabled", "false")
s = zenoh.open(c)
print("listening", flush=True)
sys.stdin.read()
s.close()
"""


def client(port: int, queue: int | None) -> zenoh.Session:
    c = zenoh.Config()
    c.insert_json5("mode", '"client"')
    c.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    c.insert_json5("scouting/multicast/enabled", "false")
    if queue:
        c.insert_json5("transport/link/tx/queue/size/interactive_high", str(queue))
    return zenoh.open(c)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--drones", type=int, default=100, help="puts per burst (one per drone, distinct keys)")
    ap.add_argument("--bursts", type=int, default=40)
    ap.add_argument("--period", type=float, default=0.5, help="s between bursts (a GS's heartbeat period)")
    ap.add_argument("--express", type=int, default=1)
    ap.add_argument("--queue", type=int, default=0, help="the sender's INTERACTIVE_HIGH queue size in batches (0: Zenoh's 2)")
    ap.add_argument("--busy", type=int, default=0, help="busy loops (processes) beside it")
    args = ap.parse_args()

    port = free_port(__import__("socket").SOCK_STREAM)
    router = subprocess.Popen([sys.executable, "-c", ROUTER, str(port)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.busy)]
    try:
        if "listening" not in router.stdout.readline():
            print(json.dumps({"error": "router did not start"}))
            return 1
        sub_s, pub_s = client(port, None), client(port, args.queue)
        got: dict[int, int] = {}
        by_position = [0] * args.drones  # frames received per place in the burst
        lock = threading.Lock()

        def on_sample(s: zenoh.Sample) -> None:
            data = s.payload.to_bytes()
            burst, place = int.from_bytes(data[:4], "big"), int.from_bytes(data[4:8], "big")
            with lock:
                got[burst] = got.get(burst, 0) + 1
                by_position[place] += 1

        sub = sub_s.declare_subscriber("zdrone/**", on_sample)
        time.sleep(0.5)
        keys = [f"zdrone/d{i + 1}/up/A/{b % 8}" for i in range(args.drones) for b in range(8)]
        pad = b"\0" * 60
        for b in range(args.bursts):
            t0 = time.monotonic()
            for i in range(args.drones):
                pub_s.put(keys[i * 8 + b % 8], b.to_bytes(4, "big") + i.to_bytes(4, "big") + pad, congestion_control=zenoh.CongestionControl.DROP,
                          priority=zenoh.Priority.INTERACTIVE_HIGH, express=bool(args.express))
            time.sleep(max(0.0, args.period - (time.monotonic() - t0)))
        time.sleep(1.0)
        sub.undeclare()
        sent = args.drones * args.bursts
        with lock:
            received = sum(got.values())
            lossy = {b: args.drones - got.get(b, 0) for b in range(args.bursts) if got.get(b, 0) < args.drones}
        print(json.dumps({"drones": args.drones, "express": bool(args.express), "queue": args.queue or 2, "busy": args.busy,
                          "sent": sent, "received": received, "lost": sent - received,
                          "bursts_with_loss": len(lossy), "of_bursts": args.bursts, "lost_per_lossy_burst": list(lossy.values())[:10],
                          # lost per tenth of the burst, first to last: the same drones lose every time
                          "lost_by_tenth": [sum(args.bursts - by_position[i] for i in range(t * args.drones // 10, (t + 1) * args.drones // 10))
                                            for t in range(10)]}))
        sub_s.close()
        pub_s.close()
        return 0
    finally:
        for p in busy:
            p.kill()
            p.wait(5)
        router.stdin.close()
        try:
            router.wait(10)
        except subprocess.TimeoutExpired:
            router.kill()
            router.wait(5)


if __name__ == "__main__":
    sys.exit(main())
