"""The vehicle link against a real ``zdrone sim`` process: frames, tracked state, LAND / RTL."""

from __future__ import annotations

import time

import pytest
from pymavlink.dialects.v20 import common as mav

from tests.procs import ZDRONE, free_port, spawn
from zdrone.core.mavlink import FrameCodec, read_header
from zdrone.vehicle.link import VehicleLink


def _until(link: VehicleLink, pred, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        link.heartbeat()
        link.recv(0.05)
        if pred():
            return True
    return False


@pytest.mark.slow
def test_vehicle_link_tracks_and_commands_the_sim():
    port = free_port()
    with spawn(ZDRONE, "sim", "--mavlink", f"udpin:127.0.0.1:{port}", "--speedup", "4") as sim:
        sim.wait_line("zdrone sim:", 20)
        link = VehicleLink(f"udpout:127.0.0.1:{port}")
        try:
            assert link.wait_vehicle(10)
            assert link.sysid == 1 and link.autopilot == mav.MAV_AUTOPILOT_PX4
            frames = link.recv(1.0)
            assert frames and all(read_header(f).sysid == 1 for f in frames)
            # raw frames from a GS (sysid 4) go through unchanged
            gs = FrameCodec(4, 190)
            link.send(gs.encode(mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)))
            link.send(gs.encode(mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, float("nan"),
                                                                 float("nan"), float("nan"), float("nan"))))
            assert _until(link, lambda: link.position is not None and link.position.alt > 8, 20)
            assert link.state().armed and link.state().mode in ("TAKEOFF", "HOLD")
            link.command_rtl()
            assert _until(link, lambda: link.state().mode == "RTL", 5)
            link.command_land()
            assert _until(link, lambda: link.state().mode == "LAND", 5)
            assert _until(link, lambda: not link.armed, 30)
            assert link.landed_state == mav.MAV_LANDED_STATE_ON_GROUND
        finally:
            link.close()
