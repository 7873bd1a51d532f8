"""Authenticated operator applications, end to end with clients nobody here wrote: MAVProxy with its
signing module and a pymavlink application with ``setup_signing`` consent through GS A's gateway under
``--gcs-signing require``; an unsigned local application (a fresh UDP socket, sysid 42, the attack
of issue 29) cannot (real router, simulator, drone node and both ground stations as processes).

The vehicle stands in the overlap of A's and B's coverages (the simulator's home 250 m east of A), so
B links on the ground and its request for control reaches A's operator without a flight.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable

import pytest
from pymavlink.dialects.v20 import common as mav

from gs.appkeys import passphrase_key
from tests.mavproxy import MavProxy
from tests.procs import ZDRONE, free_port, spawn, wait_until
from zdrone.core import fcsign
from zdrone.core.geometry import offset
from zdrone.core.mavcontrol import MAV_CMD_REQUEST_OPERATOR_CONTROL, MAV_RESULT_NOT_IN_CONTROL, decode_control_status
from zdrone.core.reference import HOME
from zdrone.fleet.files import init_fleet
from zdrone.net.eventlog import read_events

MAVPROXY_PASSPHRASE = "opsA-mavproxy-7c1e"
PYAPP_KEY = bytes.fromhex("5a" * 16 + "c3" * 16)
A_SYSID, B_SYSID = 4, 3
OVERLAP = offset(HOME, 0.0, 250.0)  # inside both coverages (A at 0 m, B at 500 m, 350 m each)


@contextlib.contextmanager
def signed_stack(tmp: Path):
    """Router, simulator at the overlap, drone, B (gateway, default signing), A (pairs; gateway with
    ``--gcs-signing require`` and a key file of two applications)."""
    init_fleet(tmp / "fleet")
    keys = tmp / "gcs-keys"
    keys.write_text(f"# GS A's operator applications\nmavproxy {MAVPROXY_PASSPHRASE}\npyapp hex:{PYAPP_KEY.hex()}\n")
    os.chmod(keys, 0o600)
    rport, sport, pa, pb = free_port(socket.SOCK_STREAM), free_port(), free_port(), free_port()
    router = f"tcp/127.0.0.1:{rport}"
    common = ["--fleet", str(tmp / "fleet"), "--router", router]
    with contextlib.ExitStack() as es:
        r = es.enter_context(spawn(ZDRONE, "router", "-c", str(tmp / "fleet/router/router.json5"), "--listen", router))
        r.wait_line("listening", 20)
        sim = es.enter_context(spawn(ZDRONE, "sim", "--mavlink", f"udpin:127.0.0.1:{sport}", "--speedup", "2",
                                     "--home", f"{OVERLAP.lat},{OVERLAP.lon}"))
        sim.wait_line("zdrone sim:", 20)
        drone = es.enter_context(spawn(ZDRONE, "drone", *common, "--vehicle", f"udpout:127.0.0.1:{sport}",
                                       "--sil-coverage", "--events", str(tmp / "drone.jsonl")))
        drone.wait_line("ready", 40)
        b = es.enter_context(spawn(ZDRONE, "gs", "--id", "B", *common, "--gcs", f"udpin:127.0.0.1:{pb}",
                                   "--events", str(tmp / "B.jsonl")))
        b.wait_line("GCS gateway", 20)
        a = es.enter_context(spawn(ZDRONE, "gs", "--id", "A", *common, "--pair", "--gcs", f"udpin:127.0.0.1:{pa}",
                                   "--gcs-keys", str(keys), "--events", str(tmp / "A.jsonl")))
        a.wait_line("GCS signing require, 2 application key(s)", 20)
        a.wait_line("paired", 30)
        yield {"a": pa, "b": pb, "gs_a": a}


class App:
    """A MAVLink application on a gateway's udpin port: pymavlink messages, signed with ``key`` (as
    ``setup_signing`` does) or not; what comes back is checked with the same key."""

    def __init__(self, port: int, sysid: int, key: bytes | None = None) -> None:
        self.sysid = sysid
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.connect(("127.0.0.1", port))
        self.sock.settimeout(0.1)
        self.enc = mav.MAVLink(None, srcSystem=sysid, srcComponent=190)
        self.dec = mav.MAVLink(None)
        if key is not None:
            for m in (self.enc, self.dec):
                m.signing.secret_key, m.signing.timestamp = key, fcsign.units(time.time())
            self.enc.signing.sign_outgoing = True
        self.status: Any = None
        self.got: list[Any] = []
        self.frames: list[bytes] = []
        self.bad = 0  # frames refused by our own signature check
        self.last_hb = 0.0

    def send(self, msg: Any) -> None:
        self.sock.send(bytes(msg.pack(self.enc)))

    def command(self, command: int, *p: float) -> float:
        since = time.monotonic()
        params = list(p) + [0.0] * (7 - len(p))
        self.send(mav.MAVLink_command_long_message(1, 1, command, 0, *params))
        return since

    def pump(self, seconds: float = 0.1) -> None:
        end = time.monotonic() + seconds
        while True:
            now = time.monotonic()
            if now - self.last_hb >= 1.0:
                self.last_hb = now
                self.send(mav.MAVLink_heartbeat_message(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))
            try:
                data = self.sock.recv(65536)
            except (socket.timeout, ConnectionRefusedError):
                data = b""
            if data:
                self.frames.append(data)
                st = decode_control_status(data)
                if st is not None:
                    self.status = st
                else:
                    try:
                        msg = self.dec.parse_char(data)
                    except mav.MAVError:
                        self.bad += 1
                        msg = None
                    if msg is not None:
                        self.got.append((now, msg))
            if time.monotonic() >= end:
                return

    def wait(self, what: str, cond: Callable[[], Any], timeout: float) -> Any:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.pump(0.1)
            got = cond()
            if got:
                return got
        raise AssertionError(f"{what}: not within {timeout} s (status {self.status}, last {[m for _, m in self.got[-5:]]})")

    def msgs(self, kind: str, since: float = 0.0) -> list[Any]:
        return [m for t, m in self.got if t >= since and m.get_type() == kind]

    def acks(self, command: int, since: float) -> list[int]:
        return [m.result for m in self.msgs("COMMAND_ACK", since) if m.command == command]

    def in_control(self) -> int | None:
        return None if self.status is None else self.status.gcs_main

    def close(self) -> None:
        self.sock.close()


def _gateway_status(events: list[dict[str, Any]]) -> dict[str, Any]:
    st = [e for e in events if e["type"] in ("status", "stop") and isinstance(e.get("gateway"), dict)]
    return st[-1]["gateway"] if st else {}


@pytest.mark.slow
def test_only_signed_applications_consent_mavproxy_with_a_key_does_an_unsigned_local_process_cannot(tmp_path):
    with signed_stack(tmp_path) as ports:
        b_app = App(ports["b"], 255)  # B's operator (B's gateway: no keys, prefer)
        signed_app = App(ports["a"], 250, PYAPP_KEY)  # one of A's operator applications, with its key
        attacker = App(ports["a"], 42)  # any local process: a fresh UDP socket, sysid 42, no key
        cwd = tmp_path / "mavproxy"
        cwd.mkdir()
        mp = None
        try:
            apps = (b_app, signed_app, attacker)

            def pump_all(seconds: float = 0.05) -> None:
                for app in apps:
                    app.pump(seconds / len(apps))

            # B links on the ground (the vehicle is in its coverage); A's applications see who is in control
            b_app.wait("B's application sees the vehicle", lambda: b_app.msgs("HEARTBEAT"), 60)
            signed_app.wait("the signed application sees itself in control", lambda: signed_app.in_control() == 250, 20)
            attacker.wait("the unsigned one sees A (never itself)", lambda: attacker.in_control() == A_SYSID, 10)
            assert signed_app.bad == 0 and signed_app.msgs("HEARTBEAT")  # telemetry, signed with its key
            assert all(fcsign.is_signed(f) for f in signed_app.frames[-20:])

            # read-only access stays for the unsigned application; commands are the signed one's
            since = attacker.command(mav.MAV_CMD_REQUEST_MESSAGE, mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
            signed_since = signed_app.command(mav.MAV_CMD_REQUEST_MESSAGE, mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
            attacker.send(mav.MAVLink_param_request_read_message(1, 1, b"NAV_DLL_ACT", -1))
            signed_app.wait("the signed application's command answered by the vehicle",
                            lambda: signed_app.acks(mav.MAV_CMD_REQUEST_MESSAGE, signed_since), 10)
            assert signed_app.acks(mav.MAV_CMD_REQUEST_MESSAGE, signed_since)[0] == mav.MAV_RESULT_ACCEPTED
            attacker.wait("the unsigned command refused", lambda: attacker.acks(mav.MAV_CMD_REQUEST_MESSAGE, since), 5)
            assert attacker.acks(mav.MAV_CMD_REQUEST_MESSAGE, since) == [MAV_RESULT_NOT_IN_CONTROL]
            attacker.wait("a parameter read answered", lambda: attacker.msgs("PARAM_VALUE", since), 10)

            # B asks for control: A's operator is asked, every application on A shown the request
            asked = b_app.command(MAV_CMD_REQUEST_OPERATOR_CONTROL, 1, 0, 30, 255)
            b_app.wait("B's request answered", lambda: b_app.acks(MAV_CMD_REQUEST_OPERATOR_CONTROL, asked), 5)
            assert b_app.acks(MAV_CMD_REQUEST_OPERATOR_CONTROL, asked)[0] == mav.MAV_RESULT_FAILED
            shown = attacker.wait("the request shown to the local process too", lambda: [
                m for m in attacker.msgs("COMMAND_LONG", asked) if m.command == MAV_CMD_REQUEST_OPERATOR_CONTROL], 10)
            assert shown[0].param4 == B_SYSID

            # issue 29, attack 1: the local process consents (and allows takeover, and commands): refused
            tried = attacker.command(MAV_CMD_REQUEST_OPERATOR_CONTROL, 0, 0, 0, B_SYSID)
            attacker.command(MAV_CMD_REQUEST_OPERATOR_CONTROL, 1, 1, 10, B_SYSID)
            attacker.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
            forged = mav.MAVLink(None, srcSystem=42, srcComponent=190)  # and signed with a guessed key
            forged.signing.secret_key, forged.signing.sign_outgoing = os.urandom(32), True
            forged.signing.timestamp = fcsign.units(time.time())
            attacker.sock.send(bytes(mav.MAVLink_command_long_message(1, 1, MAV_CMD_REQUEST_OPERATOR_CONTROL, 0, 0, 0, 0,
                                                                        B_SYSID, 0, 0, 0).pack(forged)))
            attacker.wait("both forms of consent refused",
                          lambda: len(attacker.acks(MAV_CMD_REQUEST_OPERATOR_CONTROL, tried)) >= 2, 5)
            assert attacker.acks(MAV_CMD_REQUEST_OPERATOR_CONTROL, tried)[:2] == [mav.MAV_RESULT_DENIED] * 2
            attacker.wait("the arm refused", lambda: attacker.acks(mav.MAV_CMD_COMPONENT_ARM_DISARM, tried), 5)
            assert attacker.acks(mav.MAV_CMD_COMPONENT_ARM_DISARM, tried) == [MAV_RESULT_NOT_IN_CONTROL]
            end = time.monotonic() + 3.0
            while time.monotonic() < end:  # nothing moves: B still sees A in control
                pump_all()
                assert b_app.in_control() == A_SYSID, b_app.status
            assert len(attacker.acks(MAV_CMD_REQUEST_OPERATOR_CONTROL, tried)) == 2  # the forged one got no answer

            # MAVProxy with its key (the signing module, 'signing key <passphrase>') consents: B takes control
            mp = MavProxy(ports["a"], cwd, "signing,cmdlong", sysid=251, cmd=f"signing key {MAVPROXY_PASSPHRASE}")
            assert mp.wait_for("Setup signing key", 20), mp.text()
            assert mp.wait_for("Detected vehicle 1:1", 30), mp.text()
            mp.type(f"long 32100 0 0 0 {B_SYSID}")
            b_app.wait("B in control after MAVProxy's consent", lambda: b_app.in_control() == 255, 15)
            assert mp.wait_for("COMMAND_ACK {command : 32100, result : 0", 5), mp.text()  # ACCEPTED
            signed_app.wait("A's signed application sees B in control", lambda: signed_app.in_control() == B_SYSID, 5)
        finally:
            if mp is not None:
                mp.stop()
            for app in (b_app, signed_app, attacker):
                app.close()
    a_events = read_events(tmp_path / "A.jsonl")
    granted = [e for e in a_events if e["type"] == "operator_request_granted"]
    assert [(e["to"], e.get("app")) for e in granted] == [("B", "key:mavproxy")], granted
    gw = _gateway_status(a_events)
    counters = gw.get("counters", {})
    assert counters.get("unsigned_refused:operator_control", 0) >= 2 and counters.get("unsigned_refused:command", 0) >= 2
    assert counters.get("signing_dropped:bad_signature", 0) >= 1
    assert "key:mavproxy" in gw["signing"]["apps"].values() and gw["signing"]["mode"] == "require"
    moved = [e for e in read_events(tmp_path / "drone.jsonl") if e["type"] in ("handover_complete", "authority_moved")]
    assert moved and all(e.get("to", "B") == "B" for e in moved)


@pytest.mark.slow
# on ArduPilot: the gateway's rules are the autopilot's business only in what reaches the vehicle, and PX4
# flies the other gateway tests (the suite's 10 minutes)
@pytest.mark.parametrize("autopilot", ["ardupilot"])
def test_local_app_scenario_nothing_the_unsigned_application_sends_moves_authority_or_reaches_the_vehicle(tmp_path,
                                                                                                         autopilot):
    from tests.integration.test_flight_e2e import run_demo

    s, out = run_demo(tmp_path, "local-app", autopilot=autopilot)
    assert s["_rc"] == 0 and s["ok"], s["why_not_ok"]
    done = next(e for e in read_events(out / "rogue.jsonl") if e["type"] == "attack_done")
    assert done["shown_p4"] == B_SYSID and done["accepted"] == 0 and not done["b_in_control"]
    assert done["answers"][f"{MAV_CMD_REQUEST_OPERATOR_CONTROL}:{mav.MAV_RESULT_DENIED}"] == 2 * done["sent"]["consent"]
    assert done["signed_command"] == mav.MAV_RESULT_ACCEPTED and done["resumed"] is True
    assert [(h["from"], h["to"]) for h in s["handovers"]] == [("A", "B"), ("B", "A")]
    assert (out / "gcs-keys").stat().st_mode & 0o077 == 0
    a_log = (out / "gsA.log").read_text()
    assert "GCS signing require, 1 application key(s)" in a_log and "signs with key opsA" in a_log
    assert "unsigned:127.0.0.1:" in a_log  # the refusals name the application


@pytest.mark.slow
def test_a_flood_keeps_no_signed_application_out_and_a_frame_captured_before_a_restart_is_a_replay_after(tmp_path):
    """GS A as a process (router, no drone: the gateway's checks come before any link): an unsigned local
    process holds every place of the table from 16 sockets, and A's signed application, started then,
    still gets in, each of 3 times. Its last request for control is captured; A is killed (no clean
    stop) once its replay state holds it, and started again; the capture, replayed well within the
    minute a new stream is given, is a replay (it was taken after a restart before)."""
    tmp = tmp_path
    init_fleet(tmp / "fleet")
    keys = tmp / "gcs-keys"
    keys.write_text(f"pyapp hex:{PYAPP_KEY.hex()}\n")
    os.chmod(keys, 0o600)
    state = tmp / "gcs-keys.signing-state.json"
    rport, pa = free_port(socket.SOCK_STREAM), free_port()
    router = f"tcp/127.0.0.1:{rport}"
    gs_args = ["gs", "--id", "A", "--fleet", str(tmp / "fleet"), "--router", router, "--gcs", f"udpin:127.0.0.1:{pa}",
               "--gcs-keys", str(keys)]
    hb = mav.MAVLink_heartbeat_message(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3)
    flood = [App(pa, 100 + i) for i in range(16)]
    replayer = App(pa, 42)

    def request(app: App) -> bytes:
        return bytes(mav.MAVLink_command_long_message(1, 1, MAV_CMD_REQUEST_OPERATOR_CONTROL, 0, 1, 0, 10, 0, 0, 0,
                                                      0).pack(app.enc))

    def answered(app: App, frame: bytes) -> None:
        since = time.monotonic()
        app.sock.send(frame)
        app.wait("the signed application answered", lambda: app.acks(MAV_CMD_REQUEST_OPERATOR_CONTROL, since), 10)

    def stream_saved(sig: Any) -> bool:
        try:
            saved = json.loads(state.read_text())["keys"]
        except (OSError, ValueError, KeyError):
            return False
        return any(s[:3] == [sig.link_id, sig.sysid, sig.compid] and s[3] >= sig.timestamp
                   for k in saved.values() for s in k["streams"])

    try:
        with spawn(ZDRONE, "router", "-c", str(tmp / "fleet/router/router.json5"), "--listen", router) as r:
            r.wait_line("listening", 20)
            with spawn(ZDRONE, *gs_args, "--events", str(tmp / "A1.jsonl")) as a:
                a.wait_line("GCS signing require, 1 application key(s)", 30)
                for attempt in range(3):
                    for _ in range(2):  # a second of the flood: 32 frames from the 16 sockets
                        for f in flood:
                            f.send(hb)
                    app = App(pa, 250, PYAPP_KEY)
                    app.enc.signing.link_id = attempt  # started anew: a stream of its own
                    captured = request(app)
                    answered(app, captured)
                    app.close()
                made = time.monotonic()
                assert wait_until(lambda: stream_saved(fcsign.read_signature(captured)), 10)
                a.p.kill()  # a crash: no clean stop
                a.p.wait(10)
            with spawn(ZDRONE, *gs_args, "--events", str(tmp / "A2.jsonl")) as a:
                a.wait_line("GCS signing require", 30)
                since = time.monotonic()
                replayer.sock.send(captured)
                app = App(pa, 250, PYAPP_KEY)
                app.enc.signing.link_id = 3
                answered(app, request(app))  # served after the replay: the replay has been judged
                app.close()
                replayer.pump(0.2)
                assert replayer.acks(MAV_CMD_REQUEST_OPERATOR_CONTROL, since) == []
                assert time.monotonic() - made < 0.5 * fcsign.NEW_STREAM_WINDOW / fcsign.UNITS_PER_S
    finally:
        for f in (*flood, replayer):
            f.close()
    first = read_events(tmp / "A1.jsonl")
    assert len([e for e in first if e["type"] == "operator_control_requested"]) == 3
    assert len([e for e in first if e["type"] == "gcs_app_gone" and e["reason"] == "evicted"]) == 3
    second = read_events(tmp / "A2.jsonl")
    assert len([e for e in second if e["type"] == "operator_control_requested"]) == 1  # the new stream's only
    assert _gateway_status(second)["counters"].get("signing_dropped:replay") == 1
