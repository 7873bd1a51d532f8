"""``zdrone bench view --only corridor``: the live page following a corridor fleet (20 GSs along 40 km, 100
drones flying it both ways at speed-up 1, links following them), in headless Chromium.

The processes: one router, ``zdrone view`` (the fleet's viewer V), the drones host and the stations host of
``zdrone bench scale --layout corridor``. The page is opened before the fleet pairs; from take-off it is
read once a second for ``window`` seconds: the coverage circles it draws, the drone rows, each row's owner
and the GSs its links cell lists (the drone's prepared GSs: only GSs that report a link with it). The
page *shows the corridor* when it draws every GS's circle, shows every drone, and never lists more than
the fleet's ``links_max`` GSs for a drone. A screenshot of the last sample is kept (``view-corridor.png``).
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from zdrone.bench.table import ProgressLine
from zdrone.bench.viewpage import STREAM_PROBE, Browser, start_in_order

#: What the page shows of the corridor now.
READ_CORRIDOR = """() => {
  const rows = [...document.querySelectorAll('#rows tr[data-drone]')];
  const links = rows.map((tr) => { const t = tr.querySelector('td.links').textContent.trim();
                                   return t ? t.split(' · ').length : 0; });
  return {circles: document.querySelectorAll('#coverage circle').length, rows: rows.length,
          owners: rows.filter((tr) => tr.dataset.owner).length, links_max: Math.max(0, ...links),
          links_mean: links.length ? links.reduce((a, b) => a + b, 0) / links.length : 0,
          stale: rows.filter((tr) => tr.dataset.stale === 'true').length};
}"""
K, G, LENGTH_M = 100, 20, 40_000.0


def corridor_page(browser: Browser, base: Path, window: float, status: ProgressLine, k: int = K,
                  g: int = G) -> dict[str, Any]:
    from zdrone.bench.scale import READY_TIMEOUT_S, _wait_line
    from zdrone.fleet.files import corridor_layout, corridor_nodes, init_fleet
    from zdrone.sil.ports import free_port
    from zdrone.sil.procs import stop_in_order

    d = base / f"corridor-{k}x{g}"
    d.mkdir(parents=True, exist_ok=True)
    endpoint, port = f"tcp/127.0.0.1:{free_port()}", free_port()
    init_fleet(d / "fleet", nodes_spec=corridor_nodes(k, g, LENGTH_M), coverage_radius_m=corridor_layout(g, LENGTH_M)[1])
    py = [sys.executable, "-m"]
    common = ["--fleet", str(d / "fleet"), "--out", str(d), "--corridor", str(LENGTH_M)]
    cmds = {"router": py + ["zdrone", "router", "-c", str(d / "fleet/router/router.json5"), "--listen", endpoint],
            "view": py + ["zdrone", "view", "--fleet", str(d / "fleet"), "--router", endpoint, "--port", str(port)],
            "drones": py + ["zdrone.bench.scale", "host-drones", "--k", str(k), "--speedup", "1",
                            "--duration", str(window + 120.0), "--hold", "120", "--router", endpoint, *common],
            "stations": py + ["zdrone.bench.scale", "host-stations", "--stations", str(g), "--k", str(k),
                              "--router", endpoint, *common]}
    ready = {"router": "listening", "view": "zdrone view:"}
    logs = {n: open(d / f"{n}.log", "w") for n in cmds}
    procs: dict[str, subprocess.Popen] = {}
    out: dict[str, Any] = {"k": k, "g": g, "length_m": LENGTH_M, "window_s": window, "runs": str(d)}
    samples: list[dict[str, Any]] = []
    try:
        start_in_order(cmds, ready, d, logs, procs)
        page = browser.open(f"http://127.0.0.1:{port}", STREAM_PROBE)
        status.say(f"view: corridor {k} drones x {g} GSs pairing…")
        if _wait_line(d / "drones.log", "take-off", READY_TIMEOUT_S + 120, procs["drones"]) is None:
            raise RuntimeError(f"the drones did not take off; see {d / 'drones.log'}")
        t0 = time.monotonic()
        while time.monotonic() - t0 < window:
            time.sleep(max(0.0, 1.0 - (time.monotonic() - t0) % 1.0))
            samples.append(page.evaluate(READ_CORRIDOR))
            s = samples[-1]
            status.say(f"view: corridor, {time.monotonic() - t0:.0f}/{window:.0f} s, {s['circles']} circles, "
                       f"{s['rows']} rows, at most {s['links_max']} links listed")
        shot = d / "view-corridor.png"
        page.screenshot(path=str(shot), full_page=True)
        page.close()
        last = samples[-1] if samples else {}
        out.update({"samples": len(samples), "last": last, "screenshot": str(shot),
                    "circles_min": min((s["circles"] for s in samples), default=0),
                    "rows_min": min((s["rows"] for s in samples), default=0),
                    "links_listed_max": max((s["links_max"] for s in samples), default=0),
                    "stale_max": max((s["stale"] for s in samples), default=0)})
        out["shows_corridor"] = (out["circles_min"] == g and out["rows_min"] == k and out["links_listed_max"] <= 3)
    except Exception as exc:  # a part that could not run says why (the bench goes on with the others)
        out["error"] = f"{type(exc).__name__}: {exc}"
    finally:
        stop_in_order(procs, ("stations", "drones", "view", "router"))
        for f in logs.values():
            f.close()
    return out


def render_corridor(r: dict[str, Any]) -> None:
    from zdrone.bench.table import print_table

    if "error" in r:
        print_table("View: the corridor", ["error"], [[r["error"]]])
        return
    print_table(f"View: the corridor ({r['k']} drones x {r['g']} GSs along {r['length_m'] / 1000:g} km), "
                f"{r['samples']} samples from take-off",
                ["circles (min)", "drone rows (min)", "GSs listed per drone (max)", "stale rows (max)", "shows it",
                 "screenshot"],
                [[r["circles_min"], r["rows_min"], r["links_listed_max"], r["stale_max"],
                  "yes" if r["shows_corridor"] else "no", r["screenshot"]]],
                caption="the page in headless Chromium; a drone's links cell lists only the GSs reporting a link "
                        "with it (its owner and prepared GSs)")
