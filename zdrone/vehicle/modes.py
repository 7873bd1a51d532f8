"""Flight-mode names and landed state per autopilot: one pure table for the drone node and the GS.

An autopilot is named ``"px4"`` or ``"ardupilot"`` (``autopilot_name`` of HEARTBEAT's ``autopilot``
field), ``None`` for any other or not yet known. ``mode_name`` decodes HEARTBEAT's ``custom_mode``:

* PX4: main mode << 16 | sub mode << 24, named as the simulator flies them (``px4modes``):
  ``POSCTL`` (every manual main mode), ``HOLD``, ``TAKEOFF``, ``MISSION``, ``RTL``, ``LAND``;
  anything else ``custom:0x…``.
* ArduPilot: ArduCopter's mode numbers and names (``Mode::Number``): ``STABILIZE`` 0, ``AUTO`` 3,
  ``GUIDED`` 4, ``LOITER`` 5, ``RTL`` 6, ``LAND`` 9, ``POSHOLD`` 16, ...; an unknown number
  ``custom:N``. Plane and Rover number their modes differently: this table is Copter's.
* any other autopilot: ``custom:N``.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

from pymavlink.dialects.v20 import common as mav

from zdrone.vehicle.personality import ARDUCOPTER_MODES
from zdrone.vehicle.px4modes import FlightMode
from zdrone.vehicle.px4modes import mode_name as px4_mode_name

PX4 = "px4"
ARDUPILOT = "ardupilot"
_BY_MAV_AUTOPILOT: Mapping[int, str] = MappingProxyType({mav.MAV_AUTOPILOT_PX4: PX4,
                                                         mav.MAV_AUTOPILOT_ARDUPILOTMEGA: ARDUPILOT})

#: ArduCopter's flight modes, custom_mode -> name (ArduCopter/mode.h, Mode::Number)
ARDUCOPTER_MODE_NAMES: Mapping[int, str] = MappingProxyType({
    0: "STABILIZE", 1: "ACRO", 2: "ALT_HOLD", 3: "AUTO", 4: "GUIDED", 5: "LOITER", 6: "RTL", 7: "CIRCLE",
    9: "LAND", 11: "DRIFT", 13: "SPORT", 14: "FLIP", 15: "AUTOTUNE", 16: "POSHOLD", 17: "BRAKE", 18: "THROW",
    19: "AVOID_ADSB", 20: "GUIDED_NOGPS", 21: "SMART_RTL", 22: "FLOWHOLD", 23: "FOLLOW", 24: "ZIGZAG",
    25: "SYSTEMID", 26: "AUTOROTATE", 27: "AUTO_RTL", 28: "TURTLE",
    **{row.custom_mode: row.name for row in ARDUCOPTER_MODES.rows}})  # the simulator's rows: same numbers

#: what each autopilot calls the modes the companion itself commands (LAND and RTL) and the rest of
#: the reference flight: taking off, flying the mission, holding
MODE_ROLES: Mapping[str, Mapping[str, str]] = MappingProxyType({
    PX4: MappingProxyType({"land": "LAND", "rtl": "RTL", "mission": "MISSION", "hold": "HOLD", "takeoff": "TAKEOFF"}),
    ARDUPILOT: MappingProxyType({"land": "LAND", "rtl": "RTL", "mission": "AUTO", "hold": "GUIDED",
                                 "takeoff": "GUIDED"}),
})


def autopilot_name(mav_autopilot: int | None) -> str | None:
    """``"px4"``, ``"ardupilot"`` or None, from HEARTBEAT's ``autopilot`` (MAV_AUTOPILOT_*)."""
    return _BY_MAV_AUTOPILOT.get(mav_autopilot) if mav_autopilot is not None else None


def _name(autopilot: str | int | None) -> str | None:
    return autopilot_name(autopilot) if isinstance(autopilot, int) else autopilot


def mode_name(autopilot: str | int | None, custom_mode: int) -> str:
    """The name of HEARTBEAT's ``custom_mode`` for this autopilot (a name or a MAV_AUTOPILOT_* number)."""
    ap = _name(autopilot)
    if ap == PX4:
        return px4_mode_name(custom_mode)
    if ap == ARDUPILOT:
        return ARDUCOPTER_MODE_NAMES.get(custom_mode, f"custom:{custom_mode}")
    return f"custom:{custom_mode}"


def custom_mode(autopilot: str | int | None, name: str) -> int | None:
    """The ``custom_mode`` number of a mode name for this autopilot; None if it has no such mode."""
    ap = _name(autopilot)
    if ap == PX4:
        mode = FlightMode.__members__.get(name)
        return mode.custom_mode if mode is not None else None
    if ap == ARDUPILOT:
        return next((n for n, m in ARDUCOPTER_MODE_NAMES.items() if m == name), None)
    return None


def set_mode_params(autopilot: str | int | None, name: str) -> tuple[float, float, float] | None:
    """MAV_CMD_DO_SET_MODE params 1-3 for a mode (PX4: main mode in param 2, sub mode in param 3;
    ArduPilot: the mode number in param 2); None if the autopilot has no such mode."""
    number = custom_mode(autopilot, name)
    if number is None:
        return None
    flag = float(mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED)
    if _name(autopilot) == PX4:
        return flag, float((number >> 16) & 0xFF), float((number >> 24) & 0xFF)
    return flag, float(number), 0.0


def landed_from_heartbeat(autopilot: str | int | None, system_status: int, armed: bool) -> int:
    """MAV_LANDED_STATE from HEARTBEAT alone, for when EXTENDED_SYS_STATE does not arrive.

    ArduPilot reports MAV_STATE_STANDBY exactly while landed and ACTIVE while flying (CRITICAL and
    EMERGENCY in a failsafe say nothing about it). Any autopilot: a disarmed multicopter is on the
    ground. Otherwise undefined."""
    if _name(autopilot) == ARDUPILOT:
        if system_status == mav.MAV_STATE_STANDBY:
            return mav.MAV_LANDED_STATE_ON_GROUND
        if system_status == mav.MAV_STATE_ACTIVE and armed:
            return mav.MAV_LANDED_STATE_IN_AIR
    return mav.MAV_LANDED_STATE_ON_GROUND if not armed else mav.MAV_LANDED_STATE_UNDEFINED
