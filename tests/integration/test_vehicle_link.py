"""The vehicle link against a real ``zdrone sim`` process (PX4 and ArduPilot personalities): frames,
tracked state, the streams it asks for, LAND / RTL with each autopilot's own modes."""

from __future__ import annotations

import socket
import time
from collections.abc import Iterator
from contextlib import contextmanager

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


def _rtl_then_land(link: VehicleLink) -> None:
    """The companion's two failsafe commands, in flight: RTL, then LAND until disarmed on the ground."""
    link.command_rtl()
    assert _until(link, lambda: link.state().mode == "RTL", 5)
    link.command_land()
    assert _until(link, lambda: link.state().mode == "LAND", 5)
    assert _until(link, lambda: not link.armed, 30)
    # EXTENDED_SYS_STATE comes once a second: the disarm may be seen first
    assert _until(link, lambda: link.landed_state == mav.MAV_LANDED_STATE_ON_GROUND, 3)


@contextmanager
def _px4_sim_link() -> Iterator[VehicleLink]:
    """A ``zdrone sim`` process (PX4 personality) and a vehicle link that has seen it; both closed after."""
    port = free_port()
    with spawn(ZDRONE, "sim", "--mavlink", f"udpin:127.0.0.1:{port}", "--speedup", "4", "--ready-after", "0") as sim:
        sim.wait_line("zdrone sim:", 20)
        link = VehicleLink(f"udpout:127.0.0.1:{port}")
        try:
            assert link.wait_vehicle(10)
            yield link
        finally:
            link.close()


@pytest.mark.slow
def test_vehicle_link_tracks_and_commands_the_sim():
    with _px4_sim_link() as link:
        assert link.sysid == 1 and link.autopilot == "px4"
        frames = link.recv(1.0)
        assert frames and all(read_header(f).sysid == 1 for f in frames)
        # raw frames from a GS (sysid 4) go through unchanged
        gs = FrameCodec(4, 190)
        link.send(gs.encode(mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)))
        link.send(gs.encode(mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, float("nan"),
                                                             float("nan"), float("nan"), float("nan"))))
        assert _until(link, lambda: link.position is not None and link.position.alt > 8, 20)
        assert link.state().armed and link.state().mode in ("TAKEOFF", "HOLD")
        _rtl_then_land(link)


@pytest.mark.slow
def test_vehicle_link_asks_ardupilot_for_its_streams_and_flies_it_by_its_modes():
    port = free_port(socket.SOCK_STREAM)
    with spawn(ZDRONE, "sim", "--autopilot", "ardupilot", "--mavlink", f"tcpin:127.0.0.1:{port}", "--speedup", "4",
               "--ready-after", "2") as sim:
        sim.wait_line("zdrone sim:", 20)
        link = VehicleLink(f"tcp:127.0.0.1:{port}")
        try:
            assert link.wait_vehicle(10)
            assert link.sysid == 1 and link.autopilot == "ardupilot" and link.state().mode == "STABILIZE"
            seen: set[str] = set()

            def streaming() -> bool:
                seen.update(mav.mavlink_map[read_header(f).msgid].msgname for f in link.recv(0.05)
                            if read_header(f).msgid in mav.mavlink_map)
                return {"GLOBAL_POSITION_INT", "EXTENDED_SYS_STATE", "MISSION_CURRENT", "SYS_STATUS",
                        "HOME_POSITION"} <= seen

            assert _until(link, streaming, 15), seen
            stats = link.stream_stats()
            assert stats["autopilot"] == "ardupilot"
            assert {s["via"] for s in stats["streams"].values()} == {"interval"} and not stats["counters"]
            assert link.position is not None and link.landed_state == mav.MAV_LANDED_STATE_ON_GROUND
            link.command(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4)  # GUIDED
            assert _until(link, lambda: link.state().mode == "GUIDED", 5)
            assert _until(link, lambda: _arm(link), 20)
            link.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, float("nan"), float("nan"), float("nan"), 12)
            assert _until(link, lambda: link.position is not None and link.position.alt > 8, 20)
            assert link.landed_state in (mav.MAV_LANDED_STATE_TAKEOFF, mav.MAV_LANDED_STATE_IN_AIR)
            _rtl_then_land(link)
            assert not {k: v for k, v in link.stream_stats()["counters"].items() if "refused" in k}
        finally:
            link.close()


def _arm(link: VehicleLink) -> bool:
    """Ask to arm (ArduPilot refuses until its checks pass) and say whether it is armed."""
    if not link.armed:
        link.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    return link.armed


@pytest.mark.slow
def test_the_reader_thread_hands_every_frame_to_the_inbox_and_wakes_its_loop():
    """The drone node's loop sleeps on its inbox: the vehicle link's reader thread queues each message
    (it tracks nothing itself); the loop takes it up with ``accept``."""
    from zdrone.net.inbox import Inbox

    with _px4_sim_link() as link:
        inbox = Inbox()
        assert link.start_reader(lambda msg: inbox.put("vehicle", "vehicle", msg)) and link.reading
        with pytest.raises(RuntimeError):
            link.recv(0.0)  # one reader at a time
        frames: list[bytes] = []

        def take(kind: str, peer: str, msg: object, now: float) -> None:
            assert (kind, peer) == ("vehicle", "vehicle")
            frames.append(link.accept(msg, now))

        t0 = time.monotonic()
        while not any(read_header(f).msgid == mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT for f in frames):
            assert time.monotonic() - t0 < 5, "no position through the inbox"
            inbox.drain(1.0, take)
            link.heartbeat()
        assert all(read_header(f).sysid == 1 for f in frames) and link.position is not None
        waited = time.monotonic()
        assert inbox.drain(30.0, take) >= 1  # the next message wakes the drain: it does not wait out its 30 s
        assert time.monotonic() - waited < 30.0
        link.command_rtl()  # sends while the reader reads
        assert link.next_due() <= time.monotonic() + 1.0
    assert not link.reading
