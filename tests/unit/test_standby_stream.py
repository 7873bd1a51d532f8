"""A standby GS (not the owner, no hand-over pending to it) gets each of the vehicle's stream
messages at most once a second; the owner gets every frame; non-stream frames go to everyone."""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mav

from zdrone.core.standby import STANDBY_INTERVAL_S, STREAMED, StandbyStream


def test_a_stream_message_goes_once_an_interval_and_others_always():
    s = StandbyStream()
    pos = mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT
    assert pos in STREAMED and mav.MAVLINK_MSG_ID_HEARTBEAT not in STREAMED
    assert s.allow("B", pos, 10.0) and not s.allow("B", pos, 10.5) and s.allow("B", pos, 10.0 + STANDBY_INTERVAL_S)
    assert s.allow("C", pos, 10.5)  # per GS
    assert all(s.allow("B", mav.MAVLINK_MSG_ID_COMMAND_ACK, 10.6) for _ in range(5))  # not a stream message
    assert s.held == 1
    s.forget("B")
    assert s.allow("B", pos, 11.1)


def test_the_owner_gets_every_frame_and_a_standby_gs_one_position_a_second(tmp_path):
    """The drone's core in memory with A (owner) and B linked, in the overlap: ten GLOBAL_POSITION_INT frames in a
    second go to A, one to B; a COMMAND_ACK goes to both; the held frames are counted in the status."""
    from zdrone.bench.fleetnet import FleetNet, make_fleet
    from zdrone.core.mavlink import FrameCodec
    from zdrone.core.outputs import Put

    net = FleetNet(make_fleet(tmp_path))
    net.add_gs("A", pair=True)
    net.add_gs("B")
    net.run(4.0)
    net.position = net.between(net.centre("A"), net.centre("B"), 0.45)  # in the overlap, nearer A: both hear it
    net.run(1.0)
    drone = net.drone
    assert drone.machine.owner == "A" and drone.machine.telemetry_targets() == ["A", "B"]
    codec = FrameCodec(1)
    pos = codec.encode(mav.MAVLink_global_position_int_message(0, 0, 0, 0, 0, 0, 0, 0, 0))
    ack = codec.encode(mav.MAVLink_command_ack_message(400, 0))
    t0 = 100.0
    sent = [o.peer for i in range(10) for o in drone.on_telemetry(pos, t0 + i * 0.1) if isinstance(o, Put)]
    assert sent.count("A") == 10 and sent.count("B") == 1
    sent = [o.peer for o in drone.on_telemetry(ack, t0 + 0.95) if isinstance(o, Put)]
    assert sorted(sent) == ["A", "B"]
    assert drone.report(t0 + 1.0)["counters"]["standby_held"] >= 9


def _in_the_overlap(tmp_path):
    """A drone linked with A (its owner) and B, in the overlap nearer A: B is a standby GS."""
    from zdrone.bench.fleetnet import FleetNet, make_fleet

    net = FleetNet(make_fleet(tmp_path))
    net.add_gs("A", pair=True)
    net.add_gs("B")
    net.run(4.0)
    net.position = net.between(net.centre("A"), net.centre("B"), 0.45)
    net.run(1.0)
    return net.drone


def test_a_gs_that_becomes_the_heir_first_gets_the_newest_of_each_stream_message(tmp_path):
    """Never decide from a stale position: the moment B is the GS a hand-over is pending to, the next
    vehicle frame sends it the newest position (held back from it as a standby GS) before anything else."""
    from zdrone.core.mavlink import FrameCodec
    from zdrone.core.outputs import Put

    drone, codec = _in_the_overlap(tmp_path), FrameCodec(1)
    pos = [codec.encode(mav.MAVLink_global_position_int_message(i, i, 0, 0, 0, 0, 0, 0, 0)) for i in range(3)]
    for i, frame in enumerate(pos):
        drone.on_telemetry(frame, 200.0 + 0.1 * i)  # B got the first only
    drone.machine.pending_to = "B"  # what a release to B does to the machine
    ack = codec.encode(mav.MAVLink_command_ack_message(400, 0))
    to_b = [o for o in drone.on_telemetry(ack, 200.35) if isinstance(o, Put) and o.peer == "B"]
    assert len(to_b) == 2  # the newest position, then the acknowledgement (sealed: 24 bytes more each)
    assert [len(o.payload) - 24 for o in to_b] == [len(pos[-1]), len(ack)]
    # then B is an heir like the owner: every frame
    assert sum(1 for o in drone.on_telemetry(pos[0], 200.4) if isinstance(o, Put) and o.peer == "B") == 1


def test_a_catch_up_is_counted_by_the_frames_it_sends(tmp_path):
    """What a new heir is sent at once is counted (``catch_up_frames``, in the drone's status): one
    frame per stream message seen, once per GS that becomes the owner or heir."""
    from zdrone.core.mavlink import FrameCodec

    drone, codec = _in_the_overlap(tmp_path), FrameCodec(1)
    before = drone.counters["catch_up_frames"]
    drone.on_telemetry(codec.encode(mav.MAVLink_global_position_int_message(1, 1, 0, 0, 0, 0, 0, 0, 0)), 200.0)
    drone.on_telemetry(codec.encode(mav.MAVLink_attitude_message(1, 0, 0, 0, 0, 0, 0)), 200.1)
    drone.machine.pending_to = "B"
    drone.on_telemetry(codec.encode(mav.MAVLink_command_ack_message(400, 0)), 200.2)
    drone.on_telemetry(codec.encode(mav.MAVLink_command_ack_message(400, 0)), 200.3)  # B already caught up
    assert drone.counters["catch_up_frames"] - before == len(drone._latest) >= 2
