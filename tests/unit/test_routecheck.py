"""A route checked before take-off (``zdrone.core.routecheck``): by the pure check, by the GS before
upload, and offline by ``zdrone fleet check-route``."""

from __future__ import annotations

import json
import math
from types import SimpleNamespace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gs.planner import reference_plan, shuttle_mission
from zdrone.cli import main
from zdrone.core.geometry import Circle, GeoPoint, distance_m, offset
from zdrone.core.reference import CRUISE_SPEED_MS, HOME
from zdrone.core.routecheck import HANDOVER_OVERLAP_S, check_mission, check_route, route_of

from tests.unit.test_station_core import core, fleet_dir  # noqa: F401  (fixture)


def wp(p: GeoPoint, cmd: int = 16) -> SimpleNamespace:
    return SimpleNamespace(command=cmd, params=(0.0, 0.0, 0.0, math.nan), lat=p.lat, lon=p.lon)


def east(m: float) -> GeoPoint:
    return offset(HOME, 0.0, m)


def circles(*spec: tuple[str, float, float]) -> dict[str, Circle]:
    """GSs along the east axis: (name, centre metres east of home, radius)."""
    return {g: Circle(east(x), r) for g, x, r in spec}


def test_a_route_inside_two_overlapping_coverages_passes_with_its_chain():
    legs = route_of([wp(HOME, 22), wp(east(500)), wp(HOME)], None, 12.0)
    r = check_route(legs, circles(("A", 0, 350), ("B", 500, 350)))
    assert r.ok and [g for g, _, _ in r.chain] == ["A", "B", "A"]
    assert r.length_m == pytest.approx(1000, abs=0.5)
    assert r.chain[1][1] == pytest.approx(150, abs=0.5)  # B's hand-over overlap starts where B's coverage does


def test_a_route_that_leaves_coverage_is_refused_naming_where_and_for_how_long():
    legs = route_of([wp(HOME, 22), wp(east(500)), wp(east(1200)), wp(HOME)], None, 12.0)
    r = check_route(legs, circles(("A", 0, 350), ("B", 500, 350)))
    p = r.problem
    assert p is not None and p.kind == "uncovered" and p.leg == 1 and p.from_gs == "B"
    assert p.at_m == pytest.approx(850, abs=0.5) and p.until_m == pytest.approx(1550 - 0, abs=1.0)
    assert "leg 2 (waypoint 1 -> 2)" in p.describe() and "0.850 km" in p.describe()


def test_a_crossing_with_too_short_an_overlap_is_refused_naming_the_two_gss():
    # overlap 40 m; 5 s at 12 m/s needs 60 m
    legs = route_of([wp(HOME, 22), wp(east(660)), wp(HOME)], None, 12.0)
    r = check_route(legs, circles(("A", 0, 350), ("B", 660, 350)))
    p = r.problem
    assert p is not None and p.kind == "short_overlap" and (p.from_gs, p.to_gs) == ("A", "B")
    assert p.overlap_m == pytest.approx(40, abs=0.5) and p.need_m == pytest.approx(12.0 * HANDOVER_OVERLAP_S)
    # slower, the same overlap is enough: 40 m at 6 m/s is 6.7 s
    slow = route_of([wp(HOME, 22), SimpleNamespace(command=178, params=(1.0, 6.0, -1.0, 0.0), lat=math.nan,
                                                   lon=math.nan), wp(east(660)), wp(HOME)], None, 12.0)
    assert check_route(slow, circles(("A", 0, 350), ("B", 660, 350))).ok


def test_a_corridor_of_gss_is_chained_in_order_and_the_reference_missions_pass(fleet_dir):
    spec = [(f"G{i}", 600.0 * i, 350.0) for i in range(8)]  # 8 GSs over 4.2 km, 100 m overlaps
    legs = route_of([wp(HOME, 22), wp(east(4200)), wp(HOME)], None, 12.0)
    r = check_route(legs, circles(*spec))
    assert r.ok and [g for g, _, _ in r.chain] == [f"G{i}" for i in range(8)] + [f"G{i}" for i in range(6, -1, -1)]
    from zdrone.fleet.files import load_fleet

    fleet = load_fleet(fleet_dir)
    for m in (reference_plan(), shuttle_mission(5)):
        assert check_mission(m, fleet, "d1", None, CRUISE_SPEED_MS).ok


@settings(max_examples=80, deadline=None)
@given(st.lists(st.tuples(st.floats(-900, 900), st.floats(-900, 900)), min_size=1, max_size=6),
       st.lists(st.tuples(st.floats(-900, 900), st.floats(-900, 900), st.floats(50, 600)), min_size=1, max_size=5))
def test_a_route_that_passes_is_covered_everywhere_and_every_crossing_overlaps_long_enough(points, gss):
    """Property: sampled every metre, a passing route is always inside the coverage of the GS the chain
    has it with, and each hand-over's overlap is covered by both GSs for at least the time needed."""
    cs = {f"G{i}": Circle(offset(HOME, n, e), r) for i, (n, e, r) in enumerate(gss)}
    legs = route_of([wp(HOME, 22)] + [wp(offset(HOME, n, e)) for n, e in points], None, 12.0)
    r = check_route(legs, cs)
    if not r.ok or not legs:
        return
    from zdrone.core.routecheck import _at

    for i, (g, a, b) in enumerate(r.chain):
        for k in range(int(a) + 1, int(b)):
            _, p, _ = _at(legs, float(k))
            assert distance_m(cs[g].centre, p) <= cs[g].radius_m + 0.5
        if i:
            prev_end = r.chain[i - 1][2]
            assert prev_end - a >= 12.0 * HANDOVER_OVERLAP_S - 0.05


def _plan(tmp_path, points: list[GeoPoint]) -> str:
    items = [{"type": "SimpleItem", "frame": 3, "command": 22 if i == 0 else 16,
              "params": [0, 0, 0, None, p.lat, p.lon, 30]} for i, p in enumerate(points)]
    path = tmp_path / "route.plan"
    path.write_text(json.dumps({"fileType": "Plan", "mission": {"items": items}}))
    return str(path)


def test_check_route_offline_passes_the_reference_and_refuses_a_route_out_of_coverage(tmp_path, fleet_dir, capsys):
    assert main(["fleet", "check-route", str(fleet_dir), "reference"]) == 0
    assert "d1: ok" in capsys.readouterr().out
    bad = _plan(tmp_path, [HOME, east(500), east(1200), HOME])
    assert main(["fleet", "check-route", str(fleet_dir), bad, "--json"]) == 1
    got = json.loads(capsys.readouterr().out)["routes"][0]
    assert not got["ok"] and "leaves every authorized GS's coverage after B" in got["problem"]
    assert main(["fleet", "check-route", str(fleet_dir), str(tmp_path / "none.plan")]) == 2


def test_the_gs_refuses_a_route_before_upload_and_uploads_one_that_passes(tmp_path, fleet_dir):
    from gs.planner import load_plan

    bad = load_plan(_plan(tmp_path, [HOME, east(500), east(1200), HOME]))
    a = core(fleet_dir, "A", pair=True, mission=bad)
    m = a.sessions["d1"].mission
    assert m.route_problem is not None and "leaves every authorized GS's coverage" in m.route_problem
    from gs.mission import FlightTick, Stage

    v = SimpleNamespace(autopilot="px4", armed=False, landed_state=1)
    out = m.handle(FlightTick(1.0), v, lambda msg: [msg])  # the vehicle is known: the upload would start now
    assert m.stage is Stage.FAILED
    assert m.uploader is None and m.counters["mission_refused:route"] == 1
    assert any(type(x).__name__ == "Emit" and x.kind == "mission_failed" and "route refused" in x.fields["reason"]
               for x in out)
    good = core(fleet_dir, "A", pair=True, mission=reference_plan()).sessions["d1"].mission
    assert good.route_problem is None
    good.handle(FlightTick(1.0), v, lambda msg: [msg])
    assert good.stage is Stage.UPLOADING and good.uploader is not None
