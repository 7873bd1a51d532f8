"""A run's verdict and summary from records alone: the testbed's scenarios, verdicts and summary need no
``Demo``, no router and no process (``zdrone.sil.scenarios``, ``verdicts``, ``summary``)."""

from __future__ import annotations

import json
import subprocess
import sys

from pymavlink.dialects.v20 import common as mav

from gs.planner import reference_mission
from zdrone.core.records import (AuthorityChange, AutopilotFound, DroneStatus, DroneStop, Failsafe, HandoverComplete,
                                 HandoverStart, MissionProgress, RegionEntered, Start)
from zdrone.core.reference import DELIVERY, HOME
from zdrone.core.wire import AuthorityState
from zdrone.sil.moments import AIRBORNE, AT_DELIVERY, FAILSAFE_FIRED, HANDOVER_STARTED, HANDOVERS_DONE, REGION_ENTERED, RETURNING
from zdrone.sil.scenarios import SCENARIO_BY_NAME
from zdrone.sil.summary import RunFacts, RunLogs, follow, summarize, watch, watch_state
from zdrone.sil.verdicts import Outcome, flight_unaffected, safety_invariants

T0 = 1795338600.0
ON_GROUND, IN_AIR = mav.MAV_LANDED_STATE_ON_GROUND, mav.MAV_LANDED_STATE_IN_AIR


def _at(p, alt: float = 0.0) -> tuple[float, float, float]:
    return (p.lat, p.lon, alt)


def _state(cls, t: float, position, armed: bool, landed_state: int, owner: str = "A", epoch: int = 1,
           forwarded_epochs: dict[str, int] | None = None):
    """A status of the drone (``DroneStatus``, or its last word ``DroneStop``)."""
    return cls(t=t, node="d1", owner=owner, epoch=epoch, state=AuthorityState.LINKED, pending_to=None, position=position,
               armed=armed, mode="MISSION", landed_state=landed_state, in_region=False, subscribed=(owner,), links={},
               keys={}, ha_drops={}, rejects={}, counters={"pair_answered": 1}, forwarded_commands={"A": 60, "B": 40},
               forwarded_epochs=forwarded_epochs or {}, out_of_coverage={})


def _flight(forwarded_epochs: dict[str, int] | None = None) -> RunLogs:
    """The reference flight's records: A pairs, takes off, A->B in the overlap, the delivery at B (on the
    ground, still armed, heard by B), back in the overlap B->A, landed and disarmed at home."""
    gripper = next(i for i, it in enumerate(reference_mission(autopilot="px4")) if it.command == mav.MAV_CMD_DO_GRIPPER)
    drone = [Start(t=T0, node="d1", vehicle="udpout:127.0.0.1:14540"),
             AuthorityChange(t=T0 + 1, node="d1", from_=None, to="A", epoch=1, kind="paired", time=T0 + 1, position=None),
             _state(DroneStatus, T0 + 10, _at(HOME, 30.0), True, IN_AIR),
             RegionEntered(t=T0 + 50, node="d1", detail="A, B", position=None),
             HandoverStart(t=T0 + 59, node="d1", detail="A -> B", position=None),
             HandoverComplete(t=T0 + 60, node="d1", from_="A", to="B", epoch=2, kind="handover", time=T0 + 60,
                              position=_at(DELIVERY, 30.0)),
             _state(DroneStatus, T0 + 100, _at(DELIVERY), True, ON_GROUND, owner="B", epoch=2),
             RegionEntered(t=T0 + 130, node="d1", detail="A, B", position=None),
             HandoverComplete(t=T0 + 140, node="d1", from_="B", to="A", epoch=3, kind="handover", time=T0 + 140,
                              position=_at(HOME, 30.0)),
             _state(DroneStatus, T0 + 199, _at(HOME), False, ON_GROUND, epoch=3),
             _state(DroneStop, T0 + 200, _at(HOME), False, ON_GROUND, epoch=3,
                    forwarded_epochs=forwarded_epochs or {"1:A": 40, "2:B": 40, "3:A": 20})]
    gs_a = [AutopilotFound(t=T0 + 0.5, node="A", drone="d1", autopilot="px4", mav_type=2)]
    gs_b = [MissionProgress(t=T0 + 100, node="B", drone="d1", seq=gripper + 1, reached=False, landed_state=ON_GROUND,
                            position=_at(DELIVERY))]
    return RunLogs(drone=drone, gs={"A": gs_a, "B": gs_b, "X": []})


def test_the_watch_state_and_the_moments_from_the_drones_records():
    """What the watch loop gathers, record by record, and the moments each record reaches (the
    launcher fires each the first time only)."""
    logs, state = _flight(), watch_state()
    moments = [m for ev in logs.drone for m in follow(state, ev, ev.t)]
    assert moments == [AIRBORNE, REGION_ENTERED, HANDOVER_STARTED, AT_DELIVERY, REGION_ENTERED, RETURNING, HANDOVERS_DONE]
    assert state["done"] and state["delivered"] and state["final_position"] == list(_at(HOME))
    assert [(h["from"], h["to"]) for h in state["handovers"]] == [("A", "B"), ("B", "A")]
    fs = Failsafe(t=T0 + 201, node="d1", action="LAND", reason="authority link to A lost", detect_to_command_ms=1.5,
                  position=None)
    assert follow(state, fs, fs.t) == [FAILSAFE_FIRED] and state["failsafe"] is fs
    lingering = watch(logs.drone, linger=3.0)  # the end comes ``linger`` seconds after the landing
    assert lingering["landed_at"] == T0 + 199 and not lingering["done"]


def _facts(**kw) -> RunFacts:
    return RunFacts(**{"scenario": "nominal", "speedup": 4.0, "wall": 80.0, "timed_out": False, "ended_at": T0 + 201,
                       "exit_codes": {"drone": 0, "gsA": 0, "gsB": 0}, **kw})


def test_a_summary_and_its_verdict_from_records_without_a_demo():
    logs = _flight()
    summary = summarize(SCENARIO_BY_NAME["nominal"], logs, watch(logs.drone), _facts())
    assert summary["ok"] is True and summary["why_not_ok"] == [] and summary["flight_problems"] == []
    assert [(h["from"], h["to"], h["kind"]) for h in summary["handovers"]] == [("A", "B", "handover"),
                                                                              ("B", "A", "handover")]
    assert summary["delivered_at_b"] is True and summary["distance_from_home_m"] == 0.0
    assert summary["final_owner"] == "A" and summary["commands"]["forwarded"] == {"A": 60, "B": 40}
    assert summary["radio_links"] == {} and summary["vehicle"] == {"counters": None, "ignored": [], "modes": []}
    assert json.loads(json.dumps(summary)) == summary  # summary.json is plain JSON


def test_the_verdict_names_what_failed():
    """A failsafe, an exit code that is not a fault's, and a command of B in A's epoch: each named."""
    logs = _flight(forwarded_epochs={"1:A": 40, "2:B": 40, "3:A": 20, "3:B": 2})
    logs.drone.insert(-2, Failsafe(t=T0 + 150, node="d1", action="LAND", reason="authority link to A lost",
                                   detect_to_command_ms=1.5, position=_at(HOME, 30.0)))
    summary = summarize(SCENARIO_BY_NAME["nominal"], logs, watch(logs.drone),
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


def test_revoke_uncovered_wants_the_failsafe_at_once_and_authority_moved_nowhere():
    """B revoked where no other authorized GS covers the drone: the failsafe within a second of the
    revision, no hand-over after it; an emergency hand-over to A from outside its coverage fails it."""
    from zdrone.core.records import AuthorityChange, RevisionApplied

    check = SCENARIO_BY_NAME["revoke-uncovered"].check
    rev = RevisionApplied(t=T0 + 50, node="d1", number=1, revoked=("B",), rotated=())
    fs = Failsafe(t=T0 + 50.01, node="d1", action="LAND", reason="authority link to B lost", detect_to_command_ms=None,
                  position=_at(DELIVERY))
    summary = {"notes": ["routers restarted on the files without B: router"], "final_owner": "B"}
    assert check(Outcome(summary, [rev, fs], {"A": [], "B": []}, [])) == []
    moved = AuthorityChange(t=T0 + 50.01, node="d1", from_="B", to="A", epoch=3, kind="emergency", time=T0 + 50.01,
                            position=None)
    why = check(Outcome(summary, [rev, moved], {"A": [], "B": []}, []))
    assert any("authority moved after the revision" in w for w in why) and any("no failsafe" in w for w in why)



def test_view_truth_wants_both_lies_told_and_the_old_word_replayed_and_excuses_a_failsafe_the_stop_made_late(tmp_path):
    """``view-truth``'s flight side: the companion stopped 5 s wakes to silent links: a failsafe it
    commands as it wakes is as late as the stop made it (excused); one late on its own is not. The
    insider's replayed word must be of B's epoch and older than the hand-back."""
    from zdrone.core.records import RevisionApplied
    from zdrone.net.eventlog import read_records

    check = SCENARIO_BY_NAME["view-truth"].check
    logs = _flight()
    stop = {"t": T0 + 150.0, "target": "drone", "text": "the companion stops (SIGSTOP)", "ends": T0 + 155.0}

    def failsafe(t: float):
        return Failsafe(t=t, node="d1", action="LAND", reason="authority link to A lost", detect_to_command_ms=2100.0,
                        position=_at(HOME, 30.0))

    def outcome(fs_t: float, replayed_at: float) -> Outcome:
        drone = [*logs.drone[:-2], RevisionApplied(t=T0 + 20, node="d1", number=1, revoked=(), rotated=("A",)),
                 failsafe(fs_t), *logs.drone[-2:]]
        done = [{"t": T0 + 160, "node": "rogue-ops-unauthorized", "type": "attack_done", "parts": 200, "bursts": 3},
                {"t": T0 + 160, "node": "rogue-ops-insider", "type": "attack_done", "parts": 40,
                 "replayed": {"owner": "B", "epoch": 2, "state": "linked", "at": replayed_at, "seq": 12}}]
        (tmp_path / "rogue.jsonl").write_text("".join(json.dumps(d) + "\n" for d in done))
        summary = {"handovers": [{"from": "A", "to": "B", "kind": "handover"}, {"from": "B", "to": "A", "kind": "handover"}],
                   "faults": [stop]}
        return Outcome(summary, drone, logs.gs, read_records(tmp_path / "rogue.jsonl").records)

    assert check(outcome(T0 + 155.05, T0 + 61.0)) == []
    assert check(outcome(T0 + 170.0, T0 + 61.0)) == ["failsafe 2100 ms after the threshold"]
    assert check(outcome(T0 + 155.05, T0 + 141.0)) == ["the replayed word is not older than the hand-back"]
