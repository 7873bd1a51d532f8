"""The timing sweep's cells, faults moved to a moment, and what holds wherever a fault lands."""

from __future__ import annotations

import signal

import pytest

from zdrone.bench.sweep import QUICK, SPEEDUPS, Cell, cells, render
from zdrone.sil.launcher import (AIRBORNE, MOMENTS, RETURNING, SCENARIO_BY_NAME, SCENARIO_TABLE, Outcome,
                                 fault_over_check, flight_unaffected)


def test_every_scenario_at_every_speed_up_and_each_fault_at_every_moment():
    full = cells()
    for s in SCENARIO_TABLE:
        mine = [c for c in full if c.scenario == s.name]
        moments = s.moments() or (None,)
        assert sorted((c.speedup, c.moment or "") for c in mine) == sorted((sp, m or "") for sp in SPEEDUPS for m in moments)
    moved = {c.scenario for c in full if c.moment}
    assert {"site-router-down", "gs-crash", "gs-hang", "router-restart", "companion-restart", "link-loss"} <= moved
    assert not {"site-router-down-alone", "backhaul-cut", "failsafe-recover", "nominal"} & moved  # their moment is them
    assert set(cells(quick=True)) <= set(full) and [Cell(*q) for q in QUICK] == cells(quick=True)
    assert cells(scenarios=["gs-crash"], speedups=[2.0], moments=["way_back"]) == [Cell("gs-crash", 2.0, "way_back")]


def test_a_moved_fault_keeps_its_offsets_and_is_judged_by_what_holds_at_any_moment():
    hang = SCENARIO_BY_NAME["gs-hang"]
    assert hang.at_moment(hang.own_moment()) is hang
    back = hang.at_moment("way_back")
    trigger, after = MOMENTS["way_back"]
    assert [(f.trigger, f.after, f.sig) for f in back.faults] == [(RETURNING, after, signal.SIGSTOP),
                                                                 (RETURNING, after + 5.0, signal.SIGCONT)]
    assert back.check is fault_over_check and back.name == hang.name
    recover = SCENARIO_BY_NAME["failsafe-recover"]  # its wake-up hangs on the failsafe: not moved
    with pytest.raises(ValueError):
        recover.at_moment("handover")
    early = SCENARIO_BY_NAME["link-loss"].at_moment("before_overlap")
    assert early.faults[0].trigger == AIRBORNE


def _outcome(faults: list[dict], returning: float | None, **summary) -> Outcome:
    base = {"handovers": [{"from": "A", "to": "B", "kind": "handover"}], "failsafe": None, "delivered": False,
            "delivered_at_b": False, "distance_from_home_m": 0.5, "final_owner": "A", "faults": faults,
            "moments": {RETURNING: returning} if returning else {}, "ended_at": 100.0,
            "authority_link": {"worst_state": "ok"}}
    return Outcome(base | summary, [], {"A": [], "B": []}, [])


def test_the_flight_must_complete_only_if_no_fault_is_active_when_the_drone_returns():
    over = [{"t": 10.0, "target": "router", "text": "site 1's router dies", "ends": 16.0}]
    assert fault_over_check(_outcome(over, 40.0)) == ["not delivered"]
    assert fault_over_check(_outcome(over, 40.0, delivered=True)) == []
    assert "final authority B, expected A (home's GS)" in fault_over_check(_outcome(over, 40.0, delivered=True,
                                                                                     final_owner="B"))
    active = [{"t": 30.0, "target": "gsB", "text": "GS B crashes", "ends": None}]  # never ends
    assert fault_over_check(_outcome(active, 40.0)) == []  # safe is all it can be asked
    late = [{"t": 38.0, "target": "router", "text": "hang", "ends": 45.0}]  # still active when it returned
    assert fault_over_check(_outcome(late, 40.0)) == []
    assert fault_over_check(_outcome([], None)) == ["the fault never landed (its moment never came)"]


def test_the_sweep_table_names_each_failed_cell_and_how_to_replay_it(capsys):
    rows = [{"scenario": "gs-crash", "speedup": 2.0, "moment": "way_back", "own_moment": False, "ok": False,
             "why": ["not delivered"], "run": "/tmp/x", "replay": Cell("gs-crash", 2.0, "way_back").replay()},
            {"scenario": "nominal", "speedup": 2.0, "moment": None, "own_moment": False, "ok": True, "why": [],
             "run": "/tmp/y", "replay": "zdrone demo --scenario nominal --speedup 2"}]
    render({"rows": rows, "speedups": [2.0], "cells": 2, "failed": 1, "wall_s": 1.0, "jobs": 2, "folder": "/tmp"})
    out = capsys.readouterr().out
    assert "FAILED zdrone demo --scenario gs-crash --speedup 2 --moment way_back: not delivered" in out
    assert "FAIL" in out and "ok" in out


def test_flight_unaffected_is_still_the_nominal_check():
    assert SCENARIO_BY_NAME["nominal"].check is flight_unaffected


def test_a_sweep_over_sites_flies_every_cell_over_a_router_per_site():
    over = cells(scenarios=["revoke-in-flight", "revoke-uncovered"], speedups=[1.0, 4.0], sites=True)
    assert [(c.scenario, c.speedup, c.sites) for c in over] == [
        ("revoke-in-flight", 1.0, True), ("revoke-in-flight", 4.0, True),
        ("revoke-uncovered", 1.0, True), ("revoke-uncovered", 4.0, True)]
    assert over[0].replay() == "zdrone demo --scenario revoke-in-flight --speedup 1 --sites"
    assert over[0].folder != Cell("revoke-in-flight", 1.0, None).folder
