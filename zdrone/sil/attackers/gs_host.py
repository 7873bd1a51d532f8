"""TESTBED ONLY: a local process on GS A's host, without any key: it reaches A's GCS gateway (a
UDP port on the host) as any application there can.

``gateway-flood``: a local process on GS A's machine (no credentials). Sends HEARTBEATs from 300+
distinct UDP source ports and garbage datagrams to A's GCS gateway; A must keep flying and count
the applications it refused (``app_table_full``).

``local-app``: a local process on GS A's machine (no key), an unsigned MAVLink application on A's GCS
gateway (``--gcs-port``; A runs ``--gcs-signing require``). When told to attack (A holds authority,
the drone in the overlap), A's own operator application, signed with its key (``--gcs-keys``: the
control), holds the vehicle there and sends a command; B's operator (``--gcs-port-b``) asks for
control; once A's applications are shown B's request, the attacker (a fresh UDP socket, sysid 42)
consents (p1 = 0, p4 = B), allows takeover (p1 = 1, p2 = 1), sends LAND (mode and NAV_LAND), disarm,
MISSION_CLEAR_ALL and SET_MODE, a consent signed with a key of its own guessing, and reads a
parameter, three rounds a second apart. Then the signed application resumes the mission. Nothing the
attacker sends may move authority or reach the vehicle; its reads are answered; the signed
application's commands are obeyed.
"""

from __future__ import annotations

import os
import random
import socket
import time
from collections import Counter
from typing import Any, Callable

from pymavlink.dialects.v20 import common as mav

from zdrone.core.fleet import ConfigError
from zdrone.core.mavlink import FrameCodec
from zdrone.sil.attackers.common import Ctx, gcs_heartbeat


def gateway_flood(c: Ctx) -> None:
    if c.gcs_port is None:
        raise ConfigError("--gcs-port is required for gateway-flood")
    dest = ("127.0.0.1", c.gcs_port)
    socks: list[socket.socket] = []
    rng = random.Random(11)
    sent: Counter[str] = Counter()
    try:
        for _ in range(320):
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            sock.bind(("127.0.0.1", 0))
            sock.setblocking(False)
            socks.append(sock)
        c.ready()
        if not c.wait_for_go():
            return
        ports = {sock.getsockname()[1] for sock in socks}
        going = c.attack_window()
        while going():
            for i, sock in enumerate(socks):
                try:
                    sock.sendto(FrameCodec(1 + i % 249, 190 + i // 249).encode(gcs_heartbeat()), dest)
                    sent["heartbeat"] += 1
                except OSError:
                    sent["send_failed"] += 1
                if i % 50 == 49:
                    time.sleep(0.01)  # let the gateway's socket buffer drain
            junk = socks[0]
            for n in (1, 7, 11, 20, 100, 280, 1400, 65000):
                try:
                    junk.sendto(rng.randbytes(n), dest)
                    junk.sendto(FrameCodec(9, 9).encode(gcs_heartbeat())[: max(1, n % 21)], dest)
                    sent["garbage"] += 2
                except OSError:
                    sent["send_failed"] += 1
            c.stop.wait(1.0)
        c.events.write("attack_done", source_ports=len(ports), **sent)
    finally:
        for sock in socks:
            sock.close()


class _GcsApp:
    """A MAVLink application on a gateway's udpin port (pymavlink messages, signed with ``key`` as
    ``setup_signing`` does, or not); CONTROL_STATUS decoded with today's layout."""

    def __init__(self, port: int, sysid: int, key: bytes | None = None) -> None:
        from zdrone.core import fcsign as _fcsign

        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.connect(("127.0.0.1", port))
        self.sock.setblocking(False)
        self.enc = mav.MAVLink(None, srcSystem=sysid, srcComponent=190)
        self.dec = mav.MAVLink(None)
        if key is not None:
            for m in (self.enc, self.dec):
                m.signing.secret_key, m.signing.timestamp = key, _fcsign.units(time.time())
            self.enc.signing.sign_outgoing = True
        self.gcs_main: list[int] = []  # every CONTROL_STATUS gcs_main seen
        self.got: list[tuple[float, Any]] = []
        self.autopilot: int | None = None
        self.bad = 0  # frames our own signature check refused
        self._hb = 0.0

    def _wall_clock(self) -> None:
        """Signing timestamps follow the wall clock, as QGroundControl's and MAVProxy's do: pymavlink only
        counts up from its start, and a stream first heard a minute after that start is stale (refused)."""
        from zdrone.core import fcsign as _fcsign

        if self.enc.signing.secret_key is not None:
            now = _fcsign.units(time.time())
            for m in (self.enc, self.dec):
                m.signing.timestamp = max(m.signing.timestamp, now)

    def send(self, msg: Any) -> None:
        self._wall_clock()
        try:
            self.sock.send(bytes(msg.pack(self.enc)))
        except OSError:
            pass

    def command(self, command: int, *p: float) -> float:
        since = time.monotonic()
        self.send(mav.MAVLink_command_long_message(1, 1, command, 0, *(list(p) + [0.0] * (7 - len(p)))))
        return since

    def pump(self) -> None:
        from zdrone.core.mavcontrol import decode_control_status

        now = time.monotonic()
        if now - self._hb >= 1.0:
            self._hb = now
            self.send(gcs_heartbeat())
        for _ in range(512):
            try:
                data = self.sock.recv(65536)
            except (BlockingIOError, ConnectionRefusedError, InterruptedError):
                return
            st = decode_control_status(data)
            if st is not None:
                self.gcs_main.append(st.gcs_main)
                continue
            self._wall_clock()
            try:
                msg = self.dec.parse_char(data)
            except mav.MAVError:
                self.bad += 1
                continue
            if msg is None:
                continue
            if msg.get_type() == "HEARTBEAT" and msg.get_srcComponent() == 1 and msg.type != mav.MAV_TYPE_GCS:
                self.autopilot = msg.autopilot
            self.got.append((now, msg))

    def of(self, kind: str, since: float = 0.0) -> list[Any]:
        return [m for t, m in self.got if t >= since and m.get_type() == kind]

    def acks(self, command: int, since: float = 0.0) -> list[int]:
        return [m.result for m in self.of("COMMAND_ACK", since) if m.command == command]

    def close(self) -> None:
        self.sock.close()


def local_app(c: Ctx) -> None:
    """The unsigned local application on the owner GS's host (see the module's docstring)."""
    from gs.appkeys import load_keys

    from zdrone.core import fcsign as _fcsign
    from zdrone.core.mavcontrol import MAV_CMD_REQUEST_OPERATOR_CONTROL, MAV_RESULT_NOT_IN_CONTROL
    from zdrone.vehicle.modes import set_mode_params
    from zdrone.sil.operator import MODES as OPERATOR_MODES

    if c.gcs_port is None or c.gcs_port_b is None or c.gcs_keys is None:
        raise ConfigError("--gcs-port, --gcs-port-b and --gcs-keys are required for local-app")
    keys = load_keys(c.gcs_keys)
    if not keys:
        raise ConfigError(f"{c.gcs_keys}: no application key")
    b_sysid = c.fleet.nodes["B"].sysid
    ops = _GcsApp(c.gcs_port, 250, keys[0].key)  # A's own operator application, with its key (the control)
    attacker = _GcsApp(c.gcs_port, 42)  # any local process: a fresh UDP socket, no key
    b_ops = _GcsApp(c.gcs_port_b, 255)  # B's operator, on B's gateway
    apps = (ops, attacker, b_ops)
    sent: Counter[str] = Counter()
    result: dict[str, Any] = {}

    def pump(seconds: float) -> None:
        end = time.monotonic() + seconds
        while not c.stop.is_set():
            for app in apps:
                app.pump()
            if time.monotonic() >= end:
                return
            time.sleep(0.01)

    def wait(cond: Callable[[], Any], seconds: float) -> Any:
        end = time.monotonic() + seconds
        while time.monotonic() < end and not c.stop.is_set():
            pump(0.05)
            got = cond()
            if got:
                return got
        return None

    def set_mode(which: str) -> bool:
        modes = OPERATOR_MODES.get(ops.autopilot or mav.MAV_AUTOPILOT_PX4, OPERATOR_MODES[mav.MAV_AUTOPILOT_PX4])
        for _ in range(5):
            since = ops.command(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, *modes[which])
            if wait(lambda: mav.MAV_RESULT_ACCEPTED in ops.acks(mav.MAV_CMD_DO_SET_MODE, since), 1.0):
                return True
        return False

    try:
        c.ready()
        if not c.wait_for_go():
            return
        t0 = time.monotonic()
        wait(lambda: ops.autopilot is not None, 3.0)
        result["held"] = set_mode("hold")  # A's operator (signed) keeps the drone in the overlap
        result["signed_in_control"] = bool(wait(lambda: ops.gcs_main and ops.gcs_main[-1] == 250, 3.0))
        since = ops.command(mav.MAV_CMD_REQUEST_MESSAGE, mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
        result["signed_command"] = (wait(lambda: ops.acks(mav.MAV_CMD_REQUEST_MESSAGE, since), 3.0) or [None])[0]
        asked = time.monotonic()
        shown = None
        for _ in range(10):  # B's operator asks until A's applications are shown its request
            b_ops.command(MAV_CMD_REQUEST_OPERATOR_CONTROL, 1, 0, 20, 255)
            shown = wait(lambda: [m for m in attacker.of("COMMAND_LONG", asked)
                                  if m.command == MAV_CMD_REQUEST_OPERATOR_CONTROL], 1.0)
            if shown:
                break
        result["shown_p4"] = shown[0].param4 if shown else None
        attack_t0, start = time.time(), time.monotonic()
        ardupilot = ops.autopilot == mav.MAV_AUTOPILOT_ARDUPILOTMEGA
        land = set_mode_params("ardupilot" if ardupilot else "px4", "LAND") or (1.0, 4.0, 6.0)
        nan = float("nan")
        guessed = mav.MAVLink(None, srcSystem=42, srcComponent=190)  # a consent signed with a key of its own
        guessed.signing.secret_key, guessed.signing.sign_outgoing = os.urandom(32), True
        guessed.signing.timestamp = _fcsign.units(time.time())
        for _ in range(3):
            for label, msg in (
                ("consent", mav.MAVLink_command_long_message(1, 1, MAV_CMD_REQUEST_OPERATOR_CONTROL, 0, 0, 0, 0, b_sysid,
                                                             0, 0, 0)),
                ("allow_takeover", mav.MAVLink_command_long_message(1, 1, MAV_CMD_REQUEST_OPERATOR_CONTROL, 0, 1, 1, 10,
                                                                    b_sysid, 0, 0, 0)),
                ("mode_land", mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_DO_SET_MODE, 0, *land, nan, nan, nan,
                                                               nan)),
                ("nav_land", mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_NAV_LAND, 0, 0, 0, 0, nan, nan, nan, nan)),
                ("disarm", mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0, 21196, 0, 0, 0,
                                                            0, 0)),
                ("mission_clear", mav.MAVLink_mission_clear_all_message(1, 1, 0)),
                ("set_mode", mav.MAVLink_set_mode_message(1, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4 << 16 | 6 << 24)),
                ("param_read", mav.MAVLink_param_request_read_message(1, 1, b"", 0)),  # by index: any autopilot
            ):
                attacker.send(msg)
                sent[label] += 1
            try:
                attacker.sock.send(bytes(mav.MAVLink_command_long_message(
                    1, 1, MAV_CMD_REQUEST_OPERATOR_CONTROL, 0, 0, 0, 0, b_sysid, 0, 0, 0).pack(guessed)))
                sent["guessed_key_consent"] += 1
            except OSError:
                pass
            pump(1.0)
        pump(3.0)  # what it did, if anything, shows now
        acks = attacker.of("COMMAND_ACK", start)
        refusals = (mav.MAV_RESULT_DENIED, MAV_RESULT_NOT_IN_CONTROL)
        result.update(
            sent=dict(sent), answers=dict(Counter(f"{m.command}:{m.result}" for m in acks)),
            accepted=sum(1 for m in acks if m.result not in refusals),
            refused_commands=sum(1 for m in acks if m.result in refusals),
            mission_denied=sum(1 for m in attacker.of("MISSION_ACK", start) if m.type == mav.MAV_MISSION_DENIED),
            param_values=len(attacker.of("PARAM_VALUE", start)), telemetry=len(attacker.got),
            attacker_saw=sorted(set(attacker.gcs_main)), b_in_control=255 in b_ops.gcs_main,
            signed_still_in_control=bool(ops.gcs_main) and ops.gcs_main[-1] == 250,
            signed_refused_frames=ops.bad, window=[round(attack_t0, 3), round(time.time(), 3)])
        result["resumed"] = set_mode("mission")  # A's operator lets the flight go on
        result["took_s"] = round(time.monotonic() - t0, 2)
        c.events.write("attack_done", **result)
    finally:
        for app in apps:
            app.close()
