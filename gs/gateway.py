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
the MAVLink-correct refusal (COMMAND_ACK ``MAV_RESULT_NOT_IN_CONTROL``, MISSION_ACK ``DENIED``, a
STATUSTEXT for the rest) instead of vanishing at the drone; read-only requests (parameters, heartbeats)
pass. MAVLink operator control (``gs.opcontrol``) is spoken on the vehicle's behalf, bound to fleet
identities:

* CONTROL_STATUS (512, ``zdrone.core.mavcontrol``) to each application every second and whenever it
  changes: ``gcs_main`` is the application's own sysid while this GS is in control, else the owner
  GS's fleet sysid (never the application's own: several applications share sysid 255), 0 when nobody
  is; TAKEOVER_ALLOWED is the owner's setting.
* MAV_CMD_REQUEST_OPERATOR_CONTROL (32100) from an application is this GS's operator speaking: a
  request (answered FAILED while the owner's operator is asked, IN_PROGRESS then ACCEPTED when the
  owner allows takeover), a release or a consent when this GS is the owner.
* Another GS's request, passed on by the drone to this GS as the owner, is presented to every
  application as the vehicle's COMMAND_LONG 32100 (p4: the requester's sysid); their COMMAND_ACKs of it
  are taken here, never sent to the vehicle. The vehicle's own CONTROL_STATUS is not passed on.

Applications are told apart by MAVLink 2 signing (``gs.appkeys``): each has a key of its own, listed
by name in the GS's key file (``--gcs-keys``). A frame signed with a listed key names its application
(``key:<name>``); a wrongly signed one (another key, a replayed or stale timestamp) is dropped and
counted (``signing_dropped:<reason>``), whatever it is; replies to a signed application are signed
with its key. An unsigned frame is named by its address (``unsigned:<ip:port>``). ``--gcs-signing``:

* ``require``: only signed applications speak for the operator: MAV_CMD_REQUEST_OPERATOR_CONTROL in
  any form (request, release, consent, allow takeover) from an unsigned one is answered DENIED, its
  commanding frames are refused as from a GCS not in control (COMMAND_ACK NOT_IN_CONTROL, MISSION_ACK
  DENIED, a STATUSTEXT for the rest), each counted under ``unsigned_refused:<kind>``; it keeps
  read-only access (telemetry, parameter reads) and its CONTROL_STATUS never names it.
* ``prefer``: signed applications are named by their key; unsigned ones still work, named by address.
* ``off``: no signing: signatures are neither checked nor made.

With ``require`` or ``prefer``, an application that has signed is not heard unsigned again
(``signing_dropped:unsigned_after_signed``), and no application's SETUP_SIGNING goes to the vehicle
(MAVProxy's ``signing setup`` sends one; keys are provisioned in the key file, never over the link).

The replay state (each stream's last timestamp, ``gs.appkeys``) outlives the gateway: read when it
starts, written durably (``state_path``: beside the key file or in ``$ZDRONE_STATE_DIR``) at most once a
second while it changes and when the gateway closes, so a signed frame captured before a restart is a
replay after it. A state file that cannot be read is not trusted: no stream stamped before this start is
taken then (``signing_dropped:before_start``; an application whose clock lags the GS's waits that long).

Whatever arrives on an endpoint, the station keeps flying. The applications' table (at most
``max_apps`` at once, forgotten when silent or disconnected, an unsigned one evicted for a signed one,
a bound per peer address) and the gateway's side of signing are ``gs.apptable``'s. A frame that cannot
be handled is dropped, never raised, and counted by reason in ``counters`` (``stats()`` reports them
with the application count).
"""

from __future__ import annotations

import inspect
import logging
import math
import struct
import time
from collections import Counter
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import msgspec
from pymavlink.dialects.v20 import common as mav
from zenoh import ZError

from gs.appkeys import AppSigning, SigningKey, parse_mode
from gs.apptable import (APP_EXPIRY_S, FIRST_APP_COMPID, MAX_APPS, MAX_APPS_LIMIT, App, AppFrame, AppKey, AppTable,
                         OperatorApps, RateLimit)
from zdrone.core import fcsign
from zdrone.core import records as rec
from zdrone.core.authority import State as HaState
from zdrone.core.mavcontrol import (FLAG_SYSTEM_MANAGER, FLAG_TAKEOVER_ALLOWED, MAV_CMD_REQUEST_OPERATOR_CONTROL,
                                    MAV_RESULT_NOT_IN_CONTROL, MSG_ID_CONTROL_STATUS, ControlStatus,
                                    OperatorControlRequest, encode_control_status, parse_operator_request)
from zdrone.core.mavlink import MESSAGE_CLASSES, FrameCodec, FrameError, read_header, rewrite_source
from zdrone.vehicle.transport import MavTransport

log = logging.getLogger(__name__)

#: CONTROL_STATUS at least this often (and at once on a change)
CONTROL_STATUS_PERIOD_S = 1.0
COMMAND_MSGIDS = (mav.MAVLINK_MSG_ID_COMMAND_LONG, mav.MAVLINK_MSG_ID_COMMAND_INT)
MISSION_WRITES = {mav.MAVLINK_MSG_ID_MISSION_COUNT, mav.MAVLINK_MSG_ID_MISSION_ITEM, mav.MAVLINK_MSG_ID_MISSION_ITEM_INT,
                  mav.MAVLINK_MSG_ID_MISSION_CLEAR_ALL, mav.MAVLINK_MSG_ID_MISSION_SET_CURRENT,
                  mav.MAVLINK_MSG_ID_MISSION_WRITE_PARTIAL_LIST}
#: what sending may raise: socket errors, a closed Zenoh session, a frame the link refuses to seal
SEND_ERRORS = (OSError, ZError, ValueError)
#: what encoding a reply may raise on field values out of range
ENCODE_ERRORS = (struct.error, ValueError, OverflowError)
#: what an unsigned application may never get through when signing is required, by counted kind
UNSIGNED_KINDS = {mav.MAVLINK_MSG_ID_COMMAND_LONG: "command", mav.MAVLINK_MSG_ID_COMMAND_INT: "command",
                  **{m: "mission" for m in MISSION_WRITES}}


class GcsGateway(OperatorApps):
    """Bridges local MAVLink applications and one drone of a ``GroundStation``.

    No input on a gateway endpoint ends the station: every frame is handled on its own, and a frame
    that cannot be handled is dropped and counted under a reason in ``counters`` (see ``stats``).
    """

    def __init__(self, station: Any, endpoints: list[str], drone: str | None = None, max_apps: int = MAX_APPS,
                 app_expiry: float = APP_EXPIRY_S, signing: str = "prefer", keys: Iterable[SigningKey] = (),
                 clock: Callable[[], float] = time.time, state_path: str | Path | None = None) -> None:
        if not 1 <= max_apps <= MAX_APPS_LIMIT:
            raise ValueError(f"max_apps must be 1..{MAX_APPS_LIMIT}, not {max_apps}")
        self.signing_mode = parse_mode(signing)
        self.signing = AppSigning(keys)
        self._clock = clock  # the wall clock: signing timestamps are 10 us units since 2015
        self.state_path = Path(state_path) if state_path is not None else None
        self._saved_changes = -1  # ``signing.changes`` as last written (-1: never)
        self._next_save = -math.inf
        self._save_log = RateLimit()
        self._signed_peers: dict[int, dict[Any, str]] | None = None  # endpoint -> peer -> key name (None: stale)
        self._drop_logs: dict[str, RateLimit] = {}
        self.station = station
        self.drone = drone or station.drones[0]
        if self.drone not in station.drones:
            raise ValueError(f"the station does not serve {self.drone}")
        self.vehicle_sysid = station.drone_status(self.drone, 0.0).sysid
        self.counters: Counter[str] = Counter()
        self._now = 0.0  # the latest ``now`` of the station's loop
        if self.state_path is not None and self.signing_mode != "off" and len(self.signing):
            self._restore_signing_state(self.state_path)  # before any socket: a ConfigError leaves none open
        self.apps = AppTable(max_apps, app_expiry, FIRST_APP_COMPID, self.counters)
        self.transports = [MavTransport(e) for e in endpoints]
        self.codecs: dict[tuple[int, int], FrameCodec] = {}
        self._next_status = 0.0
        self._last_control: tuple[Any, ...] | None = None
        self._awaiting: dict[AppKey, float] = {}  # applications told IN_PROGRESS: their request's deadline
        self._shown: tuple[int, int] | None = None  # (seq, epoch) of the request presented to the applications
        self._seq = 0
        self._error_log = RateLimit()
        self._op_takes_app = _takes_app(station.operator_command)
        station.frame_listeners.append(self.on_drone_frame)
        station.loop_hooks.append(self.poll)

    def status(self, now: float) -> Any:
        """The drone as the station sees it (``gs.core.DroneSeen``)."""
        return self.station.drone_status(self.drone, now)

    def endpoints(self) -> list[str]:
        return [f"{t.endpoint.kind}:{t.endpoint.host}:{t.port}" for t in self.transports]

    def stats(self) -> dict[str, Any]:
        """Applications, drop counters by reason, and per-endpoint byte counts, for the station's status."""
        return {"apps": len(self.apps), "max_apps": self.apps.max_apps, "counters": dict(self.counters),
                "signing": {"mode": self.signing_mode, "keys": len(self.signing),
                            "apps": {str(a.gs_compid): self.identity(a) for a in self.apps}},
                "endpoints": {str(t.endpoint): {"rx_frames": t.rx_frames, "tx_frames": t.tx_frames,
                                                "skipped_bytes": t.skipped_bytes} for t in self.transports}}

    def _to_app(self, app: App, frame: bytes) -> None:
        app.frames_out += 1
        if app.signer is not None and self.signing_mode != "off":
            frame = self._signed(frame, app.signer, app.transport)
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
        """``frame`` to every peer of every endpoint: signed with its key to a signed application."""
        signers = self._peer_signers() if self.signing_mode != "off" else {}
        for ti, t in enumerate(self.transports):
            if not t.has_peer():
                continue
            mine = signers.get(ti)
            try:
                if not mine:
                    t.send(frame)
                    continue
                peers = list(t.udp_peers) if t.sock is not None else list(t.tcp_clients)
                signed: dict[str, bytes] = {}
                for peer in peers:
                    signer = mine.get(peer)
                    if signer is None:
                        t.send(frame, peer)
                        continue
                    if signer not in signed:
                        signed[signer] = self._signed(frame, signer, ti)
                    t.send(signed[signer], peer)
            except OSError:
                self.counters["send_failed"] += 1

    def _to_drone(self, frame: bytes) -> None:
        try:
            self.station.send_frame(self.drone, frame)
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
        self._operator_poll(now)
        self.save_signing_state(now)

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
        if hdr.sysid == self.vehicle_sysid:  # an application never speaks as the vehicle (a frame of ours sent back)
            self.counters["vehicle_sysid"] += 1
            return
        signer: SigningKey | None = None
        if self.signing_mode != "off" and fcsign.is_signed(frame):
            signer, why = self.signing.verify(frame, self._units(), self._peer_signers().get(ti, {}).get(peer))
            if signer is None:  # another key, altered, replayed or stale: nothing of it goes anywhere
                self._signing_drop(why or "bad_signature", peer, hdr, now)
                return
            try:
                frame = fcsign.strip(frame)
            except FrameError:
                self.counters["malformed"] += 1
                return
        app = self._app(ti, peer, hdr.sysid, hdr.compid, now, signed=signer is not None)
        if app is None:
            return  # counted by the table (app_table_full, app_peer_full)
        if signer is not None and app.signer != signer.name:
            log.info("gateway: application sysid %d compid %d from %s (GS component %d) signs with key %s", app.sysid,
                     app.compid, peer, app.gs_compid, signer.name)
            app.signer = signer.name
            self._signed_peers = None
        elif signer is None and app.signer is not None and self.signing_mode != "off":
            self._signing_drop("unsigned_after_signed", peer, hdr, now)  # not the application that signed
            return
        app.frames_in += 1
        if hdr.msgid == mav.MAVLINK_MSG_ID_SETUP_SIGNING and self.signing_mode != "off":
            self.counters["setup_signing_dropped"] += 1  # keys are the key file's, never the link's
            return
        trusted = self.trusted(app)
        sent = AppFrame(app, frame)  # decoded at most once on its way, by whichever step needs its fields
        if hdr.msgid in COMMAND_MSGIDS:
            msg = sent.msg
            if msg is not None and msg.command == MAV_CMD_REQUEST_OPERATOR_CONTROL:
                if msg.target_system != self.vehicle_sysid:  # ours to the applications (the request shown), sent back
                    self.counters["operator_request_not_for_vehicle"] += 1
                    return
                if not trusted:
                    self._refuse_unsigned(app, hdr, sent, "operator_control", mav.MAV_RESULT_DENIED, msg)
                    return
                self._operator_control(app, msg, now)
                return
        elif hdr.msgid == mav.MAVLINK_MSG_ID_COMMAND_ACK:
            msg = sent.msg
            if msg is not None and msg.command == MAV_CMD_REQUEST_OPERATOR_CONTROL:
                self.counters["operator_request_acked"] += 1  # the answer to a request we presented: ours
                return
        if not trusted and hdr.commanding:
            self._refuse_unsigned(app, hdr, sent, UNSIGNED_KINDS.get(hdr.msgid, "other"), MAV_RESULT_NOT_IN_CONTROL)
            return
        status = self.status(now)
        if not status.linked:
            self.counters["no_link"] += 1
            self._refuse(app, hdr, sent, mav.MAV_RESULT_TEMPORARILY_REJECTED, "no link to the drone")
            return
        if hdr.commanding and not self.station.holds_authority(self.drone):
            self._refuse(app, hdr, sent, MAV_RESULT_NOT_IN_CONTROL, f"{self.station.name} is not in control"
                         f" ({status.owner or 'nobody'} is)")
            return
        try:
            out = rewrite_source(frame, self.station.sysid, app.gs_compid)
        except (FrameError, KeyError, ValueError):
            self.counters["rewrite_failed"] += 1
            return
        self._to_drone(out)

    def _refuse(self, app: App, hdr: Any, frame: "AppFrame", result: int, why: str) -> None:
        """Answer a frame that will not reach the vehicle as the vehicle would refuse it."""
        app.refused += 1
        self.counters["refused"] += 1
        codec = self._vehicle_codec(self.vehicle_sysid, 1)
        if hdr.msgid in COMMAND_MSGIDS:
            msg = frame.msg
            if msg is not None:
                self._reply(app, codec, mav.MAVLink_command_ack_message(msg.command, result, 0, 0, app.sysid, app.compid))
        elif hdr.msgid in MISSION_WRITES:
            msg = frame.msg
            mtype = getattr(msg, "mission_type", 0) if msg is not None else 0
            self._reply(app, codec, mav.MAVLink_mission_ack_message(app.sysid, app.compid, mav.MAV_MISSION_DENIED, mtype))
        elif hdr.commanding and self._now - app.last_text >= 1.0:
            # everything outside the read-only allowlist is refused; say why once a second, not per frame
            app.last_text = self._now
            self._reply(app, codec, mav.MAVLink_statustext_message(mav.MAV_SEVERITY_WARNING, why.encode()[:50]))

    def _refuse_unsigned(self, app: App, hdr: Any, frame: "AppFrame", kind: str, result: int, msg: Any = None) -> None:
        """``--gcs-signing require``: what an unsigned application may not do, refused the MAVLink way
        and counted under ``unsigned_refused:<kind>``; the first of each kind and every request for
        operator control is logged, naming the application."""
        name = f"unsigned_refused:{kind}"
        self.counters[name] += 1
        who = self.identity(app)
        if kind == "operator_control" and msg is not None:
            log.warning("gateway: %s (sysid %d) may not speak for the operator (--gcs-signing require): "
                        "MAV_CMD_REQUEST_OPERATOR_CONTROL p1=%g p2=%g p4=%g DENIED", who, app.sysid, msg.param1,
                        msg.param2, msg.param4)
        elif self._drop_logs.setdefault(name, RateLimit()).ready(self._now):
            log.warning("gateway: %s (sysid %d): message %d refused, unsigned applications are read-only "
                        "(--gcs-signing require; %d so far)", who, app.sysid, hdr.msgid, self.counters[name])
        self._refuse(app, hdr, frame, result, "unsigned app: read-only")

    def _operator_command(self, app: App, req: Any, now: float) -> int:
        """The station's operator entry, told which application spoke (when it takes it)."""
        if self._op_takes_app:
            return int(self.station.operator_command(self.drone, req, now, app=self.identity(app), app_sysid=app.sysid))
        return int(self.station.operator_command(self.drone, req, now))

    def _operator_control(self, app: App, msg: Any, now: float) -> None:
        """MAV_CMD_REQUEST_OPERATOR_CONTROL from an application: this GS's operator requests, releases
        or consents (``gs.opcontrol``); answered at once, and again when an IN_PROGRESS one ends."""
        req = parse_operator_request(msg.param1, msg.param2, msg.param3, msg.param4)
        who = self.identity(app)
        unread = None
        if req is not None:
            req, unread = self._bind_to_shown(app, req, now)
        if req is None:
            self.counters["operator_request_bad"] += 1
            result = mav.MAV_RESULT_DENIED
        elif unread is not None:  # a consent to a request this application has not been shown long enough
            self.counters["operator_consent_unread"] += 1
            result = mav.MAV_RESULT_DENIED
            status = self.status(now)
            self.station.events.write_record(rec.OperatorConsentRefused(
                drone=self.drone, requester=status.request.requester if status.request is not None else "",
                named=None, reason=unread, app=who))
            log.warning("gateway: %s (sysid %d): consent refused: %s", who, app.sysid, unread)
            self._ack(app, msg.command, result)
            self._show(app, status, now, again=True)  # the request pending now, shown (again) to be read
            return
        else:
            try:
                result = self._operator_command(app, req, now)
            except SEND_ERRORS:
                self.counters["send_failed"] += 1
                result = mav.MAV_RESULT_FAILED
            if req.request:
                self.station.events.write_record(rec.OperatorControlRequested(drone=self.drone, by_sysid=app.sysid,
                                                                              app=who))
            if result == mav.MAV_RESULT_IN_PROGRESS:
                self._awaiting[app.key] = now + req.timeout
        log.info("gateway: %s (sysid %d): MAV_CMD_REQUEST_OPERATOR_CONTROL p1=%g p2=%g p3=%g p4=%g -> result %d", who,
                 app.sysid, msg.param1, msg.param2, msg.param3, msg.param4, result)
        self._ack(app, msg.command, result)

    def _bind_to_shown(self, app: App, req: OperatorControlRequest,
                       now: float) -> tuple[OperatorControlRequest, str | None]:
        """A consent (p1 = 0, or p1 = 1 with p2 = 1) whose p4 is 0 or the application's own sysid (as
        QGroundControl and MAVProxy send) names the requester of the one pending request presented to
        *this* application, in this epoch, alone and unchanged for ``CONSENT_READ_S``: p4 becomes that
        requester's sysid as the application was shown it. Such a consent while a request is pending
        that it has not been shown that long is refused (the reason, second). Anything else is left as
        it came (a p4 naming another GS is refused by ``gs.opcontrol``; with nothing pending, a release
        is a let-go and an "allow takeover" is refused there)."""
        if req.sysid not in (0, app.sysid) or (req.request and not req.takeover):
            return req, None
        status = self.status(now)
        pending = status.request if status.owned else None
        if pending is None:
            return req, None
        why = app.prompt.binds(pending, status.epoch, now)
        if why is not None:
            return req, why
        self.counters["operator_consent_bound"] += 1
        return msgspec.structs.replace(req, sysid=_not_the_apps(self._sysid_of(pending.requester), app.sysid)), None

    def _show(self, app: App, status: Any, now: float, again: bool = False) -> None:
        """Present the pending request of another GS to ``app`` (p4: the requester as it sees it)."""
        req = status.request
        if req is None:
            return
        if not app.prompt.show(req.seq, req.epoch, req.requester, now) and not again:
            return
        codec = self._vehicle_codec(self.vehicle_sysid, 1)
        p4 = _not_the_apps(self._sysid_of(req.requester), app.sysid)
        self._reply(app, codec, mav.MAVLink_command_long_message(
            app.sysid, app.compid, MAV_CMD_REQUEST_OPERATOR_CONTROL, 0, 1, 0, req.timeout, p4, 0, 0, 0))

    def _ack(self, app: App, command: int, result: int) -> None:
        codec = self._vehicle_codec(self.vehicle_sysid, 1)
        self._reply(app, codec, mav.MAVLink_command_ack_message(command, result, 0, 0, app.sysid, app.compid))

    def _operator_poll(self, now: float) -> None:
        """Operator control's periodic part: the final answers of requests in progress, another GS's
        request presented to the applications, CONTROL_STATUS."""
        status = self.status(now)
        owner = status.owned
        for key, deadline in list(self._awaiting.items()):
            if not owner and now < deadline:
                continue
            del self._awaiting[key]
            app = next((a for a in self.apps if a.key == key), None)
            if app is not None:  # still there: the request's final answer
                self._ack(app, MAV_CMD_REQUEST_OPERATOR_CONTROL, mav.MAV_RESULT_ACCEPTED if owner else mav.MAV_RESULT_FAILED)
        req = status.request
        shown = (req.seq, req.epoch) if req is not None else None
        if shown != self._shown and self.apps:
            self._shown = shown
            for app in self.apps:
                if req is None:
                    app.prompt.end(now)  # what it was shown ended: a consent that does not name it binds to nothing
                else:
                    self._show(app, status, now)
            if req is not None:
                self.station.events.write_record(rec.OperatorRequestShown(drone=self.drone, requester=req.requester,
                                                                          apps=len(self.apps)))
        takeover = status.takeover
        control = (status.linked, status.owner, status.epoch, status.state, owner, takeover)
        if now >= self._next_status or control != self._last_control:
            self._next_status = now + CONTROL_STATUS_PERIOD_S
            self._last_control = control
            self._control_status(status)

    def _sysid_of(self, gs: str | None) -> int:
        node = self.station.fleet.nodes.get(gs) if gs else None
        return node.sysid if node is not None else 0

    def _control_status(self, status: Any) -> None:
        """CONTROL_STATUS (512) on the vehicle's behalf, to each application: who is in control as that
        application should see it (itself while this GS is; never itself while another GS is)."""
        if not status.linked or not self.apps:
            return
        mine, takeover = status.owned, status.takeover
        in_control = None if status.state is HaState.FAILSAFE else status.owner
        owner_sysid = self._sysid_of(in_control)
        flags = FLAG_SYSTEM_MANAGER | (FLAG_TAKEOVER_ALLOWED if takeover and in_control else 0)
        for app in self.apps:  # an unsigned application under ``require`` is never the one in control
            main = app.sysid if mine and self.trusted(app) else _not_the_apps(owner_sysid, app.sysid)
            self._seq = (self._seq + 1) % 256
            try:
                frame = encode_control_status(ControlStatus(flags, main), self.vehicle_sysid, 1, self._seq)
            except ENCODE_ERRORS:
                self.counters["encode_failed"] += 1
                continue
            self._to_app(app, frame)

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
        if hdr.msgid == MSG_ID_CONTROL_STATUS:
            self.counters["vehicle_control_status"] += 1  # the gateway speaks operator control for the vehicle
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
        self.save_signing_state()
        for t in self.transports:
            t.close()


def _takes_app(operator_command: Any) -> bool:
    """Does the station's operator entry take the application's name (``app=``, ``app_sysid=``)?"""
    try:
        params = inspect.signature(operator_command).parameters
    except (TypeError, ValueError):
        return False
    return "app" in params and "app_sysid" in params


def _not_the_apps(sysid: int, app_sysid: int) -> int:
    """``sysid`` as an application should see another GCS: never its own sysid (0 stays 0, nobody)."""
    if sysid == 0 or sysid != app_sysid:
        return sysid
    return 255 if app_sysid != 255 else 254


#: addressed messages of every dialect the GS decodes (common, development, ardupilotmega)
_TARGETED = {mid: cls for mid, cls in MESSAGE_CLASSES.items()
             if "target_system" in cls.fieldnames and "target_component" in cls.fieldnames}
