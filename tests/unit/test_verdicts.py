"""A run's verdict and summary from records alone: the testbed's scenarios, verdicts and summary need no
``Demo``, no router and no process (``zdrone.sil.scenarios``, ``verdicts``, ``summary``)."""

from __future__ import annotations

import json
import subprocess
import sys

from pymavlink.dialects.v20 import common as mav

from gs.planner import reference_mission
from zdrone.core.records import (AuthorityChange, AutopilotFound, DroneStop, Failsafe, HandoverComplete,
                                 MissionProgress, Start)
from zdrone.core.reference import DELIVERY, HOME
from zdrone.core.wire import AuthorityState
from zdrone.sil.scenarios import SCENARIO_BY_NAME
from zdrone.sil.summary import RunFacts, RunLogs, picked, summarize, watch_state
from zdrone.sil.verdicts import Outcome, flight_unaffected, safety_invariants

T0 = 1795338600.0


def _at(p, alt: float = 0.0) -> tuple[float, float, float]:
    return (p.lat, p.lon, alt)


def _final(forwarded_epochs: dict[str, int]) -> DroneStop:
    """The drone's last word: back home on the ground, A holding authority (epoch 3)."""
    return DroneStop(t=T0 + 200, node="d1", owner="A", epoch=3, state=AuthorityState.LINKED, pending_to=None,
                     position=_at(HOME), armed=False, mode="LAND", landed_state=mav.MAV_LANDED_STATE_ON_GROUND,
                     in_region=False, subscribed=("A",), links={}, keys={}, ha_drops={}, rejects={},
                     counters={"pair_answered": 1}, forwarded_commands={"A": 60, "B": 40},
                     forwarded_epochs=forwarded_epochs, out_of_coverage={})


def _flight(forwarded_epochs: dict[str, int] | None = None) -> tuple[RunLogs, dict]:
    """The reference flight's records: A pairs, A->B, B->A, the delivery at B heard by B, home; and
    the watch loop's state as it would have gathered it from the drone's log."""
    gripper = next(i for i, it in enumerate(reference_mission(autopilot="px4")) if it.command == mav.MAV_CMD_DO_GRIPPER)
    moves = [AuthorityChange(t=T0 + 1, node="d1", from_=None, to="A", epoch=1, kind="paired", time=T0 + 1, position=None),
             HandoverComplete(t=T0 + 60, node="d1", from_="A", to="B", epoch=2, kind="handover", time=T0 + 60,
                              position=_at(DELIVERY, 30.0)),
             HandoverComplete(t=T0 + 140, node="d1", from_="B", to="A", epoch=3, kind="handover", time=T0 + 140,
                              position=_at(HOME, 30.0))]
    drone = [Start(t=T0, node="d1", vehicle="udpout:127.0.0.1:14540"), *moves,
             _final(forwarded_epochs or {"1:A": 40, "2:B": 40, "3:A": 20})]
    gs_a = [AutopilotFound(t=T0 + 0.5, node="A", drone="d1", autopilot="px4", mav_type=2)]
    gs_b = [MissionProgress(t=T0 + 100, node="B", drone="d1", seq=gripper + 1, reached=False,
                            landed_state=mav.MAV_LANDED_STATE_ON_GROUND, position=_at(DELIVERY))]
    state = watch_state()
    state["handovers"] = [picked(e, ("from", "to", "epoch", "time", "kind", "position")) for e in moves[1:]]
    state["final_position"] = list(_at(HOME))
    return RunLogs(drone=drone, gs={"A": gs_a, "B": gs_b, "X": []}), state


def _facts(**kw) -> RunFacts:
    return RunFacts(**{"scenario": "nominal", "speedup": 4.0, "wall": 80.0, "timed_out": False, "ended_at": T0 + 201,
                       "exit_codes": {"drone": 0, "gsA": 0, "gsB": 0}, **kw})


def test_a_summary_and_its_verdict_from_records_without_a_demo():
    logs, state = _flight()
    summary = summarize(SCENARIO_BY_NAME["nominal"], logs, state, _facts())
    assert summary["ok"] is True and summary["why_not_ok"] == [] and summary["flight_problems"] == []
    assert [(h["from"], h["to"], h["kind"]) for h in summary["handovers"]] == [("A", "B", "handover"),
                                                                              ("B", "A", "handover")]
    assert summary["delivered_at_b"] is True and summary["distance_from_home_m"] == 0.0
    assert summary["final_owner"] == "A" and summary["commands"]["forwarded"] == {"A": 60, "B": 40}
    assert summary["radio_links"] == {} and summary["vehicle"] == {"counters": None, "ignored": [], "modes": []}
    assert json.loads(json.dumps(summary)) == summary  # summary.json is plain JSON


def test_the_verdict_names_what_failed():
    """A failsafe, an exit code that is not a fault's, and a command of B in A's epoch: each named."""
    logs, state = _flight(forwarded_epochs={"1:A": 40, "2:B": 40, "3:A": 20, "3:B": 2})
    fs = Failsafe(t=T0 + 150, node="d1", action="LAND", reason="authority link to A lost", detect_to_command_ms=1.5,
                  position=_at(HOME, 30.0))
    logs.drone.insert(-1, fs)
    state["failsafe"] = fs
    summary = summarize(SCENARIO_BY_NAME["nominal"], logs, state,
                        _facts(exit_codes={"drone": 0, "gsA": -9, "gsB": 1}, stopped=frozenset({"gsA"})))
    assert summary["ok"] is False
    assert summary["why_not_ok"] == ["non-zero exit codes {'gsB': '1'}", "failsafe triggered"]
    o = Outcome(summary, logs.drone, logs.gs, logs.rogue)
    assert flight_unaffected(o) == ["failsafe triggered"] == summary["flight_problems"]
    assert safety_invariants(o) == ["epoch 3: commands forwarded from ['A', 'B']"]


def test_the_testbeds_rooms_import_without_processes():
    """Importing the scenarios, verdicts and summary starts nothing and loads no Zenoh, no subprocess."""
    code = ("import sys\n"
            "import zdrone.sil.moments, zdrone.sil.scenarios, zdrone.sil.verdicts, zdrone.sil.summary, zdrone.sil.liveview\n"
            "print(','.join(sorted(n for n in ('zenoh', 'subprocess', 'socket', 'zdrone.sil.launcher', 'zdrone.sil.procs')"
            " if n in sys.modules)))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == ""
