"""The GCS gateway: QGroundControl, MAVProxy or MAVSDK on a ground station fly the drone through the
secure link, as if the vehicle were connected to them directly.

Theory of operation
-------------------
The gateway exposes local MAVLink endpoints (``--gcs udpin:…``, ``udpout:…``, ``tcpin:…``). Each
application (a peer address plus its own sysid/compid) is given a component id of the GS; its frames
leave under the GS's fleet sysid and that component id (the drone's security module accepts only
the GS's sysid), then are sealed onto the GS's link. Frames from the drone are opened by the station
and handed here: broadcast telemetry goes to every application; a frame addressed to (GS sysid, an
application's component id) goes back to that application only, its target rewritten to the
application's own ids; frames addressed to another GS are not shown.

Authority is visible: while this GS does not hold authority, commanding frames are answered here with
the MAVLink-correct refusal (COMMAND_ACK ``DENIED``, MISSION_ACK ``DENIED``, a STATUSTEXT for the
rest) instead of vanishing at the drone. The operator-control protocol is spoken on the vehicle's
behalf: CONTROL_STATUS (512) every second says which GS (sysid) is in control, and
MAV_CMD_REQUEST_OPERATOR_CONTROL (32100) asks the drone's authority for a hand-over to this GS.
"""

from __future__ import annotations

import logging
import struct
from collections import Counter
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import common as mav

from zdrone.core import wire
from zdrone.core.mavlink import FrameCodec, FrameError, encode_raw, read_header, rewrite_source
from zdrone.vehicle.transport import MavTransport

log = logging.getLogger(__name__)

MAV_CMD_REQUEST_OPERATOR_CONTROL = 32100
MSG_ID_CONTROL_STATUS, CRC_CONTROL_STATUS = 512, 184
GCS_CONTROL_STATUS_FLAGS_SYSTEM_MANAGER, GCS_CONTROL_STATUS_FLAGS_TAKEOVER_ALLOWED = 1, 2
FIRST_APP_COMPID = 100
MISSION_WRITES = {mav.MAVLINK_MSG_ID_MISSION_COUNT, mav.MAVLINK_MSG_ID_MISSION_ITEM, mav.MAVLINK_MSG_ID_MISSION_ITEM_INT,
                  mav.MAVLINK_MSG_ID_MISSION_CLEAR_ALL, mav.MAVLINK_MSG_ID_MISSION_SET_CURRENT,
                  mav.MAVLINK_MSG_ID_MISSION_WRITE_PARTIAL_LIST}


@dataclass
class App:
    """One application behind the gateway."""

    transport: int
    peer: Any
    sysid: int
    compid: int
    gs_compid: int
    frames_in: int = 0
    frames_out: int = 0
    refused: int = 0


class GcsGateway:
    """Bridges local MAVLink applications and one drone of a ``GroundStation``."""

    def __init__(self, station: Any, endpoints: list[str], drone: str | None = None) -> None:
        self.station = station
        self.drone = drone or next(iter(station.views))
        if self.drone not in station.views:
            raise ValueError(f"the station does not serve {self.drone}")
        self.transports = [MavTransport(e) for e in endpoints]
        self.apps: dict[tuple[int, Any, int, int], App] = {}
        self.by_compid: dict[int, App] = {}
        self.counters: Counter[str] = Counter()
        self.codecs: dict[tuple[int, int], FrameCodec] = {}
        self._next_status = 0.0
        self._last_owner: str | None = "?"
        station.frame_listeners.append(self.on_drone_frame)
        station.loop_hooks.append(self.poll)

    @property
    def view(self) -> Any:
        return self.station.views[self.drone]

    def endpoints(self) -> list[str]:
        return [f"{t.endpoint.kind}:{t.endpoint.host}:{t.port}" for t in self.transports]

    # ------------------------------------------------------------- applications
    def _app(self, ti: int, peer: Any, sysid: int, compid: int) -> App:
        key = (ti, peer, sysid, compid)
        app = self.apps.get(key)
        if app is None:
            gs_compid = FIRST_APP_COMPID + len(self.apps)
            app = App(ti, peer, sysid, compid, gs_compid)
            self.apps[key] = app
            self.by_compid[gs_compid] = app
            log.info("gateway: application sysid %d compid %d on %s is GS component %d", sysid, compid,
                     self.transports[ti].endpoint, gs_compid)
            self.station.events.write("gcs_app", sysid=sysid, compid=compid, gs_compid=gs_compid)
        return app

    def _to_app(self, app: App, frame: bytes) -> None:
        app.frames_out += 1
        self.transports[app.transport].send(frame, app.peer)

    def _broadcast(self, frame: bytes) -> None:
        for t in self.transports:
            if t.has_peer():
                t.send(frame)

    def _vehicle_codec(self, sysid: int, compid: int) -> FrameCodec:
        key = (sysid, compid)
        if key not in self.codecs:
            self.codecs[key] = FrameCodec(sysid, compid)
        return self.codecs[key]

    # ------------------------------------------------------------ app -> drone
    def poll(self, now: float) -> None:
        for ti, t in enumerate(self.transports):
            for frame, peer in t.poll(0.0):
                self.on_app_frame(ti, peer, frame, now)
        if now >= self._next_status or self.view.owner != self._last_owner:
            self._next_status = now + 1.0
            self._last_owner = self.view.owner
            self._control_status()

    def on_app_frame(self, ti: int, peer: Any, frame: bytes, now: float) -> None:
        try:
            hdr = read_header(frame)
        except FrameError:
            self.counters["malformed"] += 1
            return
        app = self._app(ti, peer, hdr.sysid, hdr.compid)
        app.frames_in += 1
        view = self.view
        if hdr.msgid in (mav.MAVLINK_MSG_ID_COMMAND_LONG, mav.MAVLINK_MSG_ID_COMMAND_INT):
            msg = self._vehicle_codec(hdr.sysid, hdr.compid).decode(frame)
            if msg is not None and msg.command == MAV_CMD_REQUEST_OPERATOR_CONTROL:
                self._operator_control(app, msg)
                return
        if view.link is None:
            self.counters["no_link"] += 1
            self._refuse(app, hdr, frame, mav.MAV_RESULT_TEMPORARILY_REJECTED, "no link to the drone")
            return
        if hdr.commanding and not self.station.holds_authority(view):
            self._refuse(app, hdr, frame, mav.MAV_RESULT_DENIED, f"{self.station.name} is not in control"
                         f" ({view.owner or 'nobody'} is)")
            return
        self.station.send_frame(view, rewrite_source(frame, self.station.sysid, app.gs_compid))

    def _refuse(self, app: App, hdr: Any, frame: bytes, result: int, why: str) -> None:
        """Answer a frame that will not reach the vehicle as the vehicle would refuse it."""
        app.refused += 1
        self.counters["refused"] += 1
        vehicle = self.view.sysid
        codec = self._vehicle_codec(vehicle, 1)
        if hdr.msgid in (mav.MAVLINK_MSG_ID_COMMAND_LONG, mav.MAVLINK_MSG_ID_COMMAND_INT):
            msg = codec.decode(frame)
            if msg is not None:
                self._to_app(app, codec.encode(mav.MAVLink_command_ack_message(msg.command, result, 0, 0, app.sysid, app.compid)))
        elif hdr.msgid in MISSION_WRITES:
            msg = codec.decode(frame)
            mtype = getattr(msg, "mission_type", 0) if msg is not None else 0
            self._to_app(app, codec.encode(mav.MAVLink_mission_ack_message(app.sysid, app.compid, mav.MAV_MISSION_DENIED, mtype)))
        elif hdr.commanding:
            self._to_app(app, codec.encode(mav.MAVLink_statustext_message(mav.MAV_SEVERITY_WARNING, why.encode()[:50])))

    def _operator_control(self, app: App, msg: Any) -> None:
        """MAV_CMD_REQUEST_OPERATOR_CONTROL: ours already, or ask the drone's authority for it."""
        codec = self._vehicle_codec(self.view.sysid, 1)
        view = self.view
        if self.station.holds_authority(view):
            result = mav.MAV_RESULT_ACCEPTED
        elif view.link is None:
            result = mav.MAV_RESULT_TEMPORARILY_REJECTED
        else:
            self.station.send_control(view, wire.HandoverRequest(self.station.name, view.epoch))
            self.station.events.write("operator_control_requested", drone=self.drone, by_sysid=app.sysid)
            result = mav.MAV_RESULT_IN_PROGRESS
        self._to_app(app, codec.encode(mav.MAVLink_command_ack_message(msg.command, result, 0, 0, app.sysid, app.compid)))

    def _control_status(self) -> None:
        """CONTROL_STATUS (512) on the vehicle's behalf: which GS (sysid) is in control."""
        view = self.view
        if view.link is None or not self.apps:
            return
        owner = view.owner
        sysid = self.station.fleet.nodes[owner].sysid if owner in self.station.fleet.nodes else 0
        flags = GCS_CONTROL_STATUS_FLAGS_SYSTEM_MANAGER | GCS_CONTROL_STATUS_FLAGS_TAKEOVER_ALLOWED
        self._broadcast(encode_raw(MSG_ID_CONTROL_STATUS, CRC_CONTROL_STATUS, struct.pack("<BB", sysid, flags),
                                   view.sysid, 1))

    # ------------------------------------------------------------ drone -> app
    def on_drone_frame(self, drone: str, frame: bytes) -> None:
        if drone != self.drone or not self.apps:
            return
        try:
            hdr = read_header(frame)
        except FrameError:
            return
        cls = _TARGETED.get(hdr.msgid)
        if cls is None:
            self._broadcast(frame)
            return
        codec = self._vehicle_codec(hdr.sysid, hdr.compid)
        msg = codec.decode(frame)
        if msg is None:
            return
        target = getattr(msg, "target_system", 0)
        if target == 0:
            self._broadcast(frame)
        elif target == self.station.sysid:
            app = self.by_compid.get(getattr(msg, "target_component", 0))
            if app is None:
                self.counters["unrouted"] += 1  # addressed to the station itself
                return
            msg.target_system, msg.target_component = app.sysid, app.compid
            codec.mav.seq = hdr.seq
            self._to_app(app, bytes(msg.pack(codec.mav)))
        else:
            self.counters["for_other_gs"] += 1

    def close(self) -> None:
        for t in self.transports:
            t.close()


_TARGETED = {mid: cls for mid, cls in mav.mavlink_map.items()
             if "target_system" in cls.fieldnames and "target_component" in cls.fieldnames}
