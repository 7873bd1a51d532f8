"""``zdrone bench restart``: how fast the owner gets its drone back after a companion restart in flight.

Flies the ``companion-restart`` scenario ``--runs`` times (speed-up 4, two flights at a time): the
drone node is killed (SIGKILL) in the air and started again 0.3 s later. Per run: the time from the
restarted node being ready (its ``restarted`` record, written as it restores the saved authority)
to A's pairing being proven again (the drone's ``paired`` record for A), the commands A sent that
the drone did not forward, whether a failsafe fired, and whether the flight completed. Goal: every
run re-paired within 0.5 s of the node being ready, no failsafe, commands lost only while the node
was down.
"""

from __future__ import annotations

import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from zdrone.core.records import Paired, Restarted, only
from zdrone.net.eventlog import read_records
from zdrone.sil.launcher import Demo, DemoOptions
from zdrone.bench.table import ProgressLine

SPEEDUP = 4.0
GOAL_S = 0.5


def repair_time(drone_log: Path) -> float | None:
    """Seconds from the restarted node's ``restarted`` record to A's next ``paired``, or None."""
    events = read_records(drone_log).records
    restarted = only(events, Restarted)
    if not restarted:
        return None
    t0 = restarted[0].t
    paired = [e.t for e in only(events, Paired) if e.gs == "A" and e.t >= t0]
    return round(paired[0] - t0, 3) if paired else None


def _one(base: Path, i: int) -> dict[str, Any]:
    d = base / f"run-{i + 1}"
    d.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    s = Demo(DemoOptions(out=d, scenario="companion-restart", speedup=SPEEDUP, quiet=True, live=False, report=False),
             d.resolve()).run()
    return {"run": i + 1, "ok": s["ok"], "repair_s": repair_time(d / "drone.jsonl"),
            "commands_lost": s["commands"]["lost"], "failsafe": s["failsafe"] is not None,
            "why_not_ok": s["why_not_ok"], "wall_s": round(time.monotonic() - t0, 1), "dir": str(d)}


def run(runs: int = 20, quick: bool = False, progress: bool = True, parallel: int = 2) -> dict[str, Any]:
    runs = min(runs, 2) if quick else runs
    base = Path(tempfile.mkdtemp(prefix="zdrone-bench-restart-"))
    bar = ProgressLine(enabled=progress)
    rows: list[dict[str, Any]] = []
    with ThreadPoolExecutor(max_workers=max(1, parallel)) as pool:
        for row in pool.map(lambda i: _one(base, i), range(runs)):
            rows.append(row)
            bar.say(f"restart run {len(rows)}/{runs}: re-paired after {row['repair_s']} s")
    bar.close()
    times = [r["repair_s"] for r in rows if r["repair_s"] is not None]
    return {"runs": len(rows), "speedup": SPEEDUP, "rows": rows,
            "repaired": len(times), "worst_repair_s": max(times) if times else None,
            "median_repair_s": sorted(times)[len(times) // 2] if times else None,
            "within_goal": sum(1 for t in times if t <= GOAL_S), "failsafes": sum(r["failsafe"] for r in rows),
            "ok": all(r["ok"] for r in rows) and len(times) == len(rows) and all(t <= GOAL_S for t in times),
            "goal": f"every run re-paired within {GOAL_S} s of the node being ready, no failsafe"}


def render(result: dict[str, Any]) -> None:
    from zdrone.bench.table import print_table

    rows = [[r["run"], r["repair_s"] if r["repair_s"] is not None else "never", r["commands_lost"],
             "yes" if r["failsafe"] else "-", "ok" if r["ok"] else "; ".join(r["why_not_ok"])] for r in result["rows"]]
    print_table(f"Companion restart: {result['runs']} runs, re-paired within {GOAL_S} s in {result['within_goal']}, "
                f"worst {result['worst_repair_s']} s, median {result['median_repair_s']} s",
                ["run", "re-paired after (s)", "commands lost", "failsafe", "verdict"], rows,
                caption=result["goal"])
