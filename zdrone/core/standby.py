"""What a drone streams to a ground station that does not command it (a *standby* GS).

The owner of authority (and the GS a hand-over is pending to) gets every vehicle frame. A standby
GS needs to know where the drone is and that its link lives, not the full stream: each of the
vehicle's periodic stream messages (``STREAMED``: position, attitude, status, ...) goes to it at
most once every ``STANDBY_INTERVAL_S``; everything else (HEARTBEAT, acknowledgements, parameters,
the mission protocol, text) goes as it comes. This keeps a slow radio's uplink for the owner and
what a GS can learn of a drone it does not command to what it needs, and makes the drone's
telemetry cost grow with its owner, not with every GS in reach. No clock: ``now`` is passed in.
"""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mav

#: Stream messages pymavlink's common dialect does not name: ArduPilot's MEMINFO, AHRS2 and
#: EKF_STATUS_REPORT; PX4's LINK_NODE_STATUS, TIME_ESTIMATE_TO_TARGET, CURRENT_EVENT_SEQUENCE and
#: CURRENT_MODE (development dialect).
_OTHER_STREAMED = (152, 178, 193, 8, 380, 411, 436)
#: The vehicle's periodic stream messages (PX4's defaults and ArduPilot's stream groups).
STREAMED: frozenset[int] = frozenset({
    mav.MAVLINK_MSG_ID_SYS_STATUS, mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, mav.MAVLINK_MSG_ID_ATTITUDE,
    mav.MAVLINK_MSG_ID_HOME_POSITION, mav.MAVLINK_MSG_ID_EXTENDED_SYS_STATE, mav.MAVLINK_MSG_ID_BATTERY_STATUS,
    mav.MAVLINK_MSG_ID_GPS_RAW_INT, mav.MAVLINK_MSG_ID_MISSION_CURRENT, mav.MAVLINK_MSG_ID_VFR_HUD,
    mav.MAVLINK_MSG_ID_SYSTEM_TIME, mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED, mav.MAVLINK_MSG_ID_ATTITUDE_QUATERNION,
    mav.MAVLINK_MSG_ID_RC_CHANNELS, mav.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW, mav.MAVLINK_MSG_ID_NAV_CONTROLLER_OUTPUT,
    mav.MAVLINK_MSG_ID_ALTITUDE, mav.MAVLINK_MSG_ID_ESTIMATOR_STATUS, mav.MAVLINK_MSG_ID_VIBRATION,
    mav.MAVLINK_MSG_ID_RAW_IMU, mav.MAVLINK_MSG_ID_SCALED_IMU, mav.MAVLINK_MSG_ID_SCALED_PRESSURE,
    mav.MAVLINK_MSG_ID_POWER_STATUS, *_OTHER_STREAMED})
#: A standby GS gets each stream message at most this often (seconds).
STANDBY_INTERVAL_S = 1.0


class StandbyStream:
    """Which vehicle frames go to a standby GS now (``allow``), one of each stream message per
    ``interval`` at most; what a GS was last sent is forgotten when it ``commands`` again."""

    def __init__(self, interval: float = STANDBY_INTERVAL_S) -> None:
        if interval <= 0:
            raise ValueError("interval must be positive")
        self.interval = interval
        self._last: dict[tuple[str, int], float] = {}
        self.held: int = 0  # frames not sent to a standby GS (counted, never silent)

    def allow(self, gs: str, msgid: int | None, now: float) -> bool:
        if msgid not in STREAMED:
            return True
        last = self._last.get((gs, msgid))
        if last is not None and now - last < self.interval:
            self.held += 1
            return False
        self._last[(gs, msgid)] = now
        return True

    def forget(self, gs: str) -> None:
        for key in [k for k in self._last if k[0] == gs]:
            del self._last[key]
