"""Autopilot personalities of the built-in simulator: where PX4 (v1.16) and ArduCopter (4.7) differ.

A ``Personality`` is a frozen table of values and small pure rules; it holds no state. The simulator
(``zdrone.vehicle.sim.SimAutopilot``) consults it wherever the two autopilots behave differently for
a companion or a ground station:

* identity: HEARTBEAT autopilot type and flags, flight modes and their ``custom_mode`` numbers,
  AUTOPILOT_VERSION;
* texts: STATUSTEXT wording and severity, and for PX4 the EVENT (410) that carries the same refusal
  (PX4 marks such STATUSTEXTs with a trailing tab);
* readiness: arming refused, with the real texts, until ``ready_after`` simulated seconds after boot
  (stages scale with it), in the real order: GPS fix, (ArduPilot) EKF origin, position estimate;
  before the fix ArduPilot reports lat = lon = 0 and PX4 no GLOBAL_POSITION_INT until its estimate is
  global; AUTO needing the position estimate on ArduPilot, which says why after its COMMAND_ACK;
* mission rules: PX4's feasibility check at MISSION_START, ArduPilot's item 0 = home, its
  "Missing Takeoff Cmd" and its disarm at a mid-mission landing unless ``MIS_OPTIONS`` bit 2;
* auto-disarm, streams (ArduPilot sends nothing but HEARTBEAT until asked), extra message ids,
  parameter names, defaults and encoding, the link-loss failsafe and the default endpoints.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import Protocol

from pymavlink.dialects.v20 import common as mav

from zdrone.core.fleet import ConfigError
from zdrone.vehicle.px4modes import FlightMode

# --------------------------------------------------------------------------- message ids
#: ids outside pymavlink's common dialect that PX4 v1.16 sends (EVENT family and friends)
MSG_LINK_NODE_STATUS = 8
MSG_TIME_ESTIMATE_TO_TARGET = 380
MSG_EVENT = 410
MSG_CURRENT_EVENT_SEQUENCE = 411
MSG_CURRENT_MODE = 436  # in pymavlink's development dialect
#: CRC_EXTRA of the ids no pymavlink dialect here defines (from the MAVLink definitions)
RAW_CRC_EXTRA: Mapping[int, int] = MappingProxyType({
    MSG_LINK_NODE_STATUS: 117, MSG_TIME_ESTIMATE_TO_TARGET: 232, MSG_EVENT: 160, MSG_CURRENT_EVENT_SEQUENCE: 106})
#: ardupilotmega-dialect ids ArduCopter streams
MSG_MEMINFO, MSG_AHRS2, MSG_EKF_STATUS_REPORT = 152, 178, 193

M = mav  # short alias for the tables below


def px4_event_id(name: str) -> int:
    """PX4's EVENT id of an event name: ``(fnv1a32(name) & 0xffffff) | 1 << 24`` (autopilot component)."""
    h = 0x811C9DC5
    for byte in name.encode():
        h = ((h ^ byte) * 0x01000193) & 0xFFFFFFFF
    return (h & 0xFFFFFF) | (1 << 24)


@dataclass(frozen=True, slots=True)
class Say:
    """One thing the autopilot tells the GCS: a STATUSTEXT and, for PX4, the EVENT behind it."""

    text: str
    severity: int = M.MAV_SEVERITY_INFO
    event: str | None = None  # PX4 event name; its id is ``px4_event_id(event)``
    log_levels: int = 0x66  # EVENT log levels: internal << 4 | external (6 info, 3 error, 2 critical)
    args: bytes = b""  # EVENT arguments (little-endian, as PX4 packs them)

    def format(self, **kw: object) -> "Say":
        """The same text with ``{name}`` placeholders filled in."""
        return replace(self, text=self.text.format(**kw))


# --------------------------------------------------------------------------------- modes
@dataclass(frozen=True, slots=True)
class ModeRow:
    """One flight mode as the autopilot names and numbers it, and the simulator behaviour behind it."""

    name: str
    custom_mode: int
    behaviour: FlightMode
    label: str = ""  # how the autopilot's own texts name it ("Mission", "AUTO")
    armable: bool = True  # arming is allowed in this mode
    user_takeoff: bool = True  # a NAV_TAKEOFF command is accepted in this mode
    needs_position: bool = False  # entering it while armed needs a position estimate (ArduPilot)
    guided_flag: bool = True  # HEARTBEAT base_mode carries MAV_MODE_FLAG_GUIDED_ENABLED
    standard_mode: int = 0  # MAV_STANDARD_MODE (CURRENT_MODE, PX4)


@dataclass(frozen=True, slots=True)
class ModeTable:
    """An autopilot's modes, the row shown when the simulator enters a behaviour by itself, and how
    DO_SET_MODE numbers a mode (PX4: main mode in param 2, sub mode in param 3; ArduPilot: param 2)."""

    rows: tuple[ModeRow, ...]
    shown: Mapping[FlightMode, str]
    px4_encoding: bool = False
    takeoff_keeps_mode: bool = False  # ArduPilot takes off in GUIDED/LOITER and stays in that mode

    def by_name(self, name: str) -> ModeRow:
        return next(r for r in self.rows if r.name == name)

    def by_custom(self, custom_mode: int) -> ModeRow | None:
        """The row of a ``custom_mode`` number, None if this autopilot has no such mode."""
        for r in self.rows:
            if r.custom_mode == custom_mode:
                return r
        if self.px4_encoding:  # PX4's manual main modes all fly as position control here
            mode = FlightMode.from_custom(custom_mode)
            return self.by_name(self.shown[mode]) if mode is not None else None
        return None

    def from_command(self, p2: float, p3: float) -> ModeRow | None:
        """The row DO_SET_MODE asks for (params 2 and 3, custom-mode flag already checked)."""
        if not (math.isfinite(p2) and math.isfinite(p3)) or abs(p2) > 2**24 or abs(p3) > 2**24:
            return None
        if self.px4_encoding:
            return self.by_custom(((int(p2) & 0xFF) << 16) | ((int(p3) & 0xFF) << 24))
        return self.by_custom(int(p2))

    def row_for(self, behaviour: FlightMode, current: ModeRow) -> ModeRow:
        """The row shown when the simulator switches to ``behaviour`` on its own."""
        if current.behaviour is behaviour:
            return current
        if behaviour is FlightMode.TAKEOFF and self.takeoff_keeps_mode and current.user_takeoff:
            return current
        return self.by_name(self.shown[behaviour])


def _px4_row(mode: FlightMode, label: str, standard: int) -> ModeRow:
    return ModeRow(mode.name, mode.custom_mode, mode, label, standard_mode=standard)


PX4_MODES = ModeTable(
    # MAV_STANDARD_MODE: 1 position hold, 5 safe recovery, 6 mission, 7 land, 8 take-off, 0 non-standard
    rows=(_px4_row(FlightMode.POSCTL, "Position", 1),
          _px4_row(FlightMode.HOLD, "Hold", 0),
          _px4_row(FlightMode.TAKEOFF, "Takeoff", 8),
          _px4_row(FlightMode.MISSION, "Mission", 6),
          _px4_row(FlightMode.RTL, "Return", 5),
          _px4_row(FlightMode.LAND, "Land", 7)),
    shown=MappingProxyType({m: m.name for m in FlightMode}),
    px4_encoding=True,
)

ARDUCOPTER_MODES = ModeTable(
    rows=(ModeRow("STABILIZE", 0, FlightMode.POSCTL, "STABILIZE", user_takeoff=False, guided_flag=False),
          ModeRow("ALT_HOLD", 2, FlightMode.POSCTL, "ALT_HOLD", guided_flag=False),
          ModeRow("AUTO", 3, FlightMode.MISSION, "AUTO", armable=False, user_takeoff=False, needs_position=True),
          ModeRow("GUIDED", 4, FlightMode.HOLD, "GUIDED", needs_position=True),
          ModeRow("LOITER", 5, FlightMode.HOLD, "LOITER", needs_position=True),
          ModeRow("RTL", 6, FlightMode.RTL, "RTL", armable=False, user_takeoff=False, needs_position=True),
          ModeRow("LAND", 9, FlightMode.LAND, "LAND", armable=False, user_takeoff=False, guided_flag=False),
          ModeRow("POSHOLD", 16, FlightMode.HOLD, "POSHOLD", needs_position=True)),
    shown=MappingProxyType({FlightMode.POSCTL: "STABILIZE", FlightMode.HOLD: "GUIDED", FlightMode.TAKEOFF: "GUIDED",
                            FlightMode.MISSION: "AUTO", FlightMode.RTL: "RTL", FlightMode.LAND: "LAND"}),
    takeoff_keeps_mode=True,
)


# ------------------------------------------------------------------------------ readiness
@dataclass(frozen=True, slots=True)
class ReadyStage:
    """Arming is refused with ``arm_refusal`` until ``until`` × ready_after seconds after boot."""

    until: float
    arm_refusal: Say
    prearm: Say | None = None  # repeated every ``Readiness.prearm_every`` seconds meanwhile (ArduPilot)


@dataclass(frozen=True, slots=True)
class Readiness:
    """How an autopilot becomes ready after boot, in fractions of the configurable ``ready_after``."""

    stages: tuple[ReadyStage, ...]
    refused_result: int  # COMMAND_ACK result of a refused ARM
    position_at: float  # from here the vehicle has a position estimate (AUTO, GUIDED, ...)
    on_ready: Say | None = None  # said once when arming becomes possible
    on_position: Say | None = None  # said once when the position estimate is there
    prearm_every: float = 0.0
    gps_fix_at: float = 0.0  # from here the GPS has a 3D fix (GPS_RAW_INT), before the estimate uses it
    origin_at: float | None = None  # ArduPilot: the EKF's origin is set (between the fix and the estimate)
    on_origin: Say | None = None  # said once when the origin is set

    def arm_refusal(self, since_boot: float, ready_after: float) -> Say | None:
        for st in self.stages:
            if since_boot < st.until * ready_after:
                return st.arm_refusal
        return None

    def stage(self, since_boot: float, ready_after: float) -> ReadyStage | None:
        return next((st for st in self.stages if since_boot < st.until * ready_after), None)


# ------------------------------------------------------------------------------ mission rules
class _Item(Protocol):
    command: int


#: PX4 commands that do not count as "an item with a position" in its take-off rule
#: (FeasibilityChecker::checkTakeoff); every other command does, DO_GRIPPER included
PX4_NON_POSITIONAL = frozenset({
    0, 93, 177, 178, 179, 189, 2003, 203, 2000, 2001, 2500, 2501, 200, 204, 205, 1000, 1001, 201, 195, 196, 197,
    206, 260, 214, 530, 531, 532, 3000})


def px4_feasibility(items: Sequence[_Item]) -> Say | None:
    """PX4's mission feasibility rule that matters here: a NAV_TAKEOFF after any item with a position
    is refused ("takeoff not first waypoint item"). None if the mission is feasible."""
    found_position = False
    for it in items:
        if it.command == M.MAV_CMD_NAV_TAKEOFF and found_position:
            return PX4_TEXTS["mission_takeoff_not_first"]
        if it.command not in PX4_NON_POSITIONAL:
            found_position = True
    return None


def no_feasibility_check(items: Sequence[_Item]) -> Say | None:
    return None


MAV_CMD_NAV_LAST = 95  # ArduPilot: commands below this are navigation commands


def ardupilot_takeoff_next(items: Sequence[_Item], index: int) -> bool:
    """AP_Mission::is_takeoff_next: the next navigation command from ``index`` is a take-off
    (DO commands and NAV_DELAY skipped, at most 16 looked at)."""
    looked = 0
    for it in items[index:]:
        if it.command >= MAV_CMD_NAV_LAST:
            continue  # a DO command: not a navigation command
        looked += 1
        if looked > 16:
            return False
        if it.command == M.MAV_CMD_NAV_TAKEOFF:
            return True
        if it.command != M.MAV_CMD_NAV_DELAY:
            return False
    return False


def ardupilot_continues_after_land(mis_options: int, items: Sequence[_Item], land_index: int) -> bool:
    """AP_Mission::continue_after_land_check_for_takeoff: MIS_OPTIONS bit 2 set and the next
    navigation command after the landing is a take-off; otherwise ArduCopter disarms at touchdown."""
    return bool(mis_options & 4) and ardupilot_takeoff_next(items, land_index + 1)


def px4_continues_after_land(mis_options: int, items: Sequence[_Item], land_index: int) -> bool:
    return True  # PX4 lands, then takes off again by itself for the next item


# --------------------------------------------------------------------------------- parameters
@dataclass(slots=True)
class Param:
    """One parameter of the simulated autopilot (mutable: its value changes with PARAM_SET)."""

    value: float
    kind: int  # MAV_PARAM_TYPE_*
    low: float
    high: float
    writable: bool = True


_I8, _I16, _I32, _F32 = M.MAV_PARAM_TYPE_INT8, M.MAV_PARAM_TYPE_INT16, M.MAV_PARAM_TYPE_INT32, M.MAV_PARAM_TYPE_REAL32
ACCEPT_RADIUS_M = 2.0


def px4_params(sysid: int) -> dict[str, Param]:
    """PX4's parameter names and defaults (multicopter, SITL), plus the simulator's own SIM_*."""
    return {
        "COM_DL_LOSS_T": Param(10, _I32, 5, 300),
        "NAV_DLL_ACT": Param(0, _I32, 0, 3),  # 0 off: the companion's handover authority owns link loss
        "MPC_XY_CRUISE": Param(12.0, _F32, 1.0, 25.0),
        "MPC_Z_VEL_MAX_UP": Param(3.0, _F32, 0.5, 8.0),
        "MPC_Z_VEL_MAX_DN": Param(2.0, _F32, 0.5, 4.0),
        "MPC_ACC_HOR": Param(4.0, _F32, 1.0, 15.0),
        "MIS_TAKEOFF_ALT": Param(10.0, _F32, 1.0, 100.0),
        "RTL_RETURN_ALT": Param(30.0, _F32, 5.0, 150.0),
        "NAV_ACC_RAD": Param(ACCEPT_RADIUS_M, _F32, 0.5, 50.0),
        "COM_DISARM_LAND": Param(2.0, _F32, 0.0, 20.0),
        "COM_DISARM_PRFLT": Param(10.0, _F32, -1.0, 20.0),  # armed without taking off: disarm after this
        "MAV_SYS_ID": Param(sysid, _I32, 1, 255, writable=False),
        "SIM_BAT_DRAIN": Param(2.0, _F32, 0.0, 100.0),  # % per minute while armed
        "SIM_GPS_NOISE": Param(0.0, _F32, 0.0, 10.0),  # metres, 1 sigma, on reported position
    }


#: ArduPilot's stream groups (REQUEST_DATA_STREAM id -> MAVn_ parameter suffix)
AP_STREAM_PARAMS: Mapping[int, str] = MappingProxyType({
    M.MAV_DATA_STREAM_RAW_SENSORS: "RAW_SENS", M.MAV_DATA_STREAM_EXTENDED_STATUS: "EXT_STAT",
    M.MAV_DATA_STREAM_RC_CHANNELS: "RC_CHAN", M.MAV_DATA_STREAM_RAW_CONTROLLER: "RAW_CTRL",
    M.MAV_DATA_STREAM_POSITION: "POSITION", M.MAV_DATA_STREAM_EXTRA1: "EXTRA1", M.MAV_DATA_STREAM_EXTRA2: "EXTRA2",
    M.MAV_DATA_STREAM_EXTRA3: "EXTRA3"})
#: the messages of each ArduPilot stream group the simulator can produce
AP_STREAM_GROUPS: Mapping[int, tuple[int, ...]] = MappingProxyType({
    M.MAV_DATA_STREAM_RAW_SENSORS: (),
    M.MAV_DATA_STREAM_EXTENDED_STATUS: (M.MAVLINK_MSG_ID_SYS_STATUS, MSG_MEMINFO, M.MAVLINK_MSG_ID_MISSION_CURRENT,
                                        M.MAVLINK_MSG_ID_GPS_RAW_INT),
    M.MAV_DATA_STREAM_RC_CHANNELS: (),
    M.MAV_DATA_STREAM_RAW_CONTROLLER: (),
    M.MAV_DATA_STREAM_POSITION: (M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,),
    M.MAV_DATA_STREAM_EXTRA1: (M.MAVLINK_MSG_ID_ATTITUDE, MSG_AHRS2),
    M.MAV_DATA_STREAM_EXTRA2: (M.MAVLINK_MSG_ID_VFR_HUD,),
    M.MAV_DATA_STREAM_EXTRA3: (M.MAVLINK_MSG_ID_SYSTEM_TIME, M.MAVLINK_MSG_ID_BATTERY_STATUS, MSG_EKF_STATUS_REPORT),
})
AP_CHANNELS = 3  # SITL: serial0..2 are MAVLink (tcp 5760, 5762, 5763); MAV1_* is serial0's


def ardupilot_params(sysid: int) -> dict[str, Param]:
    """ArduCopter 4.7's names and defaults of the parameters that matter to a companion and a GS."""
    out = {
        "MAV_SYSID": Param(sysid, _I16, 1, 255),
        "MAV_GCS_SYSID": Param(255, _I16, 1, 255),
        "MAV_OPTIONS": Param(0, _I16, 0, 0xFFFF),
        "FS_GCS_ENABLE": Param(0, _I8, 0, 7),
        "FS_GCS_TIMEOUT": Param(5.0, _F32, 2.0, 120.0),
        "MIS_OPTIONS": Param(0, _I16, 0, 0xFFFF),
        "MIS_RESTART": Param(0, _I8, 0, 1),
        "DISARM_DELAY": Param(10, _I8, 0, 127),
        "AUTO_OPTIONS": Param(0, _I32, 0, 0xFFFF),
        "RTL_ALT_M": Param(15.0, _F32, 2.0, 300.0),
    }
    for n in range(1, AP_CHANNELS + 1):
        for suffix in ("RAW_SENS", "EXT_STAT", "RC_CHAN", "RAW_CTRL", "POSITION", "EXTRA1", "EXTRA2", "EXTRA3",
                       "PARAMS", "ADSB"):
            out[f"MAV{n}_{suffix}"] = Param(0, _I16, 0, 50)  # Copter: every stream off until asked
        out[f"MAV{n}_OPTIONS"] = Param(0, _I16, 0, 0xFFFF)
    out["SIM_BAT_DRAIN"] = Param(2.0, _F32, 0.0, 100.0)
    out["SIM_GPS_NOISE"] = Param(0.0, _F32, 0.0, 10.0)
    return out


# ------------------------------------------------------------------------------ link loss
@dataclass(frozen=True, slots=True)
class LinkLossRule:
    """The autopilot's own GCS-loss failsafe (off by default on both)."""

    action_param: str
    timeout_param: str
    actions: Mapping[int, FlightMode]  # parameter value -> what it does; others: ``default_action``
    default_action: FlightMode
    gcs_sysid_param: str | None = None  # only this sysid's heartbeats count (ArduPilot); None: any GCS


# ------------------------------------------------------------------------------ heartbeat
def px4_heartbeat(row: ModeRow, armed: bool, landed: bool) -> tuple[int, int]:
    base = (M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | M.MAV_MODE_FLAG_STABILIZE_ENABLED | M.MAV_MODE_FLAG_GUIDED_ENABLED
            | M.MAV_MODE_FLAG_AUTO_ENABLED)
    if armed:
        base |= M.MAV_MODE_FLAG_SAFETY_ARMED
    return base, M.MAV_STATE_ACTIVE if armed else M.MAV_STATE_STANDBY


def ardupilot_heartbeat(row: ModeRow, armed: bool, landed: bool) -> tuple[int, int]:
    """GCS_MAVLINK_Copter::base_mode / vehicle_system_status: STANDBY whenever landed."""
    base = M.MAV_MODE_FLAG_STABILIZE_ENABLED | M.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED | M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    if row.guided_flag:
        base |= M.MAV_MODE_FLAG_GUIDED_ENABLED
    if armed:
        base |= M.MAV_MODE_FLAG_SAFETY_ARMED
    return base, M.MAV_STATE_STANDBY if landed else M.MAV_STATE_ACTIVE


# ------------------------------------------------------------------------------ texts
_CRIT, _WARN, _INFO = M.MAV_SEVERITY_CRITICAL, M.MAV_SEVERITY_WARNING, M.MAV_SEVERITY_INFO
# PX4 arm_disarm_reason_t, the argument of its "Armed by" / "Disarmed by" events
_PX4_REASON = {"external command": 4, "mission start": 5, "landing": 6, "auto preflight disarming": 7}


def _px4_by(word: str, reason: str) -> Say:
    return Say(f"{word} by {reason}", _INFO, f"commander_{word.lower()}_by", 0x66, bytes([_PX4_REASON[reason]]))


PX4_TEXTS: Mapping[str, Say] = MappingProxyType({
    "armed": _px4_by("Armed", "external command"),
    "armed_mission_start": _px4_by("Armed", "mission start"),
    "disarmed_command": _px4_by("Disarmed", "external command"),
    "disarmed_landing": _px4_by("Disarmed", "landing"),
    "disarmed_preflight": _px4_by("Disarmed", "auto preflight disarming"),
    "landing_detected": Say("Landing detected", _INFO, "commander_landing_detected"),
    "takeoff_detected": Say("Takeoff detected", _INFO, "commander_takeoff_detected"),
    "arm_not_ready": Say("Arming denied: Resolve system health failures first", _CRIT,
                         "commander_arm_denied_resolve_failures", 0x62),
    "mission_takeoff_not_first": Say("Mission rejected: takeoff not first waypoint item", _CRIT,
                                     "navigator_mis_takeoff_not_first", 0x63),
    "mission_start_no_mission": Say("Mission start denied! No valid mission", _CRIT,
                                    "commander_mission_start_denied_no_mission", 0x62),
    "mode_refused": Say("Switching to {label} is currently not available", _CRIT, "commander_modeswitch_not_avail", 0x62),
    "ready": Say("Ready for takeoff!", _INFO),
    "link_lost": Say("Connection to ground station lost: {action}", _CRIT),
})

ARDUPILOT_TEXTS: Mapping[str, Say] = MappingProxyType({
    "armed": Say("Arming motors", _INFO),  # SITL builds say so
    "disarmed_command": Say("Disarming motors", _INFO),
    "disarmed_landing": Say("Disarming motors", _INFO),
    "disarmed_preflight": Say("Disarming motors", _INFO),
    "arm_mode_not_armable": Say("Arm: Mode not armable", _CRIT),
    "mode_requires_position": Say("Mode change to {label} failed: requires position", _WARN),
    "mode_init_failed": Say("Mode change to {label} failed: init failed", _WARN),
    "auto_missing_takeoff": Say("Auto: Missing Takeoff Cmd", _CRIT),
    "position_ready": Say("EKF3 IMU0 is using GPS", _INFO),
    "link_lost": Say("GCS Failsafe: {action}", _CRIT),
    "interval_unknown": Say("No ap_message for mavlink id ({msgid})", _INFO),
    "origin_set": Say("EKF3 IMU0 origin set", _INFO),
    "payload_released": Say("Gripper Released", _INFO),  # PX4 says nothing for DO_GRIPPER
})


def _ap_stage(until: float, reason: str) -> ReadyStage:
    return ReadyStage(until, Say(f"Arm: {reason}", _CRIT), Say(f"PreArm: {reason}", _CRIT))


# ------------------------------------------------------------------------------ the table
@dataclass(frozen=True)
class Personality:
    """Everything the simulator needs to know to behave like one autopilot."""

    name: str
    label: str
    autopilot: int  # HEARTBEAT autopilot (MAV_AUTOPILOT_*)
    modes: ModeTable
    boot_mode: str
    heartbeat: Callable[[ModeRow, bool, bool], tuple[int, int]]
    texts: Mapping[str, Say]
    events: bool  # texts with an event name are also sent as EVENT (410), and their STATUSTEXT ends in a tab
    chunk_statustext: bool  # long texts are split into chunks (MAVLink 2 id/chunk_seq) rather than cut
    readiness: Readiness
    real_ready_after: float  # seconds the real autopilot needs (documentation, tests)
    default_ready_after: float  # ``zdrone sim`` default: short, so that demos at speed-up stay fast
    params: Callable[[int], dict[str, Param]]
    param_bytewise: bool  # PX4 packs integers bytewise into PARAM_VALUE's float; ArduPilot casts
    param_range_checked: bool  # PX4 refuses out-of-range sets (answering the old value); ArduPilot takes them
    physics: Mapping[str, str | float]  # simulator quantity -> parameter name (read live) or constant
    default_streams: Mapping[int, float]  # message id -> interval (s) streamed from boot
    stream_groups: Mapping[int, tuple[int, ...]]  # REQUEST_DATA_STREAM groups (ArduPilot), empty: unsupported
    sendable: frozenset[int]  # ids SET_MESSAGE_INTERVAL / REQUEST_MESSAGE may ask for
    feasibility: Callable[[Sequence[_Item]], Say | None]
    continues_after_land: Callable[[int, Sequence[_Item], int], bool]
    home_item0: bool  # mission item 0 is home: stored as home, never flown
    mission_start_checks_mission: bool  # MISSION_START refuses a missing or infeasible mission (PX4)
    mission_start_arms: bool  # MISSION_START arms a disarmed vehicle (PX4)
    mission_start_needs_zero_params: bool  # MISSION_START with first/last item is DENIED (ArduCopter)
    auto_needs_takeoff_when_landed: bool  # ArduCopter's "Auto: Missing Takeoff Cmd"
    modes_free_when_disarmed: bool  # ArduPilot takes any mode while disarmed, checks come at arming
    refused_result: int  # COMMAND_ACK result of "not now" (PX4 TEMPORARILY_REJECTED, ArduPilot FAILED)
    denied_result: int  # COMMAND_ACK result of a refused mode change or disarm (PX4 DENIED, ArduPilot FAILED)
    takeoff_alt_amsl: bool  # NAV_TAKEOFF's param 7 is AMSL (PX4) or relative to home (ArduPilot)
    takeoff_needs_ground: bool  # a NAV_TAKEOFF command only on the ground (ArduPilot's do_user_takeoff)
    hold_after_touchdown: bool  # LAND/RTL switch to HOLD on the ground (PX4) or stay (ArduPilot)
    link_loss: LinkLossRule
    version: int  # AUTOPILOT_VERSION flight_sw_version
    capabilities: int
    banner: tuple[str, ...]  # texts sent when a GCS asks for the parameter list (ArduPilot)
    endpoint: str  # default ``--mavlink`` of ``zdrone sim``
    send_to: tuple[str, int] | None  # also send to this UDP address from boot (PX4's onboard link)
    boots_on_first_client: bool  # ArduPilot SITL waits for a client on its TCP port before it boots
    extra_ids: frozenset[int] = field(default_factory=frozenset)  # ids outside pymavlink's common dialect it sends
    ftp_refuses: bool = False  # answer MAVLink FTP with NAK (no such file) so clients fall back at once
    says_after_ack: bool = False  # what a command makes it say comes after its COMMAND_ACK (ArduPilot)
    zeros_before_fix: bool = False  # GLOBAL_POSITION_INT with lat = lon = 0 before the GPS fix (ArduPilot);
    # otherwise none at all until the position estimate is there (PX4)

    def text(self, key: str) -> Say | None:
        return self.texts.get(key)


_COMMON_STREAMS: Mapping[int, float] = MappingProxyType({
    M.MAVLINK_MSG_ID_HEARTBEAT: 1.0,
    M.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
    M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 0.25,
    M.MAVLINK_MSG_ID_ATTITUDE: 0.25,
    M.MAVLINK_MSG_ID_HOME_POSITION: 2.0,
    M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 1.0,
    M.MAVLINK_MSG_ID_BATTERY_STATUS: 2.0,
    M.MAVLINK_MSG_ID_GPS_RAW_INT: 1.0,
    M.MAVLINK_MSG_ID_MISSION_CURRENT: 1.0,
})
_PX4_EXTRA = {MSG_LINK_NODE_STATUS: 1.0, MSG_TIME_ESTIMATE_TO_TARGET: 1.0, MSG_CURRENT_EVENT_SEQUENCE: 1.0,
              MSG_CURRENT_MODE: 1.0}
_CAPS = (M.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT | M.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
         | M.MAV_PROTOCOL_CAPABILITY_MISSION_INT | M.MAV_PROTOCOL_CAPABILITY_COMMAND_INT | M.MAV_PROTOCOL_CAPABILITY_MAVLINK2)
_PHYSICS_PX4 = MappingProxyType({
    "cruise": "MPC_XY_CRUISE", "up": "MPC_Z_VEL_MAX_UP", "down": "MPC_Z_VEL_MAX_DN", "acc": "MPC_ACC_HOR",
    "takeoff_alt": "MIS_TAKEOFF_ALT", "rtl_alt": "RTL_RETURN_ALT", "accept_radius": "NAV_ACC_RAD",
    "disarm_land": "COM_DISARM_LAND", "disarm_preflight": "COM_DISARM_PRFLT", "bat_drain": "SIM_BAT_DRAIN",
    "gps_noise": "SIM_GPS_NOISE"})
_PHYSICS_AP = MappingProxyType({
    "cruise": 12.0, "up": 3.0, "down": 2.0, "acc": 4.0, "takeoff_alt": 10.0, "rtl_alt": "RTL_ALT_M",
    "accept_radius": ACCEPT_RADIUS_M, "disarm_land": 0.0, "disarm_preflight": "DISARM_DELAY",
    "bat_drain": "SIM_BAT_DRAIN", "gps_noise": "SIM_GPS_NOISE"})

PX4 = Personality(
    name="px4", label="PX4 v1.16", autopilot=M.MAV_AUTOPILOT_PX4, modes=PX4_MODES, boot_mode="HOLD",
    heartbeat=px4_heartbeat, texts=PX4_TEXTS, events=True, chunk_statustext=True,
    # the real one (speed-up 1): first HEARTBEAT ~3 s, "Ready for takeoff!" ~10-15 s after start
    readiness=Readiness(stages=(ReadyStage(1.0, PX4_TEXTS["arm_not_ready"]),),
                        refused_result=M.MAV_RESULT_TEMPORARILY_REJECTED, position_at=0.6,
                        on_ready=PX4_TEXTS["ready"], gps_fix_at=0.4),
    real_ready_after=10.0, default_ready_after=1.0,
    params=px4_params, param_bytewise=True, param_range_checked=True, physics=_PHYSICS_PX4,
    default_streams=MappingProxyType({**_COMMON_STREAMS, **_PX4_EXTRA}),
    stream_groups=MappingProxyType({}),
    sendable=frozenset(_COMMON_STREAMS) | frozenset(_PX4_EXTRA) | {M.MAVLINK_MSG_ID_AUTOPILOT_VERSION},
    feasibility=px4_feasibility, continues_after_land=px4_continues_after_land, home_item0=False,
    mission_start_checks_mission=True, mission_start_arms=True, mission_start_needs_zero_params=False,
    auto_needs_takeoff_when_landed=False, modes_free_when_disarmed=False,
    refused_result=M.MAV_RESULT_TEMPORARILY_REJECTED, denied_result=M.MAV_RESULT_DENIED,
    takeoff_alt_amsl=True, takeoff_needs_ground=False, hold_after_touchdown=True,
    link_loss=LinkLossRule("NAV_DLL_ACT", "COM_DL_LOSS_T", MappingProxyType({2: FlightMode.RTL}), FlightMode.LAND),
    version=(1 << 24) | (16 << 16) | (0 << 8) | 0xFF,
    capabilities=_CAPS | M.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE,
    banner=(), endpoint="udpin:127.0.0.1:14580", send_to=("127.0.0.1", 14540), boots_on_first_client=False,
    extra_ids=frozenset({MSG_LINK_NODE_STATUS, MSG_TIME_ESTIMATE_TO_TARGET, MSG_EVENT, MSG_CURRENT_EVENT_SEQUENCE,
                         MSG_CURRENT_MODE}),
)

ARDUPILOT = Personality(
    name="ardupilot", label="ArduCopter V4.7.0-dev", autopilot=M.MAV_AUTOPILOT_ARDUPILOTMEGA, modes=ARDUCOPTER_MODES,
    boot_mode="STABILIZE", heartbeat=ardupilot_heartbeat, texts=ARDUPILOT_TEXTS, events=False, chunk_statustext=False,
    # the real one at speed-up 1: GPS fix ~10 s (lat = lon = 0 before), "EKF3 IMU0 origin set" ~19 s,
    # "EKF3 IMU0 is using GPS" ~40 s (only then AUTO); arming refused for the first ~20-30 s
    readiness=Readiness(stages=(_ap_stage(0.5, "Accels inconsistent"), _ap_stage(0.75, "EKF attitude is bad")),
                        refused_result=M.MAV_RESULT_FAILED, position_at=1.0,
                        on_position=ARDUPILOT_TEXTS["position_ready"], prearm_every=30.0,
                        gps_fix_at=0.25, origin_at=0.475, on_origin=ARDUPILOT_TEXTS["origin_set"]),
    real_ready_after=40.0, default_ready_after=6.0,
    params=ardupilot_params, param_bytewise=False, param_range_checked=False, physics=_PHYSICS_AP,
    default_streams=MappingProxyType({M.MAVLINK_MSG_ID_HEARTBEAT: 1.0}),
    stream_groups=AP_STREAM_GROUPS,
    sendable=(frozenset(_COMMON_STREAMS) | {MSG_MEMINFO, MSG_AHRS2, MSG_EKF_STATUS_REPORT, M.MAVLINK_MSG_ID_VFR_HUD,
                                            M.MAVLINK_MSG_ID_SYSTEM_TIME, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION}),
    feasibility=no_feasibility_check, continues_after_land=ardupilot_continues_after_land, home_item0=True,
    mission_start_checks_mission=False, mission_start_arms=False, mission_start_needs_zero_params=True,
    auto_needs_takeoff_when_landed=True, modes_free_when_disarmed=True,
    refused_result=M.MAV_RESULT_FAILED, denied_result=M.MAV_RESULT_FAILED,
    takeoff_alt_amsl=False, takeoff_needs_ground=True, hold_after_touchdown=False,
    link_loss=LinkLossRule("FS_GCS_ENABLE", "FS_GCS_TIMEOUT",
                           MappingProxyType({4: FlightMode.LAND, 5: FlightMode.LAND, 7: FlightMode.LAND}),
                           FlightMode.RTL, gcs_sysid_param="MAV_GCS_SYSID"),
    version=(4 << 24) | (7 << 16) | (0 << 8) | 0,  # 4.7.0, FIRMWARE_VERSION_TYPE_DEV
    capabilities=_CAPS | M.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST,
    banner=("ArduCopter V4.7.0-dev (5a44524f)", "Frame: QUAD/X"),
    endpoint="tcpin:127.0.0.1:5760", send_to=None, boots_on_first_client=True,
    extra_ids=frozenset({MSG_MEMINFO, MSG_AHRS2, MSG_EKF_STATUS_REPORT}),
    ftp_refuses=True,  # MAVProxy asks ArduPilot for @PARAM/param.pck first; a NAK makes it use PARAM_REQUEST_LIST
    says_after_ack=True, zeros_before_fix=True,
)

PERSONALITIES: Mapping[str, Personality] = MappingProxyType({p.name: p for p in (PX4, ARDUPILOT)})


def personality(name: str) -> Personality:
    """The personality called ``name``; ``ConfigError`` if there is none."""
    try:
        return PERSONALITIES[name]
    except KeyError:
        raise ConfigError(f"autopilot {name!r}: expected one of {', '.join(PERSONALITIES)}") from None
