import json

import pytest
from pymavlink.dialects.v20 import common as mav

from gs.planner import MissionUploader, encode_mission, load_plan, reference_mission, reference_plan, shuttle_mission
from tests.simpair import SimPair
from zdrone.core.fleet import ConfigError
from zdrone.core.geometry import distance_m
from zdrone.core.reference import DELIVERY, HOME


def test_reference_mission_uploads_to_the_sim_and_delivers():
    s = SimPair()
    up = MissionUploader(reference_mission(), target=(1, 1))
    out = up.start(0.0)
    for _ in range(50):
        for m in out:
            s.send(m)
        out = []
        for m in list(s.inbox):
            out += up.on_message(m, 0.0, 255)
        s.inbox.clear()
        if up.done:
            break
    assert up.accepted
    s.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    s.command(mav.MAV_CMD_MISSION_START, 0, 0)
    assert s.run_until(lambda: s.sim.payload_released, 300)
    assert distance_m(DELIVERY, s.sim.position) < 2.0
    assert s.run_until(lambda: not s.sim.armed, 300)
    assert distance_m(HOME, s.sim.position) < 2.0


def test_uploader_retries_then_gives_up():
    up = MissionUploader(reference_mission(), retry_s=1.0, max_retries=2)
    up.start(0.0)
    assert up.tick(0.5) == []
    assert len(up.tick(1.1)) == 1 and len(up.tick(2.2)) == 1
    assert up.tick(3.3) == [] and up.result == mav.MAV_MISSION_OPERATION_CANCELLED


def test_load_qgc_plan(tmp_path):
    plan = {"fileType": "Plan", "version": 1, "mission": {"items": [
        {"type": "SimpleItem", "command": 22, "frame": 3, "params": [0, 0, 0, None, HOME.lat, HOME.lon, 20], "autoContinue": True},
        {"type": "SimpleItem", "command": 16, "frame": 3, "params": [0, 0, 0, None, DELIVERY.lat, DELIVERY.lon, 20]},
        {"type": "SimpleItem", "command": 20, "frame": 2, "params": [0, 0, 0, 0, 0, 0, 0]},
    ], "plannedHomePosition": [HOME.lat, HOME.lon, 488]}}
    f = tmp_path / "m.plan"
    f.write_text(json.dumps(plan))
    items = load_plan(f)
    assert [i.command for i in items] == [22, 16, 20]
    plan["mission"]["items"].append({"type": "ComplexItem", "complexItemType": "survey"})
    f.write_text(json.dumps(plan))
    with pytest.raises(ConfigError, match=r"items\[3\]"):
        load_plan(f)
    f.write_text("{")
    with pytest.raises(ConfigError, match="not a readable"):
        load_plan(f)


def test_mission_encoded_per_autopilot():
    plan = reference_plan()
    takeoff, land, wp = mav.MAV_CMD_NAV_TAKEOFF, mav.MAV_CMD_NAV_LAND, mav.MAV_CMD_NAV_WAYPOINT
    assert [it.command for it in plan].count(takeoff) == 2
    # PX4: a take-off only first (it refuses any later one and takes off again by itself)
    px4 = reference_mission()
    assert px4 == encode_mission(plan, "px4") == reference_mission(autopilot="px4")
    assert [it.command for it in px4].count(takeoff) == 1 and px4[0].command == takeoff
    assert [it.command for it in px4] == [it.command for it in plan if it is not plan[5]]
    # ArduPilot: item 0 is home (a placeholder there), and a take-off must follow a mid-mission landing
    ardu = reference_mission(autopilot="ardupilot")
    assert ardu[1:] == plan and ardu[0].command == wp and (ardu[0].lat, ardu[0].lon) == (HOME.lat, HOME.lon)
    assert [it.command for it in ardu][4:7] == [land, mav.MAV_CMD_DO_GRIPPER, takeoff]
    assert shuttle_mission(2, autopilot="ardupilot")[1:] == shuttle_mission(2)
    with pytest.raises(ValueError, match="expected one of px4, ardupilot"):
        encode_mission(plan, "betaflight")


def test_a_shuttle_mission_stays_small_for_any_length_and_says_why_it_refuses():
    for n in (1, 2, 3, 1000, 65_000):
        plan = shuttle_mission(n)
        assert len(plan) <= 7
        jumps = [it for it in plan if it.command == mav.MAV_CMD_DO_JUMP]
        pairs, odd = divmod(n, 2)
        waypoints = sum(1 for it in plan if it.command == mav.MAV_CMD_NAV_WAYPOINT) - 1  # less the way home
        assert waypoints + sum(2 * int(j.params[1]) for j in jumps) == n
        ardu = shuttle_mission(n, autopilot="ardupilot")  # home is item 0: the jump's target moves with its item
        assert [j.params[0] + 1 for j in jumps] == [j.params[0] for j in ardu if j.command == mav.MAV_CMD_DO_JUMP]
    for n in (0, 65_001):
        with pytest.raises(ValueError, match=r"must be 1\.\.65000 \(the loop is one DO_JUMP"):
            shuttle_mission(n)
