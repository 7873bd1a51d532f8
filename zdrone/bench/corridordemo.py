"""``zdrone demo --scenario corridor | corridor-gs-down``: a beyond-line-of-sight corridor, flown by the
corridor bench's processes (its scenario table: ``zdrone.sil.scenarios.CORRIDOR_SCENARIOS``).

Eight GSs along 16 km (A … H, 2.3 km apart, coverage 1.4 km: neighbours overlap by 571 m) over two site
routers meshed by mutual TLS (the GSs alternate between the sites), one drone flying from A to H and
back at 20 m/s. Only A pairs with it; every other GS gets its link from the owner of the moment, prepared
ahead as the drone comes its way, and the drone closes the link of a GS it has left behind
(``zdrone.core.linkplan``). The processes are those of ``zdrone bench scale --layout corridor``: the
site routers, the drones host (the drone node with its in-process simulator) and the stations host (the
eight GSs, each with its own Zenoh session and loop).

``corridor`` is correct when the drone made all 14 hand-overs (one at each GS each way), was never
without exactly one owner in the air, never held more than ``links_max`` (3) links, lost no command,
never entered its failsafe, and landed where it took off.

``corridor-gs-down``: D, a GS in the middle, dies (its loop ends and its session closes in the shared
stations host, as a killed process) 0.5 s after it took authority on the way out. By the rules the drone
then goes to an heir (an authorized GS whose coverage holds its position, with a link proven there:
here C, whose coverage it has not left) or, with none, lands by its failsafe. It is correct when
the first change of authority after D's death is an emergency hand-over to a GS covering the drone's
logged position, or the failsafe fired; no GS but the owner of the moment commanded it; never more than
3 links; and the vehicle ended on the ground. Its mission does not resume past D: the heir hands it
back home (its hand-over toward the dead D fails and the vehicle, leaving its coverage, is sent home).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Any

from zdrone.core import records as rec
from zdrone.core.geometry import GeoPoint
from zdrone.net.eventlog import read_records

GSS = 8
LENGTH_M = 16_000.0
SITES = 2
MIDDLE = "D"
#: D dies this long (wall) after it took authority: the drone is still in the C-D overlap at any speed-up
#: up to 16 (its 266 m past the hand-over point at 20 m/s), so the rules give it to the heir C
KILL_AFTER_S = 0.5


def run(scenario: str, out: Path, speedup: float) -> int:
    """Fly ``scenario``; 0 when the flight is correct (``summary.json`` in ``out`` says why not)."""
    from zdrone.bench.scale import CORRIDOR_SPEED_MS, _one
    from zdrone.fleet.files import load_fleet

    out.mkdir(parents=True, exist_ok=True)
    out = out.resolve()
    print(f"zdrone demo: scenario {scenario}, speed-up {speedup:g}, output in {out}", flush=True)
    t0 = time.monotonic()
    kill = (MIDDLE, KILL_AFTER_S) if scenario == "corridor-gs-down" else None
    row = _one(1, GSS, out, timeout=(2 * LENGTH_M / CORRIDOR_SPEED_MS + 300.0) / speedup, sites=SITES,
               speedup=speedup, hosts_nice=0, corridor=LENGTH_M, round_trip=True, kill=kill)
    run_dir = Path(row.get("runs") or next(out.glob("k1-*")))
    why: list[str] = []
    if "error" in row:
        why.append(row["error"])
    drone: dict[str, Any] = {}
    try:
        drone = json.loads((run_dir / "drones.json").read_text())["results"]["d1"]
    except (OSError, ValueError, KeyError) as exc:
        why.append(f"no drone results ({exc})")
    if drone:
        why += judge(scenario, row, drone, run_dir, load_fleet(run_dir / "fleet"))
    summary = {"scenario": scenario, "ok": not why, "why_not_ok": why, "speedup": speedup,
               "wall_time_s": round(time.monotonic() - t0, 1), "handovers": drone.get("handovers"),
               "owners": drone.get("owners"), "links_max": row.get("links_max_per_drone"),
               "links_closed": row.get("links_closed"), "worst_owner_silence_s": row.get("worst_owner_silence_s"),
               "state": drone.get("state"), "landed": drone.get("landed"), "run": str(run_dir)}
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    owners = "->".join(o or "-" for o in drone.get("owners", []))
    print(f"{'OK' if not why else 'FAILED'}: {scenario} in {summary['wall_time_s']:.1f} s; owners {owners}; "
          f"{drone.get('handovers')} hand-overs; at most {row.get('links_max_per_drone')} links, "
          f"{row.get('links_closed')} closed; worst authority silence {row.get('worst_owner_silence_s')} s"
          + (f"; why: {'; '.join(why)}" if why else ""), flush=True)
    print(f"summary: {out / 'summary.json'}; events: {run_dir / 'd1.jsonl'}")
    return 0 if not why else 1


def judge(scenario: str, row: dict[str, Any], drone: dict[str, Any], run_dir: Path, fleet: Any) -> list[str]:
    """What makes the flight not correct (none: correct)."""
    why: list[str] = []
    if row.get("links_max_per_drone", 99) > fleet.links_max:
        why.append(f"{row.get('links_max_per_drone')} links at once (at most {fleet.links_max})")
    if not drone.get("flew"):
        why.append("never took off")
    if not drone.get("landed"):
        why.append("not on the ground at the end")
    if scenario == "corridor":
        return why + list(row.get("failures", {}).get("d1", []))
    try:
        killed = json.loads((run_dir / "killed.json").read_text())
    except (OSError, ValueError):
        return why + [f"{MIDDLE} was never killed (it never owned the drone in the air for {KILL_AFTER_S:g} s)"]
    records = read_records(run_dir / "d1.jsonl").records
    after = [r for r in records if r.t >= killed["t"] - 0.5]
    changes = [r for r in after if isinstance(r, (rec.HandoverComplete, rec.AuthorityChange)) and r.from_ == MIDDLE]
    failsafe = [r for r in after if isinstance(r, rec.Failsafe)]
    if changes:
        c = changes[0]
        cover = fleet.nodes[c.to].coverage.circle()
        if c.kind != "emergency":
            why.append(f"authority left {MIDDLE} by {c.kind}, not an emergency hand-over")
        if c.position is None or not cover.contains(GeoPoint(c.position[0], c.position[1])):
            why.append(f"the heir {c.to} did not cover the drone at {c.position}")
    elif not failsafe:
        why.append(f"neither an heir nor the failsafe after {MIDDLE} died")
    else:  # the failsafe is right only where no other GS covered the drone (a covering one is prepared: an heir)
        p = failsafe[0].position
        covering = [] if p is None else [g for g in fleet.ground_stations() if g != MIDDLE
                                         and fleet.nodes[g].coverage.circle().contains(GeoPoint(p[0], p[1]))]
        if covering:
            why.append(f"the failsafe fired where {', '.join(covering)} covered the drone (an heir was due)")
    forwarded = drone.get("forwarded_epochs", {})
    owners_by_epoch = {str(e): o for o, e in drone.get("epochs", [])}
    bad = [k for k in forwarded if owners_by_epoch.get(k.split(":")[0]) != k.split(":", 1)[1]]
    if bad:
        why.append(f"commands forwarded from a GS not the epoch's owner: {bad}")
    return why


def main(scenario: str, out: Path | None, speedup: float) -> int:
    """``zdrone demo`` for a corridor scenario."""
    out = out or Path("runs") / time.strftime(f"demo-{scenario}-%Y%m%d-%H%M%S")
    try:
        return run(scenario, out, speedup)
    except (RuntimeError, OSError) as exc:
        print(f"zdrone demo: failed: {exc}", file=sys.stderr)
        return 1
