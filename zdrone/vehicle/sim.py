"""The built-in multicopter simulator: a kinematic vehicle behind a PX4-like MAVLink autopilot.

Theory of operation: ``SimAutopilot`` is sans-IO. ``receive(frame, now)`` handles one MAVLink
frame from a GCS; ``step(now)`` advances the physics to ``now`` (simulated seconds) and emits the
telemetry streams that are due; ``drain()`` returns the frames to send. The socket adapter
(``zdrone.vehicle.simserver``) owns the clock (``--speedup``) and the sockets.

The flight mode is one of ``FlightMode``; each mode sets a target (position, altitude, speed) and
the kinematics move the vehicle toward it within speed, climb-rate and acceleration limits. The
mission protocol (upload, download, clear, set current) follows the MAVLink microservice spec from
the vehicle's side; parameters use PX4's bytewise encoding of integers.

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

from pymavlink.dialects.v20 import common as mav

from ..core.geometry import GeoPoint, ne_of, offset
from ..core.mavlink import FrameCodec, split_frames
from .px4modes import FlightMode

log = logging.getLogger(__name__)

MAX_MISSION_ITEMS = 500
ACCEPT_RADIUS_M = 2.0
GRAVITY = 9.81
FORCE_DISARM_MAGIC = 21196

#: default stream intervals (seconds)
DEFAULT_STREAMS: dict[int, float] = {
    mav.MAVLINK_MSG_ID_HEARTBEAT: 1.0,
    mav.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
    mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 0.25,
    mav.MAVLINK_MSG_ID_ATTITUDE: 0.25,
    mav.MAVLINK_MSG_ID_HOME_POSITION: 2.0,
    mav.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 1.0,
    mav.MAVLINK_MSG_ID_BATTERY_STATUS: 2.0,
    mav.MAVLINK_MSG_ID_GPS_RAW_INT: 1.0,
    mav.MAVLINK_MSG_ID_MISSION_CURRENT: 1.0,
}
#: messages that can be requested once (REQUEST_MESSAGE) besides the streams
ON_REQUEST = {mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION}


@dataclass(slots=True)
class Param:
    value: float
    kind: int  # MAV_PARAM_TYPE_INT32 or MAV_PARAM_TYPE_REAL32
    low: float
    high: float
    writable: bool = True


def default_params(sysid: int) -> dict[str, Param]:
    i32, f32 = mav.MAV_PARAM_TYPE_INT32, mav.MAV_PARAM_TYPE_REAL32
    return {
        "COM_DL_LOSS_T": Param(10, i32, 5, 300),
        "NAV_DLL_ACT": Param(0, i32, 0, 3),  # 0 off: the companion's handover authority owns link loss
        "MPC_XY_CRUISE": Param(12.0, f32, 1.0, 25.0),
        "MPC_Z_VEL_MAX_UP": Param(3.0, f32, 0.5, 8.0),
        "MPC_Z_VEL_MAX_DN": Param(2.0, f32, 0.5, 4.0),
        "MPC_ACC_HOR": Param(4.0, f32, 1.0, 15.0),
        "MIS_TAKEOFF_ALT": Param(10.0, f32, 1.0, 100.0),
        "RTL_RETURN_ALT": Param(30.0, f32, 5.0, 150.0),
        "NAV_ACC_RAD": Param(ACCEPT_RADIUS_M, f32, 0.5, 50.0),
        "COM_DISARM_LAND": Param(2.0, f32, 0.0, 20.0),
        "MAV_SYS_ID": Param(sysid, i32, 1, 255, writable=False),
        "SIM_BAT_DRAIN": Param(2.0, f32, 0.0, 100.0),  # % per minute while armed
        "SIM_GPS_NOISE": Param(0.0, f32, 0.0, 10.0),  # metres, 1 sigma, on reported position
    }


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
    """A PX4-like multicopter autopilot, sans-IO. Time is simulated seconds passed as ``now``."""

    def __init__(self, home: GeoPoint, sysid: int = 1, compid: int = 1, seed: int = 0, now: float = 0.0,
                 home_amsl: float = 488.0) -> None:
        self.home = home
        self.home_amsl = home_amsl
        self.sysid, self.compid = sysid, compid
        self.codec = FrameCodec(sysid, compid)
        self.rng = random.Random(seed)
        self.params = default_params(sysid)
        self.param_names = list(self.params)
        self.k = Kinematics()
        self.armed = False
        self.mode = FlightMode.HOLD
        self.landed = True
        self.battery = 100.0
        self.mission: list[MissionItem] = []
        self.mission_current = 0
        self.mission_finished = False
        self.reached: set[int] = set()
        self._item_started: float | None = None
        self._land_since: float | None = None
        self._touchdown_at: float | None = None
        self.cruise_speed: float | None = None
        self.target: tuple[float, float, float] | None = None  # north, east, alt
        self.transfer: _Transfer | None = None
        self.streams: dict[int, float] = dict(DEFAULT_STREAMS)
        self._next_due: dict[int, float] = {m: now for m in self.streams}
        self.t = now
        self.boot = now
        self.outbox: list[bytes] = []
        self.counters: Counter[str] = Counter()
        self.events: list[tuple[float, str]] = []
        self.payload_released = False
        self.last_gcs_heartbeat: float | None = None
        self._buffer = b""
        self._pause_until = 0.0  # on the ground between a mission landing and the next item
        self._reached_at = 0.0
        self._takeoff_alt = self._p("MIS_TAKEOFF_ALT")
        self._rtl_descend = False
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
            "TIMESYNC": self._on_timesync,
            "PING": self._on_ping,
        }

    # ------------------------------------------------------------------ helpers
    def _p(self, name: str) -> float:
        return self.params[name].value

    def _send(self, msg: mav.MAVLink_message) -> None:
        self.outbox.append(self.codec.encode(msg))

    def drain(self) -> list[bytes]:
        """Frames to send, oldest first."""
        out, self.outbox = self.outbox, []
        return out

    def _event(self, text: str, severity: int = mav.MAV_SEVERITY_INFO) -> None:
        log.info("sim: %s", text)
        self.events.append((self.t, text))
        self._send(mav.MAVLink_statustext_message(severity, text.encode()[:50]))

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

    def _on_timesync(self, msg: Any, now: float) -> None:
        if msg.tc1 == 0:
            self._send(mav.MAVLink_timesync_message(int(now * 1e9), msg.ts1))

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
        if cmd == mav.MAV_CMD_COMPONENT_ARM_DISARM:
            if p[0] == 1.0:
                self.armed = True
                self.mission_finished = False
                self._event("armed")
                return self._ack(msg, cmd, ok)
            if p[0] == 0.0:
                if not self.landed and p[1] != FORCE_DISARM_MAGIC:
                    return self._ack(msg, cmd, denied)
                self._disarm("disarmed by command")
                return self._ack(msg, cmd, ok)
            return self._ack(msg, cmd, denied)
        if cmd == mav.MAV_CMD_NAV_TAKEOFF:
            if not self.armed:
                return self._ack(msg, cmd, mav.MAV_RESULT_TEMPORARILY_REJECTED)
            alt = z - self.home_amsl if math.isfinite(z) else self._p("MIS_TAKEOFF_ALT")
            if not 0.5 <= alt <= 500:
                return self._ack(msg, cmd, denied)
            self._takeoff_alt = alt
            self._set_mode(FlightMode.TAKEOFF)
            return self._ack(msg, cmd, ok)
        if cmd == mav.MAV_CMD_NAV_LAND:
            if not self.armed or self.landed:
                return self._ack(msg, cmd, mav.MAV_RESULT_TEMPORARILY_REJECTED)
            self._set_mode(FlightMode.LAND)
            return self._ack(msg, cmd, ok)
        if cmd == mav.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            if not self.armed or self.landed:
                return self._ack(msg, cmd, mav.MAV_RESULT_TEMPORARILY_REJECTED)
            self._set_mode(FlightMode.RTL)
            return self._ack(msg, cmd, ok)
        if cmd == mav.MAV_CMD_MISSION_START:
            if not self.mission:
                return self._ack(msg, cmd, denied)
            first = int(p[0]) if math.isfinite(p[0]) else 0
            if not 0 <= first < len(self.mission):
                return self._ack(msg, cmd, denied)
            self._start_mission(first)
            return self._ack(msg, cmd, ok)
        if cmd == mav.MAV_CMD_DO_SET_MODE:
            if not all(math.isfinite(v) for v in p[:3]):
                return self._ack(msg, cmd, denied)
            mode = FlightMode.from_main_sub(int(p[1]), int(p[2])) if int(p[0]) & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED else None
            if mode is None:
                return self._ack(msg, cmd, mav.MAV_RESULT_UNSUPPORTED)
            return self._ack(msg, cmd, ok if self._request_mode(mode) else denied)
        if cmd == mav.MAV_CMD_DO_REPOSITION:
            if not self.armed or self.landed:
                return self._ack(msg, cmd, mav.MAV_RESULT_TEMPORARILY_REJECTED)
            if not (math.isfinite(x) and math.isfinite(y) and -90 <= x <= 90 and -180 <= y <= 180):
                return self._ack(msg, cmd, denied)
            n, e = self._ne(x, y)
            alt = self._rel_alt(frame, z) if math.isfinite(z) else self.k.alt
            if math.hypot(n, e) > 50_000 or not -10 <= alt <= 1000:
                return self._ack(msg, cmd, denied)
            if math.isfinite(p[0]) and p[0] > 0:
                self.cruise_speed = min(p[0], 25.0)
            self._set_mode(FlightMode.HOLD)
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
            if mid not in DEFAULT_STREAMS and mid not in ON_REQUEST:
                return self._ack(msg, cmd, mav.MAV_RESULT_UNSUPPORTED)
            self._ack(msg, cmd, ok)
            return self._send_message(mid)
        if cmd == mav.MAV_CMD_SET_MESSAGE_INTERVAL:
            mid = int(p[0]) if math.isfinite(p[0]) else -1
            if mid not in DEFAULT_STREAMS:
                return self._ack(msg, cmd, mav.MAV_RESULT_UNSUPPORTED)
            if not math.isfinite(p[1]) or p[1] < -1 or p[1] > 60e6:
                return self._ack(msg, cmd, denied)
            if p[1] == -1:
                self.streams.pop(mid, None)
            else:
                self.streams[mid] = DEFAULT_STREAMS[mid] if p[1] == 0 else max(p[1] / 1e6, 0.02)
                self._next_due[mid] = now
            return self._ack(msg, cmd, ok)
        if cmd == mav.MAV_CMD_DO_GRIPPER:
            self._gripper(p[1])
            return self._ack(msg, cmd, ok)
        self._ack(msg, cmd, mav.MAV_RESULT_UNSUPPORTED)

    def _on_set_mode(self, msg: Any, now: float) -> None:
        mode = FlightMode.from_custom(msg.custom_mode)
        if mode is None or not msg.base_mode & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            self._count("bad_mode", str(msg.custom_mode))
            return
        self._request_mode(mode)

    def _request_mode(self, mode: FlightMode) -> bool:
        """Switch mode on request; False if the mode cannot be entered now."""
        if mode is FlightMode.MISSION:
            if not self.mission:
                return False
            self._start_mission(self.mission_current)
            return True
        if mode in (FlightMode.RTL, FlightMode.LAND, FlightMode.TAKEOFF) and (not self.armed or (self.landed and mode is not FlightMode.TAKEOFF)):
            return False
        if mode is FlightMode.TAKEOFF:
            self._takeoff_alt = self._p("MIS_TAKEOFF_ALT")
        self._set_mode(mode)
        return True

    def _set_mode(self, mode: FlightMode) -> None:
        if mode is not self.mode:
            log.info("sim: mode %s -> %s", self.mode.name, mode.name)
            self.mode = mode
        self._land_since = None
        if mode is FlightMode.LAND:  # land where we are, not at the last target
            self.target = (self.k.north, self.k.east, -1.0)
        if mode is FlightMode.HOLD or mode is FlightMode.POSCTL:
            self.target = (self.k.north, self.k.east, self.k.alt) if not self.landed else None

    def _disarm(self, why: str) -> None:
        if self.armed:
            self.armed = False
            self._event(why)
        self.k.vn = self.k.ve = self.k.vz = 0.0
        self.target = None
        if self.mode is not FlightMode.MISSION:
            self.mode = FlightMode.HOLD

    def _gripper(self, action: float) -> None:
        if action == mav.GRIPPER_ACTION_RELEASE or action == 0:
            self.payload_released = True
            self._event("payload released")

    # ------------------------------------------------------------------ mission
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
        self.mission_current = 0
        self.mission_finished = False
        self.reached.clear()
        self._mission_ack(tr.peer, mav.MAV_MISSION_ACCEPTED, tr.mission_type)
        self._event(f"mission of {len(self.mission)} items accepted")
        self._send_mission_current()

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
        if self.mode is FlightMode.MISSION:
            self._set_mode(FlightMode.HOLD)

    def _on_mission_set_current(self, msg: Any, now: float) -> None:
        if not 0 <= msg.seq < len(self.mission):
            return self._mission_ack(self._peer(msg), mav.MAV_MISSION_INVALID_SEQUENCE, 0)
        self._set_current(msg.seq)

    def _set_current(self, seq: int) -> None:
        self.mission_current = seq
        self.mission_finished = False
        self._item_started = None
        self._land_since = None
        self._send_mission_current()

    def _start_mission(self, first: int) -> None:
        if self.mission_finished or first != self.mission_current:
            self.reached.clear()
            self.mission_finished = False
            self.mission_current = first
        self._item_started = None
        self._set_mode(FlightMode.MISSION)
        self._send_mission_current()

    def _send_mission_current(self) -> None:
        if self.mission_finished:
            state = mav.MISSION_STATE_COMPLETE
        elif not self.mission:
            state = mav.MISSION_STATE_NO_MISSION
        elif self.mode is FlightMode.MISSION and self.armed:
            state = mav.MISSION_STATE_ACTIVE
        else:
            state = mav.MISSION_STATE_NOT_STARTED
        self._send(mav.MAVLink_mission_current_message(self.mission_current, len(self.mission), state, 0))

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
            self._event("mission finished")
            if not self.landed:
                self.target = (self.k.north, self.k.east, self.k.alt)
        else:
            self.mission_current += 1
        self._send_mission_current()

    def _fly_mission(self, now: float) -> None:
        if self.mission_finished or not self.mission or not self.armed:
            if not self.landed:
                self.target = self.target or (self.k.north, self.k.east, self.k.alt)
            return
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
            if self.landed and item.command == mav.MAV_CMD_NAV_TAKEOFF:
                self._event("takeoff")
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
            if math.hypot(n - here_n, e - here_e) > ACCEPT_RADIUS_M and not self.landed and self._land_since is None:
                self.target = (n, e, max(self.k.alt, 5.0))
                return
            if self._land_since is None:
                self._land_since = now
            self.target = (n, e, -1.0)
            if self.landed:
                self._event("landed at mission item %d" % item.seq)
                self._advance_mission()
                if not self.mission_finished:
                    self._pause_until = now + 3.0  # on the ground (delivery) before the next item
            return
        alt = self._rel_alt(item.frame, item.alt)
        self.target = (n, e, alt)
        radius = item.params[1] if item.command == mav.MAV_CMD_NAV_WAYPOINT and item.params[1] > 0 else self._p("NAV_ACC_RAD")
        dist = math.hypot(n - here_n, e - here_e, alt - self.k.alt)
        if dist <= radius:
            hold = item.params[0] if math.isfinite(item.params[0]) else 0.0
            if item.seq not in self.reached:
                self._item_reached(item.seq)
                self._reached_at = now
            if now - self._reached_at >= hold:
                self._advance_mission()

    # ---------------------------------------------------------------- parameters
    def _param_value(self, name: str, peer_index: int | None = None) -> mav.MAVLink_param_value_message:
        prm = self.params[name]
        if prm.kind == mav.MAV_PARAM_TYPE_INT32:  # PX4 bytewise encoding
            value = struct.unpack("<f", struct.pack("<i", int(prm.value)))[0]
        else:
            value = float(prm.value)
        idx = self.param_names.index(name)
        return mav.MAVLink_param_value_message(name.encode(), value, prm.kind, len(self.params), idx)

    def _on_param_request_list(self, msg: Any, now: float) -> None:
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
            self._event(f"unknown parameter {name}", mav.MAV_SEVERITY_WARNING)
            return
        if prm.kind == mav.MAV_PARAM_TYPE_INT32:
            value: float = struct.unpack("<i", struct.pack("<f", msg.param_value))[0] if msg.param_type == mav.MAV_PARAM_TYPE_INT32 else msg.param_value
        else:
            value = msg.param_value
        if not prm.writable or not math.isfinite(value) or not prm.low <= value <= prm.high:
            # PX4 answers a refused set with the unchanged value; say why in a STATUSTEXT
            self._count("param_rejected", f"{name}={value}")
            self._event(f"{name}: {value} refused", mav.MAV_SEVERITY_WARNING)
        else:
            prm.value = int(value) if prm.kind == mav.MAV_PARAM_TYPE_INT32 else float(value)
        self._send(self._param_value(name))

    # ------------------------------------------------------------------ streams
    def _send_message(self, mid: int) -> None:
        t = self.t
        boot_ms = int((t - self.boot) * 1000) & 0xFFFFFFFF
        pos = self.position
        noise = self._p("SIM_GPS_NOISE")
        if noise > 0:
            pos = offset(pos, self.rng.gauss(0, noise), self.rng.gauss(0, noise))
        k = self.k
        if mid == mav.MAVLINK_MSG_ID_HEARTBEAT:
            base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mav.MAV_MODE_FLAG_STABILIZE_ENABLED | mav.MAV_MODE_FLAG_GUIDED_ENABLED | mav.MAV_MODE_FLAG_AUTO_ENABLED
            if self.armed:
                base |= mav.MAV_MODE_FLAG_SAFETY_ARMED
            status = mav.MAV_STATE_ACTIVE if self.armed else mav.MAV_STATE_STANDBY
            self._send(mav.MAVLink_heartbeat_message(mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_PX4, base,
                                                     self.mode.custom_mode, status, 3))
        elif mid == mav.MAVLINK_MSG_ID_SYS_STATUS:
            sensors = (mav.MAV_SYS_STATUS_SENSOR_3D_GYRO | mav.MAV_SYS_STATUS_SENSOR_3D_ACCEL | mav.MAV_SYS_STATUS_SENSOR_3D_MAG
                       | mav.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE | mav.MAV_SYS_STATUS_SENSOR_GPS
                       | mav.MAV_SYS_STATUS_SENSOR_BATTERY)
            self._send(mav.MAVLink_sys_status_message(sensors, sensors, sensors, 150, self._voltage_mv(), 800 if self.armed else 50,
                                                      int(self.battery), 0, 0, 0, 0, 0, 0))
        elif mid == mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT:
            hdg = int(math.degrees(k.yaw) % 360 * 100)
            self._send(mav.MAVLink_global_position_int_message(
                boot_ms, int(pos.lat * 1e7), int(pos.lon * 1e7), int((self.home_amsl + k.alt) * 1000), int(k.alt * 1000),
                int(k.vn * 100), int(k.ve * 100), int(-k.vz * 100), hdg))
        elif mid == mav.MAVLINK_MSG_ID_ATTITUDE:
            pitch = -math.atan2(k.vn * math.cos(k.yaw) + k.ve * math.sin(k.yaw), 40.0)
            roll = math.atan2(-k.vn * math.sin(k.yaw) + k.ve * math.cos(k.yaw), 40.0)
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
            caps = (mav.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT | mav.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
                    | mav.MAV_PROTOCOL_CAPABILITY_MISSION_INT | mav.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                    | mav.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE | mav.MAV_PROTOCOL_CAPABILITY_MAVLINK2)
            self._send(mav.MAVLink_autopilot_version_message(caps, (1 << 24) | (15 << 16) | 0xFF, 0, 0, 0,
                                                             [0] * 8, [0] * 8, [0] * 8, 0, 0, 0x5A44524F4E45 + self.sysid))

    def _voltage_mv(self) -> int:
        return int(13200 + (16800 - 13200) * self.battery / 100.0)

    # ------------------------------------------------------------------ physics
    def step(self, now: float) -> None:
        """Advance the simulation to ``now`` and emit the streams that are due."""
        while self.t < now:  # fixed small steps keep the kinematics stable at any speed-up
            dt = min(0.05, now - self.t)
            self._physics(dt, self.t + dt)
            self.t += dt
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
                self._next_due[mid] = max(due + interval, now - interval)

    def _check_datalink(self, now: float) -> None:
        action = int(self._p("NAV_DLL_ACT"))
        if action == 0 or not self.armed or self.landed or self.last_gcs_heartbeat is None:
            return
        if now - self.last_gcs_heartbeat > self._p("COM_DL_LOSS_T") and self.mode not in (FlightMode.LAND, FlightMode.RTL):
            self._event("data link lost: " + ("return" if action == 2 else "land"), mav.MAV_SEVERITY_CRITICAL)
            self._set_mode(FlightMode.RTL if action == 2 else FlightMode.LAND)

    def _physics(self, dt: float, now: float) -> None:
        k = self.k
        if self.armed:
            self.battery = max(0.0, self.battery - self._p("SIM_BAT_DRAIN") / 60.0 * dt)
        if not self.armed:
            return
        if self._pause_until > now:
            return
        mode = self.mode
        if mode is FlightMode.MISSION:
            self._fly_mission(now)
        elif mode is FlightMode.TAKEOFF:
            alt = self._takeoff_alt
            if self.target is None or self.landed:
                self.target = (k.north, k.east, alt)
            if k.alt >= alt - 0.3:
                self._set_mode(FlightMode.HOLD)
        elif mode is FlightMode.LAND:
            self.target = (self.target[0], self.target[1], -1.0) if self.target else (k.north, k.east, -1.0)
        elif mode is FlightMode.RTL:
            rtl_alt = max(self._p("RTL_RETURN_ALT"), k.alt) if not self._rtl_descend else -1.0
            if math.hypot(k.north, k.east) > ACCEPT_RADIUS_M and not self._rtl_descend:
                self.target = (0.0, 0.0, rtl_alt) if k.alt >= self._p("RTL_RETURN_ALT") - 1 else (k.north, k.east, rtl_alt)
            else:
                self._rtl_descend = True
                self.target = (0.0, 0.0, -1.0)
        if mode is not FlightMode.RTL:
            self._rtl_descend = False
        if self.landed and self._touchdown_at is not None:
            mission_continues = self.mode is FlightMode.MISSION and not self.mission_finished
            if not mission_continues and now - self._touchdown_at >= self._p("COM_DISARM_LAND"):
                self._touchdown_at = None
                self._disarm("disarmed after landing")
                return
        if self.target is None:
            k.vn = k.ve = k.vz = 0.0
            return
        tn, te, talt = self.target
        # vertical
        up_max, dn_max = self._p("MPC_Z_VEL_MAX_UP"), self._p("MPC_Z_VEL_MAX_DN")
        if k.alt < 5.0 and talt < k.alt:
            dn_max = min(dn_max, 1.0)  # gentle final descent
        dz = talt - k.alt
        want_vz = max(-dn_max, min(up_max, dz * 1.5))
        # horizontal: no lateral motion until clear of the ground
        dn_, de_ = tn - k.north, te - k.east
        dist = math.hypot(dn_, de_)
        acc = self._p("MPC_ACC_HOR")
        speed = self.cruise_speed or self._p("MPC_XY_CRUISE")
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
                self._touchdown_at = None
        if k.alt <= 0.0:
            k.alt = 0.0
            k.vz = max(0.0, k.vz)
            if not self.landed and talt <= 0.0:
                self.landed = True
                k.vn = k.ve = 0.0
                self._touchdown_at = now
                self._event("landed")
                if self.mode in (FlightMode.LAND, FlightMode.RTL):
                    self._set_mode(FlightMode.HOLD)
                    self.target = None
                    self._rtl_descend = False


def _wrap_pi(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi
