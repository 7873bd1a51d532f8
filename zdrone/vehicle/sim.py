"""The built-in multicopter simulator: a kinematic vehicle behind a PX4- or ArduPilot-like autopilot.

Theory of operation: ``SimAutopilot`` is sans-IO. ``receive(frame, now)`` handles one MAVLink
frame from a GCS; ``step(now)`` advances the physics to ``now`` (simulated seconds) and emits the
telemetry streams that are due; ``drain()`` returns the frames to send. The socket adapter
(``zdrone.vehicle.simserver``) owns the clock (``--speedup``) and the sockets.

What the autopilot is — PX4 v1.16 or ArduCopter 4.7 — is a ``Personality``
(``zdrone.vehicle.personality``), a frozen table the simulator consults wherever the two differ:
identity and mode numbers, texts (and PX4's EVENTs), readiness after boot, mission rules, auto-disarm,
streams, parameters, the link-loss failsafe. The flight mode is a ``FlightMode`` behaviour (each
sets a target: position, altitude, speed) shown as one of the personality's mode rows; the
kinematics move the vehicle toward the target within speed, climb-rate and acceleration limits.

Readiness is simulated time since boot: until ``ready_after`` seconds have passed arming is refused
with the autopilot's own texts (ArduPilot: AUTO also needs its position estimate). The default here
is 0 (ready at boot, for tests and in-process benches); ``zdrone sim`` passes a short per-autopilot
default, the real autopilots need about 10 s (PX4) and 20-40 s (ArduPilot).

Bad input never raises: undecodable bytes, unknown ids, frames for another system, NaN or
out-of-range values and unsupported mission items get the MAVLink-correct answer (COMMAND_ACK or
MISSION_ACK code), are counted in ``counters`` and logged.
"""

from __future__ import annotations

import logging
import math
import random
import struct
from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Callable

from pymavlink.dialects.v20 import ardupilotmega as apm
from pymavlink.dialects.v20 import common as mav

from ..core.geometry import GeoPoint, ne_of, offset
from ..core.mavlink import FrameCodec, encode_raw, split_frames
from .personality import (AP_STREAM_PARAMS, MSG_AHRS2, MSG_CURRENT_EVENT_SEQUENCE, MSG_CURRENT_MODE,
                          MSG_EKF_STATUS_REPORT, MSG_EVENT, MSG_LINK_NODE_STATUS, MSG_MEMINFO,
                          MSG_TIME_ESTIMATE_TO_TARGET, PX4, RAW_CRC_EXTRA, ModeRow, Param, Personality, Say,
                          ardupilot_takeoff_next, px4_event_id)
from .px4modes import FlightMode

try:  # CURRENT_MODE (436) lives in the development dialect
    from pymavlink.dialects.v20 import development as dev
except ImportError:  # pragma: no cover
    dev = None  # type: ignore[assignment]

log = logging.getLogger(__name__)

__all__ = ["SimAutopilot", "MissionItem", "Param", "Kinematics"]

MAX_MISSION_ITEMS = 500
GRAVITY = 9.81
FORCE_MAGIC = 21196  # param 2 of ARM_DISARM: force (arm without checks, disarm in the air)
DELIVERY_PAUSE_S = 3.0  # on the ground after a mid-mission landing before the next item
UNIX_EPOCH_AT_BOOT = 1_790_000_000  # SYSTEM_TIME: a fixed, deterministic wall clock
# MAVLink FTP opcodes and error codes (the protocol's, as in MAVProxy's ftp module)
FTP_TERMINATE_SESSION, FTP_RESET_SESSIONS, FTP_LIST_DIRECTORY, FTP_OPEN_FILE_RO = 1, 2, 3, 4
FTP_ACK, FTP_NAK = 128, 129
FTP_ERR_UNKNOWN_COMMAND, FTP_ERR_FILE_NOT_FOUND = 7, 10


@dataclass(slots=True)
class MissionItem:
    seq: int
    frame: int
    command: int
    current: int
    autocontinue: int
    params: tuple[float, float, float, float]
    lat: float
    lon: float
    alt: float  # as given in ``frame``
    mission_type: int = 0

    def to_int_msg(self, target: tuple[int, int]) -> mav.MAVLink_mission_item_int_message:
        return mav.MAVLink_mission_item_int_message(
            target[0], target[1], self.seq, self.frame, self.command, self.current, self.autocontinue,
            *self.params, int(round(self.lat * 1e7)), int(round(self.lon * 1e7)), self.alt, self.mission_type)

    def to_float_msg(self, target: tuple[int, int]) -> mav.MAVLink_mission_item_message:
        return mav.MAVLink_mission_item_message(
            target[0], target[1], self.seq, self.frame, self.command, self.current, self.autocontinue,
            *self.params, self.lat, self.lon, self.alt, self.mission_type)


NAV_COMMANDS = {mav.MAV_CMD_NAV_WAYPOINT, mav.MAV_CMD_NAV_TAKEOFF, mav.MAV_CMD_NAV_LAND,
                mav.MAV_CMD_NAV_RETURN_TO_LAUNCH, mav.MAV_CMD_NAV_LOITER_TIME}
DO_COMMANDS = {mav.MAV_CMD_DO_CHANGE_SPEED, mav.MAV_CMD_DO_GRIPPER}
GLOBAL_FRAMES = {mav.MAV_FRAME_GLOBAL, mav.MAV_FRAME_GLOBAL_INT, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT,
                 mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT}
DO_FRAMES = GLOBAL_FRAMES | {mav.MAV_FRAME_MISSION}
_INT_KINDS = {mav.MAV_PARAM_TYPE_UINT8: (0, 255), mav.MAV_PARAM_TYPE_INT8: (-128, 127),
              mav.MAV_PARAM_TYPE_UINT16: (0, 65535), mav.MAV_PARAM_TYPE_INT16: (-32768, 32767),
              mav.MAV_PARAM_TYPE_UINT32: (0, 2**32 - 1), mav.MAV_PARAM_TYPE_INT32: (-2**31, 2**31 - 1)}


@dataclass(slots=True)
class _Transfer:
    """An upload in progress (vehicle side of the mission protocol)."""

    peer: tuple[int, int]
    count: int
    mission_type: int
    items: list[MissionItem] = field(default_factory=list)
    last_request: float = 0.0
    retries: int = 0


@dataclass(slots=True)
class Kinematics:
    north: float = 0.0
    east: float = 0.0
    alt: float = 0.0  # metres above home
    vn: float = 0.0
    ve: float = 0.0
    vz: float = 0.0  # up positive
    yaw: float = 0.0  # radians, 0 north


class SimAutopilot:
    """A multicopter autopilot with a personality (PX4 by default), sans-IO. Time is simulated
    seconds passed as ``now``; ``ready_after`` is how long after boot it refuses to arm."""

    def __init__(self, home: GeoPoint, sysid: int = 1, compid: int = 1, seed: int = 0, now: float = 0.0,
                 home_amsl: float = 488.0, personality: Personality = PX4, ready_after: float = 0.0) -> None:
        self.p = personality
        self.ready_after = max(0.0, ready_after) if math.isfinite(ready_after) else 0.0
        self.home = home
        self.home_amsl = home_amsl
        self.sysid, self.compid = sysid, compid
        self.codec = FrameCodec(sysid, compid)
        self.rng = random.Random(seed)
        self.params: dict[str, Param] = personality.params(sysid)
        self.param_names = list(self.params)
        self.k = Kinematics()
        self.armed = False
        self.armed_at: float | None = None
        self._taken_off = False  # lifted off since arming
        self.mode_row: ModeRow = personality.modes.by_name(personality.boot_mode)
        self.mode: FlightMode = self.mode_row.behaviour
        self.landed = True
        self.battery = 100.0
        self.mission: list[MissionItem] = []
        self.mission_current = 0
        self.mission_finished = False
        self.mission_refusal: Say | None = None  # why the stored mission cannot be flown (PX4 feasibility)
        self.reached: set[int] = set()
        self._item_started: float | None = None
        self._land_since: float | None = None
        self._touchdown_at: float | None = None
        self.cruise_speed: float | None = None
        self.target: tuple[float, float, float] | None = None  # north, east, alt
        self.transfer: _Transfer | None = None
        self._intervals: dict[int, float | None] = {}  # SET_MESSAGE_INTERVAL: id -> interval, None = off
        self.streams: dict[int, float] = dict(personality.default_streams)
        self._next_due: dict[int, float] = {m: now for m in self.streams}
        self.t = now
        self.boot = now
        self.outbox: list[bytes] = []
        self.counters: Counter[str] = Counter()
        self.frames_streamed = 0
        self.events: list[tuple[float, str]] = []
        self.payload_released = False
        self.last_gcs_heartbeat: float | None = None
        self._gcs_heartbeats: dict[int, float] = {}  # GCS sysid -> last HEARTBEAT
        self._buffer = b""
        self._pause_until = 0.0  # on the ground between a mission landing and the next item
        self._reached_at = 0.0
        self._takeoff_alt = self._phys("takeoff_alt")
        self._rtl_descend = False
        self._text_id = 0  # STATUSTEXT id (PX4 numbers every text)
        self._event_seq = 0  # EVENT sequence (PX4)
        self._said_ready = self._said_position = False
        self._next_prearm = now
        self._handlers: dict[str, Callable[[Any, float], None]] = {
            "HEARTBEAT": self._on_heartbeat,
            "COMMAND_LONG": self._on_command_long,
            "COMMAND_INT": self._on_command_int,
            "SET_MODE": self._on_set_mode,
            "MISSION_COUNT": self._on_mission_count,
            "MISSION_ITEM_INT": self._on_mission_item,
            "MISSION_ITEM": self._on_mission_item,
            "MISSION_REQUEST_LIST": self._on_mission_request_list,
            "MISSION_REQUEST_INT": self._on_mission_request,
            "MISSION_REQUEST": self._on_mission_request,
            "MISSION_ACK": self._on_mission_ack,
            "MISSION_CLEAR_ALL": self._on_mission_clear,
            "MISSION_SET_CURRENT": self._on_mission_set_current,
            "PARAM_REQUEST_LIST": self._on_param_request_list,
            "PARAM_REQUEST_READ": self._on_param_request_read,
            "PARAM_SET": self._on_param_set,
            "REQUEST_DATA_STREAM": self._on_request_data_stream,
            "FILE_TRANSFER_PROTOCOL": self._on_ftp,
            "TIMESYNC": self._on_timesync,
            "PING": self._on_ping,
        }

    # ------------------------------------------------------------------ helpers
    def _p(self, name: str) -> float:
        return self.params[name].value

    def _phys(self, what: str) -> float:
        """A quantity of the vehicle model: a live parameter or the personality's constant."""
        src = self.p.physics[what]
        return self.params[src].value if isinstance(src, str) else src

    def _send(self, msg: Any) -> None:
        self.outbox.append(self.codec.encode(msg))

    def _send_raw(self, msgid: int, payload: bytes) -> None:
        """A message no pymavlink dialect here defines, under this codec's sequence number."""
        self.outbox.append(encode_raw(msgid, RAW_CRC_EXTRA[msgid], payload, self.sysid, self.compid, self.codec.mav.seq))
        self.codec.mav.seq = (self.codec.mav.seq + 1) % 256

    def drain(self) -> list[bytes]:
        """Frames to send, oldest first."""
        out, self.outbox = self.outbox, []
        return out

    def _say(self, what: str | Say, **fmt: object) -> None:
        """Tell the GCS: the personality's text ``what`` (a key) or a given ``Say``; PX4 also sends
        the EVENT behind it and ends the STATUSTEXT with a tab, as its mavlink_log does."""
        say = self.p.text(what) if isinstance(what, str) else what
        if say is None:
            return
        if fmt:
            say = say.format(**fmt)
        log.info("sim: %s", say.text)
        self.events.append((self.t, say.text))
        evented = self.p.events and say.event is not None
        self._statustext(say.severity, say.text + ("\t" if evented else ""))
        if evented:
            self._send_event(say)

    def _statustext(self, severity: int, text: str) -> None:
        raw = text.encode()
        if not self.p.chunk_statustext or len(raw) <= 50:
            self._send(mav.MAVLink_statustext_message(severity, raw[:50], self._text_id if self.p.chunk_statustext else 0, 0))
        else:  # PX4: 50-byte chunks sharing one id, numbered by chunk_seq
            for i, start in enumerate(range(0, len(raw), 50)):
                self._send(mav.MAVLink_statustext_message(severity, raw[start:start + 50], self._text_id, i))
        self._text_id = (self._text_id + 1) & 0xFFFF

    def _send_event(self, say: Say) -> None:
        assert say.event is not None
        boot_ms = int((self.t - self.boot) * 1000) & 0xFFFFFFFF
        payload = struct.pack("<IIHBBB", px4_event_id(say.event), boot_ms, self._event_seq, 0, 0, say.log_levels)
        self._send_raw(MSG_EVENT, payload + say.args[:40].ljust(40, b"\0"))
        self._event_seq = (self._event_seq + 1) & 0xFFFF

    def _count(self, what: str, detail: str = "") -> None:
        self.counters[what] += 1
        log.info("sim: %s %s", what, detail)

    @property
    def position(self) -> GeoPoint:
        """True position of the vehicle."""
        return offset(self.home, self.k.north, self.k.east, self.k.alt)

    def _ne(self, lat: float, lon: float) -> tuple[float, float]:
        return ne_of(self.home, GeoPoint(lat, lon))

    def _rel_alt(self, frame: int, alt: float) -> float:
        return alt - self.home_amsl if frame in (mav.MAV_FRAME_GLOBAL, mav.MAV_FRAME_GLOBAL_INT) else alt

    def landed_state(self) -> int:
        if self.landed:
            return mav.MAV_LANDED_STATE_ON_GROUND
        if self.mode is FlightMode.LAND or self._land_since is not None:
            return mav.MAV_LANDED_STATE_LANDING
        if self.mode is FlightMode.TAKEOFF:
            return mav.MAV_LANDED_STATE_TAKEOFF
        return mav.MAV_LANDED_STATE_IN_AIR

    # ---------------------------------------------------------------- readiness
    def ready_to_arm(self, now: float | None = None) -> bool:
        """True once the arming checks pass (``ready_after`` scaled stages of the personality)."""
        now = self.t if now is None else now
        return self.p.readiness.arm_refusal(now - self.boot, self.ready_after) is None

    def position_ok(self, now: float | None = None) -> bool:
        """True once the autopilot has a position estimate (ArduPilot: EKF using GPS)."""
        now = self.t if now is None else now
        return now - self.boot >= self.p.readiness.position_at * self.ready_after

    def _arm_refusal(self, now: float, forced: bool) -> Say | None:
        if forced:
            return None
        say = self.p.readiness.arm_refusal(now - self.boot, self.ready_after)
        if say is not None:
            return say
        if not self.mode_row.armable:
            return self.p.text("arm_mode_not_armable")
        return None

    def _announce_readiness(self, now: float) -> None:
        r = self.p.readiness
        if not self._said_ready and self.ready_to_arm(now):
            self._said_ready = True
            if r.on_ready is not None:
                self._say(r.on_ready)
        if not self._said_position and self.position_ok(now):
            self._said_position = True
            if r.on_position is not None:
                self._say(r.on_position)
        if r.prearm_every > 0 and not self.armed and now >= self._next_prearm:
            stage = r.stage(now - self.boot, self.ready_after)
            if stage is not None and stage.prearm is not None:
                self._say(stage.prearm)
            self._next_prearm = now + r.prearm_every

    # ---------------------------------------------------------------- receiving
    def receive_bytes(self, data: bytes, now: float) -> None:
        """Feed a chunk of a byte stream (TCP/serial); whole frames are handled, the rest kept."""
        frames, self._buffer, skipped = split_frames(self._buffer + data)
        if skipped:
            self._count("malformed", f"{skipped} stream bytes skipped")
        if len(self._buffer) > 4096:
            self._count("malformed", "stream buffer overflow")
            self._buffer = b""
        for f in frames:
            self.receive(f, now)

    def receive(self, frame: bytes, now: float) -> None:
        """Handle one MAVLink frame. Never raises on bad input."""
        msg = self.codec.decode(frame)
        if msg is None:
            self._count("malformed", f"{len(frame)} bytes")
            return
        name = msg.get_type()
        target = getattr(msg, "target_system", None)
        if target not in (None, 0, self.sysid):
            self._count("not_for_us", f"{name} for system {target}")
            return
        handler = self._handlers.get(name)
        if handler is None:
            self._count("ignored", name)
            return
        try:
            handler(msg, now)
        except Exception:  # a programming error in a handler must not kill the vehicle
            log.exception("sim: handler for %s failed", name)
            self._count("handler_error", name)

    def _on_heartbeat(self, msg: Any, now: float) -> None:
        if msg.type == mav.MAV_TYPE_GCS:
            self.last_gcs_heartbeat = now
            self._gcs_heartbeats[msg.get_srcSystem()] = now

    def _on_timesync(self, msg: Any, now: float) -> None:
        if msg.tc1 == 0:
            self._send(mav.MAVLink_timesync_message(int(now * 1e9), msg.ts1))

    def _on_ftp(self, msg: Any, now: float) -> None:
        """MAVLink FTP is not simulated. With ``ftp_refuses`` every request gets a NAK at once (open:
        no such file; session resets are ACKed), so a client falls back to the parameter protocol."""
        if not self.p.ftp_refuses:
            self._count("ignored", "FILE_TRANSFER_PROTOCOL")
            return
        raw = bytes(msg.payload)
        if len(raw) < 12:
            self._count("malformed", "FTP payload")
            return
        seq, session, opcode = struct.unpack_from("<HBB", raw)
        if opcode in (FTP_TERMINATE_SESSION, FTP_RESET_SESSIONS):
            reply = struct.pack("<HBBBBBBI", (seq + 1) & 0xFFFF, session, FTP_ACK, 0, opcode, 0, 0, 0)
        else:
            error = FTP_ERR_FILE_NOT_FOUND if opcode in (FTP_OPEN_FILE_RO, FTP_LIST_DIRECTORY) else FTP_ERR_UNKNOWN_COMMAND
            reply = struct.pack("<HBBBBBBIB", (seq + 1) & 0xFFFF, session, FTP_NAK, 1, opcode, 0, 0, 0, error)
        self._count("ftp_refused", str(opcode))
        self._send(mav.MAVLink_file_transfer_protocol_message(0, msg.get_srcSystem(), msg.get_srcComponent(),
                                                              list(reply.ljust(251, b"\0"))))

    def _on_ping(self, msg: Any, now: float) -> None:
        if msg.target_system == 0:
            self._send(mav.MAVLink_ping_message(msg.time_usec, msg.seq, msg.get_srcSystem(), msg.get_srcComponent()))

    # ----------------------------------------------------------------- commands
    def _ack(self, msg: Any, command: int, result: int) -> None:
        self._send(mav.MAVLink_command_ack_message(command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()))
        if result != mav.MAV_RESULT_ACCEPTED:
            self._count(f"command_{mav.enums['MAV_RESULT'][result].name.removeprefix('MAV_RESULT_').lower()}",
                        str(command))

    def _on_command_long(self, msg: Any, now: float) -> None:
        p = (msg.param1, msg.param2, msg.param3, msg.param4)
        self._command(msg, msg.command, p, msg.param5, msg.param6, msg.param7, mav.MAV_FRAME_GLOBAL, now)

    def _on_command_int(self, msg: Any, now: float) -> None:
        p = (msg.param1, msg.param2, msg.param3, msg.param4)
        lat = msg.x / 1e7 if msg.x not in (0, 0x7FFFFFFF) else float("nan")
        lon = msg.y / 1e7 if msg.y not in (0, 0x7FFFFFFF) else float("nan")
        self._command(msg, msg.command, p, lat, lon, msg.z, msg.frame, now)

    def _command(self, msg: Any, cmd: int, p: tuple[float, float, float, float], x: float, y: float, z: float,
                 frame: int, now: float) -> None:
        ok, denied = mav.MAV_RESULT_ACCEPTED, mav.MAV_RESULT_DENIED
        refused, not_now = self.p.denied_result, self.p.refused_result
        if cmd == mav.MAV_CMD_COMPONENT_ARM_DISARM:
            return self._ack(msg, cmd, self._arm_disarm(p, now))
        if cmd == mav.MAV_CMD_NAV_TAKEOFF:
            if not self.armed or not self.mode_row.user_takeoff or (self.p.takeoff_needs_ground and not self.landed):
                return self._ack(msg, cmd, not_now)
            default = self._phys("takeoff_alt")
            if self.p.takeoff_alt_amsl:
                alt = z - self.home_amsl if math.isfinite(z) else default
            else:
                alt = z if math.isfinite(z) and z > 0 else default
            if not 0.5 <= alt <= 500:
                return self._ack(msg, cmd, refused)
            self._takeoff_alt = alt
            self._set_mode(FlightMode.TAKEOFF)
            return self._ack(msg, cmd, ok)
        if cmd in (mav.MAV_CMD_NAV_LAND, mav.MAV_CMD_NAV_RETURN_TO_LAUNCH):
            if not self.p.modes_free_when_disarmed and (not self.armed or self.landed):
                return self._ack(msg, cmd, not_now)
            behaviour = FlightMode.LAND if cmd == mav.MAV_CMD_NAV_LAND else FlightMode.RTL
            return self._ack(msg, cmd, self._mode_change(self.p.modes.by_name(self.p.modes.shown[behaviour]), now))
        if cmd == mav.MAV_CMD_MISSION_START:
            return self._ack_then(msg, cmd, *self._mission_start(p, now))
        if cmd == mav.MAV_CMD_DO_SET_MODE:
            if not all(math.isfinite(v) for v in p[:3]):
                return self._ack(msg, cmd, denied)
            row = self.p.modes.from_command(p[1], p[2]) if int(p[0]) & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED else None
            if row is None:
                return self._ack(msg, cmd, mav.MAV_RESULT_UNSUPPORTED)
            return self._ack(msg, cmd, self._mode_change(row, now))
        if cmd == mav.MAV_CMD_DO_REPOSITION:
            if not self.armed or self.landed:
                return self._ack(msg, cmd, not_now)
            if not (math.isfinite(x) and math.isfinite(y) and -90 <= x <= 90 and -180 <= y <= 180):
                return self._ack(msg, cmd, denied)
            n, e = self._ne(x, y)
            alt = self._rel_alt(frame, z) if math.isfinite(z) else self.k.alt
            if math.hypot(n, e) > 50_000 or not -10 <= alt <= 1000:
                return self._ack(msg, cmd, denied)
            if math.isfinite(p[0]) and p[0] > 0:
                self.cruise_speed = min(p[0], 25.0)
            self._set_mode(FlightMode.HOLD, self.p.modes.by_name(self.p.modes.shown[FlightMode.HOLD]))
            self.target = (n, e, max(alt, 1.0))
            return self._ack(msg, cmd, ok)
        if cmd == mav.MAV_CMD_DO_CHANGE_SPEED:
            if not (math.isfinite(p[1]) and 0 < p[1] <= 25):
                return self._ack(msg, cmd, denied)
            self.cruise_speed = p[1]
            return self._ack(msg, cmd, ok)
        if cmd == mav.MAV_CMD_DO_SET_MISSION_CURRENT:
            seq = int(p[0]) if math.isfinite(p[0]) else -1
            if not 0 <= seq < len(self.mission):
                return self._ack(msg, cmd, denied)
            self._set_current(seq)
            return self._ack(msg, cmd, ok)
        if cmd == mav.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            self._ack(msg, cmd, ok)
            return self._send_message(mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
        if cmd == mav.MAV_CMD_REQUEST_MESSAGE:
            mid = int(p[0]) if math.isfinite(p[0]) else -1
            if mid not in self.p.sendable:
                return self._ack(msg, cmd, mav.MAV_RESULT_UNSUPPORTED)
            self._ack(msg, cmd, ok)
            return self._send_message(mid)
        if cmd == mav.MAV_CMD_SET_MESSAGE_INTERVAL:
            return self._ack(msg, cmd, self._set_interval(p, now))
        if cmd == mav.MAV_CMD_DO_GRIPPER:
            self._gripper(p[1])
            return self._ack(msg, cmd, ok)
        self._ack(msg, cmd, mav.MAV_RESULT_UNSUPPORTED)

    def _ack_then(self, msg: Any, cmd: int, result: int, after: list[Say | str]) -> None:
        """COMMAND_ACK, then the texts the autopilot sends after it."""
        self._ack(msg, cmd, result)
        for say in after:
            self._say(say)

    def _arm_disarm(self, p: tuple[float, float, float, float], now: float) -> int:
        forced = p[1] == FORCE_MAGIC
        if p[0] == 1.0:
            if self.armed:
                return mav.MAV_RESULT_ACCEPTED
            refusal = self._arm_refusal(now, forced)
            if refusal is not None:
                self._say(refusal)
                return self.p.readiness.refused_result
            self._arm(now, "armed")
            return mav.MAV_RESULT_ACCEPTED
        if p[0] == 0.0:
            if not self.landed and not forced:
                return self.p.denied_result
            self._disarm("disarmed_command")
            return mav.MAV_RESULT_ACCEPTED
        return mav.MAV_RESULT_DENIED

    def _arm(self, now: float, text: str) -> None:
        self.armed = True
        self.armed_at = now
        self._taken_off = not self.landed
        self.mission_finished = False
        self._say(text)

    def _mission_start(self, p: tuple[float, float, float, float], now: float) -> tuple[int, list[Say | str]]:
        """MAV_CMD_MISSION_START: (result, texts after the ACK)."""
        if self.p.mission_start_needs_zero_params and not (p[0] == 0 and p[1] == 0):
            return mav.MAV_RESULT_DENIED, []  # ArduCopter: first/last item not supported
        if self.p.mission_start_checks_mission:  # PX4: the stored mission must be valid
            if self.mission_refusal is not None:
                self._say(self.mission_refusal)
            if not self.mission or self.mission_refusal is not None:
                return mav.MAV_RESULT_DENIED, ["mission_start_no_mission"]
        first = int(p[0]) if math.isfinite(p[0]) and abs(p[0]) < 2**31 else -2
        if self.p.mission_start_needs_zero_params:
            first = self.mission_current
        elif first == -1:
            first = self.mission_current
        if not 0 <= first < len(self.mission) and self.p.mission_start_checks_mission:
            return mav.MAV_RESULT_DENIED, []
        row = self.p.modes.by_name(self.p.modes.shown[FlightMode.MISSION])
        if self.p.mission_start_arms and not self.armed:
            refusal = self._arm_refusal(now, False)
            if refusal is not None:
                self._say(refusal)
                self._say("mode_refused", label=row.label)
                return mav.MAV_RESULT_TEMPORARILY_REJECTED, []
            self._arm(now, "armed_mission_start")
        result = self._mode_change(row, now, first=first)
        return result, []

    def _set_interval(self, p: tuple[float, float, float, float], now: float) -> int:
        mid = int(p[0]) if math.isfinite(p[0]) and abs(p[0]) < 2**31 else -1
        if mid not in self.p.sendable:
            if self.p.text("interval_unknown") is not None:  # ArduPilot says so and fails
                self._say("interval_unknown", msgid=mid)
                return mav.MAV_RESULT_FAILED
            return mav.MAV_RESULT_UNSUPPORTED
        if not math.isfinite(p[1]) or p[1] < -1 or p[1] > 60e6:
            return mav.MAV_RESULT_DENIED
        if p[1] == -1:
            self._intervals[mid] = None
        elif p[1] == 0:
            self._intervals.pop(mid, None)  # back to the default rate
        else:
            self._intervals[mid] = max(p[1] / 1e6, 0.02)
        self._next_due[mid] = now
        self._rebuild_streams(now)
        return mav.MAV_RESULT_ACCEPTED

    def _on_set_mode(self, msg: Any, now: float) -> None:
        row = self.p.modes.by_custom(msg.custom_mode) if msg.base_mode & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED else None
        if row is None:
            self._count("bad_mode", str(msg.custom_mode))
            return
        self._mode_change(row, now)

    def _request_mode(self, mode: FlightMode | ModeRow) -> bool:
        """Switch mode on request (a behaviour or one of the personality's rows); False if refused."""
        row = mode if isinstance(mode, ModeRow) else self.p.modes.by_name(self.p.modes.shown[mode])
        return self._mode_change(row, self.t) == mav.MAV_RESULT_ACCEPTED

    def _mode_change(self, row: ModeRow, now: float, first: int | None = None) -> int:
        """A GCS asks for mode ``row``: the personality's checks, then the switch. Returns the MAV_RESULT."""
        ok, refused = mav.MAV_RESULT_ACCEPTED, self.p.denied_result
        checks = self.armed or not self.p.modes_free_when_disarmed  # ArduPilot: anything goes disarmed
        if checks and self.armed and row.needs_position and not self.position_ok(now):
            self._say("mode_requires_position", label=row.label)
            return refused
        if row.behaviour is FlightMode.MISSION:
            start = max(self.mission_current if first is None else first, self._first_real)
            if self.p.auto_needs_takeoff_when_landed:  # ModeAuto::init
                if len(self.mission) <= self._first_real and checks:
                    self._say("mode_init_failed", label=row.label)
                    return refused
                if (checks and self.armed and self.landed
                        and not ardupilot_takeoff_next(self.mission, max(start, self._first_real))):
                    self._say("auto_missing_takeoff")
                    self._say("mode_init_failed", label=row.label)
                    return refused
            elif not self.mission or self.mission_refusal is not None:
                self._say("mode_refused", label=row.label)
                return refused
            self._start_mission(start, row)
            return ok
        if (not self.p.modes_free_when_disarmed and row.behaviour in (FlightMode.RTL, FlightMode.LAND, FlightMode.TAKEOFF)
                and (not self.armed or (self.landed and row.behaviour is not FlightMode.TAKEOFF))):
            return refused
        if row.behaviour is FlightMode.TAKEOFF:
            self._takeoff_alt = self._phys("takeoff_alt")
        self._set_mode(row.behaviour, row)
        return ok

    def _set_mode(self, mode: FlightMode, row: ModeRow | None = None) -> None:
        row = row or self.p.modes.row_for(mode, self.mode_row)
        if row is not self.mode_row or mode is not self.mode:
            log.info("sim: mode %s -> %s", self.mode_row.name, row.name)
        self.mode, self.mode_row = mode, row
        self._land_since = None
        if mode is FlightMode.LAND:  # land where we are, not at the last target
            self.target = (self.k.north, self.k.east, -1.0)
        if mode is FlightMode.HOLD or mode is FlightMode.POSCTL:
            self.target = (self.k.north, self.k.east, self.k.alt) if not self.landed else None

    def _disarm(self, text: str) -> None:
        if self.armed:
            self.armed = False
            self._say(text)
        self.armed_at = None
        self.k.vn = self.k.ve = self.k.vz = 0.0
        if self.p.hold_after_touchdown and self.mode is not FlightMode.MISSION:
            self._set_mode(FlightMode.HOLD)
        self.target = None

    def _gripper(self, action: float) -> None:
        if action == mav.GRIPPER_ACTION_RELEASE or action == 0:
            self.payload_released = True
            self._say("payload_released")

    # ------------------------------------------------------------------ mission
    @property
    def _first_real(self) -> int:
        """Index of the first flown item (ArduPilot keeps item 0 as home)."""
        return 1 if self.p.home_item0 else 0

    def _mission_ack(self, peer: tuple[int, int], result: int, mission_type: int) -> None:
        self._send(mav.MAVLink_mission_ack_message(peer[0], peer[1], result, mission_type))
        if result != mav.MAV_MISSION_ACCEPTED:
            self._count(f"mission_{mav.enums['MAV_MISSION_RESULT'][result].name.removeprefix('MAV_MISSION_').lower()}")

    @staticmethod
    def _peer(msg: Any) -> tuple[int, int]:
        return msg.get_srcSystem(), msg.get_srcComponent()

    def _on_mission_count(self, msg: Any, now: float) -> None:
        peer, mtype = self._peer(msg), getattr(msg, "mission_type", 0)
        if mtype != mav.MAV_MISSION_TYPE_MISSION:
            return self._mission_ack(peer, mav.MAV_MISSION_UNSUPPORTED, mtype)
        if msg.count > MAX_MISSION_ITEMS:
            return self._mission_ack(peer, mav.MAV_MISSION_NO_SPACE, mtype)
        if msg.count == 0:
            self._clear_mission()
            return self._mission_ack(peer, mav.MAV_MISSION_ACCEPTED, mtype)
        self.transfer = _Transfer(peer, msg.count, mtype, last_request=now)
        self._request_item(0)

    def _request_item(self, seq: int) -> None:
        tr = self.transfer
        assert tr is not None
        self._send(mav.MAVLink_mission_request_int_message(tr.peer[0], tr.peer[1], seq, tr.mission_type))

    def _on_mission_item(self, msg: Any, now: float) -> None:
        tr = self.transfer
        peer = self._peer(msg)
        if tr is None or peer != tr.peer:
            self._count("mission_item_unexpected")
            return self._mission_ack(peer, mav.MAV_MISSION_DENIED, getattr(msg, "mission_type", 0))
        expected = len(tr.items)
        if msg.seq != expected:
            self._count("mission_item_out_of_sequence", f"{msg.seq} != {expected}")
            if msg.seq < expected:
                return  # a duplicate of an item we have; our request for `expected` is outstanding
            return self._request_item(expected)
        is_int = msg.get_type() == "MISSION_ITEM_INT"
        lat = msg.x / 1e7 if is_int else msg.x
        lon = msg.y / 1e7 if is_int else msg.y
        item = MissionItem(msg.seq, msg.frame, msg.command, msg.current, msg.autocontinue,
                           (msg.param1, msg.param2, msg.param3, msg.param4), lat, lon, msg.z, tr.mission_type)
        if self.p.home_item0 and item.seq == 0:
            item = self._home_item()  # ArduPilot stores home as item 0, whatever was sent
        else:
            problem = self._check_item(item)
            if problem is not None:
                log.info("sim: refusing mission item %d (command %d, frame %d)", item.seq, item.command, item.frame)
                self.transfer = None
                return self._mission_ack(tr.peer, problem, tr.mission_type)
        tr.items.append(item)
        tr.retries, tr.last_request = 0, now
        if len(tr.items) < tr.count:
            return self._request_item(len(tr.items))
        self.transfer = None
        self.mission = tr.items
        self.mission_current = self._first_real if len(self.mission) > self._first_real else 0
        self.mission_finished = False
        self.reached.clear()
        self._mission_ack(tr.peer, mav.MAV_MISSION_ACCEPTED, tr.mission_type)
        log.info("sim: mission of %d items accepted", len(self.mission))
        # PX4 checks feasibility after the upload is ACKed; a refusal only shows at MISSION_START
        self.mission_refusal = self.p.feasibility(self.mission)
        if self.mission_refusal is not None:
            self._say(self.mission_refusal)
        self._send_mission_current()

    def _home_item(self) -> MissionItem:
        return MissionItem(0, mav.MAV_FRAME_GLOBAL, mav.MAV_CMD_NAV_WAYPOINT, 0, 1, (0.0, 0.0, 0.0, 0.0),
                           self.home.lat, self.home.lon, self.home_amsl)

    def _check_item(self, item: MissionItem) -> int | None:
        """The MAV_MISSION_RESULT that refuses ``item``, or None if it can be flown."""
        if item.command not in NAV_COMMANDS and item.command not in DO_COMMANDS:
            return mav.MAV_MISSION_UNSUPPORTED
        positional = item.command in NAV_COMMANDS and item.command != mav.MAV_CMD_NAV_RETURN_TO_LAUNCH
        if item.frame not in (GLOBAL_FRAMES if positional else DO_FRAMES):
            return mav.MAV_MISSION_UNSUPPORTED_FRAME
        if item.command in NAV_COMMANDS and item.command != mav.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            takeoff_or_land = item.command in (mav.MAV_CMD_NAV_TAKEOFF, mav.MAV_CMD_NAV_LAND)
            lat_ok = math.isfinite(item.lat) and -90 <= item.lat <= 90 and (item.lat != 0 or takeoff_or_land)
            lon_ok = math.isfinite(item.lon) and -180 <= item.lon <= 180 and (item.lon != 0 or takeoff_or_land)
            if not lat_ok:
                return mav.MAV_MISSION_INVALID_PARAM5_X
            if not lon_ok:
                return mav.MAV_MISSION_INVALID_PARAM6_Y
            if not math.isfinite(item.alt) or not -100 <= self._rel_alt(item.frame, item.alt) <= 1000:
                return mav.MAV_MISSION_INVALID_PARAM7
            if item.lat != 0 and math.hypot(*self._ne(item.lat, item.lon)) > 50_000:
                return mav.MAV_MISSION_INVALID_PARAM5_X
        if item.command == mav.MAV_CMD_NAV_LOITER_TIME and not (math.isfinite(item.params[0]) and 0 <= item.params[0] <= 3600):
            return mav.MAV_MISSION_INVALID_PARAM1
        if item.command == mav.MAV_CMD_DO_CHANGE_SPEED and not (math.isfinite(item.params[1]) and -2 <= item.params[1] <= 25):
            return mav.MAV_MISSION_INVALID_PARAM2
        if item.command == mav.MAV_CMD_NAV_WAYPOINT and not (math.isnan(item.params[0]) or 0 <= item.params[0] <= 3600):
            return mav.MAV_MISSION_INVALID_PARAM1
        return None

    def _on_mission_request_list(self, msg: Any, now: float) -> None:
        mtype = getattr(msg, "mission_type", 0)
        count = len(self.mission) if mtype == mav.MAV_MISSION_TYPE_MISSION else 0
        peer = self._peer(msg)
        self._send(mav.MAVLink_mission_count_message(peer[0], peer[1], count, mtype))

    def _on_mission_request(self, msg: Any, now: float) -> None:
        mtype = getattr(msg, "mission_type", 0)
        peer = self._peer(msg)
        if mtype != mav.MAV_MISSION_TYPE_MISSION or not 0 <= msg.seq < len(self.mission):
            return self._mission_ack(peer, mav.MAV_MISSION_INVALID_SEQUENCE, mtype)
        item = self.mission[msg.seq]
        item.current = int(msg.seq == self.mission_current)
        self._send(item.to_int_msg(peer) if msg.get_type() == "MISSION_REQUEST_INT" else item.to_float_msg(peer))

    def _on_mission_ack(self, msg: Any, now: float) -> None:
        pass  # end of a download; nothing to do

    def _on_mission_clear(self, msg: Any, now: float) -> None:
        mtype = getattr(msg, "mission_type", 0)
        if mtype not in (mav.MAV_MISSION_TYPE_MISSION, mav.MAV_MISSION_TYPE_ALL):
            return self._mission_ack(self._peer(msg), mav.MAV_MISSION_ACCEPTED, mtype)  # nothing stored
        self._clear_mission()
        self._mission_ack(self._peer(msg), mav.MAV_MISSION_ACCEPTED, mtype)

    def _clear_mission(self) -> None:
        self.mission, self.mission_current, self.reached = [], 0, set()
        self.mission_refusal = None
        if self.mode is FlightMode.MISSION:
            self._set_mode(FlightMode.HOLD)

    def _on_mission_set_current(self, msg: Any, now: float) -> None:
        if not 0 <= msg.seq < len(self.mission):
            return self._mission_ack(self._peer(msg), mav.MAV_MISSION_INVALID_SEQUENCE, 0)
        self._set_current(msg.seq)

    def _set_current(self, seq: int) -> None:
        self.mission_current = max(seq, self._first_real) if len(self.mission) > self._first_real else seq
        self.mission_finished = False
        self._item_started = None
        self._land_since = None
        self._send_mission_current()

    def _start_mission(self, first: int, row: ModeRow | None = None) -> None:
        first = max(first, self._first_real)
        if self.mission_finished or first != self.mission_current:
            self.reached.clear()
            self.mission_finished = False
            self.mission_current = first
        self._item_started = None
        self._set_mode(FlightMode.MISSION, row)
        self._send_mission_current()

    def _send_mission_current(self) -> None:
        if self.mission_finished:
            state = mav.MISSION_STATE_COMPLETE
        elif len(self.mission) <= self._first_real:
            state = mav.MISSION_STATE_NO_MISSION
        elif self.mode is FlightMode.MISSION and self.armed:
            state = mav.MISSION_STATE_ACTIVE
        else:
            state = mav.MISSION_STATE_NOT_STARTED
        total = len(self.mission) - self._first_real if self.mission else 0
        self._send(mav.MAVLink_mission_current_message(self.mission_current, total, state, 0))

    def _item_reached(self, seq: int) -> None:
        if seq not in self.reached:
            self.reached.add(seq)
            self._send(mav.MAVLink_mission_item_reached_message(seq))

    def _advance_mission(self) -> None:
        self._item_reached(self.mission_current)
        self._item_started = None
        self._land_since = None
        if self.mission_current + 1 >= len(self.mission):
            self.mission_finished = True
            log.info("sim: mission finished")
            if not self.landed:
                self.target = (self.k.north, self.k.east, self.k.alt)
        else:
            self.mission_current += 1
        self._send_mission_current()

    def _fly_mission(self, now: float) -> None:
        if self.mission_finished or len(self.mission) <= self._first_real or not self.armed:
            if not self.landed:
                self.target = self.target or (self.k.north, self.k.east, self.k.alt)
            return
        self.mission_current = max(self.mission_current, self._first_real)
        for _ in range(len(self.mission)):  # DO items complete at once; stop at the first NAV item
            item = self.mission[self.mission_current]
            if item.command == mav.MAV_CMD_DO_CHANGE_SPEED:
                if item.params[1] > 0:
                    self.cruise_speed = item.params[1]
                self._advance_mission()
                continue
            if item.command == mav.MAV_CMD_DO_GRIPPER:
                self._gripper(item.params[1])
                self._advance_mission()
                continue
            break
        if self.mission_finished:
            return
        item = self.mission[self.mission_current]
        if self._item_started is None:
            self._item_started = now
        here_n, here_e = self.k.north, self.k.east
        if item.command == mav.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            self._item_reached(item.seq)
            self.mission_finished = True
            self._send_mission_current()
            self._set_mode(FlightMode.RTL)
            return
        if item.command == mav.MAV_CMD_NAV_TAKEOFF:
            alt = self._rel_alt(item.frame, item.alt)
            self.target = (here_n, here_e, alt) if self.target is None or self._item_started == now else (self.target[0], self.target[1], alt)
            if self.k.alt >= alt - 0.5:
                self._advance_mission()
            return
        n, e = self._ne(item.lat, item.lon) if item.lat or item.lon else (here_n, here_e)
        if item.command == mav.MAV_CMD_NAV_LAND:
            if math.hypot(n - here_n, e - here_e) > self._phys("accept_radius") and not self.landed and self._land_since is None:
                self.target = (n, e, max(self.k.alt, 5.0))
                return
            if self._land_since is None:
                self._land_since = now
            self.target = (n, e, -1.0)
            if self.landed:
                mis_options = int(self._p("MIS_OPTIONS")) if "MIS_OPTIONS" in self.params else 0
                if not self.p.continues_after_land(mis_options, self.mission, self.mission_current):
                    # ArduCopter: disarm at touchdown; the mission stops at this item
                    log.info("sim: landed at mission item %d: mission ends here", item.seq)
                    self.mission_finished = True
                    self._disarm("disarmed_landing")
                    self._send_mission_current()
                    return
                log.info("sim: landed at mission item %d", item.seq)
                self._advance_mission()
                if not self.mission_finished:
                    self._pause_until = now + DELIVERY_PAUSE_S  # on the ground (delivery) before the next item
            return
        alt = self._rel_alt(item.frame, item.alt)
        self.target = (n, e, alt)
        radius = item.params[1] if item.command == mav.MAV_CMD_NAV_WAYPOINT and item.params[1] > 0 else self._phys("accept_radius")
        dist = math.hypot(n - here_n, e - here_e, alt - self.k.alt)
        if dist <= radius:
            hold = item.params[0] if math.isfinite(item.params[0]) else 0.0
            if item.seq not in self.reached:
                self._item_reached(item.seq)
                self._reached_at = now
            if now - self._reached_at >= hold:
                self._advance_mission()

    # ---------------------------------------------------------------- parameters
    def _param_value(self, name: str) -> mav.MAVLink_param_value_message:
        prm = self.params[name]
        if prm.kind in _INT_KINDS and self.p.param_bytewise:  # PX4: the integer's bytes in the float
            value = struct.unpack("<f", struct.pack("<i", int(prm.value)))[0]
        else:
            value = float(prm.value)
        idx = self.param_names.index(name)
        return mav.MAVLink_param_value_message(name.encode(), value, prm.kind, len(self.params), idx)

    def _on_param_request_list(self, msg: Any, now: float) -> None:
        for text in self.p.banner:  # ArduPilot answers a parameter list request with its banner first
            self._say(Say(text))
        for name in self.param_names:
            self._send(self._param_value(name))

    @staticmethod
    def _param_id(raw: Any) -> str:
        if isinstance(raw, bytes):
            raw = raw.decode("ascii", "replace")
        return str(raw).rstrip("\x00")

    def _on_param_request_read(self, msg: Any, now: float) -> None:
        name = self._param_id(msg.param_id)
        if msg.param_index >= 0:
            if msg.param_index >= len(self.param_names):
                self._count("param_unknown", f"index {msg.param_index}")
                return
            name = self.param_names[msg.param_index]
        if name not in self.params:
            self._count("param_unknown", name)
            return
        self._send(self._param_value(name))

    def _on_param_set(self, msg: Any, now: float) -> None:
        name = self._param_id(msg.param_id)
        prm = self.params.get(name)
        if prm is None:
            self._count("param_unknown", name)
            if self.p.param_range_checked:
                self._say(Say(f"unknown parameter {name}", mav.MAV_SEVERITY_WARNING))
            return  # ArduPilot ignores it silently
        if prm.kind in _INT_KINDS and self.p.param_bytewise and msg.param_type in _INT_KINDS:
            value: float = struct.unpack("<i", struct.pack("<f", msg.param_value))[0]
        else:
            value = msg.param_value
        if not math.isfinite(value) and not self.p.param_range_checked:
            self._count("param_rejected", f"{name}={value}")
            return  # ArduPilot ignores NaN and infinities without an answer
        in_range = prm.low <= value <= prm.high or not self.p.param_range_checked
        if not prm.writable or not math.isfinite(value) or not in_range:
            # PX4 answers a refused set with the unchanged value; say why in a STATUSTEXT
            self._count("param_rejected", f"{name}={value}")
            self._say(Say(f"{name}: {value} refused", mav.MAV_SEVERITY_WARNING))
        elif prm.kind in _INT_KINDS:
            lo, hi = _INT_KINDS[prm.kind]
            prm.value = int(max(lo, min(hi, value)))
        else:
            prm.value = float(value)
        self._send(self._param_value(name))
        if self.p.stream_groups and name.startswith("MAV1_"):
            self._rebuild_streams(now)

    # ------------------------------------------------------------------ streams
    def _on_request_data_stream(self, msg: Any, now: float) -> None:
        """ArduPilot's stream groups: REQUEST_DATA_STREAM sets MAV1_<group> (0 = off); PX4 ignores it."""
        groups = self.p.stream_groups
        if not groups:
            self._count("ignored", "REQUEST_DATA_STREAM")
            return
        rate = float(min(max(msg.req_message_rate, 0), 50)) if msg.start_stop else 0.0
        ids = list(groups) if msg.req_stream_id == mav.MAV_DATA_STREAM_ALL else [msg.req_stream_id]
        for g in ids:
            if g in AP_STREAM_PARAMS:
                self.params[f"MAV1_{AP_STREAM_PARAMS[g]}"].value = int(rate)
        self._rebuild_streams(now)

    def _rebuild_streams(self, now: float) -> None:
        """Effective intervals: the personality's defaults, ArduPilot's group rates, then explicit
        SET_MESSAGE_INTERVAL requests."""
        streams = dict(self.p.default_streams)
        for group, ids in self.p.stream_groups.items():
            rate = self._p(f"MAV1_{AP_STREAM_PARAMS[group]}")
            if rate > 0:
                for mid in ids:
                    streams[mid] = min(streams.get(mid, math.inf), 1.0 / rate)
        for mid, interval in self._intervals.items():
            if interval is None:
                streams.pop(mid, None)
            else:
                streams[mid] = interval
        for mid in streams:
            if mid not in self.streams:
                self._next_due[mid] = now
        self.streams = streams

    def _send_message(self, mid: int) -> None:
        t = self.t
        boot_ms = int((t - self.boot) * 1000) & 0xFFFFFFFF
        pos = self.position
        noise = self._phys("gps_noise")
        if noise > 0:
            pos = offset(pos, self.rng.gauss(0, noise), self.rng.gauss(0, noise))
        k = self.k
        if mid == mav.MAVLINK_MSG_ID_HEARTBEAT:
            base, status = self.p.heartbeat(self.mode_row, self.armed, self.landed)
            self._send(mav.MAVLink_heartbeat_message(mav.MAV_TYPE_QUADROTOR, self.p.autopilot, base,
                                                     self.mode_row.custom_mode, status, 3))
        elif mid == mav.MAVLINK_MSG_ID_SYS_STATUS:
            sensors = (mav.MAV_SYS_STATUS_SENSOR_3D_GYRO | mav.MAV_SYS_STATUS_SENSOR_3D_ACCEL | mav.MAV_SYS_STATUS_SENSOR_3D_MAG
                       | mav.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE | mav.MAV_SYS_STATUS_SENSOR_GPS
                       | mav.MAV_SYS_STATUS_SENSOR_BATTERY | mav.MAV_SYS_STATUS_PREARM_CHECK)
            # the pre-arm bit is healthy once the arming checks pass (or while armed), as on both autopilots
            health = sensors if self.armed or self.ready_to_arm(t) else sensors & ~mav.MAV_SYS_STATUS_PREARM_CHECK
            self._send(mav.MAVLink_sys_status_message(sensors, sensors, health, 150, self._voltage_mv(), 800 if self.armed else 50,
                                                      int(self.battery), 0, 0, 0, 0, 0, 0))
        elif mid == mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT:
            hdg = int(math.degrees(k.yaw) % 360 * 100)
            self._send(mav.MAVLink_global_position_int_message(
                boot_ms, int(pos.lat * 1e7), int(pos.lon * 1e7), int((self.home_amsl + k.alt) * 1000), int(k.alt * 1000),
                int(k.vn * 100), int(k.ve * 100), int(-k.vz * 100), hdg))
        elif mid == mav.MAVLINK_MSG_ID_ATTITUDE:
            roll, pitch = self._tilt()
            self._send(mav.MAVLink_attitude_message(boot_ms, roll, pitch, _wrap_pi(k.yaw), 0.0, 0.0, 0.0))
        elif mid == mav.MAVLINK_MSG_ID_HOME_POSITION:
            self._send(mav.MAVLink_home_position_message(int(self.home.lat * 1e7), int(self.home.lon * 1e7),
                                                         int(self.home_amsl * 1000), 0, 0, 0, [1, 0, 0, 0], 0, 0, 0, int(t * 1e6)))
        elif mid == mav.MAVLINK_MSG_ID_EXTENDED_SYS_STATE:
            self._send(mav.MAVLink_extended_sys_state_message(mav.MAV_VTOL_STATE_UNDEFINED, self.landed_state()))
        elif mid == mav.MAVLINK_MSG_ID_BATTERY_STATUS:
            cells = [self._voltage_mv() // 4] * 4 + [65535] * 6
            self._send(mav.MAVLink_battery_status_message(0, mav.MAV_BATTERY_FUNCTION_ALL, mav.MAV_BATTERY_TYPE_LIPO, 2500, cells,
                                                          800 if self.armed else 50, -1, -1, int(self.battery)))
        elif mid == mav.MAVLINK_MSG_ID_GPS_RAW_INT:
            speed = math.hypot(k.vn, k.ve)
            cog = int(math.degrees(math.atan2(k.ve, k.vn)) % 360 * 100) if speed > 0.1 else 65535
            self._send(mav.MAVLink_gps_raw_int_message(int(t * 1e6), mav.GPS_FIX_TYPE_3D_FIX, int(pos.lat * 1e7), int(pos.lon * 1e7),
                                                       int((self.home_amsl + k.alt) * 1000), 80, 120, int(speed * 100), cog, 14))
        elif mid == mav.MAVLINK_MSG_ID_MISSION_CURRENT:
            self._send_mission_current()
        elif mid == mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            self._send(mav.MAVLink_autopilot_version_message(self.p.capabilities, self.p.version, 0, 0, 0,
                                                             [0] * 8, [0] * 8, [0] * 8, 0, 0, 0x5A44524F4E45 + self.sysid))
        elif mid == mav.MAVLINK_MSG_ID_VFR_HUD:
            self._send(mav.MAVLink_vfr_hud_message(math.hypot(k.vn, k.ve), math.hypot(k.vn, k.ve), int(math.degrees(k.yaw) % 360),
                                                   40 if self.armed else 0, self.home_amsl + k.alt, k.vz))
        elif mid == mav.MAVLINK_MSG_ID_SYSTEM_TIME:
            self._send(mav.MAVLink_system_time_message(int((UNIX_EPOCH_AT_BOOT + t - self.boot) * 1e6), boot_ms))
        else:
            self._send_extra(mid, boot_ms, pos)

    def _send_extra(self, mid: int, boot_ms: int, pos: GeoPoint) -> None:
        """The ids outside pymavlink's common dialect: PX4's (raw or development dialect) and
        ArduPilot's (ardupilotmega dialect)."""
        k = self.k
        if mid == MSG_LINK_NODE_STATUS:
            self._send_raw(mid, struct.pack("<QIIIIIHHHBB", int((self.t - self.boot) * 1e6), 0, 0,
                                            self.frames_streamed & 0xFFFFFFFF, 0, 0, 0, 0, 0, 100, 100))
        elif mid == MSG_TIME_ESTIMATE_TO_TARGET:
            land = -1 if self.landed else int(k.alt / max(self._phys("down"), 0.1))
            home = int(math.hypot(k.north, k.east) / max(self._phys("cruise"), 0.1)) if not self.landed else -1
            self._send_raw(mid, struct.pack("<iiiii", home, land, -1, -1, -1))
        elif mid == MSG_CURRENT_EVENT_SEQUENCE:
            self._send_raw(mid, struct.pack("<HB", (self._event_seq - 1) & 0xFFFF, 0))
        elif mid == MSG_CURRENT_MODE and dev is not None:
            row = self.mode_row
            self._send(dev.MAVLink_current_mode_message(row.standard_mode, row.custom_mode, row.custom_mode))
        elif mid == MSG_MEMINFO:
            self._send(apm.MAVLink_meminfo_message(0, 65535, 131072))
        elif mid == MSG_AHRS2:
            roll, pitch = self._tilt()
            self._send(apm.MAVLink_ahrs2_message(roll, pitch, _wrap_pi(k.yaw), self.home_amsl + k.alt,
                                                 int(pos.lat * 1e7), int(pos.lon * 1e7)))
        elif mid == MSG_EKF_STATUS_REPORT:
            self._send(apm.MAVLink_ekf_status_report_message(self._ekf_flags(), 0.02, 0.02, 0.02, 0.03, 0.0, 0.0))

    def _ekf_flags(self) -> int:
        """ArduPilot's EKF_STATUS_REPORT flags along the readiness stages (absolute position last)."""
        r = self.p.readiness
        if r.stages and self.t - self.boot < r.stages[0].until * self.ready_after:
            return apm.EKF_UNINITIALIZED  # still aligning: no usable solution yet
        flags = apm.EKF_ATTITUDE | apm.EKF_VELOCITY_HORIZ | apm.EKF_VELOCITY_VERT | apm.EKF_POS_VERT_ABS | apm.EKF_POS_HORIZ_REL
        if self.position_ok(self.t):
            flags |= apm.EKF_POS_HORIZ_ABS | apm.EKF_PRED_POS_HORIZ_REL | apm.EKF_PRED_POS_HORIZ_ABS
        else:
            flags |= apm.EKF_CONST_POS_MODE
        return flags

    def _tilt(self) -> tuple[float, float]:
        k = self.k
        pitch = -math.atan2(k.vn * math.cos(k.yaw) + k.ve * math.sin(k.yaw), 40.0)
        roll = math.atan2(-k.vn * math.sin(k.yaw) + k.ve * math.cos(k.yaw), 40.0)
        return roll, pitch

    def _voltage_mv(self) -> int:
        return int(13200 + (16800 - 13200) * self.battery / 100.0)

    # ------------------------------------------------------------------ physics
    def step(self, now: float) -> None:
        """Advance the simulation to ``now`` and emit the streams that are due."""
        while self.t < now:  # fixed small steps keep the kinematics stable at any speed-up
            dt = min(0.05, now - self.t)
            self._physics(dt, self.t + dt)
            self.t += dt
        self._announce_readiness(now)
        self._check_datalink(now)
        if self.transfer is not None and now - self.transfer.last_request > 1.0:
            self.transfer.retries += 1
            self.transfer.last_request = now
            if self.transfer.retries > 5:
                self._mission_ack(self.transfer.peer, mav.MAV_MISSION_OPERATION_CANCELLED, self.transfer.mission_type)
                self.transfer = None
            else:
                self._request_item(len(self.transfer.items))
        for mid, interval in list(self.streams.items()):
            due = self._next_due.get(mid, now)
            if now >= due:
                self._send_message(mid)
                self.frames_streamed += 1
                self._next_due[mid] = max(due + interval, now - interval)

    def _check_datalink(self, now: float) -> None:
        rule = self.p.link_loss
        action = int(self._p(rule.action_param))
        if action == 0 or not self.armed or self.landed:
            return
        last = (self._gcs_heartbeats.get(int(self._p(rule.gcs_sysid_param))) if rule.gcs_sysid_param
                else self.last_gcs_heartbeat)
        if last is None:
            return
        if now - last > self._p(rule.timeout_param) and self.mode not in (FlightMode.LAND, FlightMode.RTL):
            mode = rule.actions.get(action, rule.default_action)
            self._say("link_lost", action="return" if mode is FlightMode.RTL else "land")
            self._set_mode(mode)

    def _physics(self, dt: float, now: float) -> None:
        k = self.k
        if self.armed:
            self.battery = max(0.0, self.battery - self._phys("bat_drain") / 60.0 * dt)
        if not self.armed:
            return
        preflight = self._phys("disarm_preflight")
        if (self.landed and not self._taken_off and self.armed_at is not None and preflight > 0
                and now - self.armed_at >= preflight):
            self._disarm("disarmed_preflight")  # armed on the ground and never took off
            return
        if self._pause_until > now:
            return
        mode = self.mode
        if mode is FlightMode.MISSION:
            self._fly_mission(now)
            if not self.armed:
                return
        elif mode is FlightMode.TAKEOFF:
            alt = self._takeoff_alt
            if self.target is None or self.landed:
                self.target = (k.north, k.east, alt)
            if k.alt >= alt - 0.3:
                self._set_mode(FlightMode.HOLD)
        elif mode is FlightMode.LAND:
            self.target = (self.target[0], self.target[1], -1.0) if self.target else (k.north, k.east, -1.0)
        elif mode is FlightMode.RTL:
            rtl_return = self._phys("rtl_alt")
            rtl_alt = max(rtl_return, k.alt) if not self._rtl_descend else -1.0
            if math.hypot(k.north, k.east) > self._phys("accept_radius") and not self._rtl_descend:
                self.target = (0.0, 0.0, rtl_alt) if k.alt >= rtl_return - 1 else (k.north, k.east, rtl_alt)
            else:
                self._rtl_descend = True
                self.target = (0.0, 0.0, -1.0)
        if mode is not FlightMode.RTL:
            self._rtl_descend = False
        if self.landed and self._touchdown_at is not None:
            mission_continues = self.mode is FlightMode.MISSION and not self.mission_finished
            if not mission_continues and now - self._touchdown_at >= self._phys("disarm_land"):
                self._touchdown_at = None
                self._disarm("disarmed_landing")
                return
        if self.target is None:
            k.vn = k.ve = k.vz = 0.0
            return
        tn, te, talt = self.target
        # vertical
        up_max, dn_max = self._phys("up"), self._phys("down")
        if k.alt < 5.0 and talt < k.alt:
            dn_max = min(dn_max, 1.0)  # gentle final descent
        dz = talt - k.alt
        want_vz = max(-dn_max, min(up_max, dz * 1.5))
        # horizontal: no lateral motion until clear of the ground
        dn_, de_ = tn - k.north, te - k.east
        dist = math.hypot(dn_, de_)
        acc = self._phys("acc")
        speed = self.cruise_speed or self._phys("cruise")
        if k.alt < 2.0 and dz > 0.5:
            speed = 0.0
        want = min(speed, math.sqrt(2 * acc * dist) * 0.9, dist / max(dt, 1e-3))
        want_vn, want_ve = (dn_ / dist * want, de_ / dist * want) if dist > 1e-6 else (0.0, 0.0)
        dvn, dve = want_vn - k.vn, want_ve - k.ve
        dv = math.hypot(dvn, dve)
        if dv > acc * dt:
            dvn, dve = dvn / dv * acc * dt, dve / dv * acc * dt
        k.vn += dvn
        k.ve += dve
        dvz = want_vz - k.vz
        k.vz += max(-acc * dt, min(acc * dt, dvz))
        k.north += k.vn * dt
        k.east += k.ve * dt
        k.alt += k.vz * dt
        if math.hypot(k.vn, k.ve) > 0.5:
            k.yaw = math.atan2(k.ve, k.vn)
        if k.alt > 0.05:
            if self.landed:
                self.landed = False
                self._taken_off = True
                self._touchdown_at = None
                self._say("takeoff_detected")
        if k.alt <= 0.0:
            k.alt = 0.0
            k.vz = max(0.0, k.vz)
            if not self.landed and talt <= 0.0:
                self.landed = True
                k.vn = k.ve = 0.0
                self._touchdown_at = now
                self._say("landing_detected")
                if self.mode in (FlightMode.LAND, FlightMode.RTL):
                    if self.p.hold_after_touchdown:
                        self._set_mode(FlightMode.HOLD)
                    self.target = None
                    self._rtl_descend = False


def _wrap_pi(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi
