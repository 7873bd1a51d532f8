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

Whatever arrives on an endpoint, the station keeps flying. At most ``max_apps`` applications (16 by
default) hold a component id at once; one silent for ``app_expiry`` seconds (30) or whose TCP
connection closed is forgotten and its id freed for reuse. While the table is full, a new
application's frames are dropped. A frame that cannot be handled is dropped, never raised, and
counted by reason in ``counters`` (``stats()`` reports them with the application count).
"""

from __future__ import annotations

import logging
import math
import struct
from collections import Counter, deque
from dataclasses import dataclass, field
from typing import Any, Iterator

from pymavlink.dialects.v20 import common as mav
from zenoh import ZError

from zdrone.core import wire
from zdrone.core.mavlink import MESSAGE_CLASSES, FrameCodec, FrameError, encode_raw, read_header, rewrite_source
from zdrone.vehicle.transport import MavTransport

log = logging.getLogger(__name__)

MAV_CMD_REQUEST_OPERATOR_CONTROL = 32100
MSG_ID_CONTROL_STATUS, CRC_CONTROL_STATUS = 512, 184
GCS_CONTROL_STATUS_FLAGS_SYSTEM_MANAGER, GCS_CONTROL_STATUS_FLAGS_TAKEOVER_ALLOWED = 1, 2
#: the station's own component id (``gs.station.GCS_COMPID``), never given to an application
STATION_COMPID = mav.MAV_COMP_ID_MISSIONPLANNER
FIRST_APP_COMPID = 100
#: applications one gateway serves at once (each holds one GS component id)
MAX_APPS = 16
#: the most a gateway may be given: ids FIRST_APP_COMPID.. stay below the station's own component id
MAX_APPS_LIMIT = STATION_COMPID - FIRST_APP_COMPID
#: an application silent this long (seconds) is forgotten and its component id freed
APP_EXPIRY_S = 30.0
#: at most one warning per this many seconds for a repeated drop reason
WARN_PERIOD_S = 5.0
COMMAND_MSGIDS = (mav.MAVLINK_MSG_ID_COMMAND_LONG, mav.MAVLINK_MSG_ID_COMMAND_INT)
MISSION_WRITES = {mav.MAVLINK_MSG_ID_MISSION_COUNT, mav.MAVLINK_MSG_ID_MISSION_ITEM, mav.MAVLINK_MSG_ID_MISSION_ITEM_INT,
                  mav.MAVLINK_MSG_ID_MISSION_CLEAR_ALL, mav.MAVLINK_MSG_ID_MISSION_SET_CURRENT,
                  mav.MAVLINK_MSG_ID_MISSION_WRITE_PARTIAL_LIST}
#: what sending may raise: socket errors, a closed Zenoh session, a frame the link refuses to seal
SEND_ERRORS = (OSError, ZError, ValueError)
#: what encoding a reply may raise on field values out of range
ENCODE_ERRORS = (struct.error, ValueError, OverflowError)


@dataclass(frozen=True, slots=True)
class AppKey:
    """What tells one application from another: the gateway endpoint, the peer, its own ids."""

    transport: int
    peer: Any  # UDP address or TCP socket, as the transport reports it
    sysid: int
    compid: int


@dataclass
class App:
    """One application behind the gateway."""

    transport: int
    peer: Any
    sysid: int
    compid: int
    gs_compid: int
    last_seen: float = 0.0
    frames_in: int = 0
    frames_out: int = 0
    refused: int = 0
    last_text: float = -1e9  # when the last refusal STATUSTEXT went to it (at most one a second)
    decoder: FrameCodec = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.decoder = FrameCodec(self.sysid, self.compid)  # its own parser state: one app cannot confuse another

    @property
    def key(self) -> AppKey:
        return AppKey(self.transport, self.peer, self.sysid, self.compid)


class RateLimit:
    """True at most once per ``period`` seconds of the caller's clock."""

    def __init__(self, period: float = WARN_PERIOD_S) -> None:
        self.period = period
        self._next = -math.inf

    def ready(self, now: float) -> bool:
        if now < self._next:
            return False
        self._next = now + self.period
        return True


class AppTable:
    """The applications of one gateway, at most ``max_apps``, each with its own GS component id.

    Pure bookkeeping: no sockets and no clock (time is the caller's ``now``). Component ids are
    ``first_compid`` .. ``first_compid + max_apps - 1``; a freed id goes to the back of the queue, so
    the id of a forgotten application is reused as late as possible. A new application that finds
    the table full (none expired) is refused: ``None``, counted under ``app_table_full``.
    """

    def __init__(self, max_apps: int = MAX_APPS, expiry: float = APP_EXPIRY_S, first_compid: int = FIRST_APP_COMPID,
                 counters: Counter[str] | None = None) -> None:
        if not 1 <= first_compid <= 255 or not 1 <= max_apps <= 256 - first_compid:
            raise ValueError(f"{max_apps} applications from component id {first_compid} do not fit in 1..255")
        if not expiry > 0:
            raise ValueError(f"application expiry must be positive, not {expiry}")
        self.max_apps = max_apps
        self.expiry = expiry
        self.counters: Counter[str] = counters if counters is not None else Counter()
        self._apps: dict[AppKey, App] = {}
        self._by_compid: dict[int, App] = {}
        self._free: deque[int] = deque(range(first_compid, first_compid + max_apps))
        self._full_warning = RateLimit()
        self._full_drops = 0  # since the last warning

    def __len__(self) -> int:
        return len(self._apps)

    def __iter__(self) -> Iterator[App]:
        return iter(list(self._apps.values()))

    def get(self, key: AppKey, now: float) -> App | None:
        """The known application ``key``, marked as seen at ``now``."""
        app = self._apps.get(key)
        if app is not None:
            app.last_seen = now
        return app

    def by_compid(self, gs_compid: int) -> App | None:
        return self._by_compid.get(gs_compid)

    def add(self, key: AppKey, now: float) -> App | None:
        """A new application, or ``None`` (counted) if the table is full and none has expired."""
        if not self._free:
            self.expire(now)
        if not self._free:
            self.counters["app_table_full"] += 1
            self._full_drops += 1
            if self._full_warning.ready(now):
                log.warning("gateway: %d applications already (none silent for %.0f s): %d frame(s) of new "
                            "applications dropped, latest sysid %d compid %d from %s", len(self._apps), self.expiry,
                            self._full_drops, key.sysid, key.compid, key.peer)
                self._full_drops = 0
            return None
        app = App(key.transport, key.peer, key.sysid, key.compid, self._free.popleft(), last_seen=now)
        self._apps[key] = app
        self._by_compid[app.gs_compid] = app
        return app

    def lookup_or_add(self, key: AppKey, now: float) -> App | None:
        """The application ``key`` (seen at ``now``), added if new; ``None`` if the table is full."""
        app = self.get(key, now)
        return app if app is not None else self.add(key, now)

    def remove(self, key: AppKey) -> App | None:
        """Forget one application and free its component id."""
        app = self._apps.pop(key, None)
        if app is not None:
            del self._by_compid[app.gs_compid]
            self._free.append(app.gs_compid)
        return app

    def expire(self, now: float) -> list[App]:
        """Forget the applications silent for ``expiry`` seconds or more; return them."""
        gone = [a for a in self._apps.values() if now - a.last_seen >= self.expiry]
        for app in gone:
            self.remove(app.key)
            self.counters["app_expired"] += 1
        return gone


class GcsGateway:
    """Bridges local MAVLink applications and one drone of a ``GroundStation``.

    No input on a gateway endpoint ends the station: every frame is handled on its own, and a frame
    that cannot be handled is dropped and counted under a reason in ``counters`` (see ``stats``).
    """

    def __init__(self, station: Any, endpoints: list[str], drone: str | None = None, max_apps: int = MAX_APPS,
                 app_expiry: float = APP_EXPIRY_S) -> None:
        if not 1 <= max_apps <= MAX_APPS_LIMIT:
            raise ValueError(f"max_apps must be 1..{MAX_APPS_LIMIT}, not {max_apps}")
        self.station = station
        self.drone = drone or next(iter(station.views))
        if self.drone not in station.views:
            raise ValueError(f"the station does not serve {self.drone}")
        self.counters: Counter[str] = Counter()
        self.apps = AppTable(max_apps, app_expiry, FIRST_APP_COMPID, self.counters)
        self.transports = [MavTransport(e) for e in endpoints]
        self.codecs: dict[tuple[int, int], FrameCodec] = {}
        self._now = 0.0  # the latest ``now`` of the station's loop
        self._next_status = 0.0
        self._last_owner: str | None = "?"
        self._error_log = RateLimit()
        station.frame_listeners.append(self.on_drone_frame)
        station.loop_hooks.append(self.poll)

    @property
    def view(self) -> Any:
        return self.station.views[self.drone]

    def endpoints(self) -> list[str]:
        return [f"{t.endpoint.kind}:{t.endpoint.host}:{t.port}" for t in self.transports]

    def stats(self) -> dict[str, Any]:
        """Applications, drop counters by reason, and per-endpoint byte counts, for the station's status."""
        return {"apps": len(self.apps), "max_apps": self.apps.max_apps, "counters": dict(self.counters),
                "endpoints": {str(t.endpoint): {"rx_frames": t.rx_frames, "tx_frames": t.tx_frames,
                                                "skipped_bytes": t.skipped_bytes} for t in self.transports}}

    # ------------------------------------------------------------- applications
    def _app(self, ti: int, peer: Any, sysid: int, compid: int, now: float) -> App | None:
        key = AppKey(ti, peer, sysid, compid)
        app = self.apps.get(key, now)
        if app is None:
            app = self.apps.add(key, now)
            if app is None:
                return None
            log.info("gateway: application sysid %d compid %d on %s is GS component %d", sysid, compid,
                     self.transports[ti].endpoint, app.gs_compid)
            self.station.events.write("gcs_app", sysid=sysid, compid=compid, gs_compid=app.gs_compid)
        return app

    def _forget_apps(self, now: float) -> None:
        """Free the component ids of applications gone silent or whose TCP connection closed."""
        gone = [(a, "expired") for a in self.apps.expire(now)]
        for app in self.apps:
            t = self.transports[app.transport]
            if t.sock is None and app.peer not in t.tcp_clients:
                self.apps.remove(app.key)
                self.counters["app_disconnected"] += 1
                gone.append((app, "disconnected"))
        for app, why in gone:
            log.info("gateway: application sysid %d compid %d (GS component %d) %s", app.sysid, app.compid,
                     app.gs_compid, why)
            self.station.events.write("gcs_app_gone", sysid=app.sysid, compid=app.compid, gs_compid=app.gs_compid,
                                      reason=why)

    def _to_app(self, app: App, frame: bytes) -> None:
        app.frames_out += 1
        try:
            self.transports[app.transport].send(frame, app.peer)
        except OSError:
            self.counters["send_failed"] += 1

    def _reply(self, app: App, codec: FrameCodec, msg: Any) -> None:
        """Encode ``msg`` as the vehicle and send it to ``app``."""
        try:
            frame = codec.encode(msg)
        except ENCODE_ERRORS:
            self.counters["encode_failed"] += 1
            return
        self._to_app(app, frame)

    def _broadcast(self, frame: bytes) -> None:
        for t in self.transports:
            if t.has_peer():
                try:
                    t.send(frame)
                except OSError:
                    self.counters["send_failed"] += 1

    def _to_drone(self, view: Any, frame: bytes) -> None:
        try:
            self.station.send_frame(view, frame)
        except SEND_ERRORS:
            self.counters["send_failed"] += 1

    def _vehicle_codec(self, sysid: int, compid: int) -> FrameCodec:
        key = (sysid, compid)
        if key not in self.codecs:
            self.codecs[key] = FrameCodec(sysid, compid)
        return self.codecs[key]

    def _internal_error(self, what: str, now: float) -> None:
        """The last resort of a per-frame boundary: counted, logged with the stack (rate-limited)."""
        self.counters["internal_error"] += 1
        if self._error_log.ready(now):
            log.exception("gateway: %s dropped on an internal error (%d so far)", what, self.counters["internal_error"])

    # ------------------------------------------------------------ app -> drone
    def poll(self, now: float) -> None:
        """The station's loop hook: read the endpoints, forget silent applications, CONTROL_STATUS."""
        self._now = now
        for ti, t in enumerate(self.transports):
            try:
                frames = t.poll(0.0)
            except OSError as exc:
                self.counters["poll_failed"] += 1
                if self._error_log.ready(now):
                    log.warning("gateway: reading %s: %s", t.endpoint, exc)
                continue
            for frame, peer in frames:
                self.on_app_frame(ti, peer, frame, now)
        self._forget_apps(now)
        if now >= self._next_status or self.view.owner != self._last_owner:
            self._next_status = now + 1.0
            self._last_owner = self.view.owner
            self._control_status()

    def on_app_frame(self, ti: int, peer: Any, frame: bytes, now: float) -> None:
        """One frame from an application. Never raises: a frame that cannot be handled is counted."""
        self._now = now
        try:
            self._route_app_frame(ti, peer, frame, now)
        except Exception:  # the last resort: whatever an application sends, the station keeps flying
            self._internal_error(f"frame from {peer!r}", now)

    def _route_app_frame(self, ti: int, peer: Any, frame: bytes, now: float) -> None:
        try:
            hdr = read_header(frame)
        except FrameError:
            self.counters["malformed"] += 1
            return
        app = self._app(ti, peer, hdr.sysid, hdr.compid, now)
        if app is None:
            return  # counted by the table (app_table_full)
        app.frames_in += 1
        view = self.view
        if hdr.msgid in COMMAND_MSGIDS:
            msg = app.decoder.decode(frame)
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
        try:
            out = rewrite_source(frame, self.station.sysid, app.gs_compid)
        except (FrameError, KeyError, ValueError):
            self.counters["rewrite_failed"] += 1
            return
        self._to_drone(view, out)

    def _refuse(self, app: App, hdr: Any, frame: bytes, result: int, why: str) -> None:
        """Answer a frame that will not reach the vehicle as the vehicle would refuse it."""
        app.refused += 1
        self.counters["refused"] += 1
        codec = self._vehicle_codec(self.view.sysid, 1)
        if hdr.msgid in COMMAND_MSGIDS:
            msg = app.decoder.decode(frame)
            if msg is not None:
                self._reply(app, codec, mav.MAVLink_command_ack_message(msg.command, result, 0, 0, app.sysid, app.compid))
        elif hdr.msgid in MISSION_WRITES:
            msg = app.decoder.decode(frame)
            mtype = getattr(msg, "mission_type", 0) if msg is not None else 0
            self._reply(app, codec, mav.MAVLink_mission_ack_message(app.sysid, app.compid, mav.MAV_MISSION_DENIED, mtype))
        elif hdr.commanding and self._now - app.last_text >= 1.0:
            # everything outside the read-only allowlist is refused; say why once a second, not per frame
            app.last_text = self._now
            self._reply(app, codec, mav.MAVLink_statustext_message(mav.MAV_SEVERITY_WARNING, why.encode()[:50]))

    def _operator_control(self, app: App, msg: Any) -> None:
        """MAV_CMD_REQUEST_OPERATOR_CONTROL: ours already, or ask the drone's authority for it."""
        codec = self._vehicle_codec(self.view.sysid, 1)
        view = self.view
        if self.station.holds_authority(view):
            result = mav.MAV_RESULT_ACCEPTED
        elif view.link is None:
            result = mav.MAV_RESULT_TEMPORARILY_REJECTED
        else:
            try:
                self.station.send_control(view, wire.HandoverRequest(self.station.name, view.epoch))
            except SEND_ERRORS:
                self.counters["send_failed"] += 1
                result = mav.MAV_RESULT_FAILED
            else:
                self.station.events.write("operator_control_requested", drone=self.drone, by_sysid=app.sysid)
                result = mav.MAV_RESULT_IN_PROGRESS
        self._reply(app, codec, mav.MAVLink_command_ack_message(msg.command, result, 0, 0, app.sysid, app.compid))

    def _control_status(self) -> None:
        """CONTROL_STATUS (512) on the vehicle's behalf: which GS (sysid) is in control."""
        view = self.view
        if view.link is None or not self.apps:
            return
        owner = view.owner
        sysid = self.station.fleet.nodes[owner].sysid if owner in self.station.fleet.nodes else 0
        flags = GCS_CONTROL_STATUS_FLAGS_SYSTEM_MANAGER | GCS_CONTROL_STATUS_FLAGS_TAKEOVER_ALLOWED
        try:
            frame = encode_raw(MSG_ID_CONTROL_STATUS, CRC_CONTROL_STATUS, struct.pack("<BB", sysid, flags), view.sysid, 1)
        except ENCODE_ERRORS:
            self.counters["encode_failed"] += 1
            return
        self._broadcast(frame)

    # ------------------------------------------------------------ drone -> app
    def on_drone_frame(self, drone: str, frame: bytes) -> None:
        """One frame the station opened from the drone. Never raises."""
        if drone != self.drone or not self.apps:
            return
        try:
            self._route_drone_frame(frame)
        except Exception:  # the last resort, as for application frames
            self._internal_error(f"frame from {drone}", self._now)

    def _route_drone_frame(self, frame: bytes) -> None:
        try:
            hdr = read_header(frame)
        except FrameError:
            self.counters["drone_malformed"] += 1
            return
        cls = _TARGETED.get(hdr.msgid)
        if cls is None:
            self._broadcast(frame)
            return
        codec = self._vehicle_codec(hdr.sysid, hdr.compid)
        msg = codec.decode(frame)
        if msg is None:
            self.counters["drone_malformed"] += 1
            return
        target = getattr(msg, "target_system", 0)
        if target == 0:
            self._broadcast(frame)
        elif target == self.station.sysid:
            app = self.apps.by_compid(getattr(msg, "target_component", 0))
            if app is None:
                self.counters["unrouted"] += 1  # addressed to the station itself, or to a forgotten application
                return
            msg.target_system, msg.target_component = app.sysid, app.compid
            codec.mav.seq = hdr.seq
            try:
                out = bytes(msg.pack(codec.mav))
            except ENCODE_ERRORS:
                self.counters["encode_failed"] += 1
                return
            self._to_app(app, out)
        else:
            self.counters["for_other_gs"] += 1

    def close(self) -> None:
        for t in self.transports:
            t.close()


#: addressed messages of every dialect the GS decodes (common, development, ardupilotmega)
_TARGETED = {mid: cls for mid, cls in MESSAGE_CLASSES.items()
             if "target_system" in cls.fieldnames and "target_component" in cls.fieldnames}
