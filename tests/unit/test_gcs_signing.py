"""MAVLink 2 signing of the GCS gateway's applications (``gs.appkeys``, ``gs.gateway``), without sockets.

The key file (formats, the mode check), the keys MAVProxy and QGroundControl make of a passphrase,
and the gateway's policy per ``--gcs-signing`` mode against frames signed by pymavlink itself: who may
speak for the operator, what an unsigned application still gets, what a wrongly signed, replayed or
stale frame gets (nothing, counted), and that replies to a signed application verify with its key.
"""

from __future__ import annotations

import json
import logging
import math
import os
import re
import time
from typing import Any

import pytest
from pymavlink.dialects.v20 import common as mav

from gs.appkeys import (MAX_KEYS, STRONG_BITS, AppSigning, SigningKey, load_gs_keys, load_keys, parse_key_file,
                        parse_keys, passphrase_bits, passphrase_key, qgc_passphrase_key, signing_state_path,
                        weak_key_warning, weak_keys)
from gs.gateway import GcsGateway
from tests.unit.test_gateway_apps import GS_SYSID, VEHICLE_SYSID, MemTransport, StubStation
from zdrone.core import fcsign
from zdrone.core.fleet import ConfigError
from zdrone.core.mavcontrol import (MAV_CMD_REQUEST_OPERATOR_CONTROL, MAV_RESULT_NOT_IN_CONTROL,
                                    decode_control_status)
from zdrone.core.mavlink import FrameCodec, read_header

OPS_A = SigningKey("opsA", passphrase_key("opsA-pass-1"))
OPS_B = SigningKey("opsB", bytes(range(1, 33)))
UNSIGNED_PEER = ("127.0.0.1", 40042)
SIGNED_PEER = ("127.0.0.1", 40255)


# ------------------------------------------------------------------ the key file
def test_the_key_file_takes_hex_keys_passphrases_and_qgroundcontrol_passphrases(tmp_path):
    keys = parse_keys(["# operators of GS A", "", f"qgc1 hex:{'ab' * 32}", "mavproxy passphrase:one-word",
                       "bare another-word", "qgc2 qgc:a long passphrase with spaces"])
    assert [k.name for k in keys] == ["qgc1", "mavproxy", "bare", "qgc2"]
    assert keys[0].key == bytes([0xAB] * 32)
    assert keys[1].key == passphrase_key("one-word") and keys[2].key == passphrase_key("another-word")
    assert keys[3].key == qgc_passphrase_key("a long passphrase with spaces") != passphrase_key("a long passphrase with spaces")
    assert keys[1].identity == "key:mavproxy" and "one-word" not in repr(keys[1]) and keys[1].key.hex() not in repr(keys[1])


def test_the_passphrase_key_is_mavproxys():
    signing = pytest.importorskip("MAVProxy.modules.mavproxy_signing")
    assert passphrase_key("s3cret-Passphrase") == signing.SigningModule.passphrase_to_key(None, "s3cret-Passphrase")


@pytest.mark.parametrize("lines, error", [
    (["a hex:abcd"], "64 hex digits"),
    (["a hex:zz" + "0" * 62], "64 hex digits"),
    ([f"a hex:{'00' * 32}"], "all-zero"),
    (["a"], "no key"),
    (["bad/name x"], "application name"),
    (["a one", "a two"], "listed twice"),
    (["a same", "b same"], "same key as a"),
    ([f"k{i} pass-{i}" for i in range(MAX_KEYS + 1)], f"at most {MAX_KEYS}"),
])
def test_a_malformed_key_file_is_one_line_naming_the_line(lines, error):
    with pytest.raises(ConfigError, match=error) as exc:
        parse_keys(lines, "keys.txt")
    assert "\n" not in str(exc.value) and "keys.txt" in str(exc.value)


def test_a_key_file_readable_by_others_is_refused(tmp_path):
    path = tmp_path / "gcs-keys"
    path.write_text("opsA opsA-pass-1\n")
    os.chmod(path, 0o644)
    with pytest.raises(ConfigError, match=r"accessible by others \(mode 0644\); run chmod 600"):
        load_keys(path)
    os.chmod(path, 0o600)
    assert load_keys(path) == (OPS_A,)
    with pytest.raises(ConfigError, match="no such key file"):
        load_keys(tmp_path / "missing")


# ------------------------------------------------------------------ signatures and timestamps
def signer(key: bytes, sysid: int = 255, compid: int = 190, link: int = 0, ts: int | None = None) -> mav.MAVLink:
    """A pymavlink encoder that signs as an application does (``setup_signing``)."""
    m = mav.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    m.signing.secret_key, m.signing.sign_outgoing, m.signing.link_id = key, True, link
    m.signing.timestamp = fcsign.units(time.time()) if ts is None else ts
    return m


def signed(m: mav.MAVLink, msg: Any) -> bytes:
    return bytes(msg.pack(m))


def heartbeat() -> Any:
    return mav.MAVLink_heartbeat_message(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3)


def test_verify_takes_each_key_once_per_stream_timestamp_and_refuses_the_rest():
    s = AppSigning([OPS_B, OPS_A])
    now = fcsign.units(time.time())
    app = signer(OPS_A.key, ts=now)
    first, second = signed(app, heartbeat()), signed(app, heartbeat())
    assert s.verify(first, now) == (OPS_A, None)
    assert s.verify(first, now) == (None, "replay")
    assert s.verify(second, now) == (OPS_A, None)
    other_link = signer(OPS_A.key, link=7, ts=now - 100)  # another stream of the same key: its own timestamps
    assert s.verify(signed(other_link, heartbeat()), now) == (OPS_A, None)
    assert s.verify(signed(signer(os.urandom(32), ts=now), heartbeat()), now) == (None, "bad_signature")
    stale = signer(OPS_B.key, ts=now - 2 * fcsign.NEW_STREAM_WINDOW)
    assert s.verify(signed(stale, heartbeat()), now) == (None, "stale_stream")
    tampered = bytearray(signed(app, heartbeat()))
    tampered[12] ^= 1
    assert s.verify(bytes(tampered), now) == (None, "bad_signature")


def test_a_key_holders_future_timestamps_move_its_own_window_only():
    s = AppSigning([OPS_A, OPS_B])
    now = fcsign.units(time.time())
    assert s.verify(signed(signer(OPS_A.key, ts=now + 10**9), heartbeat()), now)[0] == OPS_A
    assert s.verify(signed(signer(OPS_B.key, ts=now), heartbeat()), now)[0] == OPS_B


def test_replies_signed_for_an_application_verify_in_pymavlink_with_its_key_only():
    s = AppSigning([OPS_A])
    now = fcsign.units(time.time())
    frame = FrameCodec(VEHICLE_SYSID, 1).encode(mav.MAVLink_heartbeat_message(2, 12, 0, 0, 4, 3))
    out = [s.sign(frame, "opsA", now) for _ in range(3)]
    app = mav.MAVLink(None)
    app.signing.secret_key, app.signing.timestamp = OPS_A.key, now
    assert [app.parse_char(f).get_type() for f in out] == ["HEARTBEAT"] * 3  # growing timestamps on one stream
    wrong = mav.MAVLink(None)
    wrong.signing.secret_key, wrong.signing.timestamp = OPS_B.key, now
    with pytest.raises(mav.MAVError, match="Invalid signature"):
        wrong.parse_char(out[0])


# ------------------------------------------------------------------ the gateway's policy
class NamingStation(StubStation):
    """A station whose operator entry takes the application's name (``station.operator_command``'s)."""

    def __init__(self) -> None:
        super().__init__()
        self.operator_calls: list[tuple[Any, str, int | None]] = []

    def operator_command(self, view: Any, req: Any, now: float, app: str = "", app_sysid: int | None = None) -> int:
        self.operator_calls.append((req, app, app_sysid))
        return mav.MAV_RESULT_ACCEPTED


class PeerTransport(MemTransport):
    """A UDP-like in-memory endpoint that knows its peers, as ``MavTransport`` does."""

    def __init__(self) -> None:
        super().__init__()
        self.udp_peers: dict[Any, float] = {}

    def deliver(self, frame: bytes, peer: Any) -> None:
        self.udp_peers[peer] = 0.0
        self.inbox.append((frame, peer))

    def to(self, peer: Any) -> list[bytes]:
        return [f for f, p in self.out if p == peer]


def make(mode: str, station: StubStation | None = None) -> tuple[GcsGateway, StubStation, PeerTransport]:
    station = station or NamingStation()
    gw = GcsGateway(station, [], signing=mode, keys=[OPS_A, OPS_B])
    t = PeerTransport()
    gw.transports = [t]
    return gw, station, t


def unsigned(msg: Any, sysid: int = 42) -> bytes:
    return FrameCodec(sysid, 190).encode(msg)


def consent() -> Any:
    return mav.MAVLink_command_long_message(VEHICLE_SYSID, 1, MAV_CMD_REQUEST_OPERATOR_CONTROL, 0, 0, 0, 10, 3, 0, 0, 0)


def arm() -> Any:
    return mav.MAVLink_command_long_message(VEHICLE_SYSID, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)


def pump(gw: GcsGateway, t: PeerTransport, frame: bytes, peer: Any) -> None:
    t.out.clear()
    t.deliver(frame, peer)
    gw.poll(time.monotonic())


def replies(t: PeerTransport, peer: Any, key: bytes | None = None) -> list[Any]:
    """What ``peer`` was sent, decoded as the application would (checking signatures with ``key``)."""
    app = mav.MAVLink(None)
    if key is not None:
        app.signing.secret_key, app.signing.timestamp = key, fcsign.units(time.time())
    out = []
    for f in t.to(peer):
        st = decode_control_status(f)
        out.append(st if st is not None else app.parse_char(f))
    return out


def acks(msgs: list[Any]) -> list[tuple[int, int]]:
    return [(m.command, m.result) for m in msgs if getattr(m, "get_type", lambda: "")() == "COMMAND_ACK"]


def test_require_an_unsigned_application_may_not_consent_command_or_write_but_reads():
    gw, station, t = make("require")
    pump(gw, t, unsigned(consent()), UNSIGNED_PEER)
    assert acks(replies(t, UNSIGNED_PEER)) == [(MAV_CMD_REQUEST_OPERATOR_CONTROL, mav.MAV_RESULT_DENIED)]
    assert station.operator_calls == [] and station.sent == []
    for p1, p2 in ((1, 1), (1, 0)):  # allow takeover, decline: every form of 32100
        pump(gw, t, unsigned(mav.MAVLink_command_long_message(1, 1, MAV_CMD_REQUEST_OPERATOR_CONTROL, 0, p1, p2, 10, 42,
                                                              0, 0, 0)), UNSIGNED_PEER)
    pump(gw, t, unsigned(arm()), UNSIGNED_PEER)
    assert acks(replies(t, UNSIGNED_PEER)) == [(mav.MAV_CMD_COMPONENT_ARM_DISARM, MAV_RESULT_NOT_IN_CONTROL)]
    pump(gw, t, unsigned(mav.MAVLink_mission_clear_all_message(1, 1, 0)), UNSIGNED_PEER)
    assert [m.type for m in replies(t, UNSIGNED_PEER) if m.get_type() == "MISSION_ACK"] == [mav.MAV_MISSION_DENIED]
    pump(gw, t, unsigned(mav.MAVLink_set_mode_message(1, 1, 6 << 16)), UNSIGNED_PEER)
    assert [m.get_type() for m in replies(t, UNSIGNED_PEER)] == ["STATUSTEXT"]
    assert station.operator_calls == [] and station.sent == []
    pump(gw, t, unsigned(mav.MAVLink_param_request_read_message(1, 1, b"NAV_DLL_ACT", -1)), UNSIGNED_PEER)
    assert [read_header(f).msgid for f in station.sent] == [mav.MAVLINK_MSG_ID_PARAM_REQUEST_READ]
    c = gw.counters
    assert (c["unsigned_refused:operator_control"], c["unsigned_refused:command"], c["unsigned_refused:mission"],
            c["unsigned_refused:other"]) == (3, 1, 1, 1)
    assert gw.stats()["signing"] == {"mode": "require", "keys": 2, "apps": {"100": "unsigned:127.0.0.1:40042"}}


def test_require_a_signed_application_consents_named_by_its_key_and_is_answered_signed():
    gw, station, t = make("require")
    app = signer(OPS_A.key)
    pump(gw, t, signed(app, consent()), SIGNED_PEER)
    (req, name, sysid), = station.operator_calls
    assert (req.request, name, sysid) == (False, "key:opsA", 255)
    got = replies(t, SIGNED_PEER, OPS_A.key)  # pymavlink with the key refuses anything unsigned or signed otherwise
    assert acks(got) == [(MAV_CMD_REQUEST_OPERATOR_CONTROL, mav.MAV_RESULT_ACCEPTED)]
    assert all(fcsign.is_signed(f) for f in t.to(SIGNED_PEER))
    pump(gw, t, signed(app, arm()), SIGNED_PEER)
    sent = station.sent[-1]
    assert not fcsign.is_signed(sent) and (read_header(sent).sysid, read_header(sent).compid) == (GS_SYSID, 100)
    pump(gw, t, signed(app, mav.MAVLink_command_long_message(1, 1, MAV_CMD_REQUEST_OPERATOR_CONTROL, 0, 1, 0, 10, 255,
                                                              0, 0, 0)), SIGNED_PEER)
    assert station.events.of("operator_control_requested") == [{"drone": "D1", "by_sysid": 255, "app": "key:opsA"}]


def test_wrongly_signed_replayed_and_stale_frames_are_dropped_counted_and_unanswered():
    gw, station, t = make("require")
    now = fcsign.units(time.time())
    good = signed(signer(OPS_A.key, ts=now), consent())
    for frame in (signed(signer(os.urandom(32)), consent()),  # a guessed key
                  signed(signer(OPS_B.key, ts=now - 3 * fcsign.NEW_STREAM_WINDOW), consent())):  # an old capture
        pump(gw, t, frame, UNSIGNED_PEER)
    pump(gw, t, good, SIGNED_PEER)
    pump(gw, t, good, SIGNED_PEER)  # the same frame again
    assert len(station.operator_calls) == 1 and t.to(SIGNED_PEER) == []
    assert {k: v for k, v in gw.counters.items() if k.startswith("signing_dropped")} == {
        "signing_dropped:bad_signature": 1, "signing_dropped:stale_stream": 1, "signing_dropped:replay": 1}
    assert len(gw.apps) == 1  # a frame no key signed makes no application
    pump(gw, t, unsigned(consent(), sysid=255), SIGNED_PEER)  # unsigned from where a signed application is
    assert gw.counters["signing_dropped:unsigned_after_signed"] == 1 and len(station.operator_calls) == 1


def test_telemetry_goes_signed_to_each_signed_application_and_as_it_is_to_the_others():
    gw, station, t = make("prefer")
    pump(gw, t, signed(signer(OPS_A.key), heartbeat()), SIGNED_PEER)
    pump(gw, t, signed(signer(OPS_B.key, sysid=250), heartbeat()), ("127.0.0.1", 40250))
    pump(gw, t, unsigned(heartbeat()), UNSIGNED_PEER)
    t.out.clear()
    position = FrameCodec(VEHICLE_SYSID, 1).encode(mav.MAVLink_global_position_int_message(1, 473977420, 85455940, 0,
                                                                                          0, 0, 0, 0, 0))
    gw.on_drone_frame("D1", position)
    assert t.to(UNSIGNED_PEER) == [position]
    assert [m.get_type() for m in replies(t, SIGNED_PEER, OPS_A.key)] == ["GLOBAL_POSITION_INT"]
    assert [m.get_type() for m in replies(t, ("127.0.0.1", 40250), OPS_B.key)] == ["GLOBAL_POSITION_INT"]


def test_control_status_never_names_an_unsigned_application_under_require():
    gw, station, t = make("require")
    pump(gw, t, signed(signer(OPS_A.key), heartbeat()), SIGNED_PEER)
    pump(gw, t, unsigned(heartbeat(), sysid=255), UNSIGNED_PEER)
    t.out.clear()
    gw._next_status = 0.0
    gw.poll(time.monotonic())
    mine = [m for m in replies(t, SIGNED_PEER, OPS_A.key) if not hasattr(m, "get_type")]
    theirs = [m for m in replies(t, UNSIGNED_PEER) if not hasattr(m, "get_type")]
    assert mine and mine[-1].gcs_main == 255  # the signed application is the one in control
    assert theirs and theirs[-1].gcs_main == GS_SYSID  # the unsigned one (same sysid 255) sees the GS, not itself


def test_prefer_an_unsigned_application_still_consents_named_by_its_address():
    gw, station, t = make("prefer")
    pump(gw, t, unsigned(consent()), UNSIGNED_PEER)
    assert [(name, sysid) for _, name, sysid in station.operator_calls] == [("unsigned:127.0.0.1:40042", 42)]
    pump(gw, t, signed(signer(os.urandom(32)), consent()), ("127.0.0.1", 40001))
    assert gw.counters["signing_dropped:bad_signature"] == 1 and len(station.operator_calls) == 1


def test_no_setup_signing_of_an_application_reaches_the_vehicle():
    gw, station, t = make("prefer")
    app = signer(OPS_A.key)
    pump(gw, t, signed(app, mav.MAVLink_setup_signing_message(1, 1, list(OPS_A.key), 1)), SIGNED_PEER)
    pump(gw, t, unsigned(mav.MAVLink_setup_signing_message(1, 1, list(os.urandom(32)), 1)), UNSIGNED_PEER)
    assert station.sent == [] and gw.counters["setup_signing_dropped"] == 2


def test_off_checks_no_signature_as_before():
    gw, station, t = make("off")
    pump(gw, t, signed(signer(os.urandom(32)), consent()), UNSIGNED_PEER)
    assert len(station.operator_calls) == 1 and not any(k.startswith("signing") for k in gw.counters)


def test_a_station_without_the_application_parameter_is_still_called():
    gw, station, t = make("require", StubStation())
    pump(gw, t, signed(signer(OPS_A.key), consent()), SIGNED_PEER)
    assert acks(replies(t, SIGNED_PEER, OPS_A.key)) == [(MAV_CMD_REQUEST_OPERATOR_CONTROL, mav.MAV_RESULT_ACCEPTED)]


# ------------------------------------------------------------------ the command line
@pytest.mark.parametrize("mode, args, error", [
    (0o644, ["--gcs-keys", "{keys}"], "accessible by others (mode 0644); run chmod 600"),
    (0o600, ["--gcs-keys", "{keys}", "--gcs-signing", "off"], "--gcs-keys with --gcs-signing off"),
    (0o600, ["--gcs-signing", "sometimes"], "invalid choice"),
])
def test_zdrone_gs_refuses_a_bad_signing_setup_in_one_line_before_connecting(tmp_path, mode, args, error):
    import subprocess
    import sys
    from pathlib import Path

    keys = tmp_path / "gcs-keys"
    keys.write_text("opsA opsA-pass-1\n")
    os.chmod(keys, mode)
    zdrone = str(Path(sys.executable).parent / "zdrone")
    out = subprocess.run([zdrone, "gs", "--id", "A", "--fleet", str(tmp_path / "none"), "--gcs", "udpin:127.0.0.1:1",
                          *[a.format(keys=keys) for a in args]], capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and error in out.stderr, out.stderr
    assert out.stderr.strip().count("\n") == 0 or "usage:" in out.stderr  # argparse prints its usage line first


def test_a_frame_the_gateway_signed_sent_back_is_never_the_applications_word():
    """Found from outside: the gateway signs the request it shows an application (COMMAND_LONG 32100 p1 = 1,
    p2 = 0, p4 = B, from the vehicle's ids) with that application's key; any local process that gets it
    (a socket bound to a silent application's udpout port) sent it back and it was taken as the operator's
    decline, named key:opsA."""
    gw, station, t = make("require")
    app = signer(OPS_A.key)
    pump(gw, t, signed(app, mav.MAVLink_heartbeat_message(mav.MAV_TYPE_GCS, 8, 0, 0, 0, 3)), SIGNED_PEER)
    shown = mav.MAVLink_command_long_message(255, 190, MAV_CMD_REQUEST_OPERATOR_CONTROL, 0, 1, 0, 10, 3, 0, 0, 0)
    codec = FrameCodec(VEHICLE_SYSID, 1)
    t.out.clear()
    gw._to_app(next(iter(gw.apps)), codec.encode(shown))  # as _operator_poll presents a request
    [reflected] = t.to(SIGNED_PEER)
    assert fcsign.is_signed(reflected)
    for peer in (SIGNED_PEER, ("127.0.0.1", 40999)):
        pump(gw, t, reflected, peer)
    assert station.operator_calls == [] and gw.counters["vehicle_sysid"] == 2
    # the same frame re-made under the application's own ids but still signed by the gateway's stream
    assert gw.signing.verify(gw.signing.sign(unsigned(shown, sysid=255), "opsA", fcsign.units(time.time()), 0),
                             fcsign.units(time.time()))[1] == "reflected"


def test_a_request_for_control_not_addressed_to_the_vehicle_is_dropped():
    gw, station, t = make("require")
    app = signer(OPS_A.key)
    pump(gw, t, signed(app, mav.MAVLink_command_long_message(255, 190, MAV_CMD_REQUEST_OPERATOR_CONTROL, 0, 1, 0, 10,
                                                              3, 0, 0, 0)), SIGNED_PEER)
    assert station.operator_calls == [] and gw.counters["operator_request_not_for_vehicle"] == 1


# ------------------------------------------------------------------ a full table (issue: the unsigned flood)
def test_an_unsigned_flood_of_every_place_never_keeps_the_operators_signed_application_out():
    """Found from outside: an unsigned local process sending 32 frames/s from 16 sockets held all 16
    places; the operator's signed application, started then, was refused 10 of 10 times."""
    gw, station, t = make("require")
    flooders = [("127.0.0.1", 45000 + i) for i in range(16)]
    now, n = 0.0, 0
    for attempt in range(10):
        for _ in range(32):  # a second of the flood
            gw.on_app_frame(0, flooders[n % 16], unsigned(heartbeat(), sysid=42 + n % 16), now)
            n, now = n + 1, now + 1 / 32
        assert len(gw.apps) == 16
        peer = ("127.0.0.1", 41000 + attempt)  # the operator's application, started anew (a new stream)
        t.out.clear()
        gw.on_app_frame(0, peer, signed(signer(OPS_A.key, link=attempt), consent()), now)
        assert acks(replies(t, peer, OPS_A.key)) == [(MAV_CMD_REQUEST_OPERATOR_CONTROL, mav.MAV_RESULT_ACCEPTED)]
    assert [name for _, name, _ in station.operator_calls] == ["key:opsA"] * 10
    assert gw.counters["app_evicted"] == 10 and gw.counters["app_table_full"] > 0
    assert [e["reason"] for e in station.events.of("gcs_app_gone")] == ["evicted"] * 10


# ------------------------------------------------------------------ the replay state across restarts
class Wall:
    """The wall clock the gateway signs and checks by, moved by hand."""

    def __init__(self) -> None:
        self.t = time.time()

    def __call__(self) -> float:
        return self.t


def start(state: Any, wall: Wall, keys: tuple[SigningKey, ...] = (OPS_A, OPS_B)) -> tuple[GcsGateway, NamingStation, PeerTransport]:
    station = NamingStation()
    gw = GcsGateway(station, [], signing="require", keys=keys, clock=wall, state_path=state)
    t = PeerTransport()
    gw.transports = [t]
    return gw, station, t


@pytest.mark.parametrize("how", ["stopped", "crashed a second later"])
def test_a_signed_frame_replayed_after_the_gs_restarts_is_still_a_replay(tmp_path, how):
    """Found from outside: a signed frame of an application that then went silent, replayed 5-10 s after
    it was made, was taken after the GS restarted (3 of 3): the replay state lived in memory only."""
    state, wall = tmp_path / "gcs-keys.A.signing-state.json", Wall()
    gw, station, t = start(state, wall)
    app = signer(OPS_A.key, ts=fcsign.units(wall.t))
    gw.on_app_frame(0, SIGNED_PEER, signed(app, heartbeat()), 0.0)
    gw.poll(0.1)

    def saved() -> list[int]:
        return [st[3] for k in json.loads(state.read_text())["keys"].values() for st in k["streams"]]

    first = saved()
    captured = signed(app, consent())
    gw.on_app_frame(0, SIGNED_PEER, captured, 0.2)
    gw.poll(0.3)
    assert len(station.operator_calls) == 1 and saved() == first  # written at most once a second
    if how == "stopped":
        gw.close()
    else:
        gw.poll(1.1)  # the next write; then the process dies
    assert saved() == [fcsign.read_signature(captured).timestamp] != first
    wall.t += 7.0
    gw, station, t = start(state, wall)
    for peer in (SIGNED_PEER, UNSIGNED_PEER):
        gw.on_app_frame(0, peer, captured, 0.0)
    assert station.operator_calls == [] and gw.counters["signing_dropped:replay"] == 2 and len(gw.apps) == 0
    gw.on_app_frame(0, SIGNED_PEER, signed(app, consent()), 0.1)  # the application itself goes on
    assert [name for _, name, _ in station.operator_calls] == ["key:opsA"]
    assert state.stat().st_mode & 0o077 == 0


def test_a_replay_state_that_cannot_be_read_is_not_trusted(tmp_path, caplog):
    state, wall = tmp_path / "state.json", Wall()
    state.write_text('{"version": 1, "keys": {"x": ')
    captured = signed(signer(OPS_A.key, ts=fcsign.units(wall.t - 5.0)), consent())  # made before the start
    with caplog.at_level(logging.WARNING, logger="gs.gateway"):
        gw, station, t = start(state, wall)
    assert gw.counters["signing_state_unreadable"] == 1 and "not trusted" in caplog.text
    gw.on_app_frame(0, SIGNED_PEER, captured, 0.0)
    assert station.operator_calls == [] and gw.counters["signing_dropped:before_start"] == 1
    gw.on_app_frame(0, SIGNED_PEER, signed(signer(OPS_A.key, link=1, ts=fcsign.units(wall.t)), consent()), 0.1)
    assert len(station.operator_calls) == 1
    assert json.loads(state.read_text())["version"] == 1  # written anew at the start


def test_a_replay_state_that_cannot_be_written_stops_the_gs_at_start(tmp_path):
    (tmp_path / "file").write_text("")
    with pytest.raises(ConfigError, match="cannot write the GCS signing replay state.*ZDRONE_STATE_DIR"):
        start(tmp_path / "file" / "state.json", Wall())


def test_the_replay_state_keeps_only_listed_keys_and_goes_to_the_state_directory(tmp_path, monkeypatch):
    s = AppSigning([OPS_A, OPS_B])
    now = fcsign.units(time.time())
    assert s.verify(signed(signer(OPS_A.key, ts=now), heartbeat()), now)[0] == OPS_A
    snap = json.loads(json.dumps(s.snapshot()))
    assert list(snap["keys"]) == [OPS_A.fingerprint] and OPS_A.key.hex() not in json.dumps(snap)
    other = AppSigning([OPS_B, SigningKey("renamed", OPS_A.key)])  # a key is known by its bytes, not its name
    assert other.restore(snap) == 1
    assert other.verify(signed(signer(OPS_A.key, ts=now), heartbeat()), now) == (None, "replay")
    for bad in ({"version": 2, "keys": {}}, {"version": 1, "keys": {OPS_B.fingerprint: {"streams": [[0, 1, 2, -1]]}}},
                {"version": 1, "keys": {OPS_B.fingerprint: {"own": [[0, 300, 1]]}}}, []):
        with pytest.raises(ValueError):
            AppSigning([OPS_B]).restore(bad)
    assert signing_state_path(tmp_path / "gcs-keys.A", "A") == tmp_path / "gcs-keys.A.signing-state.json"
    monkeypatch.setenv("ZDRONE_STATE_DIR", str(tmp_path / "state"))
    assert signing_state_path(tmp_path / "gcs-keys.A", "A") == tmp_path / "state" / "A.gcs-signing.json"


# ------------------------------------------------------------------ one key, one GS
def key_file(path: Any, text: str) -> Any:
    path.write_text(text)
    os.chmod(path, 0o600)
    return path


def test_a_key_another_gs_of_the_fleet_also_holds_is_refused(tmp_path):
    """Found from outside: the same application key in A's and B's key files: a PARAM_SET B refused,
    replayed to A, was applied (8.0 -> 9.0, 3 of 3). A signed frame names no receiver, so a GS refuses
    a key another GS's key file beside its own also holds."""
    a = key_file(tmp_path / "gcs-keys.A", "gs: A\nmavproxy opsA-10f283b85121951b4fad2d49\n")
    key_file(tmp_path / "gcs-keys.B", "ops opsA-10f283b85121951b4fad2d49\n")
    with pytest.raises(ConfigError, match=r"application mavproxy's key is also GS B's \(ops in .*gcs-keys.B\)") as exc:
        load_gs_keys(a, "A", others=["A", "B", "X"])
    assert "\n" not in str(exc.value)
    key_file(tmp_path / "gcs-keys.B", f"ops hex:{'5a' * 32}\n")
    assert [k.name for k in load_gs_keys(a, "A", others=["A", "B", "X"])] == ["mavproxy"]
    with pytest.raises(ConfigError, match="key file is for GS A .*not B"):
        load_gs_keys(a, "B", others=["A", "B"])  # the whole file copied to B
    plain = key_file(tmp_path / "gcs-keys", f"opsB hex:{'5a' * 32}\n")  # no GS suffix: gcs-keys.<other> beside it
    with pytest.raises(ConfigError, match="also GS B's"):
        load_gs_keys(plain, "A", others=["B"])


def test_zdrone_gs_refuses_a_key_another_gs_holds_in_one_line_before_connecting(tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    from zdrone.fleet.files import init_fleet

    init_fleet(tmp_path / "fleet")
    a = key_file(tmp_path / "fleet" / "gcs-keys.A", f"qgc hex:{'c3' * 32}\n")
    key_file(tmp_path / "fleet" / "gcs-keys.B", f"qgc-b hex:{'c3' * 32}\n")
    zdrone = str(Path(sys.executable).parent / "zdrone")
    out = subprocess.run([zdrone, "gs", "--id", "A", "--fleet", str(tmp_path / "fleet"), "--router", "tcp/127.0.0.1:1",
                          "--gcs", "udpin:127.0.0.1:1", "--gcs-keys", str(a)], capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "also GS B's" in out.stderr and out.stderr.strip().count("\n") == 0, out.stderr


# ------------------------------------------------------------------ whose file it is
def test_a_key_file_through_a_symlink_or_of_another_user_is_refused(tmp_path, monkeypatch):
    """Found from outside: a 0600 key file owned by another user, or a symlink to one, was taken by a GS
    running as root."""
    real = key_file(tmp_path / "real", "opsA opsA-pass-1\n")
    link = tmp_path / "gcs-keys"
    link.symlink_to(real)
    with pytest.raises(ConfigError, match="symbolic link"):
        load_keys(link)
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo, 0o600)
    with pytest.raises(ConfigError, match="not a regular file"):
        load_keys(fifo)
    if os.geteuid() == 0:
        os.chown(real, 65534, 65534)  # another user's file, the GS running as root
    else:
        monkeypatch.setattr(os, "geteuid", lambda: real.stat().st_uid + 1)  # the GS running as another user
    with pytest.raises(ConfigError, match=r"owned by uid \d+, not by the GS's user \(uid \d+\) or root") as exc:
        load_keys(real)
    assert "\n" not in str(exc.value)
    if os.geteuid() == 0:  # a root-owned file is any GS's (root could read it anyway)
        os.chown(real, 0, 0)
        monkeypatch.setattr(os, "geteuid", lambda: 1000)
        assert load_keys(real) == (OPS_A,)


# ------------------------------------------------------------------ the documented example; passphrase strength
def _gcs_doc():
    """The page that documents signed applications (it was the README's until the docs moved)."""
    from pathlib import Path

    return Path(__file__).resolve().parents[2] / "docs" / "gcs.md"


def documented_key_file() -> list[str]:
    blocks: list[list[str]] = []
    inside = False
    for line in _gcs_doc().read_text().splitlines():
        if line.startswith("```"):
            inside = not inside
            if inside:
                blocks.append([])
        elif inside:
            blocks[-1].append(line)
    block, = [b for b in blocks if b and b[0].startswith("# fleet/gcs-keys.A")]
    return block


def test_the_documented_key_file_example_works_as_it_stands(tmp_path):
    """Found from outside: the README's example (now in docs/gcs.md) failed: its trailing '#' comments
    became part of the passphrase (the MAVProxy line made another key) and its hex line was refused at start."""
    import hashlib

    lines = documented_key_file()
    kf = parse_key_file(lines, "docs/gcs.md")
    assert kf.gs == "A" and [k.name for k in kf.keys] == ["mavproxy", "qgc", "qgc-pass", "script"]
    doc = _gcs_doc().read_text()
    mavproxy_pass, = set(re.findall(r'--cmd="signing key (\S+)"', doc))
    assert kf.keys[0].key == passphrase_key(mavproxy_pass) == hashlib.sha256(mavproxy_pass.encode()).digest()
    assert kf.keys[2].key == qgc_passphrase_key("harbor-4e1d-lantern-9b2c-ribbon-07fa")
    assert weak_keys(kf.keys) == []  # the example is what the GS asks for
    path = key_file(tmp_path / "gcs-keys.A", "\n".join(lines) + "\n")
    assert load_gs_keys(path, "A", others=["A", "B"]) == kf.keys


def test_a_comment_after_a_blank_is_not_part_of_the_key():
    keys = parse_keys(["m   pass-x   # MAVProxy", "h hex:" + "ab" * 32 + "  # raw", "q qgc:two words # note",
                       "w pass#word"])
    assert keys[0].key == passphrase_key("pass-x") and keys[1].key == bytes([0xAB] * 32)
    assert keys[2].key == qgc_passphrase_key("two words") and keys[3].key == passphrase_key("pass#word")


def test_a_weak_passphrase_is_reported_with_the_strength_wanted(tmp_path, caplog):
    """Found from outside: a passphrase of ~40 random bits was taken without a word, though one captured
    frame allows an offline search (one SHA-256 a guess)."""
    assert passphrase_bits("5f1c9e27b1") == 40 and passphrase_bits("opsA-5f1c9e27b1") < STRONG_BITS
    assert passphrase_bits("10f283b85121951b4fad2d49") == 96 and passphrase_bits("correct horse battery staple") < 60
    keys = parse_keys(["weak opsA-5f1c9e27b1", "strong opsA-10f283b85121951b4fad2d49", f"raw hex:{'ab' * 32}",
                       "qweak qgc:short-words-only"])
    assert [k.name for k in weak_keys(keys)] == ["weak", "qweak"] and keys[2].bits is None
    assert keys[3].bits == pytest.approx(passphrase_bits("short-words-only") + math.log2(600_000))
    msg = weak_key_warning(keys[0], "gcs-keys.A")
    assert "about 49 bits" in msg and "80" in msg and "openssl rand -hex 16" in msg and "opsA-5f1c" not in msg
    import subprocess
    import sys
    from pathlib import Path

    path = key_file(tmp_path / "gcs-keys", "weak opsA-5f1c9e27b1\n")
    zdrone = str(Path(sys.executable).parent / "zdrone")
    out = subprocess.run([zdrone, "gs", "--id", "A", "--fleet", str(tmp_path / "none"), "--gcs", "udpin:127.0.0.1:1",
                          "--gcs-keys", str(path)], capture_output=True, text=True, timeout=60)
    assert "application weak: passphrase of about 49 bits" in out.stderr, out.stderr
