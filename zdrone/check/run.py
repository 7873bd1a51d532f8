"""``zdrone check``: which world to explore (the abstract one, operator consent, or the shipped
cores) and how the result is printed."""

from __future__ import annotations

from typing import Any

from zdrone.check.abstract import Explorer
from zdrone.check.search import Violation


def run(depth: int = 8, faults: int = 2, flaw: str | None = None, max_states: int | None = None,
        cores: bool = False, consent: bool = False) -> dict[str, Any]:
    """Explore; the result says whether every invariant held, with the figures and any violation's trace.
    ``cores``: explore the shipped cores themselves (``check_cores``) instead of the abstract world;
    ``consent`` (or a consent flaw): the operator-consent world (``check_consent``)."""
    from zdrone.check.consent import FLAWS as CONSENT_FLAWS

    if consent or flaw in CONSENT_FLAWS:
        from zdrone.check.consent import ConsentExplorer

        found, figures = ConsentExplorer(depth, flaw, max_states).run()
        violation = None if found is None else Violation(*found)
        figures = {**figures, "flaw": flaw, "world": "consent"}
    elif cores:
        from zdrone.check.cores import CoreExplorer

        broken, trace, figures = CoreExplorer(depth, faults, max_states, flaw=flaw).run()
        violation = None if broken is None else Violation(broken.invariant, broken.detail, trace)
        figures = {**figures, "flaw": flaw, "world": "cores"}
    else:
        violation, figures = Explorer(depth, faults, flaw, max_states).run()
        figures["world"] = "abstract"
    out: dict[str, Any] = {"ok": violation is None, **figures}
    if violation is not None:
        out["violation"] = {"invariant": violation.invariant, "detail": violation.detail,
                            "trace": list(violation.trace), "length": len(violation.trace)}
    return out


def render(r: dict[str, Any]) -> None:
    """Print the result for people."""
    what = f"planted flaw {r['flaw']}" if r["flaw"] else {
        "cores": "the shipped cores: DroneCore, StationCores A and B",
        "consent": "operator consent: OperatorControl at A, B and C, the drone's authority machine",
    }.get(r.get("world", ""), "the shipped rules")
    print(f"zdrone check ({what}): {r['states']} distinct states, {r['transitions']} transitions, depth "
          f"{r['depth_reached']}/{r['depth']}, faults <= {r['faults']}, {r['seconds']} s ({r['states_per_s']} states/s)")
    if r["ok"] and r.get("world") == "consent":
        print("every invariant holds: consent goes to the GS it names, in its epoch")
        return
    if r["ok"]:
        print("every invariant holds: one owner; commands only from the owner; no authority outside coverage "
              "without consent; nobody replaces another's live link; failsafe on time; the owner re-pairs after a "
              "restart; hand-overs complete; the epoch counts up; the last owner pairs first after a ground restart")
        return
    v = r["violation"]
    print(f"VIOLATION of '{v['invariant']}': {v['detail']}")
    print(f"shortest trace ({v['length']} steps):")
    for i, step in enumerate(v["trace"], 1):
        print(f"  {i:2}. {step}")
