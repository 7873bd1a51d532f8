"""What the vehicle reports of itself, decoded once for the companion and the ground station (sans-IO).

``VehicleReport`` is given the autopilot's messages (``on_message(msg, now)``, a pymavlink message of
any dialect; it reads no clock) and holds what they say: HEARTBEAT (armed, ``custom_mode``, which
autopilot, named from the first one, MAV_TYPE, ``system_status``, when), SYS_STATUS (the pre-arm
checks' health, when the autopilot reports them), EXTENDED_SYS_STATE (the landed state, when),
STATUSTEXT (the last ``TEXTS_KEPT`` texts, trailing NULs, tabs and blanks cut: PX4 ends its texts
with a tab) and the position (``fix.PositionFix``: GLOBAL_POSITION_INT, GPS_RAW_INT,
EKF_STATUS_REPORT; when the last GLOBAL_POSITION_INT came). What a message changed that a caller
acts on comes back as small frozen values (``AutopilotHeard``, ``PositionReported``, ``TextHeard``);
the rest is read from the state.

Whose messages count is the caller's policy, not this class's: the companion's ``VehicleTracker``
gives it the frames of the drone's own system (HEARTBEAT and position of its autopilot's ids only),
the ground station's ``StationCore`` the frames its drone relays (HEARTBEATs of component 1 only).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Union

from pymavlink.dialects.v20 import common as mav

from zdrone.core.geometry import GeoPoint
from zdrone.vehicle.fix import MSG_EKF_STATUS_REPORT, PositionFix
from zdrone.vehicle.modes import autopilot_name

#: the vehicle's recent STATUSTEXTs kept (the mission reads a refusal's reasons from them)
TEXTS_KEPT = 8
#: the message ids ``VehicleReport`` reads (a caller may skip decoding any other)
READ_MSGIDS = frozenset({mav.MAVLINK_MSG_ID_HEARTBEAT, mav.MAVLINK_MSG_ID_SYS_STATUS,
                         mav.MAVLINK_MSG_ID_EXTENDED_SYS_STATE, mav.MAVLINK_MSG_ID_STATUSTEXT,
                         mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, mav.MAVLINK_MSG_ID_GPS_RAW_INT,
                         MSG_EKF_STATUS_REPORT})


@dataclass(frozen=True, slots=True)
class AutopilotHeard:
    """The first HEARTBEAT: which autopilot (``"px4"``, ``"ardupilot"``, ``"other"``) and MAV_TYPE."""

    autopilot: str
    mav_type: int


@dataclass(frozen=True, slots=True)
class PositionReported:
    """A GLOBAL_POSITION_INT came (whether it is a position: ``VehicleReport.position``)."""

    at: float


@dataclass(frozen=True, slots=True)
class TextHeard:
    """A STATUSTEXT, its text cleaned."""

    text: str
    severity: int


ReportChange = Union[AutopilotHeard, PositionReported, TextHeard]


def _text(msg: Any) -> str:
    return str(msg.text).rstrip("\t\x00 ")  # PX4 ends its texts with a tab


@dataclass(slots=True, kw_only=True)
class VehicleReport:
    """The vehicle's reported state, from its messages; ``on_message`` says what changed."""

    fix: PositionFix = field(default_factory=PositionFix)  # the vehicle's own word on its position
    position_at: float | None = None  # when the last GLOBAL_POSITION_INT came
    mav_autopilot: int | None = None  # HEARTBEAT's MAV_AUTOPILOT_*; None: no HEARTBEAT yet
    autopilot: str | None = None  # "px4" | "ardupilot" | "other", from the vehicle's first HEARTBEAT
    mav_type: int | None = None  # HEARTBEAT's MAV_TYPE_*
    armed: bool = False
    disarmed_at: float | None = None  # when a HEARTBEAT last reported armed -> disarmed
    custom_mode: int = 0
    system_status: int = mav.MAV_STATE_UNINIT
    heartbeat_at: float | None = None  # when the last HEARTBEAT came
    landed_state: int = mav.MAV_LANDED_STATE_UNDEFINED  # EXTENDED_SYS_STATE's, as last reported
    landed_at: float | None = None  # when EXTENDED_SYS_STATE last came; None: not since ``restart``
    prearm_ok: bool | None = None  # SYS_STATUS pre-arm health (None: not reported)
    texts: list[tuple[float, str]] = field(default_factory=list)  # the vehicle's recent STATUSTEXTs

    @property
    def position(self) -> GeoPoint | None:
        """Where the vehicle is, None while its autopilot has no position of its own (``PositionFix``)."""
        return self.fix.position

    def restart(self) -> None:
        """The autopilot rebooted (or its link came back): its position and landed state are unknown
        until it reports them again."""
        self.fix = PositionFix()
        self.position_at = None
        self.landed_state, self.landed_at = mav.MAV_LANDED_STATE_UNDEFINED, None

    def on_message(self, msg: Any, now: float) -> tuple[ReportChange, ...]:
        """Take one message from the vehicle; what it changed that a caller acts on (often nothing)."""
        t = msg.get_type()
        if self.fix.on_message(msg):  # GLOBAL_POSITION_INT, GPS_RAW_INT, EKF_STATUS_REPORT
            if t != "GLOBAL_POSITION_INT":
                return ()
            self.position_at = now
            return (PositionReported(now),)
        if t == "HEARTBEAT":
            return self._on_heartbeat(msg, now)
        if t == "SYS_STATUS":
            if msg.onboard_control_sensors_present & mav.MAV_SYS_STATUS_PREARM_CHECK:
                self.prearm_ok = bool(msg.onboard_control_sensors_health & mav.MAV_SYS_STATUS_PREARM_CHECK)
        elif t == "EXTENDED_SYS_STATE":
            self.landed_state, self.landed_at = msg.landed_state, now
        elif t == "STATUSTEXT":
            text = _text(msg)
            self.texts = (self.texts + [(now, text)])[-TEXTS_KEPT:]
            return (TextHeard(text, msg.severity),)
        return ()

    def _on_heartbeat(self, msg: Any, now: float) -> tuple[ReportChange, ...]:
        armed = bool(msg.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)
        if self.armed and not armed:
            self.disarmed_at = now
        self.armed, self.custom_mode, self.system_status = armed, msg.custom_mode, msg.system_status
        self.mav_autopilot, self.mav_type, self.heartbeat_at = msg.autopilot, msg.type, now
        if self.autopilot is not None:
            return ()
        self.autopilot = autopilot_name(msg.autopilot) or "other"  # which autopilot it is: said once
        return (AutopilotHeard(self.autopilot, msg.type),)
