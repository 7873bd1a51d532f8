"""The flight-controller link: one small interface to ``zdrone sim``, PX4 SITL, ArduPilot SITL or serial.

Connection strings are pymavlink's: ``udpout:127.0.0.1:14580`` (``zdrone sim``),
``udpin:0.0.0.0:14540`` (PX4 SITL's offboard port), ``tcp:127.0.0.1:5760`` (ArduPilot SITL),
``/dev/ttyACM0,921600`` (serial). The link forwards raw frames both ways, every well-formed frame
whatever its message id; its ``VehicleTracker`` (``zdrone.vehicle.tracker``) keeps what the drone
node needs to know (sysid, autopilot, position, mode, armed, landed state), asks the vehicle for the
streams the drone node and the GSs depend on (on connect and after a reboot), and the link commands
LAND / RTL itself with the autopilot's own mode numbers.
"""

from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass
from typing import Any

os.environ.setdefault("MAVLINK20", "1")

from pymavlink import mavutil  # noqa: E402  (after MAVLINK20 is set)
from pymavlink.dialects.v20 import common as mav  # noqa: E402

from ..core.fleet import ConfigError  # noqa: E402
from ..core.geometry import GeoPoint  # noqa: E402
from .modes import ARDUPILOT, set_mode_params  # noqa: E402
from .tracker import DEFAULT_STREAMS, StreamWant, Timing, VehicleTracker  # noqa: E402

log = logging.getLogger(__name__)
COMPANION_COMPID = mav.MAV_COMP_ID_ONBOARD_COMPUTER


@dataclass(frozen=True, slots=True)
class VehicleState:
    """What the companion knows of the vehicle at one instant."""

    sysid: int | None
    position: GeoPoint | None
    armed: bool
    mode: str  # ``modes.mode_name``: PX4 "HOLD", "MISSION", ...; ArduPilot "GUIDED", "AUTO", ...
    landed_state: int  # MAV_LANDED_STATE_*
    autopilot: str | None  # "px4", "ardupilot" or None


class VehicleLink:
    """Raw MAVLink frames to and from the flight controller, plus its tracked state and streams."""

    def __init__(self, conn: str, companion_sysid: int = 1, baud: int = 57600,
                 streams: tuple[StreamWant, ...] = DEFAULT_STREAMS, timing: Timing = Timing()) -> None:
        try:
            # ardupilotmega (a superset of common): its ids are checked and decoded; ids of no dialect pass raw
            self.m = mavutil.mavlink_connection(conn, source_system=companion_sysid, source_component=COMPANION_COMPID,
                                                dialect="ardupilotmega", baud=baud, autoreconnect=True)
        except Exception as exc:  # mavutil raises assorted errors for bad strings / ports
            raise ConfigError(f"vehicle connection {conn!r}: {exc}") from None
        self.conn = conn
        self.tracker = VehicleTracker(companion_sysid, COMPANION_COMPID, streams, timing)
        self._last_hb_sent = 0.0

    # ------------------------------------------------------------ tracked state
    @property
    def sysid(self) -> int | None:
        return self.tracker.sysid

    @property
    def autopilot(self) -> str | None:
        """``"px4"``, ``"ardupilot"`` (from the vehicle's HEARTBEAT) or None."""
        return self.tracker.autopilot

    @property
    def position(self) -> GeoPoint | None:
        return self.tracker.position

    @property
    def armed(self) -> bool:
        return self.tracker.armed

    @property
    def custom_mode(self) -> int:
        return self.tracker.custom_mode

    @property
    def mode(self) -> str:
        return self.tracker.mode

    @property
    def landed_state(self) -> int:
        return self.tracker.landed_state(time.monotonic())

    @property
    def last_heartbeat(self) -> float | None:
        return self.tracker.last_heartbeat

    def stream_stats(self) -> dict[str, Any]:
        """What was asked of the vehicle and what came (``VehicleTracker.stats``)."""
        return self.tracker.stats()

    def state(self) -> VehicleState:
        return VehicleState(self.sysid, self.position, self.armed, self.mode, self.landed_state, self.autopilot)

    # ------------------------------------------------------------------ frames
    def heartbeat(self, now: float | None = None) -> None:
        """Send the companion's own HEARTBEAT (at most 1 Hz) so UDP autopilots know where we are, and
        whatever the tracker has to ask of the vehicle."""
        now = time.monotonic() if now is None else now
        if now - self._last_hb_sent >= 1.0:
            self._last_hb_sent = now
            self.m.mav.heartbeat_send(mav.MAV_TYPE_ONBOARD_CONTROLLER, mav.MAV_AUTOPILOT_INVALID, 0, 0, mav.MAV_STATE_ACTIVE)
        self._flush(now)

    def _flush(self, now: float) -> None:
        for msg in self.tracker.poll(now):
            self.m.mav.send(msg)

    def recv(self, timeout: float = 0.0) -> list[bytes]:
        """Frames from the vehicle (raw bytes, as received), waiting up to ``timeout`` for the first."""
        out: list[bytes] = []
        deadline = time.monotonic() + timeout
        while True:
            msg = self.m.recv_msg()
            if msg is None:
                if out or time.monotonic() >= deadline:
                    break
                self.m.select(min(0.01, max(0.0, deadline - time.monotonic())))
                continue
            if msg.get_type() == "BAD_DATA":
                continue
            self.tracker.on_message(msg, time.monotonic())
            out.append(bytes(msg.get_msgbuf()))
        self._flush(time.monotonic())
        return out

    def send(self, frame: bytes) -> None:
        """Send one raw MAVLink frame to the vehicle."""
        self.m.write(frame)

    # ---------------------------------------------------------------- commands
    def command(self, cmd: int, *params: float) -> None:
        """COMMAND_LONG to the vehicle now; resent until acknowledged (bounded, see ``Timing``)."""
        self.m.mav.send(self.tracker.command(cmd, params, time.monotonic()))

    def _set_mode(self, name: str, fallback: int) -> None:
        params = set_mode_params(self.autopilot, name) if self.autopilot == ARDUPILOT else None
        if params is not None:
            self.command(mav.MAV_CMD_DO_SET_MODE, *params)
        else:
            nan = float("nan")
            self.command(fallback, *((0.0, 0.0, 0.0, nan, nan, nan, nan) if fallback == mav.MAV_CMD_NAV_LAND else ()))

    def command_land(self) -> None:
        """Command LAND now (ArduPilot: LAND mode, DO_SET_MODE 9; PX4 and others: MAV_CMD_NAV_LAND)."""
        self._set_mode("LAND", mav.MAV_CMD_NAV_LAND)

    def command_rtl(self) -> None:
        """Command return-to-launch now (ArduPilot: RTL mode, DO_SET_MODE 6; others: NAV_RETURN_TO_LAUNCH)."""
        self._set_mode("RTL", mav.MAV_CMD_NAV_RETURN_TO_LAUNCH)

    def wait_vehicle(self, timeout: float) -> bool:
        """Heartbeat until the vehicle's own HEARTBEAT has been seen; False on timeout."""
        deadline = time.monotonic() + timeout
        while self.sysid is None and time.monotonic() < deadline:
            self.heartbeat()
            self.recv(0.1)
        return self.sysid is not None

    def close(self) -> None:
        self.m.close()
