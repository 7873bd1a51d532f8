"""The simulated autopilot's side of the link to its ground stations: who is there, the link-loss
failsafe, and the small services every GCS uses (TIMESYNC, PING, MAVLink FTP).

Theory of operation: ``GcsLink`` notes the time of every GCS HEARTBEAT, by sender. ``check(now)``,
from the autopilot's step, is the autopilot's own GCS-loss failsafe (``Personality.link_loss``; off
by default on both, the companion owns link loss): armed, in the air, and no HEARTBEAT for the
timeout parameter (from the GCS named by ``MAV_GCS_SYSID`` on ArduPilot, from any GCS on PX4), it
says so and switches to the action's mode (LAND or RTL) unless already landing or returning.

TIMESYNC requests are answered with the simulated time, PINGs to every system are answered.
MAVLink FTP is not simulated: with ``ftp_refuses`` (ArduPilot) every request gets a NAK at once
(open and list: no such file; session resets are ACKed), so a client falls back to the parameter
protocol; otherwise FTP is ignored.

Bad input never raises: a short FTP payload is counted as ``malformed``, refused FTP requests as
``ftp_refused``, FTP without ``ftp_refuses`` as ``ignored``.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Mapping
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, Protocol

from pymavlink.dialects.v20 import common as mav

from zdrone.vehicle.px4modes import FlightMode

if TYPE_CHECKING:
    from zdrone.vehicle.sim.vehicle import VehicleState
    from zdrone.vehicle.sim.outbox import Outbox
    from zdrone.vehicle.personality import ModeRow, Param, Personality


class LinkAutopilot(Protocol):
    """What the GCS link reads and does of its autopilot: all it may reach (``tests/unit/test_sim_parts.py``)."""

    out: Outbox
    p: Personality
    params: dict[str, Param]
    vehicle: VehicleState
    mode: FlightMode

    def set_mode(self, mode: FlightMode, row: ModeRow | None = None) -> None: ...


# MAVLink FTP opcodes and error codes (the protocol's, as in MAVProxy's ftp module)
FTP_TERMINATE_SESSION, FTP_RESET_SESSIONS, FTP_LIST_DIRECTORY, FTP_OPEN_FILE_RO = 1, 2, 3, 4
FTP_ACK, FTP_NAK = 128, 129
FTP_ERR_UNKNOWN_COMMAND, FTP_ERR_FILE_NOT_FOUND = 7, 10
FTP_HEADER = 12  # bytes before an FTP request's data
FTP_PAYLOAD = 251


class GcsLink:
    """The GCS side of one autopilot (``ap``): heartbeats heard, the link-loss failsafe, small services."""

    def __init__(self, ap: LinkAutopilot) -> None:
        self.ap = ap
        self.last_heartbeat: float | None = None  # from any GCS
        self.heartbeats: dict[int, float] = {}  # GCS sysid -> last HEARTBEAT
        self.handlers: Mapping[str, Callable[[Any, float], None]] = MappingProxyType({
            "HEARTBEAT": self.on_heartbeat,
            "TIMESYNC": self.on_timesync,
            "PING": self.on_ping,
            "FILE_TRANSFER_PROTOCOL": self.on_ftp,
        })

    def on_heartbeat(self, msg: Any, now: float) -> None:
        if msg.type == mav.MAV_TYPE_GCS:
            self.last_heartbeat = now
            self.heartbeats[msg.get_srcSystem()] = now

    def check(self, now: float) -> None:
        """The autopilot's GCS-loss failsafe."""
        ap = self.ap
        rule = ap.p.link_loss
        action = int(ap.params[rule.action_param].value)
        if action == 0 or not ap.vehicle.armed or ap.vehicle.landed:
            return
        last = (self.heartbeats.get(int(ap.params[rule.gcs_sysid_param].value)) if rule.gcs_sysid_param
                else self.last_heartbeat)
        if last is None:
            return
        if now - last > ap.params[rule.timeout_param].value and ap.mode not in (FlightMode.LAND, FlightMode.RTL):
            mode = rule.actions.get(action, rule.default_action)
            ap.out.say("link_lost", action="return" if mode is FlightMode.RTL else "land")
            ap.set_mode(mode)

    def on_timesync(self, msg: Any, now: float) -> None:
        if msg.tc1 == 0:
            self.ap.out.send(mav.MAVLink_timesync_message(int(now * 1e9), msg.ts1))

    def on_ping(self, msg: Any, now: float) -> None:
        if msg.target_system == 0:
            self.ap.out.send(mav.MAVLink_ping_message(msg.time_usec, msg.seq, msg.get_srcSystem(), msg.get_srcComponent()))

    def on_ftp(self, msg: Any, now: float) -> None:
        out = self.ap.out
        if not self.ap.p.ftp_refuses:
            out.count("ignored", "FILE_TRANSFER_PROTOCOL")
            return
        raw = bytes(msg.payload)
        if len(raw) < FTP_HEADER:
            out.count("malformed", "FTP payload")
            return
        seq, session, opcode = struct.unpack_from("<HBB", raw)
        if opcode in (FTP_TERMINATE_SESSION, FTP_RESET_SESSIONS):
            reply = struct.pack("<HBBBBBBI", (seq + 1) & 0xFFFF, session, FTP_ACK, 0, opcode, 0, 0, 0)
        else:
            error = FTP_ERR_FILE_NOT_FOUND if opcode in (FTP_OPEN_FILE_RO, FTP_LIST_DIRECTORY) else FTP_ERR_UNKNOWN_COMMAND
            reply = struct.pack("<HBBBBBBIB", (seq + 1) & 0xFFFF, session, FTP_NAK, 1, opcode, 0, 0, 0, error)
        out.count("ftp_refused", str(opcode))
        out.send(mav.MAVLink_file_transfer_protocol_message(0, msg.get_srcSystem(), msg.get_srcComponent(),
                                                            list(reply.ljust(FTP_PAYLOAD, b"\0"))))
