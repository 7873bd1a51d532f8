"""``zdrone bench revoke``: K drones x 3 ground stations in flight, GS B revoked by a signed fleet
revision published through A while B holds authority over a third of them.

Layout: the layout of ``zdrone bench scale`` (one router; the K drone nodes in one process, the
GSs in another: ``python -m zdrone.bench.scale host-drones | host-stations``), on a fleet of K
drones and GSs A, B, C 500 m apart, every drone flying the shuttle A -> C -> A. Once B holds
authority over a third of the drones (hand-overs A -> B in the drones' logs; or as many as it gets
within ``HELD_WAIT_S`` of its last), the bench signs
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

* **a drone out of reach for 30 s** (``OUT_OF_REACH_S``): the last drone's radio is cut (the
  drones host's coverage gate, ``--jam``) just before the revision and mended 30 s later; from back
  in reach to its ``revision_applied`` (it asks at once on coming back: ``RevisionChannel``). Its
  own failsafe (out of every GS's reach for 30 s) and commands are not in the row's figures;
* **commands lost**, per (GS, drone, epoch the GS believed it commanded in) against what the drone
  forwarded in that epoch: ``in_epoch`` lost while the GS held authority (should be 0), ``out of
  reach``: the GS's last commands to a drone that had flown out of its radio's reach (the testbed's
  coverage gate stopped them) with no heir, ``after it
  left``: sent in an epoch the drone had already left (the GS's stream ran on after a hand-over it
  had not heard of yet; the drone refuses them ``not_authority``): not commands lost, a GS's view
  that lags its drone by up to one status.

``--only rotate`` (and by default after the revocation): A's keys rotated in flight
(``zdrone.fleet.revise.rotate``, the revision published through C; the stations host reads A's new
secret from the fleet folder): revision -> applied, each drone's revision -> A's new key proven,
emergency hand-overs after it (0), failsafes (0), commands lost (0).

The routers are not restarted here (``zdrone demo --scenario revoke-in-flight`` does that, and the
``router-restart`` scenario measures what a restart costs).
"""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Sequence

from zdrone.core.records import AuthorityMoved, Failsafe, LinkConfirmed, RevisionApplied, only

QUICK_K = 3
FULL_K = 100
STATIONS = 3
REVOKED = "B"
ROTATED = "A"
#: B is revoked once it holds 1/HELD_SHARE of the drones, or no more for HELD_WAIT_S after its last
#: hand-over (the drones fly the same shuttle a few seconds apart).
HELD_SHARE = 3
HELD_WAIT_S = 5.0
#: The last drone's radio is cut just before the revocation, for this long (every GS out of reach).
OUT_OF_REACH_S = 30.0


def percentile(sorted_values: list[float], q: float) -> float:
    """The ``q``-th percentile (nearest rank) of sorted values."""
    i = min(len(sorted_values) - 1, max(0, round(q / 100.0 * len(sorted_values) + 0.5) - 1))
    return sorted_values[i]


def _records(d: Path, k: int) -> dict[str, list[Any]]:
    from zdrone.net.eventlog import read_records

    out: dict[str, list[Any]] = {}
    for i in range(k):
        p = d / f"d{i + 1}.jsonl"
        out[f"d{i + 1}"] = list(read_records(p).records) if p.exists() else []
    return out


def _held_by_b(recs: list[Any]) -> bool:
    moves = only(recs, AuthorityMoved)
    return bool(moves) and moves[-1].to == REVOKED


def run_one(k: int, base: Path, timeout: float, action: str = "revoke") -> dict[str, Any]:
    """One run: ``action`` ``revoke`` (B, with the last drone out of reach from just before the
    revision for ``OUT_OF_REACH_S``) or ``rotate`` (A's keys)."""
    from zdrone.fleet.files import init_fleet, scale_nodes
    from zdrone.fleet.revise import revoke, rotate
    from zdrone.net.revisions import publish
    from zdrone.sil.procs import spawn, stop_in_order
    from zdrone.bench.scale import SPEEDUP, _free_ports, _wait_line, hold_limit

    d = base / f"{action}-k{k}"
    d.mkdir(parents=True, exist_ok=True)
    fleet = d / "fleet"
    init_fleet(fleet, nodes_spec=scale_nodes(k, STATIONS))
    router = f"tcp/127.0.0.1:{_free_ports(1)[0]}"
    py = [sys.executable, "-m"]
    logs = {n: open(d / f"{n}.log", "w") for n in ("router", "drones", "stations")}
    procs: dict[str, subprocess.Popen] = {}
    common = ["--fleet", str(fleet), "--out", str(d), "--router", router]
    jammed = f"d{k}" if action == "revoke" and k > 1 else None
    result: dict[str, Any] = {"k": k, "g": STATIONS, "action": action, "runs": str(d), "jammed": jammed}
    t_pub: float | None = None
    held: list[str] = []
    try:
        procs["router"] = spawn(py + ["zdrone", "router", "-c", str(fleet / "router" / "router.json5"), "--listen", router],
                                stdout=logs["router"], stderr=subprocess.STDOUT)
        if _wait_line(d / "router.log", "listening", 20, procs["router"]) is None:
            raise RuntimeError(f"the router did not start; see {d / 'router.log'}")
        procs["drones"] = spawn(py + ["zdrone.bench.scale", "host-drones", "--k", str(k), "--speedup", str(SPEEDUP),
                                      "--duration", str(timeout), "--hold", str(hold_limit(k)), "--drone-router", "spread",
                                      *(["--jam", jammed] if jammed else []), *common],
                                stdout=logs["drones"], stderr=subprocess.STDOUT)
        procs["stations"] = spawn(py + ["zdrone.bench.scale", "host-stations", "--stations", str(STATIONS), *common],
                                  stdout=logs["stations"], stderr=subprocess.STDOUT)
        if _wait_line(d / "drones.log", "take-off", 180 + hold_limit(k), procs["drones"]) is None:
            raise RuntimeError(f"the drones never took off; see {d / 'drones.log'}")
        procs["stations"].send_signal(signal.SIGUSR1)
        deadline = time.monotonic() + timeout
        grew_at = time.monotonic()
        while time.monotonic() < deadline:  # B holds a third of the drones (or as many as it will)
            now_held = [n for n, recs in _records(d, k).items() if _held_by_b(recs)]
            if len(now_held) > len(held):
                held, grew_at = now_held, time.monotonic()
            if len(held) >= max(1, k // HELD_SHARE) or held and time.monotonic() - grew_at > HELD_WAIT_S:
                break
            time.sleep(0.2)
        if not held:
            raise RuntimeError("B never held authority over a drone")
        if jammed:
            procs["drones"].send_signal(signal.SIGUSR1)
            if _wait_line(d / "drones.log", f"{jammed} out of reach", 10, procs["drones"]) is None:
                raise RuntimeError(f"{jammed} was not cut off; see {d / 'drones.log'}")
        if action == "rotate":
            rotate(fleet, ROTATED, note="bench revoke: rotate")  # the stations host reads A's new secret here
            via = "C"
        else:
            revoke(fleet, REVOKED, note="bench revoke")
            via = "A"
        t_pub = time.time()
        publish(fleet, via, router, (fleet / "revision.json").read_bytes())
        if jammed:
            time.sleep(OUT_OF_REACH_S)
            procs["drones"].send_signal(signal.SIGUSR2)
        try:
            procs["drones"].wait(timeout + 60)
        except subprocess.TimeoutExpired:
            result["error"] = "the drones host did not finish"
    except RuntimeError as exc:
        result["error"] = str(exc)
    finally:
        stop_in_order(procs, ("stations", "drones", "router"))
        for f in logs.values():
            f.close()
    if t_pub is None:
        return result
    result.update(_figures(d, fleet, k, t_pub, held, action, jammed))
    return result


def _back_in_reach(d: Path, drone: str) -> float | None:
    """When the drones host mended ``drone``'s radio (wall clock), from its log."""
    for line in (d / "drones.log").read_text(errors="replace").splitlines():
        if f"{drone} back in reach at " in line:
            return float(line.rsplit(" ", 1)[1])
    return None


def lost_commands(sent_epochs: dict[str, dict[str, dict[str, int]]], drones: dict[str, Any],
                  not_gs: str | None) -> dict[str, Any]:
    """Commands of the GSs (but ``not_gs``) sent and not forwarded, per (GS, drone, epoch the GS
    believed it commanded in), split into ``after_it_left``: sent once the drone had left that GS,
    to another GS (an epoch the drone left: the drone refused them ``not_authority``) or to its
    failsafe (the GS's last epoch on a drone that refused commands in its failsafe, as many as it
    refused): the GS's stream ran on until it heard the drone's status; ``out_of_reach``: in the
    GS's last epoch on a drone whose radio (the testbed's coverage gate) stopped that GS's frames, as
    many as it stopped: the drone flew out of the GS's reach with no heir (B revoked) and the last
    commands went into the air; and ``in_epoch``: the rest, lost while the GS held authority and
    reached the drone (the figure that must be 0)."""
    out: dict[str, Any] = {"in_epoch": 0, "after_it_left": 0, "out_of_reach": 0, "where": []}
    for gs, per_drone in sent_epochs.items():
        if gs == not_gs:
            continue
        for drone, epochs in per_drone.items():
            r = drones.get(drone)
            if r is None:
                continue
            fwd = r.get("forwarded_epochs", {})
            last_epoch = max((int(k.split(":", 1)[0]) for k in fwd), default=0)
            in_failsafe = int(r.get("in_failsafe", 0))
            blocked = int(r.get("radio_blocked", {}).get(f"up:{gs}", 0))
            for epoch, n in sorted(epochs.items(), key=lambda kv: int(kv[0])):
                short = n - fwd.get(f"{epoch}:{gs}", 0)
                if short <= 0:
                    continue
                if int(epoch) < last_epoch:
                    left, how = short, "to another GS"
                else:
                    left, how = min(short, in_failsafe), "to its failsafe"
                    in_failsafe -= left
                gone = min(short - left, blocked) if int(epoch) == last_epoch else 0
                blocked -= gone
                out["after_it_left"] += left
                out["out_of_reach"] += gone
                out["in_epoch"] += short - left - gone
                why = [f"{left} after it left {how}"] if left else []
                why += [f"{gone} out of its reach"] if gone else []
                why += [f"{short - left - gone} while it held authority"] if why and short - left - gone else []
                out["where"].append(f"{gs}->{drone} epoch {epoch}: {short}" + (f" ({', '.join(why)})" if why
                                                                                else " (while it held authority)"))
    return out


def _figures(d: Path, fleet: Path, k: int, t_pub: float, held: list[str], action: str,
             jammed: str | None) -> dict[str, Any]:
    recs = _records(d, k)
    target = REVOKED if action == "revoke" else ROTATED
    field = "revoked" if action == "revoke" else "rotated"
    applied = {n: next((e.t for e in only(r, RevisionApplied) if target in getattr(e, field)), None)
               for n, r in recs.items()}
    in_reach = [n for n in recs if n != jammed]
    lat = sorted((applied[n] - t_pub) * 1000.0 for n in in_reach if applied[n] is not None)
    after = {n: [e for e in only(r, AuthorityMoved) if e.t >= t_pub] for n, r in recs.items()}
    failsafes = {n: len(only(r, Failsafe)) for n, r in recs.items()}
    covered = _failsafes_covered(fleet, {n: r for n, r in recs.items() if n != jammed})
    out: dict[str, Any] = {}
    try:
        drones = json.loads((d / "drones.json").read_text())["results"]
        sent_epochs = json.loads((d / "stations.json").read_text())["commands_sent_epochs"]
        lost = lost_commands({g: {n: e for n, e in per.items() if n != jammed} for g, per in sent_epochs.items()},
                             drones, REVOKED if action == "revoke" else None)
    except (OSError, ValueError, KeyError) as exc:
        out["error"] = f"no host results ({exc})"
        lost = {"in_epoch": None, "after_it_left": None, "out_of_reach": None, "where": []}
    out.update({
        "applied": f"{len(lat)}/{len(in_reach)}",
        "applied_ms": {"p50": round(percentile(lat, 50), 1) if lat else None,
                       "p99": round(percentile(lat, 99), 1) if lat else None,
                       "max": round(lat[-1], 1) if lat else None},
        "failsafes": sum(1 for n in in_reach if failsafes[n]),
        "failsafes_where_a_gs_covered": covered,
        "lost": lost,
    })
    if action == "revoke":
        out.update({
            "held_by_b": len(held),
            "held_went_to": {n: (after[n][0].to, after[n][0].kind) if after[n] else "failsafe" if failsafes[n] else "-"
                             for n in held},
            # after the drone applied the revision (a hand-over to B that completes between the
            # publication and its arrival is B's last)
            "b_authority_after": sum(1 for n, moves in after.items() for e in moves
                                     if e.to == REVOKED and (applied[n] is None or e.t >= applied[n])),
        })
    else:  # A's drones re-paired under its new key: authority never moved because of it
        repaired = {n: next((e.t for e in only(r, LinkConfirmed) if e.gs == ROTATED and e.t >= (applied[n] or t_pub)),
                            None) for n, r in recs.items()}
        out["repaired"] = {n: round((t - t_pub) * 1000.0, 1) if t else None for n, t in repaired.items()}
        out["emergencies_after"] = sum(1 for moves in after.values() for e in moves if e.kind == "emergency")
    if jammed:
        back = _back_in_reach(d, jammed)
        got = applied.get(jammed)
        out["out_of_reach"] = {
            "drone": jammed, "seconds": OUT_OF_REACH_S,
            "applied_before_back": got is not None and back is not None and got < back,
            "back_to_applied_ms": round((got - back) * 1000.0, 1) if got is not None and back is not None else None}
    return out


def _failsafes_covered(fleet_dir: Path, recs: dict[str, list[Any]]) -> int:
    """Failsafes commanded where an authorized GS's coverage held the vehicle (the revision's fleet)."""
    from zdrone.core.geometry import GeoPoint
    from zdrone.fleet.files import load_fleet

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


def run(quick: bool = False, k: int | None = None, timeout: float = 240.0,
        actions: Sequence[str] = ("revoke", "rotate")) -> dict[str, Any]:
    k = k or (QUICK_K if quick else FULL_K)
    base = Path(tempfile.mkdtemp(prefix="zdrone-bench-revoke-"))
    return {"rows": [run_one(k, base, timeout, a) for a in actions]}


def _lost(row: dict[str, Any]) -> str:
    lost = row["lost"]
    return f"{lost['in_epoch']} (+{lost['after_it_left']} after it left, +{lost.get('out_of_reach', 0)} out of reach)"


def render(r: dict[str, Any]) -> None:
    revoke_rows = [row for row in r["rows"] if row.get("action", "revoke") == "revoke"]
    rotate_rows = [row for row in r["rows"] if row.get("action") == "rotate"]
    print("revoke B in flight (revision signed, published through A; the GSs re-publish it every 10 s)")
    print(f"{'drones x GSs':>13} {'applied':>8} {'p50 ms':>8} {'p99 ms':>8} {'max ms':>8} {'B held':>7} "
          f"{'B after':>8} {'others lost':>40} {'failsafes':>10} {'covered':>8}")
    for row in revoke_rows:
        if "applied" not in row:
            print(f"{row['k']:>6} x {row['g']:<5} error: {row.get('error')}")
            continue
        a = row["applied_ms"]
        print(f"{row['k']:>6} x {row['g']:<5} {row['applied']:>8} {a['p50']!s:>8} {a['p99']!s:>8} {a['max']!s:>8} "
              f"{row['held_by_b']:>7} {row['b_authority_after']:>8} {_lost(row):>40} {row['failsafes']:>10} "
              f"{row['failsafes_where_a_gs_covered']:>8}")
        print(f"  where B's drones went: {row['held_went_to']}" + (f"; error: {row['error']}" if row.get("error") else ""))
        if row["lost"]["where"]:
            print(f"  others' commands not forwarded: {'; '.join(row['lost']['where'])}")
        oor = row.get("out_of_reach")
        if oor:
            print(f"  a drone out of reach for {oor['seconds']:.0f} s ({oor['drone']}, cut just before the revision; "
                  f"not in the row above): back in reach -> applied {oor['back_to_applied_ms']} ms"
                  + (" (applied BEFORE it was back: the radio cut leaked)" if oor["applied_before_back"] else ""))
        print(f"  runs: {row['runs']}")
    if rotate_rows:
        print("rotate A in flight (new keys, revision published through C; A re-pairs its drones under the new key)")
        print(f"{'drones x GSs':>13} {'applied':>8} {'p50 ms':>8} {'max ms':>8} {'re-paired':>10} {'emergency':>10} "
              f"{'lost':>26} {'failsafes':>10}")
    for row in rotate_rows:
        if "applied" not in row:
            print(f"{row['k']:>6} x {row['g']:<5} error: {row.get('error')}")
            continue
        a = row["applied_ms"]
        rep = row["repaired"]
        print(f"{row['k']:>6} x {row['g']:<5} {row['applied']:>8} {a['p50']!s:>8} {a['max']!s:>8} "
              f"{sum(v is not None for v in rep.values()):>6}/{len(rep):<3} {row['emergencies_after']:>10} "
              f"{_lost(row):>40} {row['failsafes']:>10}")
        print(f"  revision -> A's new key proven, per drone (ms): {rep}" + (f"; error: {row['error']}" if row.get("error") else ""))
        if row["lost"]["where"]:
            print(f"  commands not forwarded: {'; '.join(row['lost']['where'])}")
        print(f"  runs: {row['runs']}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="zdrone bench revoke")
    p.add_argument("--quick", action="store_true")
    p.add_argument("--drones", type=int)
    p.add_argument("--json", action="store_true")
    p.add_argument("--only", default="revoke,rotate")
    a = p.parse_args(argv)
    r = run(a.quick, a.drones, actions=[x for x in a.only.split(",") if x])
    print(json.dumps(r, indent=2)) if a.json else render(r)
    return 0 if all("error" not in row for row in r["rows"]) else 1


if __name__ == "__main__":
    sys.exit(main())
