"""The simulator, sans-IO: mission, commands, parameters and the MAVLink-correct errors."""

from __future__ import annotations

import math
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mav

from tests.simpair import SimPair, waypoint
from zdrone.core.geometry import distance_m, offset
from zdrone.core.mavlink import FrameCodec, read_header
from zdrone.core.reference import HOME
from zdrone.vehicle.px4modes import FlightMode

NAN = float("nan")


def four_waypoints():
    return [waypoint(0, 0, 0, 20, cmd=mav.MAV_CMD_NAV_TAKEOFF), waypoint(1, 100, 0, 20), waypoint(2, 100, 100, 20),
            waypoint(3, 0, 100, 20), waypoint(4, 0, 0, 20), waypoint(5, 0, 0, 0, cmd=mav.MAV_CMD_NAV_LAND)]


def test_heartbeat_identifies_as_px4_quadrotor():
    s = SimPair()
    s.run(1.1)
    hb = s.take("HEARTBEAT")[-1]
    assert hb.autopilot == mav.MAV_AUTOPILOT_PX4 and hb.type == mav.MAV_TYPE_QUADROTOR
    assert hb.base_mode & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    names = {m.get_type() for m in s.inbox}
    assert {"SYS_STATUS", "GLOBAL_POSITION_INT", "ATTITUDE", "HOME_POSITION", "EXTENDED_SYS_STATE",
            "BATTERY_STATUS", "GPS_RAW_INT", "MISSION_CURRENT"} <= names


def test_mission_flies_through_every_waypoint_and_lands():
    s = SimPair()
    items = four_waypoints()
    assert s.upload(items) == mav.MAV_MISSION_ACCEPTED
    assert s.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mav.MAV_RESULT_ACCEPTED
    assert s.command(mav.MAV_CMD_MISSION_START, 0, 0) == mav.MAV_RESULT_ACCEPTED
    closest = {i: float("inf") for i in range(1, 5)}
    targets = {i: offset(HOME, *ne) for i, ne in zip(range(1, 5), [(100, 0), (100, 100), (0, 100), (0, 0)])}
    while s.now < 300 and s.sim.armed:
        s.run(0.5)
        for i, t in targets.items():
            closest[i] = min(closest[i], distance_m(t, s.sim.position))
    assert not s.sim.armed and s.sim.landed
    assert all(d <= 2.5 for d in closest.values()), closest
    assert distance_m(HOME, s.sim.position) < 1.0
    assert [m.seq for m in s.take("MISSION_ITEM_REACHED")] == [0, 1, 2, 3, 4, 5]
    assert s.sim.mission_finished


def test_mission_download_returns_what_was_uploaded():
    s = SimPair()
    items = four_waypoints()
    s.upload(items)
    s.send(mav.MAVLink_mission_request_list_message(1, 1, 0))
    assert s.take("MISSION_COUNT")[-1].count == len(items)
    for i, it in enumerate(items):
        s.send(mav.MAVLink_mission_request_int_message(1, 1, i, 0))
        got = s.take("MISSION_ITEM_INT")[-1]
        assert (got.seq, got.command, got.x, got.y, got.z) == (it.seq, it.command, it.x, it.y, it.z)
    s.send(mav.MAVLink_mission_clear_all_message(1, 1, 0))
    assert s.take("MISSION_ACK")[-1].type == mav.MAV_MISSION_ACCEPTED
    s.send(mav.MAVLink_mission_request_list_message(1, 1, 0))
    assert s.take("MISSION_COUNT")[-1].count == 0


def test_set_current_and_delivery_land_then_takeoff():
    # PX4 refuses a second NAV_TAKEOFF (tests/unit/test_sim_personality.py): after the delivery
    # landing it takes off again by itself for the next waypoint
    s = SimPair()
    items = [waypoint(0, 0, 0, 15, cmd=mav.MAV_CMD_NAV_TAKEOFF), waypoint(1, 50, 0, 15),
             waypoint(2, 50, 0, 0, cmd=mav.MAV_CMD_NAV_LAND),
             mav.MAVLink_mission_item_int_message(1, 1, 3, mav.MAV_FRAME_MISSION, mav.MAV_CMD_DO_GRIPPER, 0, 1,
                                                  1, mav.GRIPPER_ACTION_RELEASE, 0, 0, 0, 0, 0),
             waypoint(4, 0, 0, 15),
             mav.MAVLink_mission_item_int_message(1, 1, 5, mav.MAV_FRAME_MISSION, mav.MAV_CMD_NAV_RETURN_TO_LAUNCH, 0, 1,
                                                  0, 0, 0, 0, 0, 0, 0)]
    assert s.upload(items) == mav.MAV_MISSION_ACCEPTED
    s.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    s.command(mav.MAV_CMD_MISSION_START, 0, 0)
    assert s.run_until(lambda: s.sim.payload_released, 120)
    assert distance_m(offset(HOME, 50, 0), s.sim.position) < 1.5 and s.sim.landed and s.sim.armed
    assert s.run_until(lambda: not s.sim.armed, 200)
    assert distance_m(HOME, s.sim.position) < 2.5
    s.send(mav.MAVLink_mission_set_current_message(1, 1, 2))
    assert s.take("MISSION_CURRENT")[-1].seq == 2


def test_commands_takeoff_reposition_rtl_land():
    s = SimPair()
    assert s.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, NAN) == mav.MAV_RESULT_TEMPORARILY_REJECTED
    s.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert s.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, NAN) == mav.MAV_RESULT_ACCEPTED
    assert s.run_until(lambda: s.sim.k.alt > 9.5 and s.sim.mode is FlightMode.HOLD, 30)
    # disarming in the air is refused without the force magic
    assert s.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 0) == mav.MAV_RESULT_DENIED
    p = offset(HOME, 0, 80)
    assert s.command(mav.MAV_CMD_DO_REPOSITION, -1, 0, 0, NAN, p.lat, p.lon, 488 + 20) == mav.MAV_RESULT_ACCEPTED
    assert s.run_until(lambda: distance_m(p, s.sim.position) < 1.0, 60)
    assert s.command(mav.MAV_CMD_NAV_RETURN_TO_LAUNCH) == mav.MAV_RESULT_ACCEPTED
    assert s.run_until(lambda: not s.sim.armed, 120)
    assert distance_m(HOME, s.sim.position) < 2.5
    s.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    s.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, 488 + 8)
    assert s.run_until(lambda: s.sim.k.alt > 7.5, 30)
    assert s.command(mav.MAV_CMD_NAV_LAND) == mav.MAV_RESULT_ACCEPTED
    assert s.run_until(lambda: not s.sim.armed, 60)


def test_set_mode_px4_custom_modes():
    s = SimPair()
    s.upload(four_waypoints())
    s.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    main_auto, sub_mission = 4, 4
    assert s.command(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main_auto, sub_mission) == mav.MAV_RESULT_ACCEPTED
    assert s.sim.mode is FlightMode.MISSION
    s.run(1.1)
    assert s.take("HEARTBEAT")[-1].custom_mode == FlightMode.MISSION.custom_mode
    assert s.command(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 99, 0) == mav.MAV_RESULT_UNSUPPORTED


def test_parameters_list_read_set_bytewise():
    s = SimPair()
    s.send(mav.MAVLink_param_request_list_message(1, 1))
    values = s.take("PARAM_VALUE")
    names = {v.param_id for v in values}
    assert {"COM_DL_LOSS_T", "NAV_DLL_ACT", "MPC_XY_CRUISE"} <= names and len(values) == values[0].param_count
    dll = next(v for v in values if v.param_id == "NAV_DLL_ACT")
    assert struct.unpack("<i", struct.pack("<f", dll.param_value))[0] == 0  # off by default

    def set_int(name, v):
        s.send(mav.MAVLink_param_set_message(1, 1, name.encode(), struct.unpack("<f", struct.pack("<i", v))[0], mav.MAV_PARAM_TYPE_INT32))
        got = s.take("PARAM_VALUE")[-1]
        return struct.unpack("<i", struct.pack("<f", got.param_value))[0]

    assert set_int("COM_DL_LOSS_T", 7) == 7
    s.send(mav.MAVLink_param_request_read_message(1, 1, b"COM_DL_LOSS_T", -1))
    assert struct.unpack("<i", struct.pack("<f", s.take("PARAM_VALUE")[-1].param_value))[0] == 7
    s.send(mav.MAVLink_param_set_message(1, 1, b"MPC_XY_CRUISE", 8.5, mav.MAV_PARAM_TYPE_REAL32))
    assert s.take("PARAM_VALUE")[-1].param_value == pytest.approx(8.5)
    # out of range and NaN: refused, value unchanged, counted
    assert set_int("NAV_DLL_ACT", 9) == 0
    s.send(mav.MAVLink_param_set_message(1, 1, b"MPC_XY_CRUISE", NAN, mav.MAV_PARAM_TYPE_REAL32))
    assert s.take("PARAM_VALUE")[-1].param_value == pytest.approx(8.5)
    assert set_int("MAV_SYS_ID", 9) == 1
    assert s.sim.counters["param_rejected"] == 3
    s.send(mav.MAVLink_param_set_message(1, 1, b"NO_SUCH", 1.0, mav.MAV_PARAM_TYPE_REAL32))
    assert s.sim.counters["param_unknown"] == 1


def test_link_loss_parameters_act_when_enabled():
    s = SimPair()
    s.send(mav.MAVLink_param_set_message(1, 1, b"NAV_DLL_ACT", struct.unpack("<f", struct.pack("<i", 3))[0], mav.MAV_PARAM_TYPE_INT32))
    s.send(mav.MAVLink_param_set_message(1, 1, b"COM_DL_LOSS_T", struct.unpack("<f", struct.pack("<i", 5))[0], mav.MAV_PARAM_TYPE_INT32))
    s.send(mav.MAVLink_heartbeat_message(mav.MAV_TYPE_GCS, 8, 0, 0, 4, 3))
    s.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    s.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, NAN)
    assert s.run_until(lambda: s.sim.mode is FlightMode.LAND, 10)
    assert s.now >= 5.0


@pytest.mark.parametrize("item, code", [
    (waypoint(0, 0, 0, 10, cmd=mav.MAV_CMD_DO_DIGICAM_CONTROL), mav.MAV_MISSION_UNSUPPORTED),
    (waypoint(0, 0, 0, 10, frame=mav.MAV_FRAME_LOCAL_NED), mav.MAV_MISSION_UNSUPPORTED_FRAME),
    (waypoint(0, 0, 0, NAN), mav.MAV_MISSION_INVALID_PARAM7),
    (mav.MAVLink_mission_item_int_message(1, 1, 0, 6, 16, 0, 1, 0, 0, 0, 0, 950000000, 85455940, 10), mav.MAV_MISSION_INVALID_PARAM5_X),
    (mav.MAVLink_mission_item_int_message(1, 1, 0, 6, 16, 0, 1, 0, 0, 0, 0, 473977420, 0, 10), mav.MAV_MISSION_INVALID_PARAM6_Y),
    (waypoint(0, 0, 0, 10, cmd=mav.MAV_CMD_NAV_LOITER_TIME, params=(NAN, 0, 0, 0)), mav.MAV_MISSION_INVALID_PARAM1),
])
def test_bad_mission_items_get_the_right_ack(item, code):
    s = SimPair()
    assert s.upload([item]) == code
    assert s.sim.mission == []


def test_too_many_items_and_other_mission_types():
    s = SimPair()
    s.send(mav.MAVLink_mission_count_message(1, 1, 10_000, 0))
    assert s.take("MISSION_ACK")[-1].type == mav.MAV_MISSION_NO_SPACE
    s.send(mav.MAVLink_mission_count_message(1, 1, 3, mav.MAV_MISSION_TYPE_FENCE))
    assert s.take("MISSION_ACK")[-1].type == mav.MAV_MISSION_UNSUPPORTED
    s.send(mav.MAVLink_mission_request_list_message(1, 1, mav.MAV_MISSION_TYPE_RALLY))
    assert s.take("MISSION_COUNT")[-1].count == 0
    s.send(mav.MAVLink_mission_request_int_message(1, 1, 5, 0))
    assert s.take("MISSION_ACK")[-1].type == mav.MAV_MISSION_INVALID_SEQUENCE


def test_unsolicited_mission_item_denied():
    s = SimPair()
    s.send(waypoint(0, 0, 0, 10))
    assert s.take("MISSION_ACK")[-1].type == mav.MAV_MISSION_DENIED


def test_bad_commands_get_acks():
    s = SimPair()
    assert s.command(31999) == mav.MAV_RESULT_UNSUPPORTED
    assert s.command(mav.MAV_CMD_MISSION_START) == mav.MAV_RESULT_DENIED  # no mission
    assert s.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, mav.MAVLINK_MSG_ID_ATTITUDE, NAN) == mav.MAV_RESULT_DENIED
    assert s.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, 9999, 1e6) == mav.MAV_RESULT_UNSUPPORTED
    assert s.command(mav.MAV_CMD_REQUEST_MESSAGE, 9999) == mav.MAV_RESULT_UNSUPPORTED
    assert s.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, NAN) == mav.MAV_RESULT_DENIED
    s.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    s.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, NAN)
    s.run(5)
    assert s.command(mav.MAV_CMD_DO_REPOSITION, -1, 0, 0, NAN, NAN, 8.5, 500) == mav.MAV_RESULT_DENIED
    assert s.command(mav.MAV_CMD_DO_REPOSITION, -1, 0, 0, NAN, 91.0, 8.5, 500) == mav.MAV_RESULT_DENIED
    assert s.sim.counters["command_denied"] >= 4 and s.sim.counters["command_unsupported"] == 3


def test_message_interval_and_request_message():
    s = SimPair()
    assert s.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, mav.MAVLINK_MSG_ID_ATTITUDE, 100_000) == mav.MAV_RESULT_ACCEPTED
    s.take("ATTITUDE")
    s.run(1.0)
    assert 9 <= len(s.take("ATTITUDE")) <= 11
    assert s.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, mav.MAVLINK_MSG_ID_ATTITUDE, -1) == mav.MAV_RESULT_ACCEPTED
    s.take("ATTITUDE")
    s.run(1.0)
    assert s.take("ATTITUDE") == []
    assert s.command(mav.MAV_CMD_REQUEST_MESSAGE, mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION) == mav.MAV_RESULT_ACCEPTED
    assert s.take("AUTOPILOT_VERSION")[-1].capabilities & mav.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    assert s.command(mav.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, 1) == mav.MAV_RESULT_ACCEPTED
    assert s.take("AUTOPILOT_VERSION")


def test_frames_for_another_system_are_ignored_and_counted():
    s = SimPair()
    s.send(mav.MAVLink_command_long_message(9, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0))
    assert not s.sim.armed and s.take("COMMAND_ACK") == []
    assert s.sim.counters["not_for_us"] == 1


def test_garbage_and_unknown_ids_never_raise():
    s = SimPair()
    s.sim.receive(b"\xfd\x01\x00\x00\x00\x01\x01\x99\x99\x00\x00\x00\x00", 0.0)  # unknown id 0x9999
    s.sim.receive(b"garbage", 0.0)
    s.sim.receive_bytes(b"\x00\xfd\x09" + bytes(40), 0.0)
    assert s.sim.counters["malformed"] >= 2


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=300))
def test_random_bytes_never_raise(junk):
    s = SimPair()
    s.sim.receive(junk, 0.0)
    s.sim.receive_bytes(junk, 0.0)
    s.sim.step(0.5)


@settings(max_examples=100, deadline=None)
@given(st.integers(0, 600), st.lists(st.floats(allow_nan=True, allow_infinity=True, width=32), min_size=7, max_size=7))
def test_any_command_gets_an_ack_and_never_raises(cmd, params):
    s = SimPair()
    s.send(mav.MAVLink_command_long_message(1, 1, cmd, 0, *params))
    acks = s.take("COMMAND_ACK")
    assert len(acks) == 1 and acks[0].command == cmd
    s.run(0.3)
    assert math.isfinite(s.sim.k.north) and math.isfinite(s.sim.k.alt)


def test_the_sims_frames_decode_with_an_independent_codec():
    """A second of the sim's own output (not collected by the pair) decodes with a codec of its own:
    every frame is from system 1, and the usual streams are all there."""
    s = SimPair()
    for tenth in range(1, 11):
        s.sim.step(tenth / 10)
    frames = s.sim.drain()
    assert len(frames) > 20
    codec = FrameCodec(200)
    assert all(read_header(f).sysid == 1 for f in frames)
    decoded = [m for m in map(codec.decode, frames) if m is not None]  # ids of no dialect (PX4's EVENT...) aside
    assert all(m.get_srcSystem() == 1 for m in decoded)
    assert {"HEARTBEAT", "SYS_STATUS", "GLOBAL_POSITION_INT", "ATTITUDE"} <= {m.get_type() for m in decoded}


def test_land_command_lands_where_the_vehicle_is():
    s = SimPair()
    s.upload(four_waypoints())
    s.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    s.command(mav.MAV_CMD_MISSION_START, 0, 0)
    assert s.run_until(lambda: s.sim.k.north > 50, 60)
    here = s.sim.position
    s.command(mav.MAV_CMD_NAV_LAND)
    assert s.run_until(lambda: not s.sim.armed, 60)
    assert distance_m(here, s.sim.position) < 15.0  # stops within braking distance, no further


def test_a_do_jump_loop_flies_every_crossing_then_goes_on():
    """The shuttle mission of 5 crossings: far, near, a DO_JUMP back to far once more, then far, home
    and land: the far waypoint is reached three times and the near one twice as turns."""
    from gs.planner import shuttle_mission

    plan = shuttle_mission(5)
    assert [it.command for it in plan].count(mav.MAV_CMD_DO_JUMP) == 1
    s = SimPair()
    assert s.upload([it.message(i, (1, 1)) for i, it in enumerate(plan)]) == mav.MAV_MISSION_ACCEPTED
    assert s.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mav.MAV_RESULT_ACCEPTED
    assert s.command(mav.MAV_CMD_MISSION_START, 0, 0) == mav.MAV_RESULT_ACCEPTED
    far, near = offset(HOME, 0.0, 440.0), offset(HOME, 0.0, 80.0)
    visits = {"far": 0, "near": 0}
    inside = {"far": False, "near": False}
    while s.now < 600 and s.sim.armed:
        s.run(0.5)
        for name, point in (("far", far), ("near", near)):
            now_inside = distance_m(point, s.sim.position) < 3.0
            visits[name] += now_inside and not inside[name]
            inside[name] = now_inside
    assert s.sim.landed and not s.sim.armed and distance_m(HOME, s.sim.position) < 1.0
    assert visits == {"far": 3, "near": 2 + 2}  # out and home over the near waypoint, besides its two turns
    assert [m.seq for m in s.take("MISSION_ITEM_REACHED")] == [0, 1, 2, 3, 4, 2, 3, 4, 5, 6, 7]


@pytest.mark.parametrize("target, repeat, code", [(7.0, 1.0, mav.MAV_MISSION_INVALID_PARAM1),  # forwards
                                                  (1.5, 1.0, mav.MAV_MISSION_INVALID_PARAM1),
                                                  (1.0, -2.0, mav.MAV_MISSION_INVALID_PARAM2),
                                                  (1.0, 40000.0, mav.MAV_MISSION_INVALID_PARAM2)])
def test_a_bad_do_jump_is_refused_with_its_parameter(target, repeat, code):
    items = [waypoint(0, 0, 0, 20, cmd=mav.MAV_CMD_NAV_TAKEOFF), waypoint(1, 100, 0, 20),
             mav.MAVLink_mission_item_int_message(1, 1, 2, mav.MAV_FRAME_MISSION, mav.MAV_CMD_DO_JUMP, 0, 1,
                                                  target, repeat, 0, 0, 0, 0, 0)]
    assert SimPair().upload(items) == code
