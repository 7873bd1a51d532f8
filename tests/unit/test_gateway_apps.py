"""The GCS gateway's application table and per-frame error handling, without sockets or Zenoh.

The gateway's receive/route code runs against a stand-in station and an in-memory transport: no
input may raise out of it, every dropped frame is counted under a reason, and application
component ids stay in their range however many applications come and go.
"""

from __future__ import annotations

from zdrone.core import records as rec

import logging
import struct
from collections import Counter
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as apm, common as mav
from zenoh import ZError

import gs.gateway as gateway_mod
from gs.apptable import (APP_EXPIRY_S, FIRST_APP_COMPID, MAX_APPS, MAX_APPS_LIMIT, MAX_UNSIGNED_PER_PEER,
                         STATION_COMPID, AppKey, AppTable)
from gs.gateway import GcsGateway
from gs.core import DroneSeen
from gs.opcontrol import OperatorControl
from zdrone.core import wire
from zdrone.core.mavlink import FrameCodec, FrameError, crc_seed, encode_raw, read_header

GS_SYSID = 4
VEHICLE_SYSID = 1
APP_IDS = range(FIRST_APP_COMPID, FIRST_APP_COMPID + MAX_APPS)


# ------------------------------------------------------------------ stand-ins
@dataclass
class StubView:
    """The parts of a station's ``DroneView`` the gateway reads."""

    name: str = "D1"
    sysid: int = VEHICLE_SYSID
    owner: str | None = "A"
    epoch: int = 1
    link: object | None = field(default_factory=object)
    ha_state: object | None = None
    takeover: bool = False
    stale: bool = False
    operator: OperatorControl = field(default_factory=lambda: OperatorControl("A"))


class StubEvents:
    def __init__(self) -> None:
        self.written: list[tuple[str, dict[str, Any]]] = []

    def write_record(self, record: rec.Record) -> None:
        self.written.append((rec.record_type(record), rec.fields_of(record)))

    def of(self, kind: str) -> list[dict[str, Any]]:
        return [f for k, f in self.written if k == kind]


class StubStation:
    """The parts of ``GroundStation`` the gateway uses; frames to the drone are recorded."""

    def __init__(self) -> None:
        self.name = "A"
        self.sysid = GS_SYSID
        self.views = {"D1": StubView()}
        self.fleet = SimpleNamespace(nodes={"A": SimpleNamespace(sysid=GS_SYSID)})
        self.frame_listeners: list[Any] = []
        self.loop_hooks: list[Any] = []
        self.events = StubEvents()
        self.authority = True
        self.sent: list[bytes] = []
        self.controls: list[Any] = []

    @property
    def drones(self) -> tuple[str, ...]:
        return tuple(self.views)

    def drone_status(self, drone: str, now: float) -> DroneSeen:
        v = self.views[drone]
        op = v.operator
        return DroneSeen(v.name, v.sysid, v.link is not None, v.owner, v.epoch, v.ha_state, self.authority,
                           op.is_owner(v), op.live_request(v, now), op.shown_takeover(v, now))

    def holds_authority(self, drone: str) -> bool:
        return self.authority

    def send_frame(self, drone: str, frame: bytes) -> None:
        self.sent.append(frame)

    def send_control(self, drone: str, msg: Any) -> None:
        self.controls.append(msg)

    def operator_command(self, drone: str, req: Any, now: float) -> int:
        if self.authority:
            return mav.MAV_RESULT_ACCEPTED
        self.send_control(drone, wire.HandoverRequest(self.name, self.views[drone].epoch, timeout=req.timeout))
        return mav.MAV_RESULT_FAILED


class MemTransport:
    """An in-memory endpoint with the interface of ``MavTransport`` (UDP-like unless ``tcp``)."""

    def __init__(self, tcp: bool = False) -> None:
        self.endpoint = "mem:test:0"
        self.port = 0
        self.sock = None if tcp else object()
        self.tcp_clients: dict[Any, bytes] = {}
        self.inbox: list[tuple[bytes, Any]] = []
        self.out: list[tuple[bytes, Any]] = []
        self.rx_frames = self.tx_frames = self.skipped_bytes = 0

    def has_peer(self) -> bool:
        return True

    def poll(self, timeout: float) -> list[tuple[bytes, Any]]:
        got, self.inbox = self.inbox, []
        return got

    def send(self, frame: bytes, peer: Any = None) -> None:
        self.out.append((frame, peer))

    def close(self) -> None:
        pass


def make_gateway(**kw: Any) -> tuple[GcsGateway, StubStation, MemTransport]:
    station = StubStation()
    gw = GcsGateway(station, [], **kw)
    t = MemTransport()
    gw.transports = [t]
    return gw, station, t


def heartbeat(sysid: int, compid: int = 190) -> bytes:
    return FrameCodec(sysid, compid).encode(
        mav.MAVLink_heartbeat_message(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))


def command_long(sysid: int, command: int = mav.MAV_CMD_COMPONENT_ARM_DISARM, compid: int = 190) -> bytes:
    return FrameCodec(sysid, compid).encode(
        mav.MAVLink_command_long_message(VEHICLE_SYSID, 1, command, 0, 1, 0, 0, 0, 0, 0, 0))


def key(i: int) -> AppKey:
    return AppKey(0, ("127.0.0.1", 20000 + i), 1 + i % 250, 190)


# ------------------------------------------------------------------ AppTable
def test_a_thousand_applications_at_once_get_the_first_ids_then_are_dropped_and_counted():
    table = AppTable()
    got = [table.lookup_or_add(key(i), 0.0) for i in range(1000)]
    admitted = [a for a in got if a is not None]
    assert [a.gs_compid for a in admitted] == list(APP_IDS)
    assert table.counters["app_table_full"] == 1000 - MAX_APPS and len(table) == MAX_APPS
    assert table.lookup_or_add(key(3), 0.5) is admitted[3]  # a known application is still served


def test_a_thousand_applications_coming_and_going_keep_ids_in_range():
    table = AppTable()
    seen: set[int] = set()
    admitted = 0
    for i in range(1000):  # one new application a second, each silent afterwards
        app = table.lookup_or_add(key(i), float(i))
        if app is not None:
            admitted += 1
            seen.add(app.gs_compid)
        assert len(table) <= MAX_APPS
    assert seen == set(APP_IDS)  # every id served many times, none outside the range
    assert admitted + table.counters["app_table_full"] == 1000
    assert table.counters["app_expired"] == admitted - len(table)


def test_expiry_frees_the_silent_applications_and_their_ids_are_reused():
    table = AppTable(expiry=30.0)
    apps = [table.lookup_or_add(key(i), 0.0) for i in range(MAX_APPS)]
    assert table.lookup_or_add(key(100), 10.0) is None
    assert table.get(key(0), 20.0) is apps[0]  # still talking: stays
    assert table.expire(29.9) == []
    gone = table.expire(30.0)
    assert {a.gs_compid for a in gone} == set(APP_IDS) - {apps[0].gs_compid}
    assert table.by_compid(apps[1].gs_compid) is None and table.get(key(1), 30.0) is None
    new = table.lookup_or_add(key(100), 30.0)
    assert new is not None and new.gs_compid in {a.gs_compid for a in gone}
    assert table.by_compid(new.gs_compid) is new and table.by_compid(apps[0].gs_compid) is apps[0]
    again = table.lookup_or_add(key(1), 31.0)  # a forgotten application comes back as a new one
    assert again is not None and again is not apps[1]
    assert table.counters["app_expired"] == MAX_APPS - 1


def test_a_full_table_makes_room_when_a_new_application_finds_an_expired_one():
    table = AppTable(max_apps=2, expiry=5.0)
    a, b = table.lookup_or_add(key(0), 0.0), table.lookup_or_add(key(1), 3.0)
    assert table.lookup_or_add(key(2), 4.9) is None
    c = table.lookup_or_add(key(2), 5.0)  # a expired: its id goes to c, b stays
    assert c is not None and a is not None and b is not None and c.gs_compid == a.gs_compid
    assert table.get(key(1), 5.0) is b and table.counters == Counter(app_table_full=1, app_expired=1)


def test_a_freed_id_is_reused_after_the_never_used_ones():
    table = AppTable()
    first = [table.lookup_or_add(key(i), 0.0) for i in range(3)]
    table.remove(key(0))
    assert table.lookup_or_add(key(10), 1.0).gs_compid == FIRST_APP_COMPID + 3  # type: ignore[union-attr]
    for i in range(11, 11 + MAX_APPS - 4):
        table.lookup_or_add(key(i), 1.0)
    assert table.lookup_or_add(key(99), 1.0).gs_compid == first[0].gs_compid  # type: ignore[union-attr]


def test_the_table_full_warning_is_rate_limited(caplog):
    table = AppTable(max_apps=1)
    table.lookup_or_add(key(0), 0.0)
    with caplog.at_level(logging.WARNING, logger="gs.gateway"):
        for i in range(1, 500):
            table.lookup_or_add(key(i), 1.0 + i / 1000)
        assert len(caplog.records) == 1
        table.lookup_or_add(key(999), 7.0)
    assert len(caplog.records) == 2 and "dropped" in caplog.records[1].getMessage()
    assert table.counters["app_table_full"] == 500


def test_a_signed_application_evicts_the_unsigned_one_seen_least_recently_from_a_full_table():
    """Found from outside: an unsigned local process holding all 16 places kept the operator's signed
    application out (refused 10 of 10 times)."""
    table = AppTable()
    unsigned = [table.lookup_or_add(key(i), float(i)) for i in range(MAX_APPS)]
    assert table.lookup_or_add(key(100), 20.0) is None  # another unsigned one: no room
    signed = table.lookup_or_add(key(101), 20.0, signed=True)
    assert signed is not None and signed.gs_compid == unsigned[0].gs_compid  # key(0): seen least recently
    signed.signer = "opsA"
    assert table.get(key(0), 20.0) is None and table.take_gone() == [(unsigned[0], "evicted")]
    assert table.take_gone() == [] and table.counters["app_evicted"] == 1
    for i in range(MAX_APPS - 1):  # each signed newcomer takes the place of an unsigned one
        app = table.lookup_or_add(key(200 + i), 21.0, signed=True)
        assert app is not None
        app.signer = f"k{i}"
    assert table.lookup_or_add(key(300), 22.0, signed=True) is None  # signed ones only: none is evicted for another
    assert table.counters["app_evicted"] == MAX_APPS and table.counters["app_table_full"] == 2


def test_one_peer_address_holds_at_most_four_unsigned_applications():
    table = AppTable()
    peer = ("127.0.0.1", 14550)
    got = [table.lookup_or_add(AppKey(0, peer, 1 + i, 190), 0.0) for i in range(10)]
    assert sum(a is not None for a in got) == MAX_UNSIGNED_PER_PEER == 4
    assert table.counters["app_peer_full"] == 6 and len(table) == 4
    assert table.lookup_or_add(AppKey(0, peer, 2, 190), 1.0) is got[1]  # a known one is still served
    assert table.lookup_or_add(AppKey(0, peer, 50, 190), 1.0, signed=True) is not None  # a signed one is not capped
    assert table.lookup_or_add(AppKey(0, ("127.0.0.1", 14551), 50, 190), 1.0) is not None  # another peer has its own


def test_id_ranges_are_checked():
    widest = AppTable(max_apps=156)
    ids = [widest.add(key(i), 0.0).gs_compid for i in range(156)]  # type: ignore[union-attr]
    assert ids == list(range(FIRST_APP_COMPID, 256)) and widest.add(key(156), 0.0) is None
    for bad in (dict(max_apps=0), dict(max_apps=157), dict(first_compid=0), dict(expiry=0.0)):
        with pytest.raises(ValueError):
            AppTable(**bad)  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        make_gateway(max_apps=MAX_APPS_LIMIT + 1)
    gw, station, _ = make_gateway(max_apps=MAX_APPS_LIMIT)
    for i in range(1000):
        gw.on_app_frame(0, ("127.0.0.1", 30000 + i), heartbeat(1 + i % 250, 1 + i // 250), 0.0)
    ids = {read_header(f).compid for f in station.sent}
    assert len(ids) == MAX_APPS_LIMIT and max(ids) < STATION_COMPID and min(ids) == FIRST_APP_COMPID


# ------------------------------------------------------------------ the gateway's receive/route path
def test_a_thousand_applications_never_raise_and_leave_under_valid_ids():
    gw, station, t = make_gateway()
    for i in range(1000):  # the 157th used to get component id 256 and end the station
        gw.on_app_frame(0, ("127.0.0.1", 40000 + i), heartbeat(1 + i % 250), 0.0)
    hdrs = [read_header(f) for f in station.sent]
    assert [(h.sysid, h.compid) for h in hdrs] == [(GS_SYSID, c) for c in APP_IDS]
    assert gw.counters["vehicle_sysid"] == 4  # sysid 1 is the vehicle's: never an application
    assert gw.counters["app_table_full"] == 1000 - 4 - MAX_APPS and gw.counters["internal_error"] == 0
    assert len(station.events.of("gcs_app")) == MAX_APPS


def test_silent_applications_are_forgotten_by_the_loop_and_their_ids_reused():
    gw, station, t = make_gateway(max_apps=2, app_expiry=30.0)
    a, b, c = ("127.0.0.1", 1), ("127.0.0.1", 2), ("127.0.0.1", 3)
    gw.on_app_frame(0, a, heartbeat(250), 0.0)
    gw.on_app_frame(0, b, heartbeat(251), 0.0)
    gw.on_app_frame(0, c, heartbeat(252), 1.0)
    assert gw.counters["app_table_full"] == 1 and len(station.sent) == 2
    t.inbox.append((heartbeat(251), b))
    gw.poll(29.0)  # b keeps talking
    gw.poll(30.0)
    assert len(gw.apps) == 1 and gw.counters["app_expired"] == 1
    assert [e["sysid"] for e in station.events.of("gcs_app_gone")] == [250]
    t.inbox.append((heartbeat(252), c))
    gw.poll(30.5)
    assert read_header(station.sent[-1]).compid == FIRST_APP_COMPID  # a's id, now c's
    # a command ack from the vehicle to that component id goes to c only, retargeted to c's own ids
    t.out.clear()
    ack = FrameCodec(VEHICLE_SYSID, 1).encode(mav.MAVLink_command_ack_message(400, 0, 0, 0, GS_SYSID, FIRST_APP_COMPID))
    gw.on_drone_frame("D1", ack)
    assert len(t.out) == 1 and t.out[0][1] == c
    msg = FrameCodec(252, 190).decode(t.out[0][0])
    assert msg is not None and (msg.target_system, msg.target_component) == (252, 190)


def test_an_ardupilotmega_reply_to_an_application_is_retargeted_to_it():
    gw, station, t = make_gateway()
    app = ("127.0.0.1", 7)
    gw.on_app_frame(0, app, heartbeat(250), 0.0)
    t.out.clear()
    fence = FrameCodec(VEHICLE_SYSID, 1).encode(apm.MAVLink_fence_point_message(GS_SYSID, FIRST_APP_COMPID, 0, 4, 1.0, 2.0))
    gw.on_drone_frame("D1", fence)
    assert len(t.out) == 1 and t.out[0][1] == app
    msg = FrameCodec(250, 190).decode(t.out[0][0])
    assert msg.get_type() == "FENCE_POINT" and (msg.target_system, msg.target_component) == (250, 190)


def test_a_tcp_application_is_forgotten_when_its_connection_closes():
    gw, station, _ = make_gateway()
    t = MemTransport(tcp=True)
    gw.transports = [t]
    conn = object()
    t.tcp_clients[conn] = b""
    gw.on_app_frame(0, conn, heartbeat(250), 0.0)
    gw.poll(1.0)
    assert len(gw.apps) == 1
    del t.tcp_clients[conn]
    gw.poll(2.0)
    assert len(gw.apps) == 0 and gw.counters["app_disconnected"] == 1


def test_garbage_from_applications_and_the_drone_is_counted():
    gw, station, t = make_gateway()
    peer = ("127.0.0.1", 5)
    for junk in (b"", b"\xfd", b"\x00" * 40, heartbeat(250)[:-1], heartbeat(250) + b"\x00", b"\xfe" * 300):
        gw.on_app_frame(0, peer, junk, 0.0)
    assert gw.counters["malformed"] == 6 and len(gw.apps) == 0
    gw.on_app_frame(0, peer, heartbeat(250), 0.0)  # an application must be known for drone frames to be routed
    for junk in (b"", b"\xfd\x01", bytes(range(60))):
        gw.on_drone_frame("D1", junk)
    bad_crc = bytearray(FrameCodec(VEHICLE_SYSID, 1).encode(mav.MAVLink_command_ack_message(400, 0, 0, 0, GS_SYSID, 100)))
    bad_crc[-1] ^= 0xFF
    gw.on_drone_frame("D1", bytes(bad_crc))
    assert gw.counters["drone_malformed"] == 4 and gw.counters["internal_error"] == 0


def test_a_frame_of_an_unknown_message_id_is_relayed_and_a_corrupted_one_counted():
    gw, station, _ = make_gateway()
    unknown = encode_raw(60000, 0x21, b"\x01\x02", 250, 190)  # an id of no dialect here: relayed all the same
    gw.on_app_frame(0, ("127.0.0.1", 5), unknown, 0.0)
    assert len(station.sent) == 1 and station.sent[0][10:12] == b"\x01\x02"
    assert read_header(station.sent[0]).sysid == GS_SYSID and crc_seed(station.sent[0]) == 0x21
    corrupted = unknown[:-1] + bytes([unknown[-1] ^ 0x40])  # its checksum fits no seed
    gw.on_app_frame(0, ("127.0.0.1", 5), corrupted, 0.0)
    assert gw.counters["rewrite_failed"] == 1 and len(station.sent) == 1
    assert gw.counters["internal_error"] == 0


@settings(max_examples=300, deadline=None)
@given(st.lists(st.binary(min_size=0, max_size=300), min_size=1, max_size=8), st.booleans())
def test_no_bytes_raise_out_of_the_gateway(frames: list[bytes], authority: bool):
    gw, station, _ = make_gateway(max_apps=2)
    station.authority = authority
    gw.on_app_frame(0, ("127.0.0.1", 5), heartbeat(250), 0.0)
    for i, data in enumerate(frames):
        for frame in (data, b"\xfd" + data, heartbeat(250)[:10] + data):
            gw.on_app_frame(0, ("127.0.0.1", 6 + i), frame, 0.0)
            gw.on_drone_frame("D1", frame)
    assert gw.counters["internal_error"] == 0


def test_a_rewrite_failure_is_counted(monkeypatch):
    gw, station, _ = make_gateway()

    def broken(frame: bytes, sysid: int, compid: int) -> bytes:
        raise FrameError("no")

    monkeypatch.setattr(gateway_mod, "rewrite_source", broken)
    gw.on_app_frame(0, ("127.0.0.1", 5), heartbeat(250), 0.0)
    assert gw.counters["rewrite_failed"] == 1 and station.sent == []


@pytest.mark.parametrize("exc", [OSError("down"), ZError("session closed"), ValueError("nothing to seal")])
def test_a_send_failure_towards_the_drone_is_counted(exc):
    gw, station, _ = make_gateway()

    def send(view: Any, frame: bytes) -> None:
        raise exc

    def control(view: Any, msg: Any) -> None:
        raise exc

    station.send_frame, station.send_control = send, control  # type: ignore[method-assign]
    station.authority = False
    gw.on_app_frame(0, ("127.0.0.1", 5), heartbeat(250), 0.0)
    gw.on_app_frame(0, ("127.0.0.1", 5), command_long(250, 32100), 0.0)  # operator control: a hand-over request
    assert gw.counters["send_failed"] == 2 and gw.counters["internal_error"] == 0
    ack = FrameCodec(250, 190).decode(gw.transports[0].out[-1][0])  # type: ignore[attr-defined]
    assert ack is not None and ack.command == 32100 and ack.result == mav.MAV_RESULT_FAILED


def test_a_send_failure_towards_an_application_is_counted():
    gw, station, t = make_gateway()
    station.authority = False

    def send(frame: bytes, peer: Any = None) -> None:
        raise ConnectionResetError("gone")

    t.send = send  # type: ignore[method-assign]
    gw.on_app_frame(0, ("127.0.0.1", 5), command_long(250), 0.0)  # refused: the COMMAND_ACK cannot be sent
    gw.poll(0.0)  # CONTROL_STATUS to every application
    gw.on_drone_frame("D1", heartbeat(VEHICLE_SYSID, 1))
    assert gw.counters["refused"] == 1 and gw.counters["send_failed"] == 3 and gw.counters["internal_error"] == 0


def test_an_encode_failure_is_counted():
    gw, station, t = make_gateway()
    station.authority = False
    codec = FrameCodec(VEHICLE_SYSID, 1)

    def encode(msg: Any) -> bytes:
        raise struct.error("out of range")

    codec.encode = encode  # type: ignore[method-assign]
    gw.codecs[(VEHICLE_SYSID, 1)] = codec
    gw.on_app_frame(0, ("127.0.0.1", 5), command_long(250), 0.0)
    assert gw.counters["encode_failed"] == 1 and t.out == []


def test_a_read_failure_is_counted_and_the_other_endpoints_still_served():
    gw, station, t = make_gateway()

    class Broken(MemTransport):
        def poll(self, timeout: float) -> list[tuple[bytes, Any]]:
            raise OSError("bad file descriptor")

    gw.transports = [Broken(), t]
    t.inbox.append((heartbeat(250), ("127.0.0.1", 5)))
    gw.poll(0.0)
    assert gw.counters["poll_failed"] == 1 and len(station.sent) == 1


def test_an_unexpected_error_is_logged_with_its_stack_counted_and_the_next_frame_served(caplog):
    gw, station, t = make_gateway()
    calls = {"n": 0}

    def holds_authority(view: Any) -> bool:
        calls["n"] += 1
        if calls["n"] == 1:
            raise RuntimeError("a bug")
        return True

    station.holds_authority = holds_authority  # type: ignore[method-assign]
    with caplog.at_level(logging.ERROR, logger="gs.gateway"):
        gw.on_app_frame(0, ("127.0.0.1", 5), command_long(250), 0.0)
        gw.on_app_frame(0, ("127.0.0.1", 5), command_long(250), 0.1)
    assert gw.counters["internal_error"] == 1 and len(station.sent) == 1
    assert len(caplog.records) == 1 and caplog.records[0].exc_info is not None


def test_stats_report_the_counters_and_the_applications():
    gw, station, t = make_gateway(max_apps=1)
    gw.on_app_frame(0, ("127.0.0.1", 5), heartbeat(250), 0.0)
    gw.on_app_frame(0, ("127.0.0.1", 6), heartbeat(251), 0.0)
    gw.on_app_frame(0, ("127.0.0.1", 6), b"junk", 0.0)
    s = gw.stats()
    assert s["apps"] == 1 and s["max_apps"] == 1
    assert s["counters"] == {"app_table_full": 1, "malformed": 1}
    assert s["endpoints"] == {"mem:test:0": {"rx_frames": 0, "tx_frames": 0, "skipped_bytes": 0}}
    assert APP_EXPIRY_S == 30.0 and MAX_APPS == 16
