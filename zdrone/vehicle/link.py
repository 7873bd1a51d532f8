"""The flight-controller link: one small interface to ``zdrone sim``, PX4 SITL, ArduPilot SITL or serial.

Connection strings are pymavlink's: ``udpout:127.0.0.1:14580`` (``zdrone sim``),
``udpin:0.0.0.0:14540`` (PX4 SITL's offboard port), ``tcp:127.0.0.1:5760`` (ArduPilot SITL),
``/dev/ttyACM0,921600`` (serial). The link forwards raw frames both ways, every well-formed frame
whatever its message id; its ``VehicleTracker`` (``zdrone.vehicle.tracker``) keeps what the drone
node needs to know (sysid, autopilot, position, mode, armed, landed state), asks the vehicle for the
streams the drone node and the GSs depend on (on connect and after a reboot), and the link commands
LAND / RTL itself with the autopilot's own mode numbers.

With an ``FcSigning`` (``zdrone.vehicle.fcsigning``) the link provisions MAVLink 2 signing in
``wait_vehicle`` (a key installed with SETUP_SIGNING, or the stored one), signs every frame it sends
and checks every frame it receives (dropped and counted when forged, replayed or, once the
autopilot signs, unsigned); the frames it hands on have their signature removed (the envelope
authenticates them beyond the companion).

Over UDP the link takes frames from the autopilot's endpoint only (``zdrone.vehicle.endpoint``: the
address it sends to with ``udpout:``; with ``udpin:`` the first address that proves to be the
autopilot) and sends to it only; its tracker adopts only the drone's own fleet sysid with the
autopilot's component. A position counts for authority only if it came signed
(``position_signed``), and only while it is fresh: a position not reported again within
``Timing.position_stale`` is unknown (``VehicleTracker.position_at``), so a relay that withholds the
autopilot's positions cannot freeze an old one in place. The listening socket of ``udpin:`` is the
link's own, bound without ``SO_REUSEADDR`` (``transport.bind_udp``): no other process can bind the
port after it and take the autopilot's datagrams. A LAND / RTL the link commands is followed until the autopilot shows it, and
sent again meanwhile (``VehicleTracker.watch_failsafe``).

Two ways to read it: ``recv`` (the caller polls; ``wait_vehicle`` and the tests), or, once
``start_reader`` is called, a reader thread of its own that waits on the connection and hands every
message to the caller's ``deliver`` at once (the drone node's inbox, which wakes its loop). The
reader only reads and hands over: the loop thread takes each message up with ``accept`` (the
tracker is only ever touched there). The connection is used by both threads, one call at a time
(``_io``): the reader holds it only for a non-blocking read, never while it waits.
"""

from __future__ import annotations

import logging
import os
import socket
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable

os.environ.setdefault("MAVLINK20", "1")

from pymavlink import mavutil  # noqa: E402  (after MAVLINK20 is set)
from pymavlink.dialects.v20 import common as mav  # noqa: E402

from zdrone.core import fcsign  # noqa: E402
from zdrone.core.fleet import ConfigError  # noqa: E402
from zdrone.core.mavlink import FrameError, split_frames  # noqa: E402
from zdrone.vehicle.endpoint import AutopilotEndpoint  # noqa: E402
from zdrone.vehicle.fcsigning import FcSigning, FcSigningError, FcState  # noqa: E402
from zdrone.core.geometry import GeoPoint  # noqa: E402
from zdrone.vehicle.modes import ARDUPILOT, set_mode_params  # noqa: E402
from zdrone.vehicle.transport import bind_udp  # noqa: E402
from zdrone.vehicle.tracker import AUTOPILOT_COMPID, DEFAULT_STREAMS, FailsafeOutcome, StreamWant, Timing, VehicleTracker  # noqa: E402

log = logging.getLogger(__name__)
COMPANION_COMPID = mav.MAV_COMP_ID_ONBOARD_COMPUTER
#: The companion's own HEARTBEAT goes to the vehicle this often.
HEARTBEAT_PERIOD_S = 1.0
#: The tracker's timeouts (command resends, stream requests) are a second and more: it is looked at
#: at least this often.
TRACKER_POLL_S = 0.25
#: The reader thread waits for the connection this long at most between looks at ``close``.
READ_WAIT_S = 0.1
#: Over a UDP endpoint the link learns, it listens this long after the first autopilot HEARTBEAT for
#: another address claiming the same ids (which would leave the autopilot unknown).
CLAIM_WINDOW_S = 1.5
#: Datagrams from other addresses dropped per read at most (then the reader looks at ``close`` again).
DROPS_PER_READ = 256


def _udp_listen_address(conn: str) -> tuple[str, int] | None:
    """HOST, PORT of a listening UDP connection string (pymavlink's ``udpin:`` and ``udp:``), else None."""
    scheme, sep, rest = conn.partition(":")
    if not sep or scheme not in ("udpin", "udp"):
        return None
    host, _, port = rest.removeprefix("//").rpartition(":")
    if not host or not port.isdigit():
        return None
    return host, int(port)


@dataclass(frozen=True, slots=True)
class VehicleState:
    """What the companion knows of the vehicle at one instant."""

    sysid: int | None
    position: GeoPoint | None
    armed: bool
    mode: str  # ``modes.mode_name``: PX4 "HOLD", "MISSION", ...; ArduPilot "GUIDED", "AUTO", ...
    landed_state: int  # MAV_LANDED_STATE_*
    autopilot: str | None  # "px4", "ardupilot" or None
    position_unknown: str | None = None  # why ``position`` is None (no GPS fix, 0/0, estimate not absolute)


class VehicleLink:
    """Raw MAVLink frames to and from the flight controller, plus its tracked state and streams."""

    def __init__(self, conn: str, companion_sysid: int = 1, baud: int = 57600,
                 streams: tuple[StreamWant, ...] = DEFAULT_STREAMS, timing: Timing = Timing(),
                 signing: FcSigning | None = None) -> None:
        listen = _udp_listen_address(conn)
        try:
            # ardupilotmega (a superset of common): its ids are checked and decoded; ids of no dialect pass raw
            # (a listening UDP socket: pymavlink's binds with SO_REUSEADDR, so it gets a throwaway port and
            # the link's own socket, bound without it, takes its place)
            self.m = mavutil.mavlink_connection(conn if listen is None else f"udpin:{listen[0]}:0",
                                                source_system=companion_sysid, source_component=COMPANION_COMPID,
                                                dialect="ardupilotmega", baud=baud, autoreconnect=True)
        except Exception as exc:  # mavutil raises assorted errors for bad strings / ports
            raise ConfigError(f"vehicle connection {conn!r}: {exc}") from None
        if listen is not None:
            self._own_udp_socket(conn, listen)
        self.conn = conn
        self.tracker = VehicleTracker(companion_sysid, COMPANION_COMPID, streams, timing)
        self._last_hb_sent = 0.0
        self._last_flush = 0.0
        self._io = threading.Lock()  # one call on the connection at a time (loop thread, reader thread)
        self._closing = threading.Event()
        self._reader: threading.Thread | None = None
        self.read_errors = 0
        self.signing = signing
        if signing is not None:  # only the autopilot's own signed stream proves it; ours are never taken back
            signing.expect((companion_sysid, AUTOPILOT_COMPID), (companion_sysid, COMPANION_COMPID))
        #: frames handed to ``send`` carrying the autopilot's own ids, not sent (the companion never
        #: signs a frame as the autopilot: that would be the proof a reflection needs)
        self.refused_autopilot_ids = 0
        self.endpoint: AutopilotEndpoint | None = None
        if isinstance(self.m, mavutil.mavudp) and not self.m.broadcast:
            self._guard_udp(companion_sysid)

    def _own_udp_socket(self, conn: str, listen: tuple[str, int]) -> None:
        """Replace pymavlink's listening socket (bound with SO_REUSEADDR to a throwaway port) by one
        bound to ``listen`` without it (``bind_udp``)."""
        m = self.m
        try:
            sock = bind_udp(*listen)
        except OSError as exc:
            m.close()
            raise ConfigError(f"vehicle connection {conn!r}: {exc.strerror or exc}") from None
        sock.setblocking(False)
        try:
            os.set_inheritable(sock.fileno(), False)
        except OSError:
            pass
        m.port.close()
        m.port, m.fd = sock, sock.fileno()

    def _guard_udp(self, sysid: int) -> None:
        """Take datagrams from the autopilot's endpoint only, and send to it only (``AutopilotEndpoint``)."""
        m = self.m
        fixed = None
        if not m.udp_server:  # udpout: the autopilot is where we send
            host, port = m.destination_addr
            try:
                fixed = (socket.gethostbyname(host), int(port))
            except OSError as exc:
                raise ConfigError(f"vehicle connection {self.conn!r}: {exc}") from None
        self.endpoint = AutopilotEndpoint(sysid, fixed, self._signed_by_us)
        m.recv = self._udp_recv  # pymavlink's recv_msg reads through these
        if m.udp_server:
            m.write = self._udp_write

    def _signed_by_us(self, frame: bytes) -> bool:
        """The frame proves its sender is the autopilot: signed with the link's key on the autopilot's
        own stream, fresh (``FcSigning.proves``; a reflection of the companion's own frames never does)."""
        return self.signing is not None and self.signing.proves(frame)

    def _udp_recv(self, n: int | None = None) -> bytes:
        """The next datagram from the autopilot's endpoint (b"" if none is waiting); others dropped, counted."""
        assert self.endpoint is not None
        for _ in range(DROPS_PER_READ):
            try:
                data, addr = self.m.port.recvfrom(65535)
            except (BlockingIOError, InterruptedError, ConnectionRefusedError):
                return b""
            frames, _rest, _skipped = split_frames(data)
            if self.endpoint.admit(addr, frames) is None:
                return data
        return b""

    def _udp_write(self, buf: bytes, secret: bool = False) -> None:
        """Send to the autopilot's endpoint (``secret``: to it alone, never to other claimants)."""
        assert self.endpoint is not None
        targets = self.endpoint.destinations()
        if secret or not self._key_held():  # the other claimants only ever get what a signature can answer
            targets = targets[:1]
        for addr in targets:
            try:
                self.m.port.sendto(buf, addr)
            except OSError:
                pass

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
        """None while the autopilot has no position of its own or has not reported it within
        ``Timing.position_stale`` (``VehicleTracker.position_at``)."""
        return self.tracker.position_at(time.monotonic())

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

    @property
    def position_signed(self) -> bool:
        """The position, fresh, came signed with the link's key: it is the autopilot's (``VehicleTracker``)."""
        return self.tracker.position_signed_at(time.monotonic())

    def stream_stats(self) -> dict[str, Any]:
        """What was asked of the vehicle and what came (``VehicleTracker.stats``), and over UDP the
        autopilot's endpoint (``AutopilotEndpoint.status``)."""
        stats = self.tracker.stats(time.monotonic())
        if self.refused_autopilot_ids:
            stats["refused_autopilot_ids"] = self.refused_autopilot_ids
        if self.endpoint is not None:
            stats["endpoint"] = self.endpoint.status()
        return stats

    def failsafe_outcomes(self) -> list[FailsafeOutcome]:
        """What became of the failsafe the link commanded since the last call (``VehicleTracker``)."""
        return self.tracker.failsafe_outcomes()

    def state(self) -> VehicleState:
        now = time.monotonic()
        return VehicleState(self.sysid, self.tracker.position_at(now), self.armed, self.mode, self.landed_state,
                            self.autopilot, self.tracker.position_unknown(now))

    def signing_status(self) -> dict[str, Any]:
        """MAVLink signing of this link (``FcSigning.status``); mode "off" without one."""
        return self.signing.status() if self.signing is not None else {"mode": "off", "state": "off", "signed": False}

    # ------------------------------------------------------------------ frames
    def heartbeat(self, now: float | None = None) -> None:
        """Send the companion's own HEARTBEAT (at most 1 Hz) so UDP autopilots know where we are, and
        whatever the tracker has to ask of the vehicle."""
        now = time.monotonic() if now is None else now
        if now - self._last_hb_sent >= HEARTBEAT_PERIOD_S:
            self._send_heartbeat(now)
        self._flush(now)

    def _send_heartbeat(self, now: float) -> None:
        self._last_hb_sent = now
        with self._io:
            self._send_msg(self.m.mav.heartbeat_encode(mav.MAV_TYPE_ONBOARD_CONTROLLER, mav.MAV_AUTOPILOT_INVALID,
                                                       0, 0, mav.MAV_STATE_ACTIVE))

    def next_due(self) -> float:
        """When ``heartbeat`` has something to do next (the companion's HEARTBEAT, the tracker's
        timeouts), for the caller's timer."""
        return min(self._last_hb_sent + HEARTBEAT_PERIOD_S, self._last_flush + TRACKER_POLL_S)

    def _flush(self, now: float) -> None:
        self._last_flush = now
        setup = self.signing.due_setup(now) if self.signing is not None else None
        if setup is not None:  # SETUP_SIGNING, signed with the key it replaces (unsigned: the first key)
            msg, key = setup
            with self._io:
                self._send_msg(msg, key, secret=True)
            # and a frame signed with the new key at once: an autopilot signs its replies on a link
            # once signed traffic arrives on it (PX4, ArduPilot), and its first signed frame settles
            # provisioning; waiting for the next HEARTBEAT (1 s) raced the SETUP_SIGNING's resend,
            # which the autopilot then refused (unsigned, or under the key it no longer uses)
            self._send_heartbeat(now)
        for msg in self.tracker.poll(now):
            with self._io:
                self._send_msg(msg)

    def _send_msg(self, msg: Any, sign_key: bytes | None | bool = True, secret: bool = False) -> None:
        """Pack ``msg`` under the link's sequence number and send it (with ``_io`` held), signed while
        signing (``sign_key``: True = the link's key, else that key, None unsigned); ``secret``
        (SETUP_SIGNING: the key in clear): to the autopilot's endpoint alone."""
        frame = msg.pack(self.m.mav)
        self.m.mav.seq = (self.m.mav.seq + 1) % 256
        if self.signing is not None:
            frame = self.signing.outgoing(frame) if sign_key is True else self.signing.sign_with(frame, sign_key or None)
        if secret and self.endpoint is not None and self.endpoint.learned:
            self._udp_write(frame, secret=True)
        else:
            self.m.write(frame)

    def _read_one(self) -> Any:
        """The next well-formed message already received, or None (never waits)."""
        while True:
            with self._io:
                msg = self.m.recv_msg()
            if msg is None:
                return None
            if msg.get_type() == "BAD_DATA":
                continue
            if self.signing is None or self.signing.incoming(bytes(msg.get_msgbuf())) is None:
                return msg

    def accept(self, msg: Any, now: float) -> bytes:
        """Take up one message from the vehicle (on the loop thread): track it; its raw frame."""
        raw = bytes(msg.get_msgbuf())
        self.tracker.on_message(msg, now, signed=self.signing is not None and self.signing.vouches(raw))
        if fcsign.is_signed(raw):
            try:
                return fcsign.strip(raw)
            except FrameError:
                return raw
        return raw

    def recv(self, timeout: float = 0.0) -> list[bytes]:
        """Frames from the vehicle (raw bytes, as received), waiting up to ``timeout`` for the first.
        Only while no reader thread runs (``start_reader``)."""
        if self._reader is not None:
            raise RuntimeError("recv() while the reader thread reads the vehicle")
        out: list[bytes] = []
        deadline = time.monotonic() + timeout
        while True:
            msg = self._read_one()
            if msg is None:
                if out or time.monotonic() >= deadline:
                    break
                self.m.select(min(0.01, max(0.0, deadline - time.monotonic())))
                continue
            out.append(self.accept(msg, time.monotonic()))
        self._flush(time.monotonic())
        return out

    def start_reader(self, deliver: Callable[[Any], None]) -> bool:
        """From now on read the vehicle on a thread of its own, handing every message to ``deliver``
        as it arrives (it must only queue it: the loop thread takes it up with ``accept``). Returns
        True: the frames come this way, ``recv`` is no longer used."""
        if self._reader is not None:
            raise RuntimeError("the reader thread runs already")
        self._reader = threading.Thread(target=self._read, args=(deliver,), name=f"vehicle {self.conn}", daemon=True)
        self._reader.start()
        return True

    @property
    def reading(self) -> bool:
        """The reader thread runs."""
        return self._reader is not None and self._reader.is_alive()

    def _read(self, deliver: Callable[[Any], None]) -> None:
        """The reader thread: wait for the connection, read what came, hand it over; until ``close``."""
        while not self._closing.is_set():
            try:
                msg = self._read_one()
                if msg is None:
                    self.m.select(READ_WAIT_S)
                    continue
                deliver(msg)
            except Exception as exc:  # a connection that fails while reconnecting: counted, tried again
                self.read_errors += 1
                if self.read_errors <= 5:
                    log.warning("vehicle %s: read failed: %s", self.conn, exc)
                self._closing.wait(READ_WAIT_S)

    def send(self, frame: bytes) -> None:
        """Send one raw MAVLink frame to the vehicle (signed while signing); never one that carries the
        autopilot's own ids (nobody speaks to the autopilot as the autopilot; signed by us, it would be
        a frame on the autopilot's stream for anyone to send back: counted, not sent)."""
        if len(frame) > 6 and (frame[5], frame[6]) == self.tracker.autopilot_ids:
            self.refused_autopilot_ids += 1
            if self.refused_autopilot_ids <= 3:
                log.warning("vehicle %s: a frame carrying the autopilot's own ids (%d/%d) not sent", self.conn,
                            *self.tracker.autopilot_ids)
            return
        if self.signing is not None:
            frame = self.signing.outgoing(frame)
        with self._io:
            self.m.write(frame)

    # ---------------------------------------------------------------- commands
    def command(self, cmd: int, *params: float) -> None:
        """COMMAND_LONG to the vehicle now; resent until acknowledged (bounded, see ``Timing``)."""
        msg = self.tracker.command(cmd, params, time.monotonic())
        with self._io:
            self._send_msg(msg)

    def _set_mode(self, name: str, fallback: int) -> None:
        """Command the failsafe ``name`` and follow it until the autopilot shows it (sent again meanwhile)."""
        params = set_mode_params(self.autopilot, name) if self.autopilot == ARDUPILOT else None
        if params is not None:
            cmd, args = mav.MAV_CMD_DO_SET_MODE, tuple(params)
        else:
            nan = float("nan")
            cmd, args = fallback, ((0.0, 0.0, 0.0, nan, nan, nan, nan) if fallback == mav.MAV_CMD_NAV_LAND else ())
        self.command(cmd, *args)
        self.tracker.watch_failsafe(name, cmd, args, time.monotonic())

    def command_land(self) -> None:
        """Command LAND now (ArduPilot: LAND mode, DO_SET_MODE 9; PX4 and others: MAV_CMD_NAV_LAND)."""
        self._set_mode("LAND", mav.MAV_CMD_NAV_LAND)

    def command_rtl(self) -> None:
        """Command return-to-launch now (ArduPilot: RTL mode, DO_SET_MODE 6; others: NAV_RETURN_TO_LAUNCH)."""
        self._set_mode("RTL", mav.MAV_CMD_NAV_RETURN_TO_LAUNCH)

    def wait_vehicle(self, timeout: float) -> bool:
        """Heartbeat until the vehicle's own HEARTBEAT has been seen; False on timeout. Over an endpoint
        the link learns (udpin), listen ``CLAIM_WINDOW_S`` longer: if another address also sends the
        autopilot's HEARTBEAT, which one is the autopilot cannot be told (neither signs with a key of
        ours yet): ``ConfigError``, nothing handed to either."""
        deadline = time.monotonic() + timeout
        while self.sysid is None and time.monotonic() < deadline:
            self.heartbeat()
            self.recv(0.1)
        if self.sysid is None:
            return False
        if self.endpoint is not None and self.endpoint.learned and self.endpoint.how == "heartbeat":
            settle = time.monotonic() + CLAIM_WINDOW_S
            while time.monotonic() < settle and self.endpoint.how == "heartbeat":
                self.recv(0.1)
            if self.endpoint.how == "heartbeat" and self.endpoint.claimants and not self._key_held():
                raise ConfigError(f"vehicle {self.conn}: {len(self.endpoint.claimants) + 1} addresses send the "
                                  f"autopilot's HEARTBEAT ({self.endpoint.status()['address']}, "
                                  f"{', '.join(self.endpoint.status()['claimants'])}): which is the autopilot cannot "
                                  "be told; nothing is sent to either (a local process playing the autopilot?)")
        if self.signing is not None:
            self._provision()
        return True

    def _key_held(self) -> bool:
        """A signing key is stored: the autopilot that holds it proves itself by signing (``AutopilotEndpoint``)."""
        return self.signing is not None and self.signing.mode != "off" and self.signing.key is not None

    def _provision(self) -> None:
        """MAVLink signing before anything else: the key installed or confirmed, or the link's
        fallback decided (``FcSigning``). Raises ``FcSigningError`` if the vehicle cannot be flown."""
        assert self.signing is not None and self.sysid is not None
        signing = self.signing
        # over an endpoint the link learned (udpin) the stored key is never sent again: whoever answered
        # first may not be the autopilot; the autopilot that holds it signs back and so proves itself
        learned = self.endpoint is not None and self.endpoint.learned
        signing.start(time.monotonic(), self.tracker.armed, self.sysid, resend_stored=not learned)
        while not signing.settled:
            self.heartbeat()
            self.recv(0.1)
        if signing.state is FcState.FAILED:
            raise FcSigningError(f"vehicle {self.conn}: MAVLink signing: {signing.reason}")

    def close(self) -> None:
        """Stop the reader thread (within ``READ_WAIT_S``), then close the connection."""
        self._closing.set()
        if self._reader is not None:
            self._reader.join(2 * READ_WAIT_S + 1.0)
        with self._io:
            self.m.close()
