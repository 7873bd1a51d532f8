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

A violation names its seed: ``zdrone bench chaos --seed S --runs 1`` replays it.
"""

from __future__ import annotations

import random
import signal
import tempfile
import time
from pathlib import Path
from typing import Any

from ..sil.launcher import (AIRBORNE, HANDOVERS_DONE, MISSION_STARTED, REGION_ENTERED, RESTART, Demo, DemoOptions,
                            Fault, Outcome, Scenario, safety_invariants)
from .table import ProgressLine

SPEEDUP = 4.0
MOMENTS = (MISSION_STARTED, AIRBORNE, REGION_ENTERED, HANDOVERS_DONE)


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


def invariants(o: Outcome) -> list[str]:
    """The violated invariants of one run (see the module docstring); [] = safe."""
    return safety_invariants(o)  # exit codes and the timeout: checked by the launcher for every run


def run(runs: int, seed: int, quick: bool = False, progress: bool = True) -> dict[str, Any]:
    runs = min(runs, 5) if quick else runs
    base = Path(tempfile.mkdtemp(prefix="zdrone-bench-chaos-"))
    rows: list[dict[str, Any]] = []
    bar = ProgressLine(enabled=progress)
    for i in range(runs):
        s_seed = seed + i
        faults, radio, text = schedule(s_seed)
        spec = Scenario(f"chaos-{s_seed}", "; ".join(text), "safety invariants hold", invariants, faults=faults,
                        radio=radio)
        d = base / f"seed-{s_seed}"
        d.mkdir(parents=True, exist_ok=True)
        bar.say(f"chaos run {i + 1}/{runs} (seed {s_seed}): {'; '.join(text)}")
        t0 = time.monotonic()
        summary = Demo(DemoOptions(out=d, scenario="nominal", spec=spec, speedup=SPEEDUP, quiet=True, live=False,
                                   report=False, timeout=60.0 + 240.0 / SPEEDUP), d.resolve()).run()
        violations = [w for w in summary["why_not_ok"] if not w.startswith("mission failed")]
        rows.append({"seed": s_seed, "faults": text, "violations": violations, "failsafe": summary["failsafe"] is not None,
                     "handovers": [f"{h['from']}->{h['to']} ({h['kind']})" for h in summary["handovers"]],
                     "wall_s": round(time.monotonic() - t0, 1), "run": str(d)})
    bar.close()
    return {"runs": len(rows), "violations": sum(len(r["violations"]) for r in rows), "seed": seed,
            "speedup": SPEEDUP, "schedules": rows, "goal": "0 violations in >= 50 schedules (--quick: 5)"}


def render(result: dict[str, Any]) -> None:
    from .table import print_table

    rows = [[r["seed"], "; ".join(r["faults"]), ", ".join(r["handovers"]) or "-", "yes" if r["failsafe"] else "-",
             "; ".join(r["violations"]) or "none"] for r in result["schedules"]]
    print_table(f"Chaos: {result['runs']} schedules, {result['violations']} violations",
                ["seed", "faults", "hand-overs", "failsafe", "violations"], rows,
                caption="replay one: zdrone bench chaos --seed SEED --runs 1")
