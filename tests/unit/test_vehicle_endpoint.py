"""Only the real autopilot speaks for the vehicle (issue 29, behaviours 4 and 5): the UDP endpoint rule,
the ids the tracker adopts, signed positions, a signing that never goes back to unsigned, and the
failsafe followed until the autopilot shows it. Pure parts in memory; the link against the simulator
run in this process on loopback, with a second socket playing the local attacker."""

from __future__ import annotations

import socket
import threading
import time
from contextlib import contextmanager
from typing import Iterator

import pytest
from pymavlink.dialects.v20 import common as mav

from zdrone.core import fcsign
from zdrone.core.geometry import distance_m
from zdrone.core.mavlink import FrameCodec
from zdrone.core.reference import GS_B, HOME
from zdrone.sil.ports import free_port
from zdrone.vehicle.endpoint import AutopilotEndpoint, autopilot_heartbeat
from zdrone.vehicle.fcsigning import FcKeyStore, FcSigning, FcState, StoredKey
from zdrone.vehicle.link import VehicleLink
from zdrone.vehicle.personality import ARDUPILOT, PX4
from zdrone.vehicle.simserver import SimOptions, SimServer
from zdrone.vehicle.tracker import FailsafeTiming, VehicleTracker

from tests.unit.test_vehicle_tracker import COMPANION, Bench
from tests.waiting import readable

KEY = bytes(range(32))
REAL, FAKE, OTHER = ("127.0.0.1", 14580), ("127.0.0.1", 40001), ("127.0.0.1", 40002)


def _hb(sysid: int, compid: int = 1, autopilot: int = mav.MAV_AUTOPILOT_PX4, mode: int = 0) -> bytes:
    return FrameCodec(sysid, compid).encode(mav.MAVLink_heartbeat_message(mav.MAV_TYPE_QUADROTOR, autopilot, 1, mode, 4, 3))


def _position(lat: float, lon: float, sysid: int = 1) -> bytes:
    return FrameCodec(sysid, 1).encode(mav.MAVLink_global_position_int_message(0, int(lat * 1e7), int(lon * 1e7), 30000,
                                                                               30000, 0, 0, 0, 0))


# ------------------------------------------------------------------------------ the endpoint rule
def test_a_heartbeat_counts_only_from_the_drone_sysid_and_the_autopilot_component():
    assert autopilot_heartbeat(_hb(1), 1)
    assert not autopilot_heartbeat(_hb(7), 1)  # the fake autopilot of issue 29
    assert not autopilot_heartbeat(_hb(1, compid=191), 1)
    assert not autopilot_heartbeat(_hb(1, autopilot=mav.MAV_AUTOPILOT_INVALID), 1)  # a GCS or a companion
    assert not autopilot_heartbeat(_position(1, 1), 1)


def test_a_fixed_endpoint_takes_its_own_datagrams_only():
    ep = AutopilotEndpoint(1, fixed=REAL)
    assert ep.admit(REAL, [_hb(1)]) is None
    assert ep.admit(FAKE, [_hb(1)]) == "foreign_endpoint"  # the autopilot's own ids, from elsewhere
    assert ep.admit(FAKE, [_position(47.4, 8.5)]) == "foreign_endpoint"
    assert ep.destinations() == [REAL] and ep.counters["dropped:foreign_endpoint"] == 2


def test_a_learned_endpoint_is_the_first_that_proves_to_be_the_autopilot_and_no_other():
    ep = AutopilotEndpoint(1)
    assert ep.destinations() == []
    assert ep.admit(FAKE, [_hb(7)]) == "before_autopilot"  # sysid 7 first: never the vehicle
    assert ep.admit(FAKE, [_position(47.4, 8.5)]) == "before_autopilot"
    assert ep.admit(REAL, [_hb(1)]) is None and ep.address == REAL and ep.how == "heartbeat"
    assert ep.admit(FAKE, [_hb(7)]) == "foreign_endpoint"
    assert ep.admit(FAKE, [_position(47.4, 8.5)]) == "foreign_endpoint"
    assert ep.destinations() == [REAL]
    assert ep.counters["dropped:before_autopilot"] == 2 and ep.counters["dropped:foreign_endpoint"] == 2


def test_an_endpoint_found_by_heartbeat_gives_way_once_to_the_one_signing_with_the_key():
    signed = fcsign.sign(_hb(1), KEY, 0, fcsign.units(time.time()))
    ep = AutopilotEndpoint(1, signed_by_us=lambda f: fcsign.signed_with(f, KEY))
    assert ep.admit(FAKE, [_hb(1)]) is None and ep.how == "heartbeat"  # raced with the autopilot's own ids
    assert ep.admit(REAL, [_hb(1)]) == "foreign_endpoint" and ep.claimants == [REAL]
    assert ep.destinations() == [FAKE, REAL]  # the companion's signed frames reach the real one too
    assert ep.admit(REAL, [signed]) is None and (ep.address, ep.how) == (REAL, "signed")
    assert ep.counters["moved_to_signed"] == 1 and ep.destinations() == [REAL]
    assert ep.admit(FAKE, [fcsign.sign(_hb(1), bytes(32), 0, 5)]) == "foreign_endpoint"  # another key: nothing
    assert ep.admit(OTHER, [signed]) == "foreign_endpoint"  # once proven by signature, it never moves


# ------------------------------------------------------------------------------ the tracker
def test_the_tracker_adopts_only_the_drone_sysid_with_the_autopilot_component():
    codec = FrameCodec(*COMPANION)
    t = VehicleTracker(*COMPANION)
    for frame in (_hb(7), _hb(1, compid=191)):
        t.on_message(codec.decode(frame), 0.1)
    assert t.sysid is None and t.counters["foreign_heartbeat"] == 2
    t.on_message(codec.decode(_hb(1)), 0.2)
    assert (t.sysid, t.compid, t.autopilot) == (1, 1, "px4")
    t.on_message(codec.decode(_hb(7)), 10.0)  # the vehicle silent for long: still never system 7
    assert t.sysid == 1 and t.counters["foreign_heartbeat"] == 3


def test_a_position_is_signed_only_while_the_frame_that_brought_it_was():
    codec = FrameCodec(*COMPANION)
    t = VehicleTracker(*COMPANION)
    t.on_message(codec.decode(_hb(1)), 0.0)
    t.on_message(codec.decode(_position(HOME.lat, HOME.lon)), 0.1, signed=True)
    assert t.position is not None and t.position_signed
    t.on_message(codec.decode(_position(GS_B.lat, GS_B.lon)), 0.2, signed=False)
    assert t.position is not None and not t.position_signed


@pytest.mark.parametrize("personality", [PX4, ARDUPILOT], ids=["px4", "ardupilot"])
def test_the_failsafe_is_confirmed_by_the_autopilot_mode(personality):
    from zdrone.vehicle.modes import set_mode_params

    b = Bench(personality)
    b.run(3.0)
    params = set_mode_params(b.tracker.autopilot, "LAND")
    b.command(mav.MAV_CMD_DO_SET_MODE, *params)
    b.tracker.watch_failsafe("LAND", mav.MAV_CMD_DO_SET_MODE, params, b.now)
    b.run(3.0)
    [outcome] = b.tracker.failsafe_outcomes()
    assert outcome.outcome == "confirmed" and outcome.attempts == 1 and outcome.seen in ("mode LAND", "on the ground, disarmed")
    assert not b.tracker.failsafe_pending


def test_a_failsafe_the_autopilot_does_not_show_is_sent_again_then_given_up():
    """The LAND went somewhere the autopilot never heard it: it flies on in MISSION, armed, in the air."""
    from zdrone.vehicle.modes import custom_mode

    codec = FrameCodec(*COMPANION)
    t = VehicleTracker(*COMPANION, failsafe_timing=FailsafeTiming(confirm_within=1.0, attempts=3))
    mission = custom_mode("px4", "MISSION")

    def flying(now: float) -> None:
        frame = FrameCodec(1, 1).encode(mav.MAVLink_heartbeat_message(
            mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_PX4, mav.MAV_MODE_FLAG_SAFETY_ARMED | 1, mission, 4, 3))
        t.on_message(codec.decode(frame), now)

    flying(0.0)
    t.command(mav.MAV_CMD_NAV_LAND, (), 0.0)
    t.watch_failsafe("LAND", mav.MAV_CMD_NAV_LAND, (), 0.0)
    sent = []
    now = 0.0
    while now < 5.0:
        now = round(now + 0.1, 3)
        if now % 0.5 < 1e-9:
            flying(now)
        sent += [m for m in t.poll(now) if getattr(m, "command", None) == mav.MAV_CMD_NAV_LAND]
    outcomes = [(o.outcome, o.attempts) for o in t.failsafe_outcomes()]
    assert outcomes == [("retried", 2), ("retried", 3), ("unconfirmed", 3)]
    assert t.counters["failsafe_unconfirmed"] == 1 and t.counters["failsafe_retried"] == 2
    assert len(sent) >= 2  # sent again each time (besides the resends of an unacknowledged command)
    flying(5.1)
    t.watch_failsafe("LAND", mav.MAV_CMD_NAV_LAND, (), 5.2)  # and one the autopilot shows: confirmed
    land = FrameCodec(1, 1).encode(mav.MAVLink_heartbeat_message(
        mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_PX4, mav.MAV_MODE_FLAG_SAFETY_ARMED | 1, custom_mode("px4", "LAND"), 4, 3))
    t.on_message(codec.decode(land), 5.5)
    t.poll(5.6)
    assert [(o.outcome, o.seen) for o in t.failsafe_outcomes()] == [("confirmed", "mode LAND")]


# ------------------------------------------------------------------------------ never back to unsigned
def test_once_the_autopilot_signed_the_link_never_goes_back_to_unsigned(tmp_path):
    store = FcKeyStore(tmp_path / "d1.fc-signing.json")
    fresh = FcSigning(store, "prefer", confirm_timeout=1.0, new_key=lambda: KEY)
    fresh.start(0.0, False, 1)
    signed = fcsign.sign(_hb(1), KEY, 0, fcsign.units(time.time()) + 10_000_000)
    assert fresh.incoming(signed) is None and fresh.state is FcState.SIGNED
    assert store.load().confirmed and fresh.status()["signed_before"]
    # the next start meets an "autopilot" that does not sign (someone else, or a reset): prefer refuses
    later = FcSigning(store, "prefer", confirm_timeout=1.0)
    later.start(0.0, False, 1)
    assert later.incoming(_hb(1)) is None  # unsigned frames pass while provisioning, as before
    later.due_setup(2.0)
    assert later.state is FcState.FAILED and "does not now" in later.reason
    assert later.counters["downgrade_refused"] == 1 and later.counters["unsigned_fallback"] == 0
    # a vehicle that never signed: prefer goes on unsigned, said and counted (shown to every GS)
    other = FcKeyStore(tmp_path / "d2.fc-signing.json")
    never = FcSigning(other, "prefer", confirm_timeout=1.0)
    never.start(0.0, False, 1)
    never.due_setup(2.0)
    assert never.state is FcState.UNSIGNED and never.counters["unsigned_fallback"] == 1
    assert not other.load().confirmed


def test_a_stored_key_is_not_sent_over_a_learned_endpoint():
    """SETUP_SIGNING carries the key in clear: over ``udpin`` whoever answered first may not be the
    autopilot, so the stored key is never sent there; the autopilot holding it signs back."""
    class Memory(FcKeyStore):
        def __init__(self) -> None:
            self.stored = StoredKey(KEY, 0, None, True)

        def load(self) -> StoredKey:
            return self.stored

        def save(self, stored: StoredKey) -> None:
            self.stored = stored

    s = FcSigning(Memory(), "prefer")
    s.start(0.0, False, 1, resend_stored=False)
    assert s.state is FcState.PROVISIONING and s.due_setup(0.0) is None and s.due_setup(1.5) is None
    s2 = FcSigning(Memory(), "prefer")
    s2.start(0.0, False, 1)
    assert s2.due_setup(0.0) is not None  # a fixed endpoint (udpout, TCP, serial): sent again, signed


# ------------------------------------------------------------------------------ the link on loopback
def _free_udp() -> int:
    return free_port(socket.SOCK_DGRAM)  # below the ephemeral range: no outgoing socket takes it meanwhile


@contextmanager
def _sim_sending_to(port: int, personality=PX4) -> Iterator[SimServer]:
    """The simulator sending to the companion's listening port (PX4's onboard link: it sends to 14540)."""
    server = SimServer(SimOptions(mavlink=f"udpout:127.0.0.1:{port}", personality=personality, speedup=5.0,
                                  ready_after=0.0))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        yield server
    finally:
        server.stop()
        thread.join(5)


class Fake:
    """A local process's socket writing into the companion's vehicle port."""

    def __init__(self, port: int) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.to = ("127.0.0.1", port)
        self.heard = 0

    def send(self, frame: bytes) -> None:
        self.sock.sendto(frame, self.to)

    def drain(self) -> int:
        self.sock.setblocking(False)
        while True:
            try:
                self.sock.recv(65535)
                self.heard += 1
            except BlockingIOError:
                return self.heard

    def close(self) -> None:
        self.sock.close()


@pytest.mark.parametrize("mode", ["prefer", "off"])
def test_a_fake_autopilot_racing_the_start_is_never_the_vehicle_and_its_positions_never_count(tmp_path, mode):
    port = _free_udp()
    fake = Fake(port)
    link = VehicleLink(f"udpin:127.0.0.1:{port}",
                       signing=FcSigning(FcKeyStore(tmp_path / "d1.fc-signing.json"), mode, confirm_timeout=30.0))
    try:
        for _ in range(5):  # before the real autopilot says anything
            fake.send(_hb(7))
        with _sim_sending_to(port):
            assert link.wait_vehicle(10)
            assert link.sysid == 1 and link.endpoint is not None and link.endpoint.how in ("heartbeat", "signed")
            assert link.endpoint.counters["dropped:before_autopilot"] >= 5
            assert link.signing_status()["signed"] is (mode == "prefer")
            deadline = time.monotonic() + 10
            while (link.position is None or link.position_signed is not (mode == "prefer")) \
                    and time.monotonic() < deadline:
                link.heartbeat()
                link.recv(0.05)
            assert link.position is not None and link.position_signed is (mode == "prefer")
            for _ in range(20):  # forged positions at B's centre with the autopilot's own ids
                fake.send(_hb(7))
                fake.send(_position(GS_B.lat, GS_B.lon))
                link.heartbeat()
                link.recv(0.02)
            link.recv(0.3)
            assert distance_m(HOME, link.position) < 5.0 and link.sysid == 1
            assert link.endpoint.counters["dropped:foreign_endpoint"] >= 40
            assert link.tracker.counters.get("foreign_heartbeat", 0) == 0  # never reached the tracker
            link.command_land()  # the failsafe goes to the autopilot, and it shows it
            deadline = time.monotonic() + 10
            outcomes: list = []
            while not outcomes and time.monotonic() < deadline:
                link.heartbeat()
                link.recv(0.05)
                outcomes = [o for o in link.failsafe_outcomes() if o.outcome == "confirmed"]
            assert outcomes and outcomes[0].seen in ("mode LAND", "on the ground, disarmed")
        assert fake.drain() == 0  # nothing the companion sent went to the fake (its key least of all)
    finally:
        link.close()
        fake.close()


# ------------------------------------------------------------------------------ reflection (R1)
def _stored(tmp_path, confirmed: bool = True) -> FcKeyStore:
    store = FcKeyStore(tmp_path / "d1.fc-signing.json")
    store.save(StoredKey(KEY, 0, None, confirmed))
    return store


def test_the_companions_own_signed_frames_sent_back_prove_nothing_and_are_dropped(tmp_path):
    """A local process that got the companion's signed HEARTBEAT (1/191) sends it straight back: it is
    signed with the key and a new stream to the replay check, but no stream of the autopilot's."""
    s = FcSigning(_stored(tmp_path), "require", confirm_timeout=4.0)
    s.expect((1, 1), (1, 191))
    s.start(0.0, False, 1, resend_stored=False)
    ours = s.outgoing(FrameCodec(1, 191).encode(mav.MAVLink_heartbeat_message(
        mav.MAV_TYPE_ONBOARD_CONTROLLER, mav.MAV_AUTOPILOT_INVALID, 0, 0, 4, 3)))
    assert fcsign.is_signed(ours) and not s.vouches(ours) and not s.proves(ours)
    assert s.incoming(ours) == "reflected" and s.state is FcState.PROVISIONING
    forwarded = s.outgoing(FrameCodec(255, 190).encode(mav.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3)))
    assert s.incoming(forwarded) == "reflected"  # a GS's frame we forwarded, sent back: dropped too
    # a frame of ours carrying the autopilot's ids would prove it: the link never signs one (below)
    assert s.counters["dropped:reflected"] == 2 and s.counters.get("verified_in", 0) == 0
    s.due_setup(4.0)
    assert s.state is FcState.FAILED  # nobody signed on the autopilot's stream: require refuses to fly


def test_only_a_fresh_frame_on_the_autopilots_stream_proves_it(tmp_path):
    s = FcSigning(_stored(tmp_path), "require", confirm_timeout=4.0)
    s.expect((1, 1), (1, 191))
    s.start(0.0, False, 1, resend_stored=False)
    ts = fcsign.units(time.time()) + 10_000_000
    other_component = fcsign.sign(_hb(1, compid=154), KEY, 0, ts)
    assert not s.proves(other_component) and s.incoming(other_component) is None  # taken, but proves nothing
    assert s.state is FcState.PROVISIONING
    real = fcsign.sign(_hb(1), KEY, 0, ts + 1)
    assert s.proves(real) and s.incoming(real) is None and s.state is FcState.SIGNED
    assert s.vouches(real) and not s.proves(real)  # the same frame again (relayed from elsewhere): no proof
    assert s.proves(fcsign.sign(_hb(1), KEY, 0, ts + 2))


def test_an_endpoint_found_by_heartbeat_is_not_proven_by_a_reflection(tmp_path):
    s = FcSigning(_stored(tmp_path), "require")
    s.expect((1, 1), (1, 191))
    s.start(0.0, False, 1, resend_stored=False)
    ep = AutopilotEndpoint(1, signed_by_us=s.proves)
    assert ep.admit(FAKE, [_hb(1)]) is None and ep.how == "heartbeat"  # raced with the autopilot's ids
    assert ep.admit(REAL, [_hb(1)]) == "foreign_endpoint" and ep.claimants == [REAL]
    ours = s.outgoing(FrameCodec(1, 191).encode(mav.MAVLink_heartbeat_message(18, 8, 0, 0, 4, 3)))
    assert ep.admit(FAKE, [ours]) is None and ep.how == "heartbeat"  # taken as before, never "signed"
    assert ep.admit(OTHER, [ours]) == "foreign_endpoint" and ep.address == FAKE
    real = fcsign.sign(_hb(1), KEY, 0, fcsign.units(time.time()) + 10_000_000)
    assert ep.admit(REAL, [real]) is None and (ep.address, ep.how) == (REAL, "signed")


def test_the_link_never_sends_a_frame_carrying_the_autopilots_ids(tmp_path):
    port = _free_udp()
    fake = Fake(port)
    link = VehicleLink(f"udpin:127.0.0.1:{port}", signing=FcSigning(_stored(tmp_path), "prefer"))
    try:
        link.endpoint.admit(fake.sock.getsockname(), [_hb(1)])
        link.send(_hb(1))  # as the autopilot: not sent, counted
        link.send(_hb(255, compid=190))  # a GS's: sent
        assert readable([fake.sock], 5.0)  # both were sent before: whatever arrives is there now
        assert fake.drain() == 1 and link.refused_autopilot_ids == 1
        assert link.stream_stats()["refused_autopilot_ids"] == 1
    finally:
        link.close()
        fake.close()


def test_a_position_not_reported_again_is_unknown():
    """A relay that withholds GLOBAL_POSITION_INT cannot keep an old (signed) position in place."""
    t = VehicleTracker(*COMPANION)
    codec = FrameCodec(0, 0)
    t.on_message(codec.decode(_hb(1)), 0.0)
    t.on_message(codec.decode(_position(47.4, 8.5)), 1.0, signed=True)
    assert t.position_at(1.0) is not None and t.position_signed_at(2.0)
    assert t.position_at(2.6) is None and not t.position_signed_at(2.6)
    assert t.position_unknown(2.6).startswith("no position report for 1.6 s")
    assert t.stats(2.6)["position"]["known"] is False
    t.on_message(codec.decode(_position(47.4, 8.5)), 2.7, signed=True)
    assert t.position_at(2.8) is not None and t.position_unknown(2.8) is None


def test_the_listening_socket_cannot_be_bound_again(tmp_path):
    """udpin: the link's socket is bound without SO_REUSEADDR: a second bind of its port fails, even
    one that sets SO_REUSEADDR (pymavlink's own socket would have let it take the port over)."""
    port = _free_udp()
    link = VehicleLink(f"udpin:127.0.0.1:{port}", signing=FcSigning(None, "off"))
    try:
        assert link.m.port.getsockname() == ("127.0.0.1", port)
        thief = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        thief.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        with pytest.raises(OSError):
            thief.bind(("127.0.0.1", port))
        thief.close()
        from zdrone.core.fleet import ConfigError
        with pytest.raises(ConfigError):
            VehicleLink(f"udpin:127.0.0.1:{port}", signing=FcSigning(None, "off"))
    finally:
        link.close()
