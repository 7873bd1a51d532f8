"""The in-process vehicle of the bench hosts: when it is due to be stepped (testbed)."""

from __future__ import annotations

import time

from pymavlink.dialects.v20 import common as mav

from zdrone.core.mavlink import FrameCodec
from zdrone.core.reference import HOME
from zdrone.vehicle.inproc import STEP_MAX_S, InProcessVehicle


def test_it_is_due_when_its_next_stream_message_is_and_at_once_after_a_frame_was_sent_to_it() -> None:
    v = InProcessVehicle(HOME, sysid=1, speedup=4.0, seed=0)
    assert v.recv()  # the streams due at boot
    wait = v.next_due() - time.monotonic()
    assert 0.0 < wait <= 0.25 / 4.0 + 0.01  # the fastest stream (4 Hz) at speed-up 4
    gcs = FrameCodec(255, 190)
    v.send(gcs.encode(mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_REQUEST_MESSAGE, 0,
                                                      mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION, 0, 0, 0, 0, 0, 0)))
    assert v.next_due() <= time.monotonic()  # its answer is ready
    assert any(FrameCodec(255, 190).decode(f).get_type() == "COMMAND_ACK" for f in v.recv())
    assert v.next_due() - time.monotonic() <= STEP_MAX_S


def test_vehicles_made_at_once_do_not_stream_in_step() -> None:
    vs = [InProcessVehicle(HOME, sysid=i + 1, speedup=1.0, seed=i) for i in range(8)]
    firsts = {round(min(v.sim.telemetry.next_due.values()), 3) for v in vs}
    assert len(firsts) == 8 and max(firsts) - min(firsts) > 0.5  # spread over the first second


def test_a_bench_flies_it_bare_as_a_gcs_would() -> None:
    from gs.planner import shuttle_mission

    v = InProcessVehicle(HOME, sysid=1, speedup=4.0, seed=0)
    gcs = FrameCodec(200, 190)
    assert v.upload(shuttle_mission(1, far_east_m=440.0), gcs)
    v.sim.ready_after = 0.0
    for _ in range(200):  # until the simulator says it may arm
        v.recv()
        v.arm_and_start(gcs)
        if v.armed:
            break
        time.sleep(0.01)
    assert v.armed
