"""Real clients nobody here wrote (MAVSDK, pymavlink) against a real ``zdrone sim`` process."""

from __future__ import annotations

import math
import struct
import time

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mav

from tests.procs import ZDRONE, free_port, spawn
from tests.waiting import wait_until
from zdrone.core.geometry import GeoPoint, distance_m, offset
from zdrone.core.reference import HOME

SQUARE = [(60, 0), (60, 60), (0, 60), (0, 0)]


@pytest.mark.slow
def test_mavsdk_flies_a_four_waypoint_mission():
    from mavsdk import ComponentType, Configuration, Mavsdk
    from mavsdk.plugins.action import Action
    from mavsdk.plugins.mission import Mission, MissionItem, MissionPlan
    from mavsdk.plugins.telemetry import Telemetry

    port = free_port()
    with spawn(ZDRONE, "sim", "--mavlink", f"udpin:127.0.0.1:{port}", "--speedup", "5", "--ready-after", "0") as sim:
        sim.wait_line("zdrone sim:", 20)
        m = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
        try:
            m.add_any_connection(f"udpout://127.0.0.1:{port}")
            system = m.first_autopilot(15.0)
            assert system is not None, "MAVSDK did not discover the simulator"
            tel, act, mis = Telemetry(system), Action(system), Mission(system)
            points = [offset(HOME, n, e) for n, e in SQUARE]
            items = [MissionItem(latitude_deg=p.lat, longitude_deg=p.lon, relative_altitude_m=15.0, speed_m_s=10.0,
                                 is_fly_through=False, acceptance_radius_m=2.0) for p in points]
            mis.set_return_to_launch_after_mission(True)
            mis.upload_mission(MissionPlan(items))
            act.arm()
            mis.start_mission()
            closest = [math.inf] * len(points)
            progress_seen: set[int] = set()

            def finished_mission() -> bool:
                nonlocal closest
                pos = tel.position()
                if math.isfinite(pos.latitude_deg):
                    here = GeoPoint(pos.latitude_deg, pos.longitude_deg)
                    closest = [min(c, distance_m(p, here)) for c, p in zip(closest, points)]
                progress_seen.add(mis.mission_progress().current)
                return mis.is_mission_finished() and not tel.armed()

            finished = wait_until(finished_mission, 90, step=0.1)
            assert finished, f"mission did not finish; progress seen {sorted(progress_seen)}"
            assert all(c <= 4.0 for c in closest), f"waypoints missed: {closest}"
            assert {1, 2, 3} <= progress_seen
            pos = tel.position()
            assert distance_m(HOME, GeoPoint(pos.latitude_deg, pos.longitude_deg)) < 3.0
            assert pos.relative_altitude_m < 0.5 and not tel.in_air()
        finally:
            m.destroy()


def _conn(url: str) -> mavutil.mavfile:
    c = mavutil.mavlink_connection(url, source_system=255, source_component=190, dialect="common")
    deadline = time.monotonic() + 15
    while time.monotonic() < deadline:
        c.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        if c.wait_heartbeat(timeout=0.5):
            return c
    raise TimeoutError("no heartbeat from the simulator")


def _ack(c: mavutil.mavfile, cmd: int, timeout: float = 5.0) -> int:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        m = c.recv_match(type="COMMAND_ACK", blocking=True, timeout=0.5)
        if m is not None and m.command == cmd:
            return m.result
    raise TimeoutError(f"no COMMAND_ACK for {cmd}")


def _cmd(c, cmd, *p):
    p = list(p) + [0.0] * (7 - len(p))
    c.mav.command_long_send(1, 1, cmd, 0, *p)
    return _ack(c, cmd)


def _upload(c, items) -> int:
    c.mav.mission_count_send(1, 1, len(items), 0)
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline:
        m = c.recv_match(type=["MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"], blocking=True, timeout=1)
        if m is None:
            continue
        if m.get_type() == "MISSION_ACK":
            return m.type
        c.mav.send(items[m.seq])
    raise TimeoutError("mission upload did not finish")


def _item(seq, n, e, alt, cmd=mav.MAV_CMD_NAV_WAYPOINT, frame=mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT):
    p = offset(HOME, n, e)
    return mav.MAVLink_mission_item_int_message(1, 1, seq, frame, cmd, 0, 1, 0, 0, 0, float("nan"),
                                                int(p.lat * 1e7), int(p.lon * 1e7), alt)


@pytest.mark.slow
@pytest.mark.parametrize("transport", ["udp", "tcp"])
def test_pymavlink_mission_params_and_errors(transport):
    if transport == "udp":
        port = free_port()
        listen, connect = f"udpin:127.0.0.1:{port}", f"udpout:127.0.0.1:{port}"
    else:
        import socket
        port = free_port(socket.SOCK_STREAM)
        listen, connect = f"tcpin:127.0.0.1:{port}", f"tcp:127.0.0.1:{port}"
    with spawn(ZDRONE, "sim", "--mavlink", listen, "--speedup", "8", "--ready-after", "0") as sim:
        sim.wait_line("zdrone sim:", 20)
        c = _conn(connect)
        try:
            # parameters: set and read back (PX4 bytewise int encoding)
            as_f = lambda v: struct.unpack("<f", struct.pack("<i", v))[0]
            as_i = lambda f: struct.unpack("<i", struct.pack("<f", f))[0]
            c.mav.param_set_send(1, 1, b"COM_DL_LOSS_T", as_f(6), mav.MAV_PARAM_TYPE_INT32)
            v = c.recv_match(type="PARAM_VALUE", blocking=True, timeout=5)
            assert v.param_id == "COM_DL_LOSS_T" and as_i(v.param_value) == 6
            c.mav.param_request_read_send(1, 1, b"COM_DL_LOSS_T", -1)
            v = c.recv_match(type="PARAM_VALUE", blocking=True, timeout=5)
            assert as_i(v.param_value) == 6
            c.mav.param_set_send(1, 1, b"MPC_XY_CRUISE", float("nan"), mav.MAV_PARAM_TYPE_REAL32)
            v = c.recv_match(type="PARAM_VALUE", blocking=True, timeout=5)
            assert v.param_value == pytest.approx(12.0)
            # error codes over the wire
            assert _cmd(c, 31999) == mav.MAV_RESULT_UNSUPPORTED
            assert _upload(c, [_item(0, 0, 0, 10, frame=mav.MAV_FRAME_LOCAL_NED)]) == mav.MAV_MISSION_UNSUPPORTED_FRAME
            c.write(b"garbage \xfd\x03\x00\x00\x07\x09\x01\x00\x00\x00 bad crc \x00\x01")
            # the mission
            items = [_item(0, 0, 0, 15, cmd=mav.MAV_CMD_NAV_TAKEOFF)] + [
                _item(i + 1, n, e, 15) for i, (n, e) in enumerate(SQUARE)] + [
                _item(5, 0, 0, 0, cmd=mav.MAV_CMD_NAV_LAND)]
            assert _upload(c, items) == mav.MAV_MISSION_ACCEPTED
            assert _cmd(c, mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mav.MAV_RESULT_ACCEPTED
            assert _cmd(c, mav.MAV_CMD_MISSION_START, 0, 0) == mav.MAV_RESULT_ACCEPTED
            reached: set[int] = set()
            closest = [math.inf] * 4
            pts = [offset(HOME, n, e) for n, e in SQUARE]
            armed_seen = disarmed_after = False
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline and not disarmed_after:
                m = c.recv_match(type=["MISSION_ITEM_REACHED", "GLOBAL_POSITION_INT", "HEARTBEAT"], blocking=True, timeout=1)
                if m is None:
                    continue
                if m.get_type() == "MISSION_ITEM_REACHED":
                    reached.add(m.seq)
                elif m.get_type() == "GLOBAL_POSITION_INT":
                    here = GeoPoint(m.lat / 1e7, m.lon / 1e7)
                    closest = [min(a, distance_m(p, here)) for a, p in zip(closest, pts)]
                elif m.get_srcSystem() == 1:
                    armed = bool(m.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)
                    armed_seen |= armed
                    disarmed_after = armed_seen and not armed
            assert disarmed_after, "vehicle did not land and disarm"
            assert reached == set(range(6))
            assert all(d < 3.0 for d in closest), closest
        finally:
            c.close()
