"""The reference flight and its faults in memory, on both autopilot personalities: the drone's core,
GS A's and GS B's cores, the simulated autopilot and the drone's vehicle tracker
(``tests/coreflight.py``) fly pairing -> key sharing -> hand-over -> delivery -> hand-back -> home
in simulated time, a whole flight in a fraction of a second. ``tests/fleetnet.py`` checks the
protocol's corner cases on a scripted position; the process flights of ``tests/integration`` fly
the same through Zenoh and real processes. These pin the flight's outcomes without a wall clock, so
they hold at any machine load."""

from __future__ import annotations

import pytest

from gs.planner import encode_mission, reference_plan
from tests.coreflight import DRONE, CoreFlight
from zdrone.core import records as rec
from zdrone.core.geometry import GeoPoint, distance_m
from zdrone.core.reference import DELIVERY, HOME
from zdrone.sil.launcher import delivered_at
from zdrone.vehicle.personality import personality

AUTOPILOTS = ["px4", "ardupilot"]


@pytest.fixture(scope="module")
def fleet_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("fleet")


def _moves(f: CoreFlight) -> list[tuple[str | None, str, int, str]]:
    return [(r.from_, r.to, r.epoch, r.kind) for _, r in f.of(rec.AuthorityMoved)]


def _inside(f: CoreFlight, gs: str, pos) -> bool:
    return f.coverage[gs].contains(GeoPoint(pos[0], pos[1]))


def _home_distance(f: CoreFlight) -> float:
    return distance_m(HOME, f.sim.position)


def _one_authority_from_pairing_on(f: CoreFlight) -> None:
    """From the first pairing on, at every step exactly one GS holds authority, and epochs only grow."""
    first = next(i for i, (_, owner, _, _) in enumerate(f.statuses) if owner)
    held = f.statuses[first:]
    assert all(owner in ("A", "B") for _, owner, _, _ in held), "an instant without an authority"
    epochs = [e for _, _, e, _ in held]
    assert epochs == sorted(epochs)


def _no_command_lost_or_doubled(f: CoreFlight) -> None:
    """Every commanding frame an authority sent in its epoch was forwarded to the vehicle, once; no GS
    commanded in an epoch not its own."""
    owners = {r.epoch: r.to for _, r in f.of(rec.AuthorityMoved)}
    sent = {f"{epoch}:{g}": n for g, st in f.gs.items() for epoch, n in st.core.sessions[DRONE].commands_sent.items() if n}
    assert sent and all(owners[int(k.split(":")[0])] == k.split(":")[1] for k in sent), (sent, owners)
    assert dict(f.drone.forwarded_epochs) == sent


def _flight(fleet_dir, autopilot: str) -> CoreFlight:
    return CoreFlight(fleet_dir, personality(autopilot))


def _found_and_encoded_for(f: CoreFlight, autopilot: str) -> None:
    """GS A found the autopilot and encoded the mission for it (ArduPilot: item 0 is home, and
    MIS_OPTIONS says go on after a landing)."""
    assert [x["autopilot"] for _, x in f.gs_logs("A", "autopilot")] == [autopilot]
    uploads = f.gs_logs("A", "mission_upload")
    assert uploads and uploads[0][1]["items"] == len(encode_mission(reference_plan(), autopilot))
    assert autopilot == "px4" or uploads[0][1]["items"] == 9  # home placeholder + the plan
    assert bool(f.gs_logs("A", "vehicle_param")) == (autopilot == "ardupilot")


@pytest.mark.parametrize("autopilot", AUTOPILOTS)
def test_the_reference_flight_hands_over_to_b_and_back_inside_the_overlap(fleet_dir, autopilot):
    f = _flight(fleet_dir, autopilot)
    assert f.run_until(f.flown, 400), f"not flown: stage {f.gs['A'].core.sessions[DRONE].mission.stage}"
    assert _moves(f) == [(None, "A", 1, "paired"), ("A", "B", 2, "handover"), ("B", "A", 3, "handover")]
    for _, r in f.of(rec.HandoverComplete):
        assert _inside(f, "A", r.position) and _inside(f, "B", r.position), r
    _one_authority_from_pairing_on(f)
    _no_command_lost_or_doubled(f)
    assert f.drone.forwarded["A"] > 0 and f.drone.forwarded["B"] > 0  # both commanded in their turn
    # the key sharing: A asked B, B's key reached the drone as a grant, B proved it before the overlap
    assert [t for t, _ in f.gs_logs("A", "linkkey_received")] and f.gs_logs("A", "key_granted")
    [(proven_at, how)] = [(t, x["how"]) for t, x in f.gs_logs("B", "link_confirmed")]
    assert how == "linkkey:A" and proven_at < f.of(rec.HandoverComplete)[0][0]
    # B held authority at the delivery and heard the vehicle go past its DO_GRIPPER item on the ground there
    assert delivered_at([rec.MissionProgress(**x) for _, x in f.gs_logs("B", "mission_progress")], autopilot)
    assert not delivered_at([rec.MissionProgress(**x) for _, x in f.gs_logs("A", "mission_progress")], autopilot)
    if autopilot == "ardupilot":  # ArduCopter says so; PX4 says nothing
        assert "Gripper Released" in [x["text"] for _, x in f.gs_logs("B", "vehicle_text")]
    assert f.sim.mission_finished and _home_distance(f) < 3.0
    assert f.commands == [] and f.of(rec.Failsafe) == [] and f.of(rec.Drop) == []
    assert f.persisted[-1].owner == "A" and f.persisted[-1].epoch == 3
    _found_and_encoded_for(f, autopilot)


def _fly_until(f: CoreFlight, pred, what: str, timeout: float = 200) -> None:
    assert f.run_until(pred, timeout), f"never {what} (t={f.now}, owner {f.drone.machine.owner})"


def _east_of_home(f: CoreFlight) -> float:
    return distance_m(HOME, GeoPoint(f.sim.position.lat, f.sim.position.lon))


@pytest.mark.parametrize("autopilot", AUTOPILOTS)
def test_the_authority_falling_silent_before_the_overlap_lands_the_drone_where_it_is(fleet_dir, autopilot):
    f = _flight(fleet_dir, autopilot)
    _fly_until(f, lambda: _east_of_home(f) > 60 and not f.in_range("B"), "60 m out")
    f.gs["A"].down = True
    _fly_until(f, lambda: bool(f.commands), "a failsafe", timeout=10)
    [(t, fs)] = f.of(rec.Failsafe)
    assert fs.action == "LAND" and fs.reason == "authority link to A lost"
    assert 0 <= fs.detect_to_command_ms <= f.dt * 1000  # at the first step past the loss threshold
    _fly_until(f, f.landed, "landed", timeout=120)
    assert _moves(f) == [(None, "A", 1, "paired")] and _home_distance(f) > 20.0  # landed where it was


@pytest.mark.parametrize("autopilot", AUTOPILOTS)
def test_the_heir_crashing_before_the_hand_over_leaves_authority_with_a_who_brings_it_home(fleet_dir, autopilot):
    f = _flight(fleet_dir, autopilot)
    _fly_until(f, lambda: f.in_range("B") and f.in_range("A"), "in the overlap")
    f.gs["B"].down = True
    _fly_until(f, f.landed, "landed", timeout=300)
    assert _moves(f) == [(None, "A", 1, "paired")]
    assert f.of(rec.HandoverTimeout) or f.of(rec.HandoverAborted)
    assert f.gs_logs("A", "handover_failed") and f.drone.machine.owner == "A"
    assert f.of(rec.Failsafe) == [] and _home_distance(f) < 3.0
    assert distance_m(DELIVERY, GeoPoint(f.sim.position.lat, f.sim.position.lon)) > 100  # it came home, undelivered


@pytest.mark.parametrize("autopilot", AUTOPILOTS)
def test_a_hung_authority_loses_authority_to_the_proven_heir_and_learns_it_on_waking(fleet_dir, autopilot):
    f = _flight(fleet_dir, autopilot)
    _fly_until(f, lambda: f.in_range("B") and f.in_range("A") and f.gs["B"].core.sessions[DRONE].link is not None,
               "in the overlap with B proven")
    hung = f.now
    f.gs["A"].down = True
    _fly_until(f, lambda: f.now >= hung + 5.0, "5 s later", timeout=6)
    f.gs["A"].down = False
    _fly_until(f, f.flown, "home", timeout=300)
    assert _moves(f)[:2] == [(None, "A", 1, "paired"), ("A", "B", 2, "emergency")]
    back = _moves(f)[2:]  # then ordinary hand-overs only (by position), ending with A
    assert back and all(kind == "handover" for *_, kind in back) and back[-1][1] == "A", back
    woke = [x for t, x in f.gs_logs("A", "authority_status") if t > hung and x["owner"] == "B"]
    assert woke and woke[0]["epoch"] == 2
    assert {r.value: n for r, n in f.drone.machine.drops.items()}.get("not_authority", 0) == 0  # A never tried
    _one_authority_from_pairing_on(f)
    assert f.of(rec.Failsafe) == [] and _home_distance(f) < 3.0


@pytest.mark.parametrize("autopilot", AUTOPILOTS)
@pytest.mark.parametrize("speedup", [1, 2, 4])
def test_a_companion_restart_in_the_overlap_still_hands_over_at_any_speed_up(fleet_dir, autopilot, speedup):
    """Issue 19: the companion's node restarts 0.5 s into the overlap and is back 2 s later with no key
    but A's (re-paired); B refuses to share its key while its own link still looks alive, up to the
    loss threshold. However fast the vehicle flies meanwhile, the outcome is the same: A holds the
    vehicle at the edge of its coverage until B's key is there, then the hand-overs and the delivery
    happen as on a flight without the restart. (Faster still, the vehicle leaves A's coverage while
    the companion is down: nobody can hold it then, and the failsafe lands it.)"""
    f = CoreFlight(fleet_dir, personality(autopilot), speedup=speedup)
    _fly_until(f, lambda: f.in_range("B") and f.in_range("A"), "in the overlap", timeout=400 / speedup)
    f.run_until(lambda: False, 0.5)
    f.restart_drone(2.0)
    assert f.run_until(f.flown, 400 / speedup + 60), \
        f"not flown (x{speedup}): owner {f.drone.machine.owner}, A: {[k for _, k, _ in f.gs['A'].logs][-8:]}"
    assert f.of(rec.Restarted)
    assert [(a, b, kind) for a, b, _, kind in _moves(f)] == [(None, "A", "paired"), ("A", "B", "handover"),
                                                           ("B", "A", "handover")]
    assert delivered_at([rec.MissionProgress(**x) for _, x in f.gs_logs("B", "mission_progress")], autopilot)
    assert f.commands == [] and f.of(rec.Failsafe) == [] and _home_distance(f) < 3.0
    assert not [x for _, x in f.gs_logs("A", "handover_failed") if x["action"] == "RTL"]
    holds = f.gs_logs("A", "handover_hold")
    assert len(holds) == len(f.gs_logs("A", "handover_resume")) <= 1  # a hold, if any, was resumed


def _restart_with_b_refusing(f: CoreFlight, refuse_for: float, lose: str | None) -> None:
    """Fly to 0.5 s into the overlap and restart the companion (back 2 s later); B answers A's
    key-sharing queries ``live_link`` for ``refuse_for`` s after the restart; the first DO_SET_MODE
    of ``lose`` ("HOLD" or "MISSION") A sends is lost on the radio."""
    from pymavlink.dialects.v20 import common as mav

    from gs.actions import QueryAnswer
    from zdrone.vehicle.modes import set_mode_params

    a, b = f.gs["A"].core, f.gs["B"].core
    view = a.sessions["d1"]
    send, lost = view._command, []

    def lossy(command, *params):
        if (command == mav.MAV_CMD_DO_SET_MODE and lose and not lost
                and tuple(params) == tuple(set_mode_params(view.autopilot, lose))):
            lost.append(f.now)
            return []
        return send(command, *params)

    view._command = lossy
    _fly_until(f, lambda: f.in_range("B") and f.in_range("A"), "in the overlap", timeout=200)
    f.run_until(lambda: False, 0.5)
    f.restart_drone(2.0)
    t0, answer = f.now, b.on_linkkey_query
    b.on_linkkey_query = lambda d, p, now, s, w=None: ((QueryAnswer(error=b"live_link"), []) if now < t0 + refuse_for
                                                      else answer(d, p, now, s, w))
    f.lost_modes = lost  # type: ignore[attr-defined]


@pytest.mark.parametrize("lose", ["HOLD", "MISSION"])
def test_a_lost_hold_or_resume_is_sent_again_and_the_flight_completes(fleet_dir, lose):
    """Review 3 H1: one frame lost on the radio — the hold's or the resume's mode change — is sent
    again until the vehicle confirms it; the release waits for the mission mode."""
    f = CoreFlight(fleet_dir, personality("px4"), speedup=4)
    _restart_with_b_refusing(f, 10.0, lose)
    assert f.run_until(f.flown, 200), f"not flown: {[k for _, k, _ in f.gs['A'].logs][-8:]}"
    assert f.lost_modes and f.gs_logs("A", "handover_hold") and f.gs_logs("A", "handover_resume")
    assert f.gs["A"].core.counters["handover_hold_resent" if lose == "HOLD" else "handover_resume_resent"] >= 1
    assert [(a, b, kind) for a, b, _, kind in _moves(f)][1:] == [("A", "B", "handover"), ("B", "A", "handover")]
    assert f.commands == [] and f.of(rec.Failsafe) == [] and _home_distance(f) < 3.0


@pytest.mark.parametrize("autopilot", AUTOPILOTS)
def test_a_key_that_never_comes_ends_the_hold_in_rtl_home(fleet_dir, autopilot):
    """B keeps saying its link looks alive: the hold ends after ``HOLD_FOR_KEY_S`` and A brings the
    vehicle home (RTL), undelivered, no failsafe."""
    f = CoreFlight(fleet_dir, personality(autopilot), speedup=4)
    _restart_with_b_refusing(f, 10_000.0, None)
    _fly_until(f, f.landed, "landed", timeout=200)
    assert f.gs_logs("A", "handover_hold") and not f.gs_logs("A", "handover_resume")
    assert f.gs["A"].core.counters["handover_hold_over:expired"] == 1
    assert [(a, b) for a, b, _, _ in _moves(f)] == [(None, "A")] and f.drone.machine.owner == "A"
    assert f.commands == [] and f.of(rec.Failsafe) == [] and _home_distance(f) < 3.0


@pytest.mark.parametrize("autopilot", AUTOPILOTS)
def test_a_radio_outage_on_the_ground_after_pairing_is_no_failsafe_and_the_flight_goes_on(fleet_dir, autopilot):
    """``bench chaos`` schedule 5, in memory: A's link is lost for 3.65 s right after pairing, the vehicle
    disarmed at home. No failsafe on the ground (as the autopilots); A has the drone back when its link
    returns, and the reference flight completes."""
    f = _flight(fleet_dir, autopilot)
    _fly_until(f, lambda: f.drone.machine.owner == "A", "paired", timeout=60)
    f.gs["A"].down = True
    t0 = f.now
    _fly_until(f, lambda: f.now >= t0 + 3.65, "the outage's end", timeout=10)
    f.gs["A"].down = False
    assert f.of(rec.OwnerLinkLostOnGround) and f.commands == [] and f.of(rec.Failsafe) == []
    assert f.run_until(f.flown, 400), f"not flown: stage {f.gs['A'].core.sessions[DRONE].mission.stage}"
    assert _moves(f) == [(None, "A", 1, "paired"), ("A", "B", 2, "handover"), ("B", "A", 3, "handover")]
    assert f.commands == [] and f.of(rec.Failsafe) == [] and _home_distance(f) < 3.0
