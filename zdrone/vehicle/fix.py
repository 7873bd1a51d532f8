"""Whether an autopilot's reported position is a position (sans-IO): a GPS fix, not (0, 0), an
absolute estimate.

ArduCopter sends GLOBAL_POSITION_INT with lat = lon = 0 until its GPS has a fix, and its EKF uses
GPS (EKF_STATUS_REPORT flag EKF_POS_HORIZ_ABS) only well after that; PX4 sends no
GLOBAL_POSITION_INT until its estimate is global. ``PositionFix`` is given every message
(``on_message``) and says what the position is (``position``, None while unknown) and, while it
is unknown, why (``unknown_because``). A report it never received (no GPS_RAW_INT, no
EKF_STATUS_REPORT) does not count against the position; a report that came does.
"""

from __future__ import annotations

from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as apm

from zdrone.core.geometry import GeoPoint

#: GPS_RAW_INT fix_type from which a position is a position (GPS_FIX_TYPE_3D_FIX)
MIN_FIX_TYPE = 3
MSG_EKF_STATUS_REPORT = 193


class PositionFix:
    """The vehicle's position as far as the autopilot itself vouches for it."""

    def __init__(self) -> None:
        self.reported: GeoPoint | None = None  # the last GLOBAL_POSITION_INT as sent (zeros included)
        self.fix_type: int | None = None  # the last GPS_RAW_INT fix_type; None: none seen
        self.ekf_flags: int | None = None  # the last EKF_STATUS_REPORT flags; None: none seen (PX4)
        self.course: tuple[float, float] | None = None  # the last GLOBAL_POSITION_INT's ground velocity (north, east m/s)

    def on_message(self, msg: Any) -> bool:
        """Take one message from the autopilot; True if it was one of those this class reads."""
        t = msg.get_type()
        if t == "GLOBAL_POSITION_INT":
            self.reported = GeoPoint(msg.lat / 1e7, msg.lon / 1e7, msg.relative_alt / 1000.0)
            self.course = (msg.vx / 100.0, msg.vy / 100.0)
        elif t == "GPS_RAW_INT":
            self.fix_type = int(msg.fix_type)
        elif t == "EKF_STATUS_REPORT":
            self.ekf_flags = int(msg.flags)
        else:
            return False
        return True

    @property
    def estimate_absolute(self) -> bool:
        """The autopilot's estimate has an absolute horizontal position (ArduPilot: its EKF uses GPS;
        an autopilot without EKF_STATUS_REPORT: a position is known)."""
        if self.ekf_flags is not None:
            return bool(self.ekf_flags & apm.EKF_POS_HORIZ_ABS) and not self.ekf_flags & apm.EKF_UNINITIALIZED
        return self.reported is not None

    @property
    def unknown_because(self) -> str | None:
        """Why there is no position (None: there is one)."""
        if self.reported is None:
            return "no position report"
        if self.fix_type is not None and self.fix_type < MIN_FIX_TYPE:
            return f"no GPS fix (fix type {self.fix_type})"
        if self.reported.lat == 0.0 and self.reported.lon == 0.0:
            return "position 0, 0 (no fix)"
        if not self.estimate_absolute:
            return "estimate not absolute (EKF not using GPS)"
        return None

    @property
    def position(self) -> GeoPoint | None:
        """The reported position if the autopilot vouches for it, else None."""
        return self.reported if self.unknown_because is None else None

    def describe(self) -> dict[str, Any]:
        """For a status: known or not, why, and the raw reports behind it."""
        return {"known": self.unknown_because is None, "why": self.unknown_because, "fix_type": self.fix_type,
                "ekf_flags": self.ekf_flags}
