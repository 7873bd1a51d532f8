"""``zdrone bench traffic [--autopilot px4|ardupilot]``: the paper's Table 1, measured on our own flights.

Three complete stacks (router, simulator, drone, GS A, GS B) fly the reference mission at the same
time, in real time, against the same autopilot personality of the simulator, differing only in the
security layer:

* ``plain``: MAVLink over Zenoh with no security layer (the same nodes, envelope disabled);
* ``zdrone``: our envelope (ChaCha20-Poly1305, 24 bytes), liveness from the MAVLink HEARTBEAT;
* ``paper``: the paper's layer: Fernet per frame plus a separate security heartbeat at 2 Hz.

All three send the GCS HEARTBEAT at 2 Hz (the drone's authority needs the liveness either way).
Packets and bytes are counted at the Zenoh layer by a tap in each router process (every sample on
``zdrone/**``; bytes are sample payload bytes, without Zenoh/TCP framing), per direction:
``up`` = GS -> drone, ``down`` = drone -> GS. A drone's publication is a bundle of a pass's envelopes
(``zdrone.core.bundle``): the tap counts the frames in it, and the bytes added are per frame.

The downlink is the autopilot's own stream: PX4 streams its default set unasked (the paper's figures
were taken with PX4's real stream); ArduPilot streams nothing until asked, so its downlink is what
the drone node's vehicle link asks for (``zdrone.vehicle.tracker.DEFAULT_STREAMS``) plus HEARTBEAT,
STATUSTEXT and the protocol replies.
"""

from __future__ import annotations

import json
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from ..sil.launcher import Demo, DemoOptions

VARIANTS = {"plain": ("plain", False), "zdrone": ("zdrone", False), "paper": ("fernet", True)}
PAPER = {"without": {"packets_per_min": 161, "mean_packet_bytes": 433.2},
         "with": {"packets_per_min": 196, "mean_packet_bytes": 435.3}}


def _rates(tap: dict[str, Any]) -> dict[str, Any]:
    window = max(1e-6, (tap.get("last") or 0) - (tap.get("first") or 0))
    out: dict[str, Any] = {"window_s": round(window, 2)}
    tot_n = tot_b = tot_f = 0
    for direction in ("up", "down"):
        n = sum(v[0] for k, v in tap["keys"].items() if f"/{direction}/" in k)
        b = sum(v[1] for k, v in tap["keys"].items() if f"/{direction}/" in k)
        f = sum(v[2] if len(v) > 2 else v[0] for k, v in tap["keys"].items() if f"/{direction}/" in k)
        out[direction] = {"packets_per_min": round(n / window * 60, 1), "mean_packet_bytes": round(b / n, 1) if n else 0.0,
                          "packets": n, "bytes": b, "frames": f}
        tot_n, tot_b, tot_f = tot_n + n, tot_b + b, tot_f + f
    out["packets_per_min"] = round(tot_n / window * 60, 1)
    out["mean_packet_bytes"] = round(tot_b / tot_n, 1) if tot_n else 0.0
    # a drone sends a pass's envelopes as one bundle: the security layer's cost is per frame
    out["mean_frame_bytes"] = round(tot_b / tot_f, 1) if tot_f else 0.0
    return out


AUTOPILOTS = ("px4", "ardupilot")


def run(quick: bool = False, out: Path | None = None, progress: bool = True, autopilot: str = "px4") -> dict[str, Any]:
    if autopilot not in AUTOPILOTS:
        raise ValueError(f"autopilot {autopilot!r}: expected one of {', '.join(AUTOPILOTS)}")
    base = out or Path(tempfile.mkdtemp(prefix=f"zdrone-bench-traffic-{autopilot}-"))
    demos: dict[str, Demo] = {}
    results: dict[str, Any] = {}
    errors: dict[str, str] = {}

    def fly(name: str) -> None:
        cipher, paper_hb = VARIANTS[name]
        d = base / name
        d.mkdir(parents=True, exist_ok=True)
        opts = DemoOptions(out=d, speedup=1.0, live=False, quiet=True, tap=True, cipher=cipher, paper_heartbeat=paper_hb,
                           command_rate=0.0, report=False, max_wall=15.0 if quick else None, autopilot=autopilot)
        demo = demos[name] = Demo(opts, d.resolve())
        try:
            results[name] = demo.run()
        except Exception as exc:  # reported in the table, never silently
            errors[name] = str(exc)
            demo.shutdown()

    threads = [threading.Thread(target=fly, args=(n,), daemon=True) for n in VARIANTS]
    for t in threads:
        t.start()
    _show_progress(demos, threads, expected=20.0 if quick else 170.0, enabled=progress)
    for t in threads:
        t.join()
    rows = []
    for name in VARIANTS:
        tap_file = base / name / "tap.json"
        if name in errors or not tap_file.exists():
            rows.append({"variant": name, "error": errors.get(name, "no tap data")})
            continue
        r = _rates(json.loads(tap_file.read_text()))
        s = results.get(name, {})
        rows.append({"variant": name, **r, "flight_ok": bool(s.get("ok")) if not quick else None,
                     "handovers": len(s.get("handovers", []))})
    plain = next((r for r in rows if r["variant"] == "plain" and "error" not in r), None)
    for r in rows:
        if plain and "error" not in r:
            r["change_vs_plain"] = {
                "packets_pct": round((r["packets_per_min"] / plain["packets_per_min"] - 1) * 100, 2),
                "mean_bytes_added": round(r["mean_frame_bytes"] - plain["mean_frame_bytes"], 1)}
    return {"autopilot": autopilot, "rows": rows, "paper_table1": PAPER, "quick": quick,
            "measured_at": "router tap, Zenoh sample payload bytes",
            "targets": {"packets_pct_max": 5.0, "mean_bytes_added_max": 24.0}, "runs": str(base)}


def _show_progress(demos: dict[str, Demo], threads: list[threading.Thread], expected: float, enabled: bool) -> None:
    if not enabled:
        return
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    with Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.fields[stage]}"), TimeElapsedColumn(),
                  transient=True) as prog:
        tasks = {n: prog.add_task(f"flight {n:6}", total=expected, stage="starting") for n in VARIANTS}
        t0 = time.monotonic()
        while any(t.is_alive() for t in threads):
            for n, task in tasks.items():
                d = demos.get(n)
                st = d.progress.get("status", {}) if d else {}
                stage = f"authority {st.get('owner')} epoch {st.get('epoch')}" if st else "starting"
                prog.update(task, completed=min(expected, time.monotonic() - t0), stage=stage)
            time.sleep(0.5)


def render(result: dict[str, Any]) -> None:
    from .table import print_table

    rows = []
    for r in result["rows"]:
        if "error" in r:
            rows.append([r["variant"], "error", r["error"], "", "", "", ""])
            continue
        ch = r.get("change_vs_plain", {})
        rows.append([r["variant"], r["packets_per_min"], r["mean_packet_bytes"], r["up"]["packets_per_min"],
                     r["down"]["packets_per_min"], f"{ch.get('packets_pct', 0):+.2f} %", f"{ch.get('mean_bytes_added', 0):+.1f}"])
    p = result["paper_table1"]
    rows.append(["paper, without", p["without"]["packets_per_min"], p["without"]["mean_packet_bytes"], "", "", "", ""])
    rows.append(["paper, with", p["with"]["packets_per_min"], p["with"]["mean_packet_bytes"], "", "", "+21.74 %", "+2.1"])
    autopilot = result.get("autopilot", "px4")
    print_table(f"Table 1 — traffic through the router (per minute of flight), {autopilot} personality",
                ["variant", "packets/min", "mean bytes", "up pkt/min", "down pkt/min", "packets vs plain", "bytes vs plain"],
                rows, caption="target for zdrone: ≤ +5 % packets, ≤ +24 bytes mean per frame vs plain; "
                              "the paper's rows were measured with PX4's stream")
