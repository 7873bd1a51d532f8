"""The flight-controller link: one small interface to ``zdrone sim``, PX4 SITL, ArduPilot SITL or serial.

Connection strings are pymavlink's: ``udpout:127.0.0.1:14580`` (``zdrone sim``),
``udpin:0.0.0.0:14540`` (PX4 SITL's offboard port), ``tcp:127.0.0.1:5760`` (ArduPilot SITL),
``/dev/ttyACM0,921600`` (serial). The link forwards raw frames both ways, tracks what the drone
node needs to know (sysid, position, mode, armed, landed state) and commands LAND / RTL itself.
"""

from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass

os.environ.setdefault("MAVLINK20", "1")

from pymavlink import mavutil  # noqa: E402  (after MAVLINK20 is set)
from pymavlink.dialects.v20 import common as mav  # noqa: E402

from ..core.fleet import ConfigError  # noqa: E402
from ..core.geometry import GeoPoint  # noqa: E402
from .px4modes import mode_name  # noqa: E402

log = logging.getLogger(__name__)
COMPANION_COMPID = mav.MAV_COMP_ID_ONBOARD_COMPUTER

# ArduCopter flight-mode numbers used for LAND / RTL
ARDU_LAND, ARDU_RTL = 9, 6


@dataclass(frozen=True, slots=True)
class VehicleState:
    """What the companion knows of the vehicle at one instant."""

    sysid: int | None
    position: GeoPoint | None
    armed: bool
    mode: str
    landed_state: int
    autopilot: int | None


class VehicleLink:
    """Raw MAVLink frames to and from the flight controller, plus its tracked state."""

    def __init__(self, conn: str, companion_sysid: int = 1, baud: int = 57600) -> None:
        try:
            self.m = mavutil.mavlink_connection(conn, source_system=companion_sysid, source_component=COMPANION_COMPID,
                                                dialect="common", baud=baud, autoreconnect=True)
        except Exception as exc:  # mavutil raises assorted errors for bad strings / ports
            raise ConfigError(f"vehicle connection {conn!r}: {exc}") from None
        self.conn = conn
        self.sysid: int | None = None
        self.autopilot: int | None = None
        self.position: GeoPoint | None = None
        self.armed = False
        self.custom_mode = 0
        self.landed_state = mav.MAV_LANDED_STATE_UNDEFINED
        self.last_heartbeat: float | None = None
        self._last_hb_sent = 0.0

    def heartbeat(self, now: float | None = None) -> None:
        """Send the companion's own HEARTBEAT (at most 1 Hz) so UDP autopilots know where we are."""
        now = time.monotonic() if now is None else now
        if now - self._last_hb_sent >= 1.0:
            self._last_hb_sent = now
            self.m.mav.heartbeat_send(mav.MAV_TYPE_ONBOARD_CONTROLLER, mav.MAV_AUTOPILOT_INVALID, 0, 0, mav.MAV_STATE_ACTIVE)

    def recv(self, timeout: float = 0.0) -> list[bytes]:
        """Frames from the vehicle (raw bytes, as received), waiting up to ``timeout`` for the first."""
        out: list[bytes] = []
        deadline = time.monotonic() + timeout
        while True:
            msg = self.m.recv_msg()
            if msg is None:
                if out or time.monotonic() >= deadline:
                    return out
                self.m.select(min(0.01, max(0.0, deadline - time.monotonic())))
                continue
            if msg.get_type() == "BAD_DATA":
                continue
            self._track(msg)
            out.append(bytes(msg.get_msgbuf()))

    def _track(self, msg: object) -> None:
        t = msg.get_type()  # type: ignore[attr-defined]
        src = msg.get_srcSystem()  # type: ignore[attr-defined]
        if t == "HEARTBEAT" and msg.type not in (mav.MAV_TYPE_GCS, mav.MAV_TYPE_ONBOARD_CONTROLLER):  # type: ignore[attr-defined]
            self.sysid = src
            self.autopilot = msg.autopilot  # type: ignore[attr-defined]
            self.armed = bool(msg.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)  # type: ignore[attr-defined]
            self.custom_mode = msg.custom_mode  # type: ignore[attr-defined]
            self.last_heartbeat = time.monotonic()
        elif t == "GLOBAL_POSITION_INT" and src == self.sysid:
            self.position = GeoPoint(msg.lat / 1e7, msg.lon / 1e7, msg.relative_alt / 1000.0)  # type: ignore[attr-defined]
        elif t == "EXTENDED_SYS_STATE" and src == self.sysid:
            self.landed_state = msg.landed_state  # type: ignore[attr-defined]

    def send(self, frame: bytes) -> None:
        """Send one raw MAVLink frame to the vehicle."""
        self.m.write(frame)

    def state(self) -> VehicleState:
        mode = mode_name(self.custom_mode) if self.autopilot == mav.MAV_AUTOPILOT_PX4 else str(self.custom_mode)
        return VehicleState(self.sysid, self.position, self.armed, mode, self.landed_state, self.autopilot)

    def command(self, cmd: int, *params: float) -> None:
        p = list(params) + [0.0] * (7 - len(params))
        self.m.mav.command_long_send(self.sysid or 1, 1, cmd, 0, *p)

    def command_land(self) -> None:
        """Command LAND now (PX4: NAV_LAND; ArduPilot: LAND mode)."""
        if self.autopilot == mav.MAV_AUTOPILOT_ARDUPILOTMEGA:
            self.command(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, ARDU_LAND)
        else:
            self.command(mav.MAV_CMD_NAV_LAND, 0, 0, 0, float("nan"), float("nan"), float("nan"), float("nan"))

    def command_rtl(self) -> None:
        """Command return-to-launch now."""
        if self.autopilot == mav.MAV_AUTOPILOT_ARDUPILOTMEGA:
            self.command(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, ARDU_RTL)
        else:
            self.command(mav.MAV_CMD_NAV_RETURN_TO_LAUNCH)

    def wait_vehicle(self, timeout: float) -> bool:
        """Heartbeat until the vehicle's own HEARTBEAT has been seen; False on timeout."""
        deadline = time.monotonic() + timeout
        while self.sysid is None and time.monotonic() < deadline:
            self.heartbeat()
            self.recv(0.1)
        return self.sysid is not None

    def close(self) -> None:
        self.m.close()


