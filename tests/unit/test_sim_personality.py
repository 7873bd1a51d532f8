"""The simulator's personalities, sans-IO: each refuses what the real autopilot refuses, with its text
and ACK result (facts measured with PX4 SITL v1.16 and ArduCopter SITL 4.7-dev)."""

from __future__ import annotations

import socket
import struct
import threading
import time

import pytest

from tests.procs import wait_until
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mav
from pymavlink.generator.mavcrc import x25crc

from gs.planner import encode_mission, reference_mission, reference_plan
from tests.simpair import RawFrame, SimPair, waypoint
from zdrone.core.geometry import distance_m
from zdrone.core.mavlink import FrameCodec
from zdrone.core.reference import DELIVERY, HOME
from zdrone.vehicle.personality import (ARDUPILOT, PX4, RAW_CRC_EXTRA, personality, px4_event_id)
from zdrone.vehicle.px4modes import FlightMode
from zdrone.vehicle.simserver import SimOptions, SimServer
from zdrone.vehicle.transport import MavTransport

NAN = float("nan")
AP_GUIDED, AP_AUTO, AP_LAND, AP_STABILIZE = 4, 3, 9, 0


def msgs(items):
    """Planned items as the MISSION_ITEM_INT messages a GCS uploads."""
    return [it.message(i, (1, 1)) for i, it in enumerate(items)]


def events(s: SimPair) -> list[tuple[int, int]]:
    """(event id, log levels) of the EVENTs (410) in the inbox, taken from it."""
    out = []
    for m in s.take("UNKNOWN_410"):
        payload = m.payload.ljust(53, b"\0")  # MAVLink 2 drops trailing zeros
        ev_id, _boot_ms, _seq, _dc, _ds, levels = struct.unpack_from("<IIHBBB", payload)
        out.append((ev_id, levels))
    return out


def texts_and_acks(s: SimPair) -> list[str]:
    """STATUSTEXTs (chunks joined) and COMMAND_ACK results, in the order they came; inbox emptied."""
    out: list[str] = []
    for m in s.inbox:
        if m.get_type() == "STATUSTEXT":
            if m.chunk_seq > 0 and out:
                out[-1] += m.text
            else:
                out.append(m.text)
        elif m.get_type() == "COMMAND_ACK":
            out.append(f"ACK {m.command} {m.result}")
    s.inbox.clear()
    return out


def set_param(s: SimPair, name: str, value: float, kind: int = mav.MAV_PARAM_TYPE_REAL32) -> float:
    s.send(mav.MAVLink_param_set_message(1, 1, name.encode(), value, kind))
    return s.take("PARAM_VALUE")[-1].param_value


# ======================================================================== PX4
def test_px4_identity_and_mode_numbers():
    s = SimPair()
    s.run(1.1)
    hb = s.take("HEARTBEAT")[-1]
    assert hb.autopilot == mav.MAV_AUTOPILOT_PX4 and hb.custom_mode == (4 << 16) | (3 << 24)  # AUTO.LOITER
    assert s.command(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 3, 0) == mav.MAV_RESULT_ACCEPTED
    s.run(1.0)
    assert s.take("HEARTBEAT")[-1].custom_mode == 3 << 16  # POSCTL
    cur = s.take("CURRENT_MODE")[-1]  # id 436, development dialect
    assert cur.custom_mode == 3 << 16 and cur.standard_mode == 1  # MAV_STANDARD_MODE_POSITION_HOLD


def test_px4_refuses_a_takeoff_after_a_positional_item_at_mission_start_not_at_upload():
    s = SimPair()
    assert s.upload(msgs(reference_plan())) == mav.MAV_MISSION_ACCEPTED  # ACKed first ...
    assert "Mission rejected: takeoff not first waypoint item\t" in s.texts()  # ... checked after the ACK
    s.inbox.clear()
    s.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    s.inbox.clear()
    s.send(mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_MISSION_START, 0, 0, 0, 0, 0, 0, 0, 0))
    evs = events(s)
    assert texts_and_acks(s) == ["Mission rejected: takeoff not first waypoint item\t",
                                 f"ACK {mav.MAV_CMD_MISSION_START} {mav.MAV_RESULT_DENIED}",
                                 "Mission start denied! No valid mission\t"]
    # PX4 gives the reasons as EVENTs too (the STATUSTEXT's trailing tab says so)
    assert evs == [(px4_event_id("navigator_mis_takeoff_not_first"), 0x63),
                   (px4_event_id("commander_mission_start_denied_no_mission"), 0x62)]
    s.run(5)
    assert s.sim.landed and s.sim.k.alt == 0.0


def test_px4_takes_off_again_by_itself_after_a_mid_mission_landing():
    s = SimPair()
    items = reference_mission()  # PX4 encoding: no second take-off
    assert [it.command for it in items].count(mav.MAV_CMD_NAV_TAKEOFF) == 1
    assert s.upload(msgs(items)) == mav.MAV_MISSION_ACCEPTED
    assert s.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mav.MAV_RESULT_ACCEPTED
    assert s.command(mav.MAV_CMD_MISSION_START, 0, 0) == mav.MAV_RESULT_ACCEPTED
    assert s.run_until(lambda: s.sim.payload_released, 300)
    assert s.sim.landed and s.sim.armed and distance_m(DELIVERY, s.sim.position) < 2.0
    assert s.run_until(lambda: s.sim.k.alt > 10, 30) and s.sim.armed  # no disarm, no take-off item
    assert s.run_until(lambda: not s.sim.armed, 300)
    assert distance_m(HOME, s.sim.position) < 2.0
    assert "Disarmed by landing\t" in s.texts()


def test_px4_refuses_to_arm_until_ready_then_says_so():
    s = SimPair(ready_after=10.0)
    s.run(1.0)
    sys_status = s.take("SYS_STATUS")[-1]
    assert sys_status.onboard_control_sensors_present & mav.MAV_SYS_STATUS_PREARM_CHECK
    assert not sys_status.onboard_control_sensors_health & mav.MAV_SYS_STATUS_PREARM_CHECK
    s.inbox.clear()
    s.send(mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0))
    assert events(s) == [(px4_event_id("commander_arm_denied_resolve_failures"), 0x62)]
    assert texts_and_acks(s) == ["Arming denied: Resolve system health failures first\t",  # two chunks, one text
                                 f"ACK {mav.MAV_CMD_COMPONENT_ARM_DISARM} {mav.MAV_RESULT_TEMPORARILY_REJECTED}"]
    assert not s.sim.armed
    s.run(9.5)
    assert "Ready for takeoff!" in s.texts()
    assert s.take("SYS_STATUS")[-1].onboard_control_sensors_health & mav.MAV_SYS_STATUS_PREARM_CHECK
    assert s.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mav.MAV_RESULT_ACCEPTED
    assert s.texts() == ["Armed by external command\t"]


def test_px4_mission_start_arms_a_ready_vehicle_and_is_refused_before():
    s = SimPair(ready_after=5.0)
    assert s.upload(msgs(reference_mission())) == mav.MAV_MISSION_ACCEPTED
    assert s.command(mav.MAV_CMD_MISSION_START, 0, 0) == mav.MAV_RESULT_TEMPORARILY_REJECTED
    assert "Switching to Mission is currently not available\t" in s.texts()
    s.run(5.5)
    s.inbox.clear()
    assert s.command(mav.MAV_CMD_MISSION_START, 0, 0) == mav.MAV_RESULT_ACCEPTED
    assert s.sim.armed and s.texts() == ["Armed by mission start\t"]


def test_px4_disarms_itself_when_armed_idle_on_the_ground():
    s = SimPair()
    s.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    s.run(9.5)
    assert s.sim.armed
    s.run(1.0)
    assert not s.sim.armed
    assert s.texts()[-1] == "Disarmed by auto preflight disarming\t"


def test_px4_streams_its_extra_ids_with_valid_checksums():
    s = SimPair()
    s.run(10.05)
    extra = {m.msgid: 0 for m in s.inbox if isinstance(m, RawFrame)}
    for m in s.inbox:
        if isinstance(m, RawFrame):
            extra[m.msgid] += 1
    assert set(extra) == {8, 380, 411}  # plus CURRENT_MODE (436), decoded by the development dialect
    assert all(9 <= n <= 11 for n in extra.values())  # ~1 Hz each: about 4 frames/s with CURRENT_MODE
    assert 9 <= len(s.take("CURRENT_MODE")) <= 11
    # the frames no dialect defines carry the right checksum (CRC_EXTRA of their definitions)
    s.sim.drain()
    s.sim.telemetry.send_message(411)
    frame = s.sim.drain()[0]
    crc = x25crc(frame[1:10 + frame[1]])
    crc.accumulate(bytes([RAW_CRC_EXTRA[411]]))
    assert frame[10 + frame[1]] | frame[11 + frame[1]] << 8 == crc.crc


def test_px4_parameters_and_endpoints():
    s = SimPair()
    s.send(mav.MAVLink_param_request_list_message(1, 1))
    names = {v.param_id for v in s.take("PARAM_VALUE")}
    assert {"COM_DL_LOSS_T", "NAV_DLL_ACT", "COM_DISARM_PRFLT", "MAV_SYS_ID"} <= names
    assert not {"FS_GCS_ENABLE", "MIS_OPTIONS"} & names
    assert PX4.endpoint == "udpin:127.0.0.1:14580" and PX4.send_to == ("127.0.0.1", 14540)
    assert PX4.real_ready_after == 10.0 and PX4.default_ready_after <= 1.0


def test_event_id_is_px4s_hash():
    # (fnv1a32(name) & 0xffffff) | 1 << 24, as PX4's events::ID()
    assert px4_event_id("") == (0x811C9DC5 & 0xFFFFFF) | 1 << 24
    assert px4_event_id("a") == (0xE40C292C & 0xFFFFFF) | 1 << 24


# =================================================================== ArduPilot
def ap(ready_after: float = 0.0) -> SimPair:
    return SimPair(personality=ARDUPILOT, ready_after=ready_after)


def test_ardupilot_identity_and_mode_numbers():
    s = ap()
    s.run(1.1)
    hb = s.take("HEARTBEAT")[-1]
    assert hb.autopilot == mav.MAV_AUTOPILOT_ARDUPILOTMEGA and hb.type == mav.MAV_TYPE_QUADROTOR
    assert hb.custom_mode == AP_STABILIZE and hb.system_status == mav.MAV_STATE_STANDBY
    for custom in (AP_GUIDED, AP_LAND, AP_AUTO):
        assert s.command(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, custom) == mav.MAV_RESULT_ACCEPTED
        s.run(1.0)
        assert s.take("HEARTBEAT")[-1].custom_mode == custom  # any mode while disarmed
    assert s.command(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 42) == mav.MAV_RESULT_UNSUPPORTED
    assert s.sim.mode is FlightMode.MISSION and s.sim.mode_row.name == "AUTO"


def test_ardupilot_sends_nothing_but_heartbeat_until_asked():
    s = ap()
    s.run(5.0)
    assert {m.get_type() for m in s.inbox} <= {"HEARTBEAT", "STATUSTEXT"}
    s.inbox.clear()
    s.send(mav.MAVLink_request_data_stream_message(1, 1, mav.MAV_DATA_STREAM_ALL, 4, 1))
    s.run(2.0)
    got = {m.get_type() for m in s.inbox}
    assert {"GLOBAL_POSITION_INT", "SYS_STATUS", "MISSION_CURRENT", "MEMINFO", "EKF_STATUS_REPORT"} <= got
    assert "EXTENDED_SYS_STATE" not in got  # in no stream group: only by interval
    assert s.sim.params["MAV1_POSITION"].value == 4
    assert s.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, mav.MAVLINK_MSG_ID_EXTENDED_SYS_STATE, 500_000) == mav.MAV_RESULT_ACCEPTED
    s.inbox.clear()
    s.run(2.0)
    assert 3 <= len(s.take("EXTENDED_SYS_STATE")) <= 5
    s.send(mav.MAVLink_request_data_stream_message(1, 1, mav.MAV_DATA_STREAM_ALL, 0, 0))
    s.inbox.clear()
    s.run(2.0)
    assert {m.get_type() for m in s.inbox} <= {"HEARTBEAT", "EXTENDED_SYS_STATE"}


def test_ardupilot_meminfo_is_an_ardupilotmega_id():
    s = ap()
    s.send(mav.MAVLink_request_data_stream_message(1, 1, mav.MAV_DATA_STREAM_EXTENDED_STATUS, 2, 1))
    s.run(1.0)
    assert s.take("MEMINFO")  # decoded with the ardupilotmega dialect
    s.sim.telemetry.send_message(152)
    frame = s.sim.drain()[0]
    assert frame[7] == 152 and 152 not in mav.mavlink_map  # not in common: the GS decodes it with ardupilotmega
    assert FrameCodec(255).decode(frame).get_type() == "MEMINFO"


def test_ardupilot_keeps_item_0_as_home_and_loses_a_takeoff_sent_there():
    s = ap()
    px4_style = [waypoint(0, 0, 0, 20, cmd=mav.MAV_CMD_NAV_TAKEOFF), waypoint(1, 100, 0, 20),
                 waypoint(2, 100, 0, 0, cmd=mav.MAV_CMD_NAV_LAND)]
    assert s.upload(px4_style) == mav.MAV_MISSION_ACCEPTED
    s.send(mav.MAVLink_mission_request_int_message(1, 1, 0, 0))
    home = s.take("MISSION_ITEM_INT")[-1]
    assert (home.command, home.x, home.y) == (mav.MAV_CMD_NAV_WAYPOINT, int(round(HOME.lat * 1e7)), int(round(HOME.lon * 1e7)))
    assert s.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mav.MAV_RESULT_ACCEPTED
    s.inbox.clear()
    s.send(mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_MISSION_START, 0, 0, 0, 0, 0, 0, 0, 0))
    assert texts_and_acks(s) == [f"ACK {mav.MAV_CMD_MISSION_START} {mav.MAV_RESULT_FAILED}",  # its reasons after it
                                 "Auto: Missing Takeoff Cmd", "Mode change to AUTO failed: init failed"]
    assert s.sim.mode_row.name == "STABILIZE" and s.sim.landed
    # first/last item in MISSION_START: not supported
    assert s.command(mav.MAV_CMD_MISSION_START, 1, 2) == mav.MAV_RESULT_DENIED


def test_ardupilot_refuses_to_arm_and_auto_until_ready():
    s = ap(ready_after=40.0)
    assert s.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mav.MAV_RESULT_FAILED
    assert s.texts()[-1] == "Arm: Accels inconsistent"
    s.run(25.0)
    assert s.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mav.MAV_RESULT_FAILED
    assert s.texts()[-1] == "Arm: EKF attitude is bad"
    s.run(6.0)
    assert s.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mav.MAV_RESULT_ACCEPTED
    assert s.sim.armed and s.texts()[-1] == "Arming motors"
    assert s.upload(msgs(reference_mission(autopilot="ardupilot"))) == mav.MAV_MISSION_ACCEPTED
    assert s.command(mav.MAV_CMD_MISSION_START, 0, 0) == mav.MAV_RESULT_FAILED
    assert s.texts()[-1] == "Mode change to AUTO failed: requires position"
    s.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 0)
    s.run(9.0)
    assert "EKF3 IMU0 is using GPS" in s.texts()
    assert s.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mav.MAV_RESULT_ACCEPTED
    assert s.command(mav.MAV_CMD_MISSION_START, 0, 0) == mav.MAV_RESULT_ACCEPTED
    assert s.run_until(lambda: s.sim.k.alt > 5, 20)


def test_ardupilot_repeats_its_prearm_failures():
    s = ap(ready_after=100.0)  # accels until 50 s, EKF attitude until 75 s
    s.run(61.0)
    prearm = [t for t in s.texts() if t.startswith("PreArm:")]
    assert prearm == ["PreArm: Accels inconsistent", "PreArm: Accels inconsistent", "PreArm: EKF attitude is bad"]


def test_ardupilot_disarms_at_a_mid_mission_landing_without_mis_options_4():
    s = ap()
    assert s.upload(msgs(reference_mission(autopilot="ardupilot"))) == mav.MAV_MISSION_ACCEPTED
    s.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert s.command(mav.MAV_CMD_MISSION_START, 0, 0) == mav.MAV_RESULT_ACCEPTED
    assert s.run_until(lambda: not s.sim.armed, 300)
    assert distance_m(DELIVERY, s.sim.position) < 2.0 and s.sim.landed
    assert not s.sim.payload_released  # the mission ended at the landing
    assert s.texts()[-1] == "Disarming motors" and s.sim.mode_row.name == "AUTO"
    s.run(10.0)
    assert not s.sim.armed and s.sim.landed


def test_ardupilot_continues_after_land_with_mis_options_4_and_a_takeoff_next():
    s = ap()
    assert set_param(s, "MIS_OPTIONS", 4.0, mav.MAV_PARAM_TYPE_INT16) == 4.0
    assert s.upload(msgs(reference_mission(autopilot="ardupilot"))) == mav.MAV_MISSION_ACCEPTED
    s.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    s.command(mav.MAV_CMD_MISSION_START, 0, 0)
    assert s.run_until(lambda: s.sim.payload_released, 300) and s.sim.armed
    assert s.run_until(lambda: not s.sim.armed, 300)
    assert distance_m(HOME, s.sim.position) < 2.0
    # MIS_OPTIONS 4 alone is not enough: the next navigation item must be a take-off
    s2 = ap()
    set_param(s2, "MIS_OPTIONS", 4.0, mav.MAV_PARAM_TYPE_INT16)
    no_second_takeoff = encode_mission(reference_mission(), "ardupilot")
    s2.upload(msgs(no_second_takeoff))
    s2.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    s2.command(mav.MAV_CMD_MISSION_START, 0, 0)
    assert s2.run_until(lambda: not s2.sim.armed, 300)
    assert distance_m(DELIVERY, s2.sim.position) < 2.0 and not s2.sim.payload_released


def test_ardupilot_disarms_itself_when_armed_idle():
    s = ap()
    s.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    s.run(9.5)
    assert s.sim.armed
    s.run(1.0)
    assert not s.sim.armed and s.texts()[-1] == "Disarming motors"


def test_ardupilot_takeoff_needs_guided_and_arming_in_auto_is_refused():
    s = ap()
    s.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert s.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, 10) == mav.MAV_RESULT_FAILED  # STABILIZE
    assert s.command(mav.MAV_CMD_DO_SET_MODE, 1, AP_GUIDED) == mav.MAV_RESULT_ACCEPTED
    assert s.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, 10) == mav.MAV_RESULT_ACCEPTED
    assert s.run_until(lambda: s.sim.k.alt > 9.5, 30) and s.sim.mode_row.name == "GUIDED"
    assert s.command(mav.MAV_CMD_DO_SET_MODE, 1, AP_LAND) == mav.MAV_RESULT_ACCEPTED
    assert s.run_until(lambda: not s.sim.armed, 60)
    assert s.sim.mode_row.name == "LAND"  # ArduPilot stays in LAND on the ground
    s.command(mav.MAV_CMD_DO_SET_MODE, 1, AP_AUTO)
    assert s.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mav.MAV_RESULT_FAILED
    assert s.texts()[-1] == "Arm: Mode not armable"


def test_ardupilot_parameters_names_defaults_and_encoding():
    s = ap()
    s.send(mav.MAVLink_param_request_list_message(1, 1))
    assert s.texts() == ["ArduCopter V4.7.0-dev (5a44524f)", "Frame: QUAD/X"]  # the banner first
    values = {v.param_id: v for v in s.take("PARAM_VALUE")}
    assert values["FS_GCS_ENABLE"].param_value == 0.0 and values["FS_GCS_ENABLE"].param_type == mav.MAV_PARAM_TYPE_INT8
    assert values["FS_GCS_TIMEOUT"].param_value == 5.0
    assert values["MAV_SYSID"].param_value == 1.0 and values["MAV_GCS_SYSID"].param_value == 255.0  # a cast, not bytewise
    assert values["MIS_OPTIONS"].param_value == 0.0
    assert all(values[f"MAV{n}_{g}"].param_value == 0.0 for n in (1, 2, 3) for g in ("EXT_STAT", "POSITION", "EXTRA1"))
    assert "COM_DL_LOSS_T" not in values and "NAV_DLL_ACT" not in values
    # ArduPilot takes what it is given (no range check), and ignores an unknown name without an answer
    assert set_param(s, "FS_GCS_TIMEOUT", 500.0) == 500.0
    s.send(mav.MAVLink_param_set_message(1, 1, b"NO_SUCH", 1.0, mav.MAV_PARAM_TYPE_REAL32))
    assert s.take("PARAM_VALUE") == [] and s.sim.counters["param_unknown"] == 1
    assert set_param(s, "MAV1_POSITION", 2.0, mav.MAV_PARAM_TYPE_INT16) == 2.0
    s.run(2.0)
    assert 3 <= len(s.take("GLOBAL_POSITION_INT")) <= 5  # the stream rate parameter is live


def test_mavlink_ftp_is_refused_by_the_ardupilot_personality_so_clients_fall_back():
    open_ro = struct.pack("<HBBBBBBI", 7, 0, 4, 0, 0, 0, 0, 0) + b"@PARAM/param.pck\0"
    s = ap()
    s.send(mav.MAVLink_file_transfer_protocol_message(0, 1, 1, list(open_ro.ljust(251, b"\0"))))
    reply = bytes(s.take("FILE_TRANSFER_PROTOCOL")[-1].payload)
    seq, _session, opcode, size, req_opcode = struct.unpack_from("<HBBBB", reply)
    assert (seq, opcode, size, req_opcode, reply[12]) == (8, 129, 1, 4, 10)  # NAK, file not found
    px4 = SimPair()
    px4.send(mav.MAVLink_file_transfer_protocol_message(0, 1, 1, list(open_ro.ljust(251, b"\0"))))
    assert px4.take("FILE_TRANSFER_PROTOCOL") == [] and px4.sim.counters["ignored"] == 1


def test_ardupilot_gcs_failsafe_counts_only_mav_gcs_sysid():
    s = ap()
    set_param(s, "FS_GCS_ENABLE", 5.0, mav.MAV_PARAM_TYPE_INT8)  # 5: land
    gs4 = FrameCodec(4, 190)
    s.sim.receive(FrameCodec(255, 190).encode(mav.MAVLink_heartbeat_message(mav.MAV_TYPE_GCS, 8, 0, 0, 4, 3)), 0.0)
    s.command(mav.MAV_CMD_DO_SET_MODE, 1, AP_GUIDED)
    s.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    s.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, 20)
    while s.now < 10 and s.sim.mode is not FlightMode.LAND:  # a GS with another sysid keeps talking
        s.sim.receive(gs4.encode(mav.MAVLink_heartbeat_message(mav.MAV_TYPE_GCS, 8, 0, 0, 4, 3)), s.now)
        s.run(0.5)
    assert s.sim.mode is FlightMode.LAND and s.sim.mode_row.name == "LAND" and 5.0 <= s.now <= 6.5
    assert "GCS Failsafe: land" in s.texts()


def test_ardupilot_endpoint_and_boot_on_first_client():
    assert ARDUPILOT.endpoint == "tcpin:127.0.0.1:5760" and ARDUPILOT.send_to is None
    assert ARDUPILOT.real_ready_after == 40.0 and personality("ardupilot") is ARDUPILOT
    probe = socket.socket()
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    server = SimServer(SimOptions(mavlink=f"tcpin:127.0.0.1:{port}", personality=ARDUPILOT, speedup=10.0))
    th = threading.Thread(target=server.run)
    th.start()
    try:
        assert not wait_until(lambda: server.sim.t > 0.0, 0.5)  # no client yet: not booted
        connecting = time.monotonic()
        with socket.create_connection(("127.0.0.1", port), timeout=10.0) as c:
            c.settimeout(10.0)
            data = c.recv(1024)
    finally:
        server.stop()
        th.join(10.0)
    connected_for = time.monotonic() - connecting
    assert not th.is_alive()
    assert data[0] == 0xFD  # its first frames came once the client had connected
    # its clock started at the connection (not when the server started, 0.5 s earlier): no bound on load
    assert 0.0 < server.sim.t <= connected_for * 10.0


def test_px4_onboard_link_sends_to_its_fixed_peer_and_reads_past_refusals():
    listener = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    listener.bind(("127.0.0.1", 0))
    listener.settimeout(2.0)
    closed = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    closed.bind(("127.0.0.1", 0))
    nobody = closed.getsockname()[1]
    closed.close()  # a peer that is not listening: ICMP port unreachable for every frame sent there
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", 0))
    mine = probe.getsockname()[1]
    probe.close()
    t = MavTransport(f"udpin:127.0.0.1:{mine}", peers=(("127.0.0.1", listener.getsockname()[1]), ("127.0.0.1", nobody)))
    try:
        frame = FrameCodec(1).encode(mav.MAVLink_heartbeat_message(2, 12, 0, 0, 3, 3))
        t.send(frame)
        assert listener.recv(300) == frame  # sent from boot, nobody had to talk first
        listener.sendto(frame, ("127.0.0.1", t.port))
        got = []
        for _ in range(5):
            t.send(frame)  # each send to `nobody` queues a refusal on the socket
            got += t.poll(0.2)
            if got:
                break
        assert got and got[0][0] == frame
    finally:
        t.close()
        listener.close()


def test_unknown_autopilot_is_a_config_error():
    from zdrone.core.fleet import ConfigError

    with pytest.raises(ConfigError, match="expected one of px4, ardupilot"):
        personality("betaflight")


@settings(max_examples=100, deadline=None)
@given(st.integers(0, 600), st.lists(st.floats(allow_nan=True, allow_infinity=True, width=32), min_size=7, max_size=7))
def test_ardupilot_any_command_gets_one_ack_and_never_raises(cmd, params):
    s = ap()
    s.send(mav.MAVLink_command_long_message(1, 1, cmd, 0, *params))
    acks = s.take("COMMAND_ACK")
    assert len(acks) == 1 and acks[0].command == cmd
    s.run(0.3)
    assert s.sim.counters["handler_error"] == 0


# =================================================================== the real start-up (issue 22)
def _positions(s: SimPair) -> list[tuple[float, int, int]]:
    """(time since boot, lat, lon) of the GLOBAL_POSITION_INTs in the inbox, taken from it."""
    return [(m.time_boot_ms / 1000.0, m.lat, m.lon) for m in s.take("GLOBAL_POSITION_INT")]


def test_ardupilot_boots_like_arducopter_zeros_then_fix_then_origin_then_gps_in_its_estimate():
    """At its real timeline (40 s): lat = lon = 0 and no GPS fix until ~10 s, the EKF origin ~19 s,
    the EKF using GPS at 40 s; only then is AUTO accepted, and its refusal's reason comes after the ACK."""
    from pymavlink.dialects.v20 import ardupilotmega as apm

    s = ap(ready_after=40.0)
    s.send(mav.MAVLink_request_data_stream_message(1, 1, mav.MAV_DATA_STREAM_ALL, 4, 1))
    s.run(9.5)
    assert {(lat, lon) for _, lat, lon in _positions(s)} == {(0, 0)}
    assert {m.fix_type for m in s.take("GPS_RAW_INT")} == {mav.GPS_FIX_TYPE_NO_FIX}
    s.run(0.6)  # the fix at 10 s
    s.inbox.clear()
    s.run(0.5)
    assert all(abs(lat / 1e7 - HOME.lat) < 1e-5 for _, lat, _lon in _positions(s)) and \
        s.take("GPS_RAW_INT")[-1].fix_type == mav.GPS_FIX_TYPE_3D_FIX
    assert not s.take("EKF_STATUS_REPORT")[-1].flags & apm.EKF_POS_HORIZ_ABS
    s.run(19.4)  # 30.5 s: ready to arm (STABILIZE), AUTO still refused
    assert "EKF3 IMU0 origin set" in s.texts() and not s.take("EKF_STATUS_REPORT")[-1].flags & apm.EKF_POS_HORIZ_ABS
    assert s.take("SYS_STATUS")[-1].onboard_control_sensors_health & mav.MAV_SYS_STATUS_PREARM_CHECK
    set_param(s, "MIS_OPTIONS", 4.0, mav.MAV_PARAM_TYPE_INT16)  # continue after the landing at the delivery
    assert s.upload(msgs(reference_mission(autopilot="ardupilot"))) == mav.MAV_MISSION_ACCEPTED
    assert s.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mav.MAV_RESULT_ACCEPTED
    s.inbox.clear()
    s.send(mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_MISSION_START, 0, 0, 0, 0, 0, 0, 0, 0))
    assert texts_and_acks(s) == [f"ACK {mav.MAV_CMD_MISSION_START} {mav.MAV_RESULT_FAILED}",
                                 "Mode change to AUTO failed: requires position"]
    assert s.run_until(lambda: not s.sim.armed, 11.0) and 9.5 <= s.now - 30.5 <= 10.6  # disarms itself on the ground
    said = s.texts()
    assert "Disarming motors" in said
    s.run(max(0.0, 40.2 - s.now))
    said += s.texts()
    assert said.index("Disarming motors") < said.index("EKF3 IMU0 is using GPS")
    assert s.take("EKF_STATUS_REPORT")[-1].flags & apm.EKF_POS_HORIZ_ABS
    assert s.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mav.MAV_RESULT_ACCEPTED
    assert s.command(mav.MAV_CMD_MISSION_START, 0, 0) == mav.MAV_RESULT_ACCEPTED
    assert s.run_until(lambda: s.sim.payload_released, 300)
    assert "Gripper Released" in s.texts() and not any("payload" in t for t in s.texts())


def test_px4_sends_no_global_position_before_its_estimate_and_says_nothing_of_its_gripper():
    s = SimPair(ready_after=10.0)
    s.run(5.5)
    assert _positions(s) == [] and s.take("GPS_RAW_INT")[-1].fix_type == mav.GPS_FIX_TYPE_3D_FIX  # fix at 4 s
    s.run(1.0)
    assert _positions(s) and all(t >= 6.0 for t, _, _ in _positions(s) or [(6.0, 0, 0)])
    s.run(4.0)
    assert "Ready for takeoff!" in s.texts()
    assert s.upload(msgs(reference_mission())) == mav.MAV_MISSION_ACCEPTED
    assert s.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mav.MAV_RESULT_ACCEPTED
    assert s.command(mav.MAV_CMD_MISSION_START, 0, 0) == mav.MAV_RESULT_ACCEPTED
    assert s.run_until(lambda: s.sim.payload_released, 300)
    s.run(1.0)
    assert not [t for t in s.texts() if "payload" in t.lower() or "gripper" in t.lower()]


def test_the_boot_timeline_keeps_the_real_order_at_any_length():
    for p in (PX4, ARDUPILOT):
        r = p.readiness
        marks = [r.gps_fix_at] + ([r.origin_at] if r.origin_at is not None else []) + [r.position_at]
        assert marks == sorted(marks) and 0 < r.gps_fix_at < r.position_at <= 1.0, p.name
        assert p.default_ready_after <= 6.0 < p.real_ready_after or p.name == "px4"  # short by default
