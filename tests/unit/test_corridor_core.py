"""Links that follow the drone, in memory: a corridor of 8 GSs over 16 km, one drone out and back.

The cores of the drone and of every GS, the simulated autopilot, simulated time, the radio as the
fleet's coverage (``tests.coreflight``). GS A pairs and flies the mission; every other GS gets its link
only from the owner's plan (``zdrone.core.linkplan``) by key sharing. What must hold: 14 hand-overs,
never a moment without exactly one owner, never more than ``links_max`` live links, a link left behind
closed and wiped on both ends, and every GS whose coverage holds the drone linked (an heir ready)
within seconds of the drone entering its coverage.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from gs.core import CoreOptions
from gs.planner import shuttle_mission
from zdrone.core import records as rec
from zdrone.core.geometry import GeoPoint
from zdrone.core.linkplan import LinkGrace, plan_links
from zdrone.core.geometry import Circle, offset
from zdrone.core.reference import HOME
from zdrone.fleet.files import corridor_layout, corridor_nodes, init_fleet
from gs.linkfollow import WIPE_SILENT_S
from tests.coreflight import CoreFlight

GSS = 8
LENGTH_M = 16_000.0
SPEED = 20.0


def _corridor(tmp: Path, stations: int = GSS, length: float = LENGTH_M) -> tuple[Path, list[str]]:
    _, radius = corridor_layout(stations, length)
    init_fleet(tmp, nodes_spec=corridor_nodes(1, stations, length), coverage_radius_m=radius)
    return tmp, [chr(ord("A") + i) for i in range(stations)]


def _flight(tmp: Path, speedup: float, made: bool = False) -> tuple[CoreFlight, list[str]]:
    d, names = (tmp, [chr(ord("A") + i) for i in range(GSS)]) if made else _corridor(tmp)
    mission = shuttle_mission(2, far_east_m=LENGTH_M, speed=SPEED)
    opts = {g: CoreOptions(pair=(g == "A"), mission=mission if g == "A" else None, command_rate=1.0) for g in names}
    return CoreFlight(d, stations=opts, dt=0.1, speedup=speedup), names


# speed-up 8 as CI's process flight; 4 and 1 fly in the tests below (the rules at every speed: one 32 km
# flight is 10-13 s of CPU, the suite's 10 minutes)
@pytest.mark.parametrize("speedup", [8.0])
def test_the_corridor_flight_holds_at_most_three_links_and_hands_over_14_times(tmp_path: Path, speedup: float) -> None:
    f, names = _flight(tmp_path, speedup)
    most, owned_gap, uncovered_heir = 0, 0, []
    entered: dict[str, float] = {}

    def watch() -> bool:
        nonlocal most, owned_gap
        most = max(most, len(f.drone.links))
        m = f.drone.machine
        if f.sim.armed and m.state.value not in ("linked", "handover_pending"):
            owned_gap += 1
        for g in names:  # a covering GS is linked within 10 s (node time) of the drone entering its coverage
            if g in m.inside and f.sim.armed:
                t = entered.setdefault(g, f.now)
                if f.now - t > 10.0 and g not in f.drone.links and g not in uncovered_heir:
                    uncovered_heir.append(g)
            else:
                entered.pop(g, None)
        return f.flown()

    assert f.run_until(watch, timeout=2 * LENGTH_M / SPEED / speedup + 300.0), "the flight did not end"
    m = f.drone.machine
    assert m.epoch - 1 == 2 * (GSS - 1), [o for _, o, _ in m.history]  # 14 hand-overs, one per crossing
    assert [o for _, o, _ in m.history][:2] == ["A", "B"] and m.owner == "A"
    assert owned_gap == 0 and not f.commands  # never without an owner in the air, never a failsafe
    assert most <= f.fleet.links_max == 3, most
    assert not uncovered_heir, uncovered_heir
    closed = f.of(rec.LinkClosedNote)
    assert len(closed) >= GSS - 2, closed  # every GS left behind was let go
    kept = f.of(rec.LinkKeptNote)
    assert not kept
    # on the way back each GS left behind on the way out was prepared again by the owner of the moment
    # (it made a key for the drone twice: ``linkkey_shared`` counts the answers of the GS asked)
    assert [g for g in names[1:-3] if f.gs[g].core.counters["linkkey_shared"] < 2] == []
    # both ends wiped: a GS the drone closed holds no key for it once its silence says so (the drone's notice
    # goes out of that GS's radio reach), until the owner prepares it again
    f.run_until(lambda: False, timeout=WIPE_SILENT_S + 5.0)
    for g in names:
        if g not in f.drone.links:
            assert f.gs[g].core.sessions["d1"].link is None, g
    assert sum(st.core.counters["link_wiped"] for st in f.gs.values()) >= len(closed)
    # no command lost: every commanding frame a GS sent in its epoch was forwarded
    sent = sum(sum(st.core.sessions["d1"].commands_sent.values()) for st in f.gs.values())
    assert sent > 0 and sum(f.drone.forwarded.values()) >= sent - 2


def test_the_owner_prepares_covering_gss_then_the_next_on_the_course() -> None:
    spacing, radius = corridor_layout(GSS, LENGTH_M)
    names = [chr(ord("A") + i) for i in range(GSS)]
    circles = {g: Circle(offset(HOME, 0.0, spacing * i), radius) for i, g in enumerate(names)}
    east = (0.0, 20.0)
    # over A's centre heading east: B is next (its coverage starts 0.9 km ahead; 60 s at 20 m/s reach 1.2 km)
    p = plan_links("A", names[1:], circles, offset(HOME, 0.0, 0.0), east, 3)
    assert p.covering == () and p.ahead == ("B",) and p.wanted == ("A", "B")
    # in the A-B overlap, owner A: B covers it, C is not within reach yet
    p = plan_links("A", names[1:], circles, offset(HOME, 0.0, spacing - radius + 50), east, 3)
    assert p.covering == ("B",) and p.wanted[:2] == ("A", "B")
    # owner B past the overlap heading east: C next, A behind is not wanted
    p = plan_links("B", [g for g in names if g != "B"], circles, offset(HOME, 0.0, spacing * 1.1), east, 3)
    assert "A" not in p.wanted and p.wanted == ("B", "C")
    # heading west from the same point: A is next on the course
    p = plan_links("B", [g for g in names if g != "B"], circles, offset(HOME, 0.0, spacing * 1.1), (0.0, -20.0), 3)
    assert p.wanted == ("B", "A")
    # hovering: only what covers it; an unknown course likewise
    assert plan_links("B", names, circles, offset(HOME, 0.0, spacing * 1.1), (0.0, 0.0), 3).wanted == ("B",)
    assert plan_links("B", names, circles, offset(HOME, 0.0, spacing * 1.1), None, 3).wanted == ("B",)
    # never more than links_max, the owner first, heirs before the course
    p = plan_links("Z", names, circles, offset(HOME, 0.0, spacing - radius + 50), east, 2)
    assert p.wanted == ("Z", "A") and len(p.wanted) == 2


def test_the_grace_closes_the_longest_closable_first() -> None:
    g = LinkGrace(grace_s=10.0)
    g.update({"A"}, 0.0)
    g.update({"A", "C"}, 4.0)
    assert g.due(9.0) == [] and g.next_due() == 10.0
    assert g.oldest() == "A" and g.oldest(besides="A") == "C"
    assert g.due(10.0) == ["A"] and g.due(14.0) == ["A", "C"]
    g.update({"C"}, 5.0)  # A became needed again (it covers the drone): its clock starts over if it comes back
    assert g.oldest() == "C"
    g.update({"A", "C"}, 6.0)
    assert g.since["A"] == 6.0


def test_the_corridor_demo_verdict_can_fail(tmp_path: Path) -> None:
    """``zdrone.bench.corridordemo.judge`` on made-up results: too many links, a lost hand-over, no landing."""
    from zdrone.bench.corridordemo import judge
    from zdrone.fleet.files import load_fleet

    d, _ = _corridor(tmp_path)
    fleet = load_fleet(d)
    good = {"flew": True, "landed": True}
    assert judge("corridor", {"links_max_per_drone": 3, "failures": {}}, good, tmp_path, fleet) == []
    assert judge("corridor", {"links_max_per_drone": 4, "failures": {}}, good, tmp_path, fleet)
    assert judge("corridor", {"links_max_per_drone": 3, "failures": {"d1": ["13/14 hand-overs"]}}, good, tmp_path, fleet)
    assert judge("corridor", {"links_max_per_drone": 3, "failures": {}}, {"flew": True, "landed": False}, tmp_path, fleet)
    # the GS never died: the scenario did not happen
    assert judge("corridor-gs-down", {"links_max_per_drone": 3}, good, tmp_path, fleet)


def test_a_drone_at_links_max_with_nothing_closable_refuses_a_grant_and_a_pairing_from_afar(tmp_path: Path) -> None:
    """links_max 2: in the A-B overlap the drone holds A (owner) and B (covering it): neither may close.
    A grant for C (even from the owner) and C's own pairing (C does not cover the drone) are refused
    ``links_full``; nothing the drone held is touched."""
    import msgspec

    from zdrone.core import wire
    from zdrone.core.fleet import encode_fleet
    from zdrone.core.pairing import PairingInitiator, PairRefusal, PairRefused
    from zdrone.fleet.files import load_fleet, load_secret
    from tests.coreflight import WALL0

    d, names = _corridor(tmp_path)
    fleet = msgspec.structs.replace(load_fleet(d), links_max=2)
    (d / "fleet.json5").write_text(encode_fleet(fleet))
    f, _ = _flight(tmp_path, 4.0, made=True)
    assert f.fleet.links_max == 2
    m = f.drone.machine
    assert f.run_until(lambda: m.inside == {"A", "B"} and set(f.drone.links) == {"A", "B"} and m.owner == "A"
                       and m.is_proven("B"), timeout=200.0)
    # C's own pairing, from outside its coverage
    c = PairingInitiator(load_secret(d, "C", fleet).identity, "C", "d1", fleet.nodes["d1"].public_bytes,
                         stamp=WALL0 + f.now)
    ans, _ = f.drone.on_pair_query("C", c.start(), f.now, bytes(32), WALL0 + f.now)
    assert isinstance(ans, PairRefused) and ans.reason is PairRefusal.LINKS_FULL
    # a grant for C from the owner
    grant = f.gs["A"].core.sessions["d1"].send_control(wire.KeyGrant("C", fleet.nodes["C"].sysid, bytes(32), 999))
    f.station("A", grant)
    assert f.drone.counters["grant_refused:links_full"] == 1 and set(f.drone.links) == {"A", "B"}
    # the flight goes on: the hand-over to B, and B's plan prepares C once A is left behind
    assert f.run_until(lambda: m.owner == "B" and "C" in f.drone.links, timeout=200.0)
    assert len(f.drone.links) <= 2


def test_a_gs_left_behind_pairs_again_only_on_its_operators_request(tmp_path: Path) -> None:
    """B, whose link the drone closed and which wiped its end, does not pair by itself; its operator's
    request for control pairs it on demand (answered TEMPORARILY_REJECTED until then), within links_max."""
    from pymavlink.dialects.v20 import common as mav

    from zdrone.core.mavcontrol import OperatorControlRequest

    f, _ = _flight(tmp_path, 4.0)
    b = f.gs["B"].core
    m = f.drone.machine
    assert f.run_until(lambda: b.sessions["d1"].link is None and b.counters["link_wiped"] == 1 and m.owner not in "AB",
                       timeout=600.0)
    sent = b.counters["pair_sent"]
    f.run_until(lambda: False, timeout=20.0)
    assert b.counters["pair_sent"] == sent  # no pairing of its own
    req = OperatorControlRequest(request=True, takeover=False, timeout=30.0, sysid=0)
    answer, acts = b.operator_command("d1", req, f.now, app="qgc")
    f.station("B", acts)
    assert answer.value == mav.MAV_RESULT_TEMPORARILY_REJECTED
    f.run_until(lambda: b.counters["pair_sent"] > sent, timeout=5.0)
    assert b.counters["pair_sent"] > sent  # it pairs on demand (the drone's radio may not reach it from there)


def test_a_gs_dying_in_the_middle_hands_the_drone_to_its_covering_heir_and_it_comes_home(tmp_path: Path) -> None:
    """D dies 0.5 s after it took authority, the drone still in the C-D overlap (at speed-up 1 the 3 s loss
    threshold is 60 m of flight): C, covering it with a proven link, takes it (emergency); C's hand-over
    toward the dead D times out, the vehicle leaving C's coverage is sent home, and it is handed back C ->
    B -> A on the way. (At speed-up 8, as in CI's process flight, the drone has left C's coverage by the
    time D's silence counts: its failsafe lands it, by the same rules.)"""
    from zdrone.core.geometry import distance_m

    f, _ = _flight(tmp_path, 1.0)
    m = f.drone.machine
    assert f.run_until(lambda: m.owner == "D", timeout=600.0)
    f.run_until(lambda: False, timeout=0.5)
    f.gs["D"].down = True
    assert f.run_until(lambda: m.owner != "D" or m.state.value == "failsafe", timeout=10.0)
    assert m.owner == "C" and m.state.value == "linked", (m.owner, m.state)
    last = f.of(rec.HandoverComplete)[-1][1]
    assert last.kind == "emergency" and last.to == "C"
    assert f.run_until(f.landed, timeout=1200.0)
    assert not f.commands  # no failsafe
    assert [o for _, o, _ in m.history][-3:] == ["C", "B", "A"] and "D" not in [o for _, o, _ in m.history][4:]
    p = f.sim.position
    assert distance_m(HOME, GeoPoint(p.lat, p.lon)) < 100.0  # home
