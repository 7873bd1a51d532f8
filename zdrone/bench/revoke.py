"""``zdrone bench revoke``: K drones x 3 ground stations in flight, GS B revoked by a signed fleet
revision published through A while B holds authority over some of them.

Layout: the layout of ``zdrone bench scale`` (one router; the K drone nodes in one process, the
GSs in another: ``python -m zdrone.bench.scale host-drones | host-stations``), on a fleet of K
drones and GSs A, B, C 500 m apart, every drone flying the shuttle A -> C -> A. Once B holds
authority over at least one drone (its first hand-over A -> B in the drones' logs), the bench signs
the revision revoking B on the fleet directory (``zdrone.fleet.revise.revoke``) and publishes it on
A's revision key (``zdrone.net.revisions.publish``); the GSs re-publish it every 10 s.

Figures, from the drones' event logs and the hosts' results:

* **revision -> applied**, per drone: from the publication to the drone's ``revision_applied``
  record (wall clock, one machine), p50 / p99 / max. From that instant no frame of B opens on the
  drone (its link and keys are gone): this bounds the time to the last frame of B accepted;
* the drones B held at the revocation, and where they went (an heir, else the failsafe);
* commands of the other GSs lost (sent by A or C and not forwarded), failsafes in all, and those
  commanded where an authorized GS's coverage held the vehicle (``covered``: should be 0; in the
  shuttle, B's area between A and C is covered by nobody once B is out, so a drone flying on into
  it lands: that is the failsafe the issue expects where no authorized GS covers the drone).

The routers are not restarted here (``zdrone demo --scenario revoke-in-flight`` does that, and the
``router-restart`` scenario measures what a restart costs).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from ..core.records import AuthorityMoved, Failsafe, RevisionApplied, only

QUICK_K = 3
FULL_K = 100
STATIONS = 3
REVOKED = "B"


def percentile(sorted_values: list[float], q: float) -> float:
    """The ``q``-th percentile (nearest rank) of sorted values."""
    i = min(len(sorted_values) - 1, max(0, round(q / 100.0 * len(sorted_values) + 0.5) - 1))
    return sorted_values[i]


def _records(d: Path, k: int) -> dict[str, list[Any]]:
    from ..net.eventlog import read_records

    out: dict[str, list[Any]] = {}
    for i in range(k):
        p = d / f"d{i + 1}.jsonl"
        out[f"d{i + 1}"] = list(read_records(p).records) if p.exists() else []
    return out


def _held_by_b(recs: list[Any]) -> bool:
    moves = only(recs, AuthorityMoved)
    return bool(moves) and moves[-1].to == REVOKED


def run_one(k: int, base: Path, timeout: float) -> dict[str, Any]:
    from ..fleet.files import init_fleet, scale_nodes
    from ..fleet.revise import revoke
    from ..net.revisions import publish
    from ..sil.procs import spawn
    from .scale import SPEEDUP, _free_ports, _wait_line, hold_limit

    d = base / f"k{k}"
    d.mkdir(parents=True, exist_ok=True)
    fleet = d / "fleet"
    init_fleet(fleet, nodes_spec=scale_nodes(k, STATIONS))
    router = f"tcp/127.0.0.1:{_free_ports(1)[0]}"
    py = [sys.executable, "-m"]
    logs = {n: open(d / f"{n}.log", "w") for n in ("router", "drones", "stations")}
    procs: dict[str, subprocess.Popen] = {}
    common = ["--fleet", str(fleet), "--out", str(d), "--router", router]
    result: dict[str, Any] = {"k": k, "g": STATIONS, "runs": str(d)}
    t_pub: float | None = None
    held: list[str] = []
    try:
        procs["router"] = spawn(py + ["zdrone", "router", "-c", str(fleet / "router" / "router.json5"), "--listen", router],
                                stdout=logs["router"], stderr=subprocess.STDOUT)
        if _wait_line(d / "router.log", "listening", 20, procs["router"]) is None:
            raise RuntimeError(f"the router did not start; see {d / 'router.log'}")
        procs["drones"] = spawn(py + ["zdrone.bench.scale", "host-drones", "--k", str(k), "--speedup", str(SPEEDUP),
                                      "--duration", str(timeout), "--hold", str(hold_limit(k)), "--drone-router", "spread",
                                      *common], stdout=logs["drones"], stderr=subprocess.STDOUT)
        procs["stations"] = spawn(py + ["zdrone.bench.scale", "host-stations", "--stations", str(STATIONS), *common],
                                  stdout=logs["stations"], stderr=subprocess.STDOUT)
        if _wait_line(d / "drones.log", "take-off", 180 + hold_limit(k), procs["drones"]) is None:
            raise RuntimeError(f"the drones never took off; see {d / 'drones.log'}")
        procs["stations"].send_signal(__import__("signal").SIGUSR1)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:  # B's first hand-over
            held = [n for n, recs in _records(d, k).items() if _held_by_b(recs)]
            if held:
                break
            time.sleep(0.2)
        if not held:
            raise RuntimeError("B never held authority over a drone")
        revoke(fleet, REVOKED, note="bench revoke")
        t_pub = time.time()
        publish(fleet, "A", router, (fleet / "revision.json").read_bytes())
        try:
            procs["drones"].wait(timeout + 60)
        except subprocess.TimeoutExpired:
            result["error"] = "the drones host did not finish"
    except RuntimeError as exc:
        result["error"] = str(exc)
    finally:
        for name in ("stations", "drones", "router"):
            p = procs.get(name)
            if p is not None and p.poll() is None:
                p.terminate()
                try:
                    p.wait(20)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait(5)
        for f in logs.values():
            f.close()
    if t_pub is None:
        return result
    recs = _records(d, k)
    applied = {n: next((e.t for e in only(r, RevisionApplied) if REVOKED in e.revoked), None) for n, r in recs.items()}
    lat = sorted((t - t_pub) * 1000.0 for t in applied.values() if t is not None)
    after = {n: [e for e in only(r, AuthorityMoved) if e.t >= t_pub] for n, r in recs.items()}
    failsafes = {n: len(only(r, Failsafe)) for n, r in recs.items()}
    covered = _failsafes_covered(fleet, recs)
    lost_others = 0
    try:
        drones = json.loads((d / "drones.json").read_text())["results"]
        sent = json.loads((d / "stations.json").read_text())["commands_sent"]
        for n, r in drones.items():
            for gs in sent:
                if gs != REVOKED:
                    lost_others += max(0, sent[gs].get(n, 0) - r["forwarded"].get(gs, 0))
    except (OSError, ValueError, KeyError) as exc:
        result["error"] = result.get("error") or f"no host results ({exc})"
    b_after = sum(1 for moves in after.values() for e in moves if e.to == REVOKED)
    result.update({
        "applied": f"{len(lat)}/{k}",
        "applied_ms": {"p50": round(percentile(lat, 50), 1) if lat else None,
                       "p99": round(percentile(lat, 99), 1) if lat else None,
                       "max": round(lat[-1], 1) if lat else None},
        "held_by_b": len(held),
        "held_went_to": {n: (after[n][0].to, after[n][0].kind) if after[n] else "failsafe" if failsafes[n] else "-"
                         for n in held},
        "b_authority_after": b_after,
        "other_commands_lost": lost_others,
        "failsafes": sum(1 for v in failsafes.values() if v),
        "failsafes_where_a_gs_covered": covered,
    })
    return result


def _failsafes_covered(fleet_dir: Path, recs: dict[str, list[Any]]) -> int:
    """Failsafes commanded where an authorized GS's coverage held the vehicle (the revision's fleet)."""
    from ..core.geometry import GeoPoint
    from ..fleet.files import load_fleet

    fleet = load_fleet(fleet_dir)
    n = 0
    for drone, r in recs.items():
        for e in only(r, Failsafe):
            if e.position is None:
                continue
            p = GeoPoint(e.position[0], e.position[1])
            n += any(fleet.nodes[g].coverage.circle().contains(p) for g in fleet.nodes[drone].authorized_gs  # type: ignore[union-attr]
                     if not fleet.is_revoked(g))
    return n


def run(quick: bool = False, k: int | None = None, timeout: float = 240.0) -> dict[str, Any]:
    k = k or (QUICK_K if quick else FULL_K)
    base = Path(tempfile.mkdtemp(prefix="zdrone-bench-revoke-"))
    return {"rows": [run_one(k, base, timeout)]}


def render(r: dict[str, Any]) -> None:
    print("revoke B in flight (revision signed, published through A; the GSs re-publish it every 10 s)")
    print(f"{'drones x GSs':>13} {'applied':>8} {'p50 ms':>8} {'p99 ms':>8} {'max ms':>8} {'B held':>7} "
          f"{'B after':>8} {'others lost':>12} {'failsafes':>10} {'covered':>8}")
    for row in r["rows"]:
        if "applied" not in row:
            print(f"{row['k']:>6} x {row['g']:<5} error: {row.get('error')}")
            continue
        a = row["applied_ms"]
        print(f"{row['k']:>6} x {row['g']:<5} {row['applied']:>8} {a['p50']!s:>8} {a['p99']!s:>8} {a['max']!s:>8} "
              f"{row['held_by_b']:>7} {row['b_authority_after']:>8} {row['other_commands_lost']:>12} {row['failsafes']:>10} "
              f"{row['failsafes_where_a_gs_covered']:>8}")
        print(f"  where B's drones went: {row['held_went_to']}" + (f"; error: {row['error']}" if row.get("error") else ""))
        print(f"  runs: {row['runs']}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="zdrone bench revoke")
    p.add_argument("--quick", action="store_true")
    p.add_argument("--drones", type=int)
    p.add_argument("--json", action="store_true")
    a = p.parse_args(argv)
    r = run(a.quick, a.drones)
    print(json.dumps(r, indent=2)) if a.json else render(r)
    return 0 if all("error" not in row for row in r["rows"]) else 1


if __name__ == "__main__":
    sys.exit(main())
