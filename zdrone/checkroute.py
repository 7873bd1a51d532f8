"""``zdrone fleet check-route FLEET MISSION``: a mission's route checked offline against a fleet's
coverages (``zdrone.core.routecheck``), as a GS checks it before upload."""

from __future__ import annotations

import argparse
from typing import Any

from zdrone.core.errors import UsageError


def add_parser(fsub: Any) -> None:
    """``zdrone fleet check-route`` (``zdrone/cli.py`` calls this)."""
    fc = fsub.add_parser("check-route", help="check a mission's route before take-off: inside the authorized GSs' "
                         "coverage, every crossing with an overlap long enough for a hand-over at cruise speed")
    fc.add_argument("fleet_dir", metavar="FLEET", help="the fleet directory (or fleet.json5)")
    fc.add_argument("mission", metavar="MISSION", help="a QGroundControl .plan, 'reference', or 'shuttle:N'")
    fc.add_argument("--drone", action="append", metavar="D", help="check for this drone (default: every drone)")
    fc.add_argument("--json", action="store_true", help="print JSON instead of text")
    fc.set_defaults(func=_check_route)


def _check_route(args: argparse.Namespace) -> int:
    """Exit 0 when the route passes for every drone asked, 1 naming the first bad segment of each that
    does not (bad input: 2)."""
    import json

    from zdrone.commands import mission_from_arg
    from zdrone.core.reference import CRUISE_SPEED_MS
    from zdrone.core.routecheck import HANDOVER_OVERLAP_S, check_mission
    from zdrone.fleet.files import load_fleet

    fleet = load_fleet(args.fleet_dir)
    mission = mission_from_arg(args.mission)
    drones = args.drone or sorted(n for n, v in fleet.nodes.items() if v.role == "drone")
    for d in drones:
        if d not in fleet.nodes or fleet.nodes[d].role != "drone":
            raise UsageError(f"--drone {d}: not a drone of the fleet {args.fleet_dir}")
    out, bad = [], 0
    for d in drones:
        r = check_mission(mission, fleet, d, None, CRUISE_SPEED_MS)
        bad += not r.ok
        out.append({"drone": d, "ok": r.ok, "length_m": round(r.length_m, 1),
                    "chain": [{"gs": g, "from_m": round(a, 1), "to_m": round(b, 1)} for g, a, b in r.chain],
                    "problem": None if r.ok else r.problem.describe()})  # type: ignore[union-attr]
    if args.json:
        print(json.dumps({"overlap_s": HANDOVER_OVERLAP_S, "routes": out}, indent=2))
    else:
        for o in out:
            chain = " -> ".join(f"{c['gs']} ({c['from_m']:.0f}-{c['to_m']:.0f} m)" for c in o["chain"])
            print(f"{o['drone']}: {'ok' if o['ok'] else 'REFUSED'}, {o['length_m'] / 1000:.3f} km: {chain}"
                  + ("" if o["ok"] else f"\n  first bad segment: {o['problem']}"))
    return 1 if bad else 0
