"""``zdrone bench chaos``: seeded random fault schedules over the reference flight, and the safety
invariants checked over every event log.

Each run draws, from its own seed, one to three faults among: GS B killed, GS A hung 2-5 s (SIGSTOP,
then SIGCONT), the router killed and restarted 0.3-1.5 s later, the companion node killed and
restarted, and the radio's loss bursts (Gilbert-Elliott, mean 20 s good / 0.5-4 s bad) — each at a
random moment (a flight milestone plus 0-4 s), and flies the reference flight with them. It never
asks that the mission succeed (a fault may rightly end it in a failsafe); it asks that the flight
stay safe:

1. **one commander per epoch**: the commanding frames the drone forwarded in each epoch all came
   from one GS, and that GS held authority in that epoch;
2. **the failsafe on time**: every failsafe was commanded within threshold + 100 ms;
3. **no silent authority**: whenever the authority's link was LOST, the drone handed over (to a
   proven GS) or entered its failsafe within 100 ms;
4. **clean processes**: every process the schedule did not kill exited 0 at the end, and the run
   ended (landed, or failed with a reason) before its timeout.

With ``--sites`` (a router per site, meshed over a backhaul, each site's radio a real link) the
fault set also has a site router killed (back 0.5-6 s later) or hung (1-5 s), the backhaul cut
(mended 2-15 s later) and radio-link flaps (a site's radio down 0.3-4 s, one to three times), at the
hand-over and on the way back too; and one more invariant:

5. **the flight completes when the faults are over**: whenever no fault is still active when the
   drone turns for home (back in the overlap after the delivery, an RTL, or the failsafe), it is
   delivered, lands at home, and authority ends with A, the GS that covers home. (Radio loss bursts
   and a killed GS B last the whole flight.)

A violation names its seed: ``zdrone bench chaos [--sites] --seed S --runs 1`` replays it.
"""

from __future__ import annotations

import random
import signal
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor, as_completed
from functools import partial
from pathlib import Path
from typing import Any

from zdrone.sil.launcher import (AIRBORNE, HANDOVER_STARTED, HANDOVERS_DONE, LINK_DOWN, LINK_UP, MISSION_STARTED,
                            REGION_ENTERED, RESTART, RETURNING, Demo, DemoOptions, Fault, Outcome, Scenario,
                            active_faults, flight_completes, return_time, safety_invariants)
from zdrone.bench.table import ProgressLine

SPEEDUP = 4.0
MOMENTS = (MISSION_STARTED, AIRBORNE, REGION_ENTERED, HANDOVERS_DONE)
#: With sites, the hand-over itself and the way back are moments too.
SITE_MOMENTS = (MISSION_STARTED, AIRBORNE, REGION_ENTERED, HANDOVER_STARTED, HANDOVERS_DONE, RETURNING)
#: The site routers' process names in the launcher (site 1: A's, site 2: B's).
SITE_ROUTERS = {"site-1": "router", "site-2": "router2"}


def schedule(seed: int) -> tuple[tuple[Fault, ...], tuple[str, ...], list[str]]:
    """The faults (and radio options) of run ``seed``, and their description."""
    rng = random.Random(seed)
    faults: list[Fault] = []
    radio: list[str] = []
    text: list[str] = []
    kinds = rng.sample(["kill_b", "hang_a", "router", "companion", "bursts"], rng.randint(1, 3))
    for kind in kinds:
        at, after = rng.choice(MOMENTS), round(rng.uniform(0.0, 4.0), 2)
        if kind == "kill_b":
            faults.append(Fault(at, "gsB", signal.SIGKILL, "GS B killed", after=after))
            text.append(f"kill B at {at}+{after}s")
        elif kind == "hang_a":
            hang = round(rng.uniform(2.0, 5.0), 2)
            faults.append(Fault(at, "gsA", signal.SIGSTOP, "GS A hangs", after=after))
            faults.append(Fault(at, "gsA", signal.SIGCONT, "GS A wakes", after=after + hang))
            text.append(f"hang A {hang}s at {at}+{after}s")
        elif kind == "router":
            down = round(rng.uniform(0.3, 1.5), 2)
            faults.append(Fault(at, "router", RESTART, "router restarted", down=down, after=after))
            text.append(f"router down {down}s at {at}+{after}s")
        elif kind == "companion":
            faults.append(Fault(at, "drone", RESTART, "companion restarted", down=0.3, after=after))
            text.append(f"companion restart at {at}+{after}s")
        else:
            bad = round(rng.uniform(0.5, 4.0), 2)
            radio += ["--sil-bursts", f"20:{bad}", "--sil-seed", str(seed)]
            text.append(f"radio bursts 20s/{bad}s")
    return tuple(faults), tuple(radio), text


def schedule_sites(seed: int) -> tuple[tuple[Fault, ...], tuple[str, ...], list[str]]:
    """The faults (and radio options) of run ``seed`` over sites, and their description."""
    rng = random.Random(seed)
    faults: list[Fault] = []
    radio: list[str] = []
    text: list[str] = []
    kinds = rng.sample(["kill_b", "hang_a", "companion", "bursts", "site_kill", "site_hang", "backhaul", "flap"],
                       rng.randint(1, 3))
    for kind in kinds:
        at, after = rng.choice(SITE_MOMENTS), round(rng.uniform(0.0, 4.0), 2)
        site = rng.choice(sorted(SITE_ROUTERS))
        if kind == "kill_b":
            faults.append(Fault(at, "gsB", signal.SIGKILL, "GS B killed", after=after))
            text.append(f"kill B at {at}+{after}s")
        elif kind == "hang_a":
            hang = round(rng.uniform(2.0, 5.0), 2)
            faults += [Fault(at, "gsA", signal.SIGSTOP, "GS A hangs", after=after),
                       Fault(at, "gsA", signal.SIGCONT, "GS A wakes", after=after + hang)]
            text.append(f"hang A {hang}s at {at}+{after}s")
        elif kind == "companion":
            faults.append(Fault(at, "drone", RESTART, "companion restarted", down=0.3, after=after))
            text.append(f"companion restart at {at}+{after}s")
        elif kind == "bursts":
            bad = round(rng.uniform(0.5, 4.0), 2)
            radio += ["--sil-bursts", f"20:{bad}", "--sil-seed", str(seed)]
            text.append(f"radio bursts 20s/{bad}s")
        elif kind == "site_kill":
            down = round(rng.uniform(0.5, 6.0), 2)
            faults.append(Fault(at, SITE_ROUTERS[site], RESTART, f"{site}'s router killed", down=down, after=after))
            text.append(f"{site} router down {down}s at {at}+{after}s")
        elif kind == "site_hang":
            hang = round(rng.uniform(1.0, 5.0), 2)
            faults += [Fault(at, SITE_ROUTERS[site], signal.SIGSTOP, f"{site}'s router hangs", after=after),
                       Fault(at, SITE_ROUTERS[site], signal.SIGCONT, f"{site}'s router wakes", after=after + hang)]
            text.append(f"{site} router hangs {hang}s at {at}+{after}s")
        elif kind == "backhaul":
            cut = round(rng.uniform(2.0, 15.0), 2)
            faults += [Fault(at, "backhaul", LINK_DOWN, "backhaul cut", after=after),
                       Fault(at, "backhaul", LINK_UP, "backhaul mended", after=after + cut)]
            text.append(f"backhaul cut {cut}s at {at}+{after}s")
        else:
            t = after
            for _ in range(rng.randint(1, 3)):
                down = round(rng.uniform(0.3, 4.0), 2)
                faults += [Fault(at, site, LINK_DOWN, f"{site}'s radio flaps down", after=round(t, 2)),
                           Fault(at, site, LINK_UP, f"{site}'s radio back", after=round(t + down, 2))]
                text.append(f"{site} radio down {down}s at {at}+{round(t, 2)}s")
                t += down + rng.uniform(0.5, 3.0)
    return tuple(faults), tuple(radio), text


def invariants(o: Outcome) -> list[str]:
    """The violated invariants of one run (see the module docstring); [] = safe."""
    return safety_invariants(o)  # exit codes and the timeout: checked by the launcher for every run


def site_invariants(o: Outcome, whole_flight: bool = False) -> list[str]:
    """The invariants of a run over sites: the safety invariants, and the flight completes (delivered,
    home, authority with A) if no fault is still active when the drone turns for home
    (``whole_flight``: a fault that lasts the whole flight, as radio loss bursts)."""
    why = safety_invariants(o)
    if not whole_flight and not active_faults(o, return_time(o)):
        why += [f"faults over, yet {w}" for w in flight_completes(o)]
    return why


def fly(s_seed: int, base: Path, sites: bool) -> dict[str, Any]:
    """One schedule, flown; its row."""
    faults, radio, text = (schedule_sites if sites else schedule)(s_seed)
    if sites:
        whole = "--sil-bursts" in radio or any(f.target == "gsB" and f.sig == signal.SIGKILL for f in faults)
        check = partial(site_invariants, whole_flight=whole)
    else:
        check = invariants
    spec = Scenario(f"chaos-{s_seed}", "; ".join(text), "invariants hold", check, faults=faults, radio=radio,
                    sites=sites)
    d = base / f"seed-{s_seed}"
    d.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    try:
        summary = Demo(DemoOptions(out=d, scenario="nominal", spec=spec, speedup=SPEEDUP, quiet=True, live=False,
                                   report=False, timeout=60.0 + 240.0 / SPEEDUP, sites=sites), d.resolve()).run()
    except (RuntimeError, OSError) as exc:  # could not start: the schedule was not flown
        return {"seed": s_seed, "faults": text, "violations": [f"did not start: {exc}"], "failsafe": False,
                "handovers": [], "wall_s": round(time.monotonic() - t0, 1), "run": str(d)}
    violations = [w for w in summary["why_not_ok"] if not w.startswith("mission failed")]
    return {"seed": s_seed, "faults": text, "violations": violations, "failsafe": summary["failsafe"] is not None,
            "handovers": [f"{h['from']}->{h['to']} ({h['kind']})" for h in summary["handovers"]],
            "delivered": bool(summary.get("delivered")), "final_owner": summary.get("final_owner"),
            "wall_s": round(time.monotonic() - t0, 1), "run": str(d)}


def run(runs: int, seed: int, quick: bool = False, progress: bool = True, sites: bool = False,
        jobs: int = 1) -> dict[str, Any]:
    runs = min(runs, 5) if quick else runs
    base = Path(tempfile.mkdtemp(prefix="zdrone-bench-chaos-"))
    rows: list[dict[str, Any]] = []
    bar = ProgressLine(enabled=progress)
    with ThreadPoolExecutor(max_workers=max(1, jobs)) as pool:  # each flight's children belong to its thread
        futures = [pool.submit(fly, seed + i, base, sites) for i in range(runs)]
        for fut in as_completed(futures):
            rows.append(fut.result())
            bar.say(f"chaos: {len(rows)}/{runs} schedules, {sum(len(r['violations']) for r in rows)} violations")
    bar.close()
    rows.sort(key=lambda r: r["seed"])
    return {"runs": len(rows), "violations": sum(len(r["violations"]) for r in rows), "seed": seed, "sites": sites,
            "speedup": SPEEDUP, "schedules": rows, "folder": str(base),
            "goal": "0 violations in >= 50 schedules (--sites: >= 30; --quick: 5)"}


def render(result: dict[str, Any]) -> None:
    from zdrone.bench.table import print_table

    rows = [[r["seed"], "; ".join(r["faults"]), ", ".join(r["handovers"]) or "-", "yes" if r["failsafe"] else "-",
             "; ".join(r["violations"]) or "none"] for r in result["schedules"]]
    print_table(f"Chaos: {result['runs']} schedules, {result['violations']} violations",
                ["seed", "faults", "hand-overs", "failsafe", "violations"], rows,
                caption=f"replay one: zdrone bench chaos {'--sites ' if result.get('sites') else ''}--seed SEED --runs 1")
