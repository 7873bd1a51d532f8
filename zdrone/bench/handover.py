"""``zdrone bench handover``: repeated hand-overs under a 20 Hz command stream, and link-loss trials.

Part 1 flies a shuttle mission across the overlap ``N`` times (A->B->A...), the authority GS sending
a 20 Hz command stream. From the drone's event log and the GSs' counters: authority gap (time with
no owner after pairing; every switch is one atomic step of the authority machine), commands lost
(sent by the authority, neither forwarded nor refused) and duplicated (forwarded more than sent),
and the hand-over duration from entering the region to the switch.

Part 2 runs the ``link-loss`` scenario ``M`` times: the authority GS goes silent; the drone's
detection-to-LAND latency is measured from the instant the TBM threshold passed.
"""

from __future__ import annotations

import statistics
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from zdrone.core.records import AnyRecord, HandoverComplete, RegionEntered
from zdrone.net.eventlog import read_records
from zdrone.sil.launcher import Demo, DemoOptions
from zdrone.bench.table import ProgressLine


def _shuttle(base: Path, crossings: int, speedup: float) -> dict[str, Any]:
    d = base / "shuttle"
    d.mkdir(parents=True, exist_ok=True)
    demo = Demo(DemoOptions(out=d, speedup=speedup, quiet=True, live=False, command_rate=20.0, report=False,
                            mission=f"shuttle:{crossings}"), d.resolve())
    summary = demo.run()
    handovers, durations = _region_to_switch(read_records(d / "drone.jsonl").records, speedup)
    c = summary["commands"]
    sent = sum(c["sent_as_authority"].values())
    fwd = sum(int(v) for v in c["forwarded"].values())
    return {"crossings": crossings, "handovers": len(handovers), "authority_gap_ms": summary["authority_gap_ms"],
            "commands_sent": sent, "commands_forwarded": fwd, "commands_lost": max(0, c["lost"]),
            "commands_duplicated": max(0, fwd - sent), "refused_not_authority": c["refused_not_authority"],
            "region_to_switch_s": {"mean": round(statistics.mean(durations), 2) if durations else None,
                                   "max": round(max(durations), 2) if durations else None},
            "flight_ok": summary["ok"] or summary["distance_from_home_m"] is not None and summary["distance_from_home_m"] < 3}


def _region_to_switch(events: list[AnyRecord], speedup: float) -> tuple[list[HandoverComplete], list[float]]:
    """The hand-overs, and for each one after an entry into the region, the simulated seconds of
    flight from that entry to the switch."""
    handovers: list[HandoverComplete] = []
    durations: list[float] = []
    entered: float | None = None
    for e in events:
        if isinstance(e, RegionEntered):
            entered = e.t
        elif isinstance(e, HandoverComplete):
            handovers.append(e)
            if entered is not None:
                durations.append((e.t - entered) * speedup)  # simulated seconds of flight in the region
                entered = None
    return handovers, durations


def _link_loss(base: Path, trials: int, speedup: float) -> list[float | None]:
    out: list[float | None] = [None] * trials

    def one(i: int) -> None:
        d = base / f"linkloss-{i}"
        d.mkdir(parents=True, exist_ok=True)
        s = Demo(DemoOptions(out=d, scenario="link-loss", speedup=speedup, quiet=True, live=False, report=False,
                             command_rate=0.0), d.resolve()).run()
        fs = s.get("failsafe") or {}
        out[i] = fs.get("detect_to_command_ms")

    threads = [threading.Thread(target=one, args=(i,), daemon=True) for i in range(trials)]
    for t in threads:  # trials run side by side: each is its own router, sim, drone and GSs
        t.start()
    for t in threads:
        t.join()
    return out


def run(quick: bool = False, crossings: int | None = None, trials: int | None = None, progress: bool = True) -> dict[str, Any]:
    base = Path(tempfile.mkdtemp(prefix="zdrone-bench-handover-"))
    n = crossings or (2 if quick else 6)
    m = trials or (1 if quick else 3)
    t0 = time.monotonic()
    status = ProgressLine(progress)
    status.say(f"shuttle flight: {n} crossings under a 20 Hz command stream")
    shuttle = _shuttle(base, n, 4.0)
    status.say(f"link-loss trials: {m}")
    ll = _link_loss(base, m, 4.0)
    status.close()
    vals = [v for v in ll if v is not None]
    return {"handover": shuttle,
            "link_loss": {"trials": m, "detect_to_land_ms": [round(v, 2) for v in vals],
                          "max_ms": round(max(vals), 2) if vals else None, "threshold_s": 3.0,
                          "missing": m - len(vals)},
            "targets": {"authority_gap_ms": 0, "commands_lost": 0, "commands_duplicated": 0, "detect_to_land_ms_max": 100},
            "wall_s": round(time.monotonic() - t0, 1), "runs": str(base)}


def render(r: dict[str, Any]) -> None:
    from zdrone.bench.table import print_table

    h, ll = r["handover"], r["link_loss"]
    rows = [["hand-overs completed", f"{h['handovers']} of {h['crossings']} crossings"],
            ["authority gap", f"{h['authority_gap_ms']:.0f} ms"],
            ["commands sent / forwarded", f"{h['commands_sent']} / {h['commands_forwarded']}"],
            ["commands lost / duplicated", f"{h['commands_lost']} / {h['commands_duplicated']}"],
            ["region entered -> switch (sim s)", f"mean {h['region_to_switch_s']['mean']}, max {h['region_to_switch_s']['max']}"],
            ["link loss -> LAND after 3 s threshold", ", ".join(f"{v:.1f} ms" for v in ll["detect_to_land_ms"]) or "n/a"]]
    print_table("Hand-over under a 20 Hz command stream", ["measure", "value"], rows,
                caption="targets: 0 ms gap, 0 lost, 0 duplicated, LAND ≤ threshold + 100 ms")
