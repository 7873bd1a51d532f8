"""The simulated autopilot's commands: COMMAND_LONG and COMMAND_INT through one table.

Theory of operation: both messages become one ``Command`` value (params 1-4; x and y in degrees,
NaN where COMMAND_INT leaves them unset; z; the frame of the position, MAV_FRAME_GLOBAL for
COMMAND_LONG). ``COMMANDS`` maps each supported MAV_CMD to its handler, ``handler(ap, command, now)``,
which acts on the autopilot ``ap`` and returns the MAV_RESULT, or a ``Reply`` when something
follows the COMMAND_ACK: the texts the autopilot says after it, or the message that was asked for.
``CommandProtocol.handle`` looks the handler up, sends the ACK to the sender and then what follows;
a command not in the table is UNSUPPORTED.

Where PX4 and ArduPilot answer differently the personality says how: ``refused_result`` for "not
now" (disarmed, in the air, wrong mode), ``denied_result`` for a refused mode change, disarm or
value; the mode changes themselves go through ``CommandedAutopilot.change_mode``.

Bad input never raises: NaN, infinite or out-of-range params get DENIED (or the personality's
refusal), an unknown mode or message id UNSUPPORTED; every ACK other than ACCEPTED is counted as
``command_<result>``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, Protocol

from pymavlink.dialects.v20 import common as mav

from zdrone.core.geometry import GeoPoint, ne_of
from zdrone.vehicle.personality import Say
from zdrone.vehicle.px4modes import FlightMode
from zdrone.vehicle.sim.mission import MAX_DISTANCE_M, relative_alt

if TYPE_CHECKING:
    from zdrone.vehicle.sim.vehicle import VehicleState
    from zdrone.vehicle.sim.guidance import Guidance
    from zdrone.vehicle.sim.mission import MissionProtocol
    from zdrone.vehicle.sim.outbox import Outbox
    from zdrone.vehicle.sim.telemetry import Telemetry
    from zdrone.vehicle.personality import ModeRow, Personality, Say


class CommandedAutopilot(Protocol):
    """What the command table reads and does of its autopilot: all it may reach
    (``tests/unit/test_sim_parts.py``)."""

    out: Outbox
    p: Personality
    home: GeoPoint
    home_amsl: float
    guidance: Guidance
    vehicle: VehicleState
    mode_row: ModeRow
    mission_protocol: MissionProtocol
    telemetry: Telemetry

    def arm(self, now: float, text: str) -> None: ...

    def arm_refusal(self, now: float, forced: bool) -> Say | None: ...

    def disarm(self, text: str) -> None: ...

    def set_mode(self, mode: FlightMode, row: ModeRow | None = None) -> None: ...

    def change_mode(self, row: ModeRow, now: float, first: int | None = None) -> int: ...

    def operate_gripper(self, action: float) -> None: ...

    def phys(self, what: str) -> float: ...


FORCE_MAGIC = 21196  # param 2 of ARM_DISARM: force (arm without checks, disarm in the air)
MAX_SPEED = 25.0  # m/s: DO_CHANGE_SPEED and DO_REPOSITION's speed
TAKEOFF_ALT_RANGE = (0.5, 500.0)  # metres above home
REPOSITION_ALT_RANGE = (-10.0, 1000.0)
UNSET_INT = (0, 0x7FFFFFFF)  # COMMAND_INT x/y that carry no position
ACCEPTED = mav.MAV_RESULT_ACCEPTED
DENIED = mav.MAV_RESULT_DENIED
UNSUPPORTED = mav.MAV_RESULT_UNSUPPORTED


@dataclass(frozen=True, slots=True)
class Command:
    """One COMMAND_LONG or COMMAND_INT."""

    command: int
    params: tuple[float, float, float, float]
    x: float  # latitude, degrees (NaN: none)
    y: float  # longitude, degrees (NaN: none)
    z: float
    frame: int
    sender: tuple[int, int]  # system, component

    @classmethod
    def from_long(cls, msg: Any) -> Command:
        return cls(msg.command, (msg.param1, msg.param2, msg.param3, msg.param4), msg.param5, msg.param6, msg.param7,
                   mav.MAV_FRAME_GLOBAL, (msg.get_srcSystem(), msg.get_srcComponent()))

    @classmethod
    def from_int(cls, msg: Any) -> Command:
        lat = msg.x / 1e7 if msg.x not in UNSET_INT else math.nan
        lon = msg.y / 1e7 if msg.y not in UNSET_INT else math.nan
        return cls(msg.command, (msg.param1, msg.param2, msg.param3, msg.param4), lat, lon, msg.z, msg.frame,
                   (msg.get_srcSystem(), msg.get_srcComponent()))


@dataclass(frozen=True, slots=True)
class Reply:
    """A handler's answer when something follows the COMMAND_ACK."""

    result: int  # MAV_RESULT
    texts: tuple[Say | str, ...] = ()  # said after the ACK
    message: int | None = None  # this message id is sent after the ACK


Handler = Callable[[CommandedAutopilot, Command, float], "int | Reply"]


# ------------------------------------------------------------------ handlers
def _arm_disarm(ap: CommandedAutopilot, c: Command, now: float) -> int:
    p = c.params
    forced = p[1] == FORCE_MAGIC
    if p[0] == 1.0:
        if ap.vehicle.armed:
            return ACCEPTED
        refusal = ap.arm_refusal(now, forced)
        if refusal is not None:
            ap.out.say(refusal)
            return ap.p.readiness.refused_result
        ap.arm(now, "armed")
        return ACCEPTED
    if p[0] == 0.0:
        if not ap.vehicle.landed and not forced:
            return ap.p.denied_result
        ap.disarm("disarmed_command")
        return ACCEPTED
    return DENIED


def _takeoff(ap: CommandedAutopilot, c: Command, now: float) -> int:
    if not ap.vehicle.armed or not ap.mode_row.user_takeoff or (ap.p.takeoff_needs_ground and not ap.vehicle.landed):
        return ap.p.refused_result
    default = ap.phys("takeoff_alt")
    if ap.p.takeoff_alt_amsl:
        alt = c.z - ap.home_amsl if math.isfinite(c.z) else default
    else:
        alt = c.z if math.isfinite(c.z) and c.z > 0 else default
    if not TAKEOFF_ALT_RANGE[0] <= alt <= TAKEOFF_ALT_RANGE[1]:
        return ap.p.denied_result
    ap.guidance.set_takeoff_alt(alt)
    ap.set_mode(FlightMode.TAKEOFF)
    return ACCEPTED


def _enter(ap: CommandedAutopilot, behaviour: FlightMode, now: float) -> int:
    """LAND or RTL by command: only armed and in the air, unless the autopilot takes any mode disarmed."""
    if not ap.p.modes_free_when_disarmed and (not ap.vehicle.armed or ap.vehicle.landed):
        return ap.p.refused_result
    return ap.change_mode(ap.p.modes.by_name(ap.p.modes.shown[behaviour]), now)


def _land(ap: CommandedAutopilot, c: Command, now: float) -> int:
    return _enter(ap, FlightMode.LAND, now)


def _return_to_launch(ap: CommandedAutopilot, c: Command, now: float) -> int:
    return _enter(ap, FlightMode.RTL, now)


def _mission_start(ap: CommandedAutopilot, c: Command, now: float) -> int | Reply:
    p = c.params
    mission = ap.mission_protocol
    if ap.p.mission_start_needs_zero_params and not (p[0] == 0 and p[1] == 0):
        return DENIED  # ArduCopter: first/last item not supported
    if ap.p.mission_start_checks_mission:  # PX4: the stored mission must be valid
        if mission.refusal is not None:
            ap.out.say(mission.refusal)
        if not mission.items or mission.refusal is not None:
            return Reply(DENIED, texts=("mission_start_no_mission",))
    first = int(p[0]) if math.isfinite(p[0]) and abs(p[0]) < 2**31 else -2
    if ap.p.mission_start_needs_zero_params or first == -1:
        first = mission.current
    if not 0 <= first < len(mission.items) and ap.p.mission_start_checks_mission:
        return DENIED
    row = ap.p.modes.by_name(ap.p.modes.shown[FlightMode.MISSION])
    if ap.p.mission_start_arms and not ap.vehicle.armed:
        refusal = ap.arm_refusal(now, False)
        if refusal is not None:
            ap.out.say(refusal)
            ap.out.say("mode_refused", label=row.label)
            return mav.MAV_RESULT_TEMPORARILY_REJECTED
        ap.arm(now, "armed_mission_start")
    return ap.change_mode(row, now, first=first)


def _set_mode(ap: CommandedAutopilot, c: Command, now: float) -> int:
    p = c.params
    if not all(math.isfinite(v) for v in p[:3]):
        return DENIED
    row = ap.p.modes.from_command(p[1], p[2]) if int(p[0]) & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED else None
    if row is None:
        return UNSUPPORTED
    return ap.change_mode(row, now)


def _reposition(ap: CommandedAutopilot, c: Command, now: float) -> int:
    if not ap.vehicle.armed or ap.vehicle.landed:
        return ap.p.refused_result
    if not (math.isfinite(c.x) and math.isfinite(c.y) and -90 <= c.x <= 90 and -180 <= c.y <= 180):
        return DENIED
    n, e = ne_of(ap.home, GeoPoint(c.x, c.y))
    alt = relative_alt(c.frame, c.z, ap.home_amsl) if math.isfinite(c.z) else ap.vehicle.k.alt
    if math.hypot(n, e) > MAX_DISTANCE_M or not REPOSITION_ALT_RANGE[0] <= alt <= REPOSITION_ALT_RANGE[1]:
        return DENIED
    speed = c.params[0]
    if math.isfinite(speed) and speed > 0:
        ap.guidance.set_speed(min(speed, MAX_SPEED))
    ap.set_mode(FlightMode.HOLD, ap.p.modes.by_name(ap.p.modes.shown[FlightMode.HOLD]))
    ap.guidance.fly_to(n, e, max(alt, 1.0))
    return ACCEPTED


def _change_speed(ap: CommandedAutopilot, c: Command, now: float) -> int:
    speed = c.params[1]
    if not (math.isfinite(speed) and 0 < speed <= MAX_SPEED):
        return DENIED
    ap.guidance.set_speed(speed)
    return ACCEPTED


def _set_mission_current(ap: CommandedAutopilot, c: Command, now: float) -> int:
    seq = int(c.params[0]) if math.isfinite(c.params[0]) else -1
    if not 0 <= seq < len(ap.mission_protocol.items):
        return DENIED
    ap.mission_protocol.set_current(seq)
    return ACCEPTED


def _request_capabilities(ap: CommandedAutopilot, c: Command, now: float) -> Reply:
    return Reply(ACCEPTED, message=mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION)


def _request_message(ap: CommandedAutopilot, c: Command, now: float) -> int | Reply:
    mid = int(c.params[0]) if math.isfinite(c.params[0]) else -1
    if mid not in ap.p.sendable:
        return UNSUPPORTED
    return Reply(ACCEPTED, message=mid)


def _set_message_interval(ap: CommandedAutopilot, c: Command, now: float) -> int:
    return ap.telemetry.set_interval(c.params, now)


def _gripper(ap: CommandedAutopilot, c: Command, now: float) -> int:
    ap.operate_gripper(c.params[1])
    return ACCEPTED


#: MAV_CMD -> handler; any other command is UNSUPPORTED
COMMANDS: Mapping[int, Handler] = MappingProxyType({
    mav.MAV_CMD_COMPONENT_ARM_DISARM: _arm_disarm,
    mav.MAV_CMD_NAV_TAKEOFF: _takeoff,
    mav.MAV_CMD_NAV_LAND: _land,
    mav.MAV_CMD_NAV_RETURN_TO_LAUNCH: _return_to_launch,
    mav.MAV_CMD_MISSION_START: _mission_start,
    mav.MAV_CMD_DO_SET_MODE: _set_mode,
    mav.MAV_CMD_DO_REPOSITION: _reposition,
    mav.MAV_CMD_DO_CHANGE_SPEED: _change_speed,
    mav.MAV_CMD_DO_SET_MISSION_CURRENT: _set_mission_current,
    mav.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: _request_capabilities,
    mav.MAV_CMD_REQUEST_MESSAGE: _request_message,
    mav.MAV_CMD_SET_MESSAGE_INTERVAL: _set_message_interval,
    mav.MAV_CMD_DO_GRIPPER: _gripper,
})


class CommandProtocol:
    """COMMAND_LONG and COMMAND_INT for one autopilot (``ap``), answered through ``COMMANDS``."""

    def __init__(self, ap: CommandedAutopilot) -> None:
        self.ap = ap
        self.handlers: Mapping[str, Callable[[Any, float], None]] = MappingProxyType({
            "COMMAND_LONG": lambda msg, now: self.handle(Command.from_long(msg), now),
            "COMMAND_INT": lambda msg, now: self.handle(Command.from_int(msg), now),
        })

    def handle(self, c: Command, now: float) -> None:
        out = self.ap.out
        before = len(out.frames)
        handler = COMMANDS.get(c.command)
        reply = handler(self.ap, c, now) if handler is not None else UNSUPPORTED
        if not isinstance(reply, Reply):
            reply = Reply(reply)
        said: list[bytes] = []
        if self.ap.p.says_after_ack:  # ArduPilot queues its texts: the reason comes after the ACK
            said, out.frames = out.frames[before:], out.frames[:before]
        self._ack(c, reply.result)
        out.frames.extend(said)
        if reply.message is not None:
            self.ap.telemetry.send_message(reply.message)
        for say in reply.texts:
            self.ap.out.say(say)

    def _ack(self, c: Command, result: int) -> None:
        out = self.ap.out
        out.send(mav.MAVLink_command_ack_message(c.command, result, 0, 0, *c.sender))
        if result != ACCEPTED:
            out.count(f"command_{mav.enums['MAV_RESULT'][result].name.removeprefix('MAV_RESULT_').lower()}", str(c.command))
