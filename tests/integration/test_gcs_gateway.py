"""The GCS gateway with real clients nobody here wrote: MAVSDK, MAVProxy, pymavlink, through the secure
link (real router, simulator, drone node and ground stations as processes)."""

from __future__ import annotations

import contextlib
import math
import os
import signal
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mav

from gs.planner import reference_mission
from tests.mavproxy import MavProxy
from tests.procs import ZDRONE, free_port, spawn
from tests.waiting import wait_until
from zdrone.core.geometry import GeoPoint, distance_m
from zdrone.core.mavcontrol import MAV_RESULT_NOT_IN_CONTROL, ControlStatus, decode_control_status
from zdrone.core.reference import DELIVERY, HOME
from zdrone.fleet.files import init_fleet
from zdrone.net.eventlog import read_events
from zdrone.vehicle.px4modes import FlightMode


@contextlib.contextmanager
def stack(tmp: Path, speedup: str, with_b: bool, autopilot: str = "px4"):
    init_fleet(tmp / "fleet")
    rport, sport, pa, pb = free_port(socket.SOCK_STREAM), free_port(), free_port(), free_port()
    ta = free_port(socket.SOCK_STREAM)
    router = f"tcp/127.0.0.1:{rport}"
    common = ["--fleet", str(tmp / "fleet"), "--router", router]
    with contextlib.ExitStack() as es:
        r = es.enter_context(spawn(ZDRONE, "router", "-c", str(tmp / "fleet/router/router.json5"), "--listen", router))
        r.wait_line("listening", 20)
        if autopilot == "ardupilot":  # like ArduPilot SITL: a TCP server that boots on the first client
            tport = free_port(socket.SOCK_STREAM)
            sim = es.enter_context(spawn(ZDRONE, "sim", "--autopilot", "ardupilot", "--mavlink", f"tcpin:127.0.0.1:{tport}",
                                         "--speedup", speedup))
            vehicle = f"tcp:127.0.0.1:{tport}"
        else:
            sim = es.enter_context(spawn(ZDRONE, "sim", "--mavlink", f"udpin:127.0.0.1:{sport}", "--speedup", speedup))
            vehicle = f"udpout:127.0.0.1:{sport}"
        sim.wait_line("zdrone sim:", 20)
        drone = es.enter_context(spawn(ZDRONE, "drone", *common, "--vehicle", vehicle, "--sil-coverage",
                                       "--handover-timeout", "2", "--events", str(tmp / "drone.jsonl")))
        drone.wait_line("ready", 40)
        if with_b:
            b = es.enter_context(spawn(ZDRONE, "gs", "--id", "B", *common, "--gcs", f"udpin:127.0.0.1:{pb}",
                                       "--events", str(tmp / "B.jsonl")))
            b.wait_line("GCS gateway", 20)
        a = es.enter_context(spawn(ZDRONE, "gs", "--id", "A", *common, "--pair", "--gcs", f"udpin:127.0.0.1:{pa}",
                                   "--gcs", f"tcpin:127.0.0.1:{ta}", "--events", str(tmp / "A.jsonl")))
        a.wait_line("paired", 30)
        yield {"a": pa, "b": pb, "a_tcp": ta}


class RawApp:
    """A minimal MAVLink application over TCP that also sees messages pymavlink's dialect lacks (512)."""

    def __init__(self, port: int, sysid: int) -> None:
        from zdrone.core.mavlink import FrameCodec

        self.sock = socket.create_connection(("127.0.0.1", port), timeout=5)
        self.codec = FrameCodec(sysid, 190)
        self.buf = b""
        self.send(mav.MAVLink_heartbeat_message(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))

    def send(self, msg) -> None:
        self.sock.sendall(self.codec.encode(msg))

    def _frames(self, timeout: float) -> list[bytes]:
        self.sock.settimeout(timeout)
        try:
            self.buf += self.sock.recv(65536)
        except socket.timeout:
            return []
        out = []
        while len(self.buf) >= 12:
            i = self.buf.find(b"\xfd")
            if i < 0:
                self.buf = b""
                break
            self.buf = self.buf[i:]
            total = 12 + self.buf[1]
            if len(self.buf) < total:
                break
            out.append(self.buf[:total])
            self.buf = self.buf[total:]
        return out

    def wait_control_status(self, timeout: float) -> ControlStatus | None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for f in self._frames(0.5):
                if (status := decode_control_status(f)) is not None:  # msgid 512, today's three fields
                    return status
        return None

    def wait(self, pred, timeout: float):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for f in self._frames(0.5):
                m = self.codec.decode(f)
                if m is not None and pred(m):
                    return m
        raise AssertionError("expected message not received")

    def close(self) -> None:
        self.sock.close()


def _client(port: int, sysid: int) -> mavutil.mavfile:
    c = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=sysid, source_component=190, dialect="common")
    c.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
    return c


def _ack(c, command: int, timeout: float = 3.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        m = c.recv_match(type="COMMAND_ACK", blocking=True, timeout=0.2)
        if m is not None and m.command == command:
            return m
    return None


@pytest.mark.slow
def test_mavproxy_reads_parameters_and_switches_mode(tmp_path):
    with stack(tmp_path, "3", with_b=False) as ports:
        cwd = tmp_path / "mavproxy"
        cwd.mkdir()
        mp = MavProxy(ports["a"], cwd, "mode,param,cmdlong")
        raw = RawApp(ports["a_tcp"], sysid=251)  # a second application on the same GS, over TCP
        try:
            assert mp.wait_for("Detected vehicle 1:1", 30), mp.text()
            # operator control: A holds authority; the gateway says so (CONTROL_STATUS) and grants the request
            status = raw.wait_control_status(10)
            assert status is not None and status.gcs_main == 251, status  # A is in control: "you are", to each app
            raw.send(mav.MAVLink_command_long_message(1, 1, 32100, 0, 0, 0, 0, 0, 0, 0, 0))
            ack = raw.wait(lambda m: m.get_type() == "COMMAND_ACK" and m.command == 32100, 10)
            assert ack.result == mav.MAV_RESULT_ACCEPTED and (ack.target_system, ack.target_component) == (251, 190)
            raw.send(mav.MAVLink_param_request_read_message(1, 1, b"NAV_DLL_ACT", -1))
            pv = raw.wait(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == "NAV_DLL_ACT", 10)
            assert struct.unpack("<i", struct.pack("<f", pv.param_value))[0] == 0
            assert mp.wait_for(" parameters", 30) and "Received" in mp.text(), mp.text()  # fetched on connect
            mp.type("param show COM_DL_LOSS_T")
            assert mp.wait_for("COM_DL_LOSS_T", 10), mp.text()
            mp.type("long DO_SET_MODE 1 3 0")  # custom mode, PX4 main mode 3 = POSCTL (MAVProxy's cmdlong module)
            assert mp.wait_for("Mode POSCTL", 15), mp.text()
        finally:
            raw.close()
            mp.stop()
        text = mp.text()
        assert "Mode POSCTL" in text, text  # the vehicle's HEARTBEAT after the mode command went through
        params = dict(line.split()[:2] for line in (cwd / "mav.parm").read_text().splitlines() if line.strip())
        assert float(params["COM_DL_LOSS_T"]) == 10 and float(params["NAV_DLL_ACT"]) == 0
        status = [e for e in read_events(tmp_path / "drone.jsonl") if e["type"] == "status"]
        assert status[-1]["mode"] == "POSCTL"
        apps = {e["sysid"]: e["gs_compid"] for e in read_events(tmp_path / "A.jsonl") if e["type"] == "gcs_app"}
        assert set(apps) == {250, 251} and len(set(apps.values())) == 2  # two applications, two component ids


@pytest.mark.slow
def test_mavsdk_flies_through_a_while_b_is_refused_until_it_holds_authority(tmp_path):
    from mavsdk import ComponentType, Configuration, Mavsdk
    from mavsdk.plugins.action import Action
    from mavsdk.plugins.mission_raw import MissionItem, MissionRaw
    from mavsdk.plugins.telemetry import Telemetry

    with stack(tmp_path, "3", with_b=True) as ports:
        m = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
        b = _client(ports["b"], 254)
        try:
            m.add_any_connection(f"udpout://127.0.0.1:{ports['a']}")
            system = m.first_autopilot(20.0)
            assert system is not None, "MAVSDK did not find the vehicle behind GS A's gateway"
            tel, act, mis = Telemetry(system), Action(system), MissionRaw(system)
            items = [MissionItem(i, it.frame, it.command, int(i == 0), 1, *it.params,
                                 0 if math.isnan(it.lat) else int(round(it.lat * 1e7)),
                                 0 if math.isnan(it.lon) else int(round(it.lon * 1e7)), it.alt, 0)
                     for i, it in enumerate(reference_mission())]
            mis.upload_mission(items)
            act.arm()
            mis.start_mission()
            hold = FlightMode.HOLD.value
            mission = FlightMode.MISSION.value
            refused = accepted = resumed = False
            closest_delivery = math.inf

            def flown() -> bool:
                """One look at both applications; True once the flight ended at home after the delivery."""
                nonlocal closest_delivery, refused, accepted, resumed
                # the delivery point is beyond A's coverage: B's application sees it through B's gateway
                while (gp := b.recv_match(type="GLOBAL_POSITION_INT", blocking=False)) is not None:
                    if gp.relative_alt < 1000:
                        closest_delivery = min(closest_delivery, distance_m(DELIVERY, GeoPoint(gp.lat / 1e7, gp.lon / 1e7)))
                if not accepted:
                    b.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                    b.mav.command_long_send(1, 1, mav.MAV_CMD_DO_SET_MODE, 0, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                                            hold[0], hold[1], 0, 0, 0, 0)
                    ack = _ack(b, mav.MAV_CMD_DO_SET_MODE, 1.0)
                    if ack is not None and ack.result == MAV_RESULT_NOT_IN_CONTROL:
                        refused = True  # B's application while B is not in control
                    elif ack is not None and ack.result == mav.MAV_RESULT_ACCEPTED:
                        accepted = True  # after the hand-over to B: it holds until the vehicle's next heartbeat
                        b.recv_match(type="HEARTBEAT", blocking=True, timeout=3.0)
                        b.mav.command_long_send(1, 1, mav.MAV_CMD_DO_SET_MODE, 0, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                                                mission[0], mission[1], 0, 0, 0, 0)
                        resumed = (_ack(b, mav.MAV_CMD_DO_SET_MODE, 3.0) or ack).result == mav.MAV_RESULT_ACCEPTED
                if accepted and not tel.armed() and closest_delivery < 5:
                    p = tel.position()
                    return math.isfinite(p.latitude_deg) and distance_m(HOME, GeoPoint(p.latitude_deg, p.longitude_deg)) < 3
                return False

            finished = wait_until(flown, 150, step=0.2)
            events = read_events(tmp_path / "drone.jsonl")
            hv = [(e["from"], e["to"]) for e in events if e["type"] == "handover_complete"]
            assert refused, "B's application was never refused while A held authority"
            assert accepted and resumed, f"B's application could not command after the hand-over (hand-overs {hv})"
            assert hv == [("A", "B"), ("B", "A")]
            assert closest_delivery < 5 and finished, f"delivery {closest_delivery:.1f} m; finished {finished}"
            assert mis.mission_progress().current >= len(items) - 1
            b_apps = [e for e in read_events(tmp_path / "B.jsonl") if e["type"] == "gcs_app"]
            assert b_apps and b_apps[0]["sysid"] == 254
        finally:
            b.close()
            m.destroy()


@pytest.mark.slow
def test_mavproxy_detects_arducopter_through_the_gateway_and_fetches_its_parameters(tmp_path):
    """Issue 10: MAVProxy behind GS A's gateway, the ArduPilot personality behind the drone."""
    with stack(tmp_path, "3", with_b=False, autopilot="ardupilot") as ports:
        cwd = tmp_path / "mavproxy"
        cwd.mkdir()
        mp = MavProxy(ports["a"], cwd, "mode,param")
        try:
            assert mp.wait_for("Detected vehicle 1:1", 30), mp.text()
            assert mp.wait_for("ArduCopter V4.7.0-dev", 30), mp.text()  # its banner, relayed by the gateway
            assert mp.wait_for("Received", 60), mp.text()  # "Received N parameters"
        finally:
            mp.stop()
        params = dict(line.split()[:2] for line in (cwd / "mav.parm").read_text().splitlines() if line.strip())
        assert float(params["FS_GCS_ENABLE"]) == 0 and float(params["MAV_GCS_SYSID"]) == 255 and "MIS_OPTIONS" in params
        status = [e for e in read_events(tmp_path / "drone.jsonl") if e["type"] == "status"]
        assert status[-1]["autopilot"] == "ardupilot" and status[-1]["position"] is not None  # streams were asked for


@pytest.mark.slow
def test_mavsdk_sees_and_arms_the_ardupilot_personality_through_the_gateway(tmp_path):
    """Issue 10: MAVSDK behind GS A's gateway; ArduPilot streams nothing until asked, so a position
    here means the drone's vehicle link asked for it; arming waits for its pre-arm checks."""
    from mavsdk import ComponentType, Configuration, Mavsdk
    from mavsdk.plugins.action import Action, ActionError
    from mavsdk.plugins.telemetry import Telemetry

    with stack(tmp_path, "3", with_b=False, autopilot="ardupilot") as ports:
        m = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
        m.add_any_connection(f"udpout://127.0.0.1:{ports['a']}")
        system = m.first_autopilot(20.0)
        assert system is not None, "MAVSDK did not find the vehicle behind GS A's gateway"
        tel, act = Telemetry(system), Action(system)
        wait_until(lambda: math.isfinite(tel.position().latitude_deg), 20, step=0.2)
        p = tel.position()
        assert math.isfinite(p.latitude_deg) and distance_m(HOME, GeoPoint(p.latitude_deg, p.longitude_deg)) < 5
        def arms() -> bool:
            try:
                act.arm()
                return True
            except ActionError:  # "Arm: Accels inconsistent" and friends until the vehicle is ready
                return False
        assert wait_until(arms, 30, step=1.0)
        act.disarm()
