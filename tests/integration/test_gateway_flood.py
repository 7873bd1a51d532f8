"""A hostile flood on the GCS gateway's real UDP endpoint: the gateway keeps serving the application
that was there first, and counts what it dropped by reason.

The station is a stand-in (see ``tests/unit/test_gateway_apps.py``): this is about the socket input
path, not Zenoh. The gateway is driven the way the station's loop drives it, ``poll(now)``.
"""

from __future__ import annotations

import random
import socket
import time

from pymavlink.dialects.v20 import common as mav

from gs.apptable import FIRST_APP_COMPID, MAX_APPS
from gs.gateway import GcsGateway
from tests.procs import free_port
from tests.unit.test_gateway_apps import GS_SYSID, VEHICLE_SYSID, StubStation, command_long, heartbeat
from tests.waiting import readable
from zdrone.core.mavlink import FrameCodec, read_header

MAX_UDP = 65507  # the largest IPv4 UDP payload: a "64 KiB" datagram


def _udp(port: int) -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    s.connect(("127.0.0.1", port))
    s.settimeout(2.0)
    return s


def _pump(gw: GcsGateway, rounds: int = 5) -> None:
    """The station's loop: a few passes of the gateway's hook, each once its socket has input (or 2 ms on)."""
    socks = [t.sock for t in gw.transports if t.sock is not None]
    for _ in range(rounds):
        readable(socks, 0.002)
        gw.poll(time.monotonic())


def _recv_msgid(s: socket.socket, msgid: int, gw: GcsGateway) -> bytes | None:
    """The first datagram ``s`` receives carrying ``msgid`` (the gateway pumped meanwhile)."""
    s.settimeout(0.05)
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline:
        _pump(gw, 1)
        try:
            data = s.recv(65535)
        except socket.timeout:
            continue
        if len(data) >= 10 and data[0] == 0xFD and int.from_bytes(data[7:10], "little") == msgid:
            return data
    return None


def test_flood_of_applications_and_garbage_leaves_the_gateway_serving():
    station = StubStation()
    port = free_port()
    gw = GcsGateway(station, [f"udpin:127.0.0.1:{port}"])
    good = _udp(port)
    socks: list[socket.socket] = []
    rng = random.Random(7)
    try:
        good.send(heartbeat(250))
        _pump(gw)
        assert [read_header(f).compid for f in station.sent] == [FIRST_APP_COMPID]
        good_compid = FIRST_APP_COMPID

        # 300 applications, one per UDP source port, in batches the socket buffer holds
        for batch in range(6):
            for i in range(50):
                s = _udp(port)
                socks.append(s)
                s.send(heartbeat(2 + (batch * 50 + i) % 248, 190))  # never sysid 1, the vehicle's
            _pump(gw)
        assert gw.counters["app_table_full"] == 300 - (MAX_APPS - 1)
        assert len(gw.apps) == MAX_APPS

        # garbage: random bytes, truncated frames, 64 KiB of noise, 64 KiB of frames from ~3000 "applications"
        junk = socks[0]
        skipped_before = gw.transports[0].skipped_bytes
        for _ in range(20):
            junk.send(rng.randbytes(rng.randint(1, 300)))
        for n in (1, 5, 11, 20):
            junk.send(heartbeat(7)[:n])
        junk.send(rng.randbytes(MAX_UDP))
        _pump(gw)
        hb = heartbeat(9)
        packed = b"".join(FrameCodec(2 + i % 248, 1 + i // 248).encode(
            mav.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3)) for i in range(MAX_UDP // len(hb)))
        junk.send(packed)
        _pump(gw)
        assert gw.transports[0].skipped_bytes > skipped_before + MAX_UDP // 2  # the noise, counted by the endpoint
        assert gw.counters["app_table_full"] >= 300 - (MAX_APPS - 1) + MAX_UDP // len(hb)
        assert gw.counters["internal_error"] == 0

        # the first application is still served both ways
        station.sent.clear()
        good.send(command_long(250))
        _pump(gw)
        assert [(read_header(f).sysid, read_header(f).compid) for f in station.sent] == [(GS_SYSID, good_compid)]
        ack = FrameCodec(VEHICLE_SYSID, 1).encode(
            mav.MAVLink_command_ack_message(mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0, 0, GS_SYSID, good_compid))
        gw.on_drone_frame("D1", ack)
        frame = _recv_msgid(good, mav.MAVLINK_MSG_ID_COMMAND_ACK, gw)
        assert frame is not None, "the first application did not get its COMMAND_ACK"
        msg = FrameCodec(250, 190).decode(frame)
        assert msg is not None and (msg.target_system, msg.target_component) == (250, 190)

        stats = gw.stats()
        assert stats["apps"] == MAX_APPS and stats["counters"]["app_table_full"] == gw.counters["app_table_full"]
        assert stats["endpoints"][f"udpin:127.0.0.1:{port}"]["skipped_bytes"] > MAX_UDP // 2
    finally:
        for s in [good, *socks]:
            s.close()
        gw.close()
