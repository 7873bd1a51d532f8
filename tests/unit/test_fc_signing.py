"""MAVLink 2 signing of the flight controller's link: the frame maths, the simulated autopilots'
enforcement (PX4 1.17 and ArduCopter 4.7 rules), and the companion's link provisioning and keeping
the key against a ``zdrone sim`` server run in this process (loopback sockets, a TELEM2 endpoint)."""

from __future__ import annotations

import os
import socket
import stat
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega, common as mav

from zdrone.core import fcsign
from zdrone.core.mavlink import FrameCodec, encode_raw, read_header
from zdrone.core.reference import HOME
from zdrone.sil.ports import free_port
from zdrone.vehicle.fcsigning import FcKeyStore, FcSigning, FcSigningError, FcState
from zdrone.vehicle.link import VehicleLink
from zdrone.vehicle.personality import ARDUPILOT, PX4
from zdrone.vehicle.sim import SimAutopilot
from zdrone.vehicle.sim.signing import RULES, SigningStorage, SimSigning
from zdrone.vehicle.simserver import SimOptions, SimServer
from zdrone.vehicle.transport import MavTransport

KEY = bytes(range(32))
NOW = 1_780_000_000.0  # a wall clock for the tests (2026)


def _cmd(cmd: int, *params: float, sysid: int = 250) -> bytes:
    p = list(params) + [0.0] * (7 - len(params))
    return FrameCodec(sysid, 190).encode(mav.MAVLink_command_long_message(1, 1, cmd, 0, *p))


# ------------------------------------------------------------------------------ the frame maths
def test_a_signed_frame_is_13_bytes_longer_and_pymavlink_accepts_its_signature():
    frame = FrameCodec(1, 191).encode(mav.MAVLink_heartbeat_message(18, 8, 0, 0, 4, 3))
    ts = fcsign.units(NOW)
    signed = fcsign.sign(frame, KEY, 1, ts)
    assert len(signed) == len(frame) + 13 and fcsign.is_signed(signed)
    assert fcsign.strip(signed) == frame and fcsign.strip(frame) == frame
    sig = fcsign.read_signature(signed)
    assert sig is not None and (sig.link_id, sig.timestamp, sig.sysid, sig.compid) == (1, ts, 1, 191)
    rx = ardupilotmega.MAVLink(None)
    rx.signing.secret_key = KEY
    rx.signing.timestamp = ts - 10
    msg = rx.parse_buffer(signed)[0]
    assert msg.get_type() == "HEARTBEAT" and rx.signing.goodsig_count == 1
    # another key, an altered byte, a replay: refused
    assert not fcsign.signed_with(signed, bytes(32))
    clock = fcsign.StreamClock(ts)
    assert clock.check(signed, KEY) is None
    assert clock.check(signed, KEY) is fcsign.Refusal.REPLAY
    assert clock.check(signed[:12] + bytes([signed[12] ^ 1]) + signed[13:], KEY) is fcsign.Refusal.BAD_SIGNATURE
    old = fcsign.sign(frame, KEY, 2, ts - fcsign.NEW_STREAM_WINDOW - 1)
    assert clock.check(old, KEY) is fcsign.Refusal.STALE_STREAM


def test_a_frame_of_no_known_dialect_is_signed_and_stripped_by_its_own_checksum():
    frame = encode_raw(60001, 77, b"\x01\x02\x03", 4, 190)
    signed = fcsign.sign(frame, KEY, 0, 5)
    assert fcsign.strip(signed) == frame and read_header(signed).length == len(frame) + 13


# ----------------------------------------------------------------- the simulated autopilots' rules
def _provisioned(personality=PX4, storage=None) -> SimAutopilot:
    sim = SimAutopilot(HOME, personality=personality,
                       signing=SimSigning(RULES[personality.name], storage, wall=lambda: NOW))
    sim.receive(FrameCodec(1, 191).encode(mav.MAVLink_setup_signing_message(1, 1, list(KEY), fcsign.units(NOW))), 0.0)
    assert sim.signing.key == KEY
    sim.drain()
    return sim


def _answers(sim: SimAutopilot, cmd: int) -> list[int]:
    codec = FrameCodec(255, 190)
    return [m.result for m in map(codec.decode, sim.drain()) if m is not None and m.get_type() == "COMMAND_ACK"
            and m.command == cmd]


@pytest.mark.parametrize("personality", [PX4, ARDUPILOT], ids=["px4", "ardupilot"])
def test_with_a_key_unsigned_and_wrongly_signed_commands_are_refused_on_telem2(personality):
    sim = _provisioned(personality)
    arm = _cmd(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1, 21196)
    sim.receive(arm, 0.0, link=1)
    sim.receive(fcsign.sign(arm, bytes(32), 0, fcsign.units(NOW) + 5), 0.0, link=1)
    assert not sim.armed and _answers(sim, mav.MAV_CMD_COMPONENT_ARM_DISARM) == []
    assert sim.signing.counters["refused:unsigned"] == 1 and sim.signing.counters["refused:bad_signature"] == 1
    sim.receive(fcsign.sign(arm, KEY, 0, fcsign.units(NOW) + 10), 0.0, link=1)
    assert sim.armed and _answers(sim, mav.MAV_CMD_COMPONENT_ARM_DISARM) == [mav.MAV_RESULT_ACCEPTED]
    # it answers signed on the link where signed traffic arrived, unsigned on the other
    frame = FrameCodec(1, 1).encode(mav.MAVLink_heartbeat_message(2, 12, 0, 0, 4, 3))
    assert fcsign.signed_with(sim.signing.outgoing(frame, 1), KEY) and sim.signing.outgoing(frame, 0) == frame


def test_px4_accepts_unsigned_heartbeats_and_refuses_unsigned_commands_on_every_link():
    sim = _provisioned(PX4)
    for link in (0, 1):
        sim.receive(FrameCodec(250, 190).encode(mav.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3)), 0.0, link)
        sim.receive(_cmd(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1, 21196), 0.0, link)
    assert not sim.armed and sim.gcs_link.heartbeats.get(250) is not None
    assert sim.signing.counters["refused:unsigned"] == 2


def test_ardupilot_serial0_always_accepts_unsigned():
    sim = _provisioned(ARDUPILOT)
    sim.receive(_cmd(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1, 2989), 0.0, link=0)
    assert sim.armed


def test_a_new_key_must_come_signed_with_the_old_one_and_never_while_armed():
    sim = _provisioned(PX4)
    other = bytes(32 * [7])
    setup = FrameCodec(1, 191).encode(mav.MAVLink_setup_signing_message(1, 1, list(other), fcsign.units(NOW)))
    sim.receive(setup, 0.0, link=0)
    assert sim.signing.key == KEY  # unsigned: dropped
    sim.vehicle.armed = True
    sim.receive(fcsign.sign(setup, KEY, 1, fcsign.units(NOW) + 1), 0.0, link=0)
    assert sim.signing.key == KEY and "MAVLink signing: rejected while armed" in [t for _, t in sim.events]
    sim.vehicle.armed = False
    sim.receive(fcsign.sign(setup, KEY, 1, fcsign.units(NOW) + 2), 0.0, link=0)
    assert sim.signing.key == other


def test_the_key_survives_a_restart_and_ardupilot_resumes_60_s_past_its_saved_timestamp(tmp_path):
    for personality, ahead in ((PX4, 0.0), (ARDUPILOT, 60.0)):
        storage = SigningStorage(tmp_path / personality.name, RULES[personality.name])
        _provisioned(personality, storage)
        path = storage.path
        assert stat.S_IMODE(path.stat().st_mode) == 0o600
        again = SimSigning(RULES[personality.name], SigningStorage(tmp_path / personality.name, RULES[personality.name]),
                           wall=lambda: NOW)
        assert again.key == KEY
        assert again.clock.timestamp == fcsign.units(NOW) + int(ahead * fcsign.UNITS_PER_S)


# ---------------------------------------------------------- the companion's link against a sim server
@contextmanager
def _sim_server(personality=PX4, signing: bool = True, storage: Path | None = None,
                speedup: float = 5.0) -> Iterator[tuple[SimServer, str, int]]:
    """A ``zdrone sim`` server on loopback in a thread: (server, the companion's connection, TELEM2 port)."""
    telem2 = _free_udp()
    if personality is PX4:
        port = _free_udp()
        opts = SimOptions(mavlink=f"udpin:127.0.0.1:{port}", personality=PX4, speedup=speedup, ready_after=0.0,
                          telem2=f"udpin:127.0.0.1:{telem2}", storage=str(storage) if storage else None, signing=signing)
        conn = f"udpout:127.0.0.1:{port}"
    else:
        port = _free_tcp()
        opts = SimOptions(mavlink=f"tcpin:127.0.0.1:{port}", personality=ARDUPILOT, speedup=speedup, ready_after=0.0,
                          telem2=f"udpin:127.0.0.1:{telem2}", storage=str(storage) if storage else None, signing=signing)
        conn = f"tcp:127.0.0.1:{port}"
    server = SimServer(opts)
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        yield server, conn, telem2
    finally:
        server.stop()
        thread.join(5)


def _free_udp() -> int:
    return free_port(socket.SOCK_DGRAM)  # below the ephemeral range: no outgoing socket takes it meanwhile


def _free_tcp() -> int:
    return free_port(socket.SOCK_STREAM)


@contextmanager
def _link(conn: str, store: FcKeyStore | None, mode: str = "prefer", rotate: bool = False,
          **kw) -> Iterator[VehicleLink]:
    # an autopilot that signs settles the link with its first signed frames; the wait for them is long
    # here so that a loaded machine never reads it as an autopilot that does not sign (those tests say 1 s)
    kw.setdefault("confirm_timeout", 30.0)
    link = VehicleLink(conn, signing=FcSigning(store, mode, rotate, **kw))
    try:
        yield link
    finally:
        link.close()


def _until(link: VehicleLink, pred, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        link.heartbeat()
        link.recv(0.05)
        if pred():
            return True
    return pred()


class Radio:
    """Someone on TELEM2: a GCS with no key (sysid 250)."""

    def __init__(self, port: int) -> None:
        self.t = MavTransport(f"udpout:127.0.0.1:{port}")
        self.codec = FrameCodec(250, 190)
        self.acks: list[tuple[int, int]] = []
        self.t.send(self.codec.encode(mav.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3)))

    def command(self, cmd: int, *params: float) -> None:
        p = list(params) + [0.0] * (7 - len(params))
        self.t.send(self.codec.encode(mav.MAVLink_command_long_message(1, 1, cmd, 0, *p)))

    def listen(self, seconds: float, until=lambda: False) -> None:
        """Collect the acks sent to us for ``seconds``, or until ``until()`` (checked between polls)."""
        end = time.monotonic() + seconds
        while time.monotonic() < end and not until():
            for frame, _ in self.t.poll(0.05):
                msg = self.codec.decode(fcsign.strip(frame))
                if msg is not None and msg.get_type() == "COMMAND_ACK" and msg.target_system == 250:
                    self.acks.append((msg.command, msg.result))

    def close(self) -> None:
        self.t.close()


@pytest.mark.parametrize("personality", [PX4, ARDUPILOT], ids=["px4", "ardupilot"])
def test_the_link_provisions_signing_and_a_radio_on_telem2_is_not_obeyed(tmp_path, personality):
    store = FcKeyStore(tmp_path / "secrets" / "d1.fc-signing.json")
    with _sim_server(personality) as (server, conn, telem2), _link(conn, store) as link:
        assert link.wait_vehicle(10)
        assert link.signing_status()["state"] == "signed" and link.signing_status()["signed"]
        assert stat.S_IMODE(store.path.stat().st_mode) == 0o600 and store.load().key == server.sim.signing.key
        # settled by the first SETUP_SIGNING and the signed frame right behind it: nothing sent again,
        # nothing of ours refused by the autopilot
        assert link.signing.counters["setup_sent"] == 1 and server.sim.counters["signing_refused"] == 0
        frames = link.recv(5.0)  # returns with the first frames
        assert frames and not any(fcsign.is_signed(f) for f in frames)  # handed on without the signature
        assert link.signing.counters["verified_in"] > 0
        radio = Radio(telem2)
        try:
            radio.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1, 21196)
            radio.command(mav.MAV_CMD_DO_SET_MODE, 1, 4)
            radio.listen(10.0, until=lambda: server.sim.signing.counters["refused:unsigned"] >= 2)  # both seen
            radio.listen(0.3)  # an ack, had there been one, would follow its command at once
            assert radio.acks == [] and not server.sim.armed
            assert server.sim.signing.counters["refused:unsigned"] >= 2
            # the companion's own commands are obeyed (signed)
            link.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1, 21196)
            assert _until(link, lambda: link.armed, 20)
        finally:
            radio.close()


def test_without_signing_the_radio_on_telem2_takes_over(tmp_path):
    with _sim_server(PX4) as (server, conn, telem2), _link(conn, None, "off") as link:
        assert link.wait_vehicle(10) and link.signing_status()["state"] == "off"
        radio = Radio(telem2)
        try:
            radio.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1, 21196)
            radio.listen(10.0, until=lambda: bool(radio.acks))
            assert (mav.MAV_CMD_COMPONENT_ARM_DISARM, mav.MAV_RESULT_ACCEPTED) in radio.acks and server.sim.armed
        finally:
            radio.close()


def test_an_autopilot_that_does_not_sign_prefer_goes_on_unsigned_require_refuses(tmp_path):
    store = FcKeyStore(tmp_path / "d1.fc-signing.json")
    with _sim_server(PX4, signing=False) as (server, conn, _):
        with _link(conn, store, "prefer", confirm_timeout=1.0) as link:
            assert link.wait_vehicle(10)
            st = link.signing_status()
            assert st["state"] == "unsigned" and not st["signed"] and st["counters"]["unsigned_fallback"] == 1
            frame = FrameCodec(4, 190).encode(mav.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))
            assert link.signing.outgoing(frame) == frame  # goes on unsigned
        with _link(conn, store, "require", confirm_timeout=1.0) as link:
            with pytest.raises(FcSigningError, match="does not sign"):
                link.wait_vehicle(10)


def test_rotation_installs_a_new_key_signed_with_the_old_one_and_is_refused_while_armed(tmp_path):
    store = FcKeyStore(tmp_path / "d1.fc-signing.json")
    with _sim_server(PX4) as (server, conn, _):
        with _link(conn, store) as link:
            assert link.wait_vehicle(10) and link.signing_status()["signed"]
        first = store.load().key
        with _link(conn, store, rotate=True) as link:
            assert link.wait_vehicle(10) and link.signing_status()["signed"]
        second = store.load()
        assert second.key != first and second.previous is None and server.sim.signing.key == second.key
        with _link(conn, store) as link:
            assert link.wait_vehicle(10) and link.signing_status()["signed"]
            link.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1, 21196)
            assert _until(link, lambda: link.armed, 20)
        with _link(conn, store, rotate=True) as link:
            with pytest.raises(FcSigningError, match="armed"):
                link.wait_vehicle(10)
        assert store.load().key == second.key == server.sim.signing.key


def test_signing_timestamps_never_go_back_across_restarts(tmp_path):
    """The link is closed and made again with the same state directory, the wall clock set back a
    day: every timestamp it signs with is still larger than any before, and the autopilot (which
    refuses a stream's timestamp that does not grow) keeps answering."""
    store = FcKeyStore(tmp_path / "d1.fc-signing.json")
    wall = [time.time()]
    seen: list[int] = []
    frame = FrameCodec(1, 191).encode(mav.MAVLink_heartbeat_message(18, 8, 0, 0, 4, 3))
    with _sim_server(PX4) as (server, conn, _):
        for restart in range(3):
            with _link(conn, store, clock=lambda: wall[0]) as link:
                assert link.wait_vehicle(10) and link.signing_status()["signed"], link.signing_status()
                for _ in range(5):
                    seen.append(fcsign.read_signature(link.signing.outgoing(frame)).timestamp)
                link.command(mav.MAV_CMD_REQUEST_MESSAGE, mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
                assert _until(link, lambda: link.signing.counters["verified_in"] > 3, 20)
            wall[0] -= 86400.0  # the companion's clock goes back a day before the next start
        assert server.sim.signing.counters.get("refused:replay", 0) == 0
    assert seen == sorted(seen) and len(set(seen)) == len(seen)
    assert stat.S_IMODE(os.stat(store.path).st_mode) == 0o600


def test_ardupilot_after_a_restart_answers_a_sender_that_follows_its_timestamps(tmp_path):
    """ArduPilot resumes 60 s past its saved timestamp: a new stream signed with the wall clock is
    refused, but the autopilot signs back and the link takes up its timestamp."""
    storage = tmp_path / "ap"
    store = FcKeyStore(tmp_path / "d1.fc-signing.json")
    with _sim_server(ARDUPILOT, storage=storage) as (server, conn, _), _link(conn, store) as link:
        assert link.wait_vehicle(10) and link.signing_status()["signed"]
    store2 = FcKeyStore(tmp_path / "d2.fc-signing.json")
    store2.save(store.load().__class__(store.load().key, 0, None))  # same key, no timestamp history
    with _sim_server(ARDUPILOT, storage=storage) as (server, conn, _), _link(conn, store2) as link:
        assert server.sim.signing.key is not None
        assert link.wait_vehicle(10) and link.signing_status()["signed"], link.signing_status()
        link.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1, 2989)
        assert _until(link, lambda: link.armed, 20)


def test_setup_signing_from_a_gcs_app_is_never_forwarded():
    """The gateway's apps speak unsigned MAVLink on the GS's machine; the drone's uplink policy
    denies SETUP_SIGNING to every GS (even the authority), so no app can change the autopilot's key."""
    from zdrone.core.uplink import DEFAULT_POLICY, UplinkClass

    assert DEFAULT_POLICY.classify(mav.MAVLINK_MSG_ID_SETUP_SIGNING) is UplinkClass.DENIED


def test_a_restart_in_the_air_sends_no_setup_signing_and_takes_up_the_signed_link(tmp_path):
    store = FcKeyStore(tmp_path / "d1.fc-signing.json")
    with _sim_server(PX4) as (server, conn, _):
        with _link(conn, store) as link:
            assert link.wait_vehicle(10) and link.signing_status()["signed"]
            link.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1, 21196)
            assert _until(link, lambda: link.armed, 20)
        with _link(conn, store) as link:  # the companion restarted, the vehicle armed
            assert link.wait_vehicle(10) and link.signing_status()["signed"]
            assert link.signing.counters["setup_sent"] == 0 and server.sim.armed
        assert server.sim.signing.counters.get("refused:setup_armed", 0) == 0


def test_the_key_store_lives_beside_the_secret_or_in_the_service_state_directory(tmp_path, monkeypatch):
    from zdrone.fleet.bundle import check_bundle, export_bundle
    from zdrone.fleet.files import init_fleet
    from zdrone.vehicle.fcsigning import StoredKey

    init_fleet(tmp_path / "fleet")
    monkeypatch.delenv("ZDRONE_STATE_DIR", raising=False)
    export_bundle(tmp_path / "fleet", "d1", tmp_path / "d1")
    store = FcKeyStore.for_node(tmp_path / "d1", "d1")
    assert store.path == tmp_path / "d1" / "secrets" / "d1.fc-signing.json"
    store.save(StoredKey(KEY, 5))
    assert check_bundle(tmp_path / "d1")  # the drone's own key file belongs in its bundle
    monkeypatch.setenv("ZDRONE_STATE_DIR", str(tmp_path / "state"))
    assert FcKeyStore.for_node(tmp_path / "d1", "d1").path == tmp_path / "state" / "d1.fc-signing.json"
    os.chmod(store.path, 0o644)  # readable by others: refused, as the node's secret is
    with pytest.raises(Exception, match="accessible by others"):
        store.load()
