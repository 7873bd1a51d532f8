"""``zdrone bench sweep``: every scenario of the scenario table at speed-ups 1, 2 and 4 and, for each
fault, at every moment of the flight it can land at (``MOMENTS``: before the overlap, inside it,
during the hand-over, on the way back); a table scenario x speed x moment of the outcomes.

A scenario passes at every speed-up and whatever moment its fault lands, or it does not pass. At a
scenario's own moment its own check decides; moved elsewhere, what holds at any moment
(``fault_over_check``: the safety invariants, and a completed flight whenever no fault is still
active when the drone returns). A cell replays alone with
``zdrone demo --scenario S --speedup X --moment M``.

The flights of one sweep run ``jobs`` at a time (each in its own folder, on its own free ports);
each cell's result is appended to ``cells.jsonl`` in the sweep's folder as it ends, so a sweep cut
short still says what it found.
"""

from __future__ import annotations

import json
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

from zdrone.sil.launcher import SCENARIO_BY_NAME, SCENARIO_TABLE, Demo, DemoOptions
from zdrone.bench.table import ProgressLine

SPEEDUPS = (1.0, 2.0, 4.0)
#: ``--quick``: two cells flown at once (about 45 s): the failure this sweep was made for (A's site
#: router dying in the overlap at speed-up 2) and B dying on the way back while it holds authority.
#: (A's site router dying during the hand-over is ``zdrone bench chaos --sites --seed 39``, in the suite.)
QUICK: tuple[tuple[str, float, str | None], ...] = (
    ("site-router-down", 2.0, "in_overlap"),
    ("gs-crash", 4.0, "way_back"),
)
DEFAULT_JOBS = 2


@dataclass(frozen=True)
class Cell:
    """One flight of the sweep: a scenario at a speed-up, its fault at a moment (None: no fault)."""

    scenario: str
    speedup: float
    moment: str | None
    sites: bool = False  # over a router per site (``zdrone demo --sites``) whatever the scenario's own row says

    @property
    def label(self) -> str:
        return (f"{self.scenario} x{self.speedup:g}" + (f" @{self.moment}" if self.moment else "")
                + (" (sites)" if self.sites else ""))

    @property
    def folder(self) -> str:
        return f"{self.scenario}-x{self.speedup:g}-{self.moment or 'none'}" + ("-sites" if self.sites else "")

    def replay(self) -> str:
        return (f"zdrone demo --scenario {self.scenario} --speedup {self.speedup:g}"
                + (f" --moment {self.moment}" if self.moment else "") + (" --sites" if self.sites else ""))


def cells(quick: bool = False, scenarios: Sequence[str] = (), speedups: Sequence[float] = (),
          moments: Sequence[str] = (), sites: bool = False) -> list[Cell]:
    """The sweep's cells (filtered by scenario, speed-up and moment when given); with ``sites``, each
    flown over a router per site (``zdrone demo --sites``)."""
    if quick:
        out = [Cell(*c) for c in QUICK]
    else:
        out = [Cell(s.name, sp, m) for s in SCENARIO_TABLE for sp in SPEEDUPS for m in (s.moments() or (None,))]
    out = [Cell(c.scenario, c.speedup, c.moment, True) for c in out] if sites else out
    return [c for c in out if (not scenarios or c.scenario in scenarios) and (not speedups or c.speedup in speedups)
            and (not moments or c.moment in moments)]


def fly(cell: Cell, base: Path) -> dict[str, Any]:
    """Fly one cell; its row of the table."""
    spec = SCENARIO_BY_NAME[cell.scenario]
    own = spec.own_moment()
    out = base / cell.folder
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    opts = DemoOptions(out=out, scenario=cell.scenario, speedup=cell.speedup,
                       moment=cell.moment if cell.moment != own else None, quiet=True, live=False, report=False,
                       sites=spec.sites or cell.sites, tls=spec.tls)
    demo = Demo(opts, out.resolve())
    try:
        summary = demo.run()
    except (RuntimeError, OSError) as exc:  # could not start (Demo.run stopped its children): a failed cell
        return {"scenario": cell.scenario, "speedup": cell.speedup, "moment": cell.moment, "sites": cell.sites, "ok": False,
                "why": [f"did not start: {exc}"], "wall_s": round(time.monotonic() - t0, 1), "run": str(out),
                "replay": cell.replay()}
    return {"scenario": cell.scenario, "speedup": cell.speedup, "moment": cell.moment, "sites": cell.sites,
            "own_moment": cell.moment == own,
            "ok": bool(summary["ok"]), "why": summary["why_not_ok"],
            "handovers": [f"{h['from']}->{h['to']} ({h['kind']})" for h in summary["handovers"]],
            "failsafe": summary["failsafe"] is not None, "delivered": bool(summary.get("delivered")),
            "faults": [f["text"] for f in summary.get("faults", [])],
            "crashes": [n for n in summary["notes"] if " crashed: " in n],  # a child's signal and its stacks
            "wall_s": round(time.monotonic() - t0, 1), "run": str(out), "replay": cell.replay()}


def run(quick: bool = False, jobs: int = DEFAULT_JOBS, scenarios: Sequence[str] = (), speedups: Sequence[float] = (),
        moments: Sequence[str] = (), out: Path | None = None, progress: bool = True,
        sites: bool = False) -> dict[str, Any]:
    todo = cells(quick, scenarios, speedups, moments, sites)
    base = out or Path(tempfile.mkdtemp(prefix="zdrone-bench-sweep-"))
    base.mkdir(parents=True, exist_ok=True)
    journal = base / "cells.jsonl"
    bar = ProgressLine(enabled=progress)
    rows: list[dict[str, Any]] = []
    lock = threading.Lock()
    t0 = time.monotonic()
    with ThreadPoolExecutor(max_workers=max(1, jobs)) as pool:
        futures = {pool.submit(fly, c, base): c for c in todo}
        for fut in as_completed(futures):
            row = fut.result()
            with lock:
                rows.append(row)
                with journal.open("a") as fh:
                    fh.write(json.dumps(row) + "\n")
            failed = sum(not r["ok"] for r in rows)
            bar.say(f"sweep: {len(rows)}/{len(todo)} cells, {failed} failed; last {futures[fut].label}: "
                    f"{'ok' if row['ok'] else 'FAILED'}")
    bar.close()
    order = {c: i for i, c in enumerate(todo)}
    rows.sort(key=lambda r: order[Cell(r["scenario"], r["speedup"], r["moment"], r.get("sites", False))])
    return {"cells": len(rows), "failed": sum(not r["ok"] for r in rows), "jobs": jobs, "quick": quick,
            "speedups": sorted({r["speedup"] for r in rows}), "wall_s": round(time.monotonic() - t0, 1),
            "folder": str(base), "rows": rows, "goal": "every cell passes"}


def render(result: dict[str, Any]) -> None:
    """A table: one row per scenario and moment, one column per speed-up; then why each failed cell failed."""
    from zdrone.bench.table import print_table

    speeds = result["speedups"]
    grid: dict[tuple[str, str], dict[float, str]] = {}
    for r in result["rows"]:
        moment = ((r["moment"] or "-") + (" (own)" if r.get("own_moment") and r["moment"] else "")
                  + (" (sites)" if r.get("sites") else ""))
        grid.setdefault((r["scenario"], moment), {})[r["speedup"]] = "ok" if r["ok"] else "FAIL"
    rows = [[sc, m, *(cols.get(sp, "") for sp in speeds)] for (sc, m), cols in grid.items()]
    print_table(f"Sweep: {result['cells']} cells, {result['failed']} failed ({result['wall_s']:.0f} s, "
                f"{result['jobs']} at a time)", ["scenario", "fault moment", *(f"x{sp:g}" for sp in speeds)], rows,
                caption=f"runs in {result['folder']}")
    for r in result["rows"]:
        if not r["ok"]:
            print(f"FAILED {r['replay']}: {'; '.join(r['why'])} ({r['run']})")
        for crash in r.get("crashes", ()):
            print(crash)
