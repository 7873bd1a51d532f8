"""What the companion knows of its vehicle, and the telemetry it asks the vehicle for (sans-IO).

``VehicleTracker`` is given every message from the vehicle side (``on_message(msg, now)``) and
asked for what to send it (``poll(now)``); it never blocks, sends or reads a clock. ``VehicleLink``
(``zdrone.vehicle.link``) is its I/O; the unit tests drive it against the simulator in memory.

Theory of operation
-------------------
**Connect.** The first HEARTBEAT of the drone's own autopilot fixes which autopilot it is: it must
come from the drone's fleet sysid (the companion's own) and the autopilot's component
(MAV_COMP_ID_AUTOPILOT1) and name an autopilot (not MAV_AUTOPILOT_INVALID). A HEARTBEAT from any
other ids never becomes "the vehicle" (counted ``foreign_heartbeat``): a local process that sends one
before the real autopilot (issue 29) is not adopted, not provisioned, not commanded. **Reboot.** Its heartbeats resume after
a gap of ``Timing.reboot_gap`` seconds, or a ``time_boot_ms`` of its messages goes back by more than
``Timing.boot_back_ms``. Both (re)start a round of stream requests.

**Reports.** What the autopilot says of itself (armed, mode, landed state, texts, position) is
decoded by ``report.VehicleReport`` (``vehicle``), as the GS decodes it; the tracker decides whose
frames count: HEARTBEAT and the position of the autopilot's ids only, the landed state and texts of
any component of its system.

**Position.** A position is one only while the autopilot vouches for it (``fix.PositionFix``: a GPS
fix, not lat = lon = 0, an absolute estimate); until then ``position`` is None and ``stats`` says why.
And only while it is fresh (``position_at``): a GLOBAL_POSITION_INT not followed by another within
``Timing.position_stale`` seconds leaves the position unknown, so whoever stands between the
autopilot and the companion cannot hold an old position in place by withholding the new ones (an
heir chosen from where the vehicle was).

**Streams.** The drone node needs GLOBAL_POSITION_INT (region, coverage) and the landed state; the
GSs need those, HEARTBEAT, MISSION_CURRENT, SYS_STATUS, HOME_POSITION and the unsolicited protocol
replies (COMMAND_ACK, MISSION_*, STATUSTEXT). PX4 streams them unasked; ArduPilot streams nothing
but HEARTBEAT until asked. Each wanted stream (``StreamWant``) that has not arrived twice (one
message alone, a reply or a change, is no stream) within ``Timing.wait_before_asking`` is asked for,
one request in flight at a time (a COMMAND_ACK does not say which message id it answers):

1. MAV_CMD_SET_MESSAGE_INTERVAL; ACCEPTED, then the message must arrive within ``Timing.seen_within``;
   no ACK or no message: asked again, ``Timing.attempts`` times in all.
2. Refused (ArduPilot: FAILED and "No ap_message for mavlink id (N)"; PX4: UNSUPPORTED) or out of
   attempts: REQUEST_DATA_STREAM of the ArduPilot stream group that carries it, ``Timing.attempts``
   times at most.
3. Still nothing, or no group carries it: FAILED, logged and counted (``stats``). Landed state then
   comes from HEARTBEAT (``modes.landed_from_heartbeat``).

A stream that arrived and then stays silent for ``Timing.lapse_after`` while heartbeats go on is
asked for again, ``Timing.max_lapses`` times per connection. Streams that arrive unasked are never
touched: the autopilot's own rates stay as they are.

**Position and signing.** ``on_message`` is told whether the frame came signed with the link's key
(``signed``); ``position_signed`` says whether the position now held came so. Only such a position
may grant authority (the drone node's rule, unless its operator opted in for an unsigned link).

**Failsafe.** ``watch_failsafe`` follows a LAND or RTL the companion commanded until the autopilot
shows it (its HEARTBEAT's mode is that mode, or it is on the ground and disarmed, after the command
went out): the command is sent again every ``FailsafeTiming.confirm_within`` seconds until then,
``FailsafeTiming.attempts`` sends in all; each outcome (confirmed, retried, unconfirmed) is handed
out once by ``failsafe_outcomes`` for the event log.

**Commands.** ``command`` returns a COMMAND_LONG to send at once and keeps it until the vehicle
acknowledges it: resent after ``Timing.ack_timeout`` without an ACK or after TEMPORARILY_REJECTED,
``Timing.attempts`` sends in all; another refusal is logged and counted.
"""

from __future__ import annotations

import enum
import logging
import math
from collections import Counter
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

from pymavlink.dialects.v20 import common as mav

from zdrone.core.geometry import GeoPoint
from zdrone.vehicle.fix import MSG_EKF_STATUS_REPORT, PositionFix
from zdrone.vehicle.modes import autopilot_name, landed_from_heartbeat, mode_name
from zdrone.vehicle.report import PositionReported, TextHeard, VehicleReport

log = logging.getLogger(__name__)

#: The autopilot's component id (MAV_COMP_ID_AUTOPILOT1): the vehicle is this component of the drone's sysid.
AUTOPILOT_COMPID = mav.MAV_COMP_ID_AUTOPILOT1
#: A STATUSTEXT this soon after a refused SET_MESSAGE_INTERVAL is its reason (ArduPilot says why after
#: the ACK).
REASON_AFTER_ACK_S = 0.5

_RESULT_NAMES = MappingProxyType({v: e.name.removeprefix("MAV_RESULT_") for v, e in mav.enums["MAV_RESULT"].items()})


@dataclass(frozen=True, slots=True)
class StreamWant:
    """One message the companion wants streamed, how often, and the ArduPilot stream group that carries it."""

    msgid: int
    name: str
    interval: float  # seconds
    group: int | None  # MAV_DATA_STREAM_* for REQUEST_DATA_STREAM; None: no group carries it
    why: str = ""
    autopilots: tuple[str, ...] | None = None  # asked of these autopilots only (None: of every one)

    def wanted_of(self, autopilot: str | None) -> bool:
        return self.autopilots is None or autopilot in self.autopilots


#: What the drone node and the ground stations depend on (gs.context.USED_MSGIDS besides the replies).
DEFAULT_STREAMS: tuple[StreamWant, ...] = (
    StreamWant(mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, "GLOBAL_POSITION_INT", 0.25, mav.MAV_DATA_STREAM_POSITION,
               "drone: region and coverage; GS: position"),
    StreamWant(mav.MAVLINK_MSG_ID_EXTENDED_SYS_STATE, "EXTENDED_SYS_STATE", 1.0, None, "drone and GS: landed state"),
    StreamWant(mav.MAVLINK_MSG_ID_SYS_STATUS, "SYS_STATUS", 1.0, mav.MAV_DATA_STREAM_EXTENDED_STATUS,
               "GS: health, pre-arm checks, battery"),
    StreamWant(mav.MAVLINK_MSG_ID_MISSION_CURRENT, "MISSION_CURRENT", 1.0, mav.MAV_DATA_STREAM_EXTENDED_STATUS,
               "GS: mission progress"),
    StreamWant(mav.MAVLINK_MSG_ID_HOME_POSITION, "HOME_POSITION", 2.0, None, "GS: home, position estimate"),
    StreamWant(mav.MAVLINK_MSG_ID_GPS_RAW_INT, "GPS_RAW_INT", 1.0, mav.MAV_DATA_STREAM_EXTENDED_STATUS,
               "drone and GS: a position only with a GPS fix"),
    StreamWant(MSG_EKF_STATUS_REPORT, "EKF_STATUS_REPORT", 1.0, mav.MAV_DATA_STREAM_EXTRA3,
               "drone and GS: a position only once the EKF uses GPS", autopilots=("ardupilot",)),
)
#: Not asked by default (nothing here depends on them): what gives a GCS application behind a GS
#: that does not hold authority (whose own stream requests never reach the vehicle) a live view.
VIEW_STREAMS: tuple[StreamWant, ...] = (
    StreamWant(mav.MAVLINK_MSG_ID_ATTITUDE, "ATTITUDE", 0.25, mav.MAV_DATA_STREAM_EXTRA1, "GCS applications: attitude"),
    StreamWant(mav.MAVLINK_MSG_ID_VFR_HUD, "VFR_HUD", 1.0, mav.MAV_DATA_STREAM_EXTRA2, "GCS applications: HUD"),
)


@dataclass(frozen=True, slots=True)
class Timing:
    """Timeouts and bounds of the stream requests and command retries (seconds unless said)."""

    grace: float = 1.0  # after (re)connect, leave streams this long (at least 2.5 intervals) to arrive unasked
    ack_timeout: float = 1.0
    attempts: int = 3  # per method (SET_MESSAGE_INTERVAL, then REQUEST_DATA_STREAM) and per command
    min_seen_within: float = 2.0  # a requested stream must arrive within max(this, 3 intervals)
    lapse_after_min: float = 5.0  # a seen stream silent for max(this, 10 intervals) is asked for again
    max_lapses: int = 3
    reboot_gap: float = 3.0  # heartbeats resuming after this gap: a reboot (or a link back)
    boot_back_ms: int = 1000  # time_boot_ms going back by more than this: a reboot
    landed_stale: float = 5.0  # EXTENDED_SYS_STATE older than this: landed state from HEARTBEAT
    position_stale: float = 1.5  # no GLOBAL_POSITION_INT for this long: the position is unknown

    def wait_before_asking(self, want: StreamWant) -> float:
        return max(self.grace, 2.5 * want.interval)  # time for two messages: one alone is no stream

    def seen_within(self, want: StreamWant) -> float:
        return max(self.min_seen_within, 3.0 * want.interval)

    def lapse_after(self, want: StreamWant) -> float:
        return max(self.lapse_after_min, 10.0 * want.interval)


@dataclass(frozen=True, slots=True)
class FailsafeTiming:
    """How a commanded LAND / RTL is confirmed: seen within this long of each send, else sent again."""

    confirm_within: float = 2.0
    attempts: int = 5


@dataclass(frozen=True, slots=True)
class FailsafeOutcome:
    """What became of a commanded failsafe: ``confirmed`` (``seen``: what the autopilot showed), ``retried``
    (sent again: ``seen`` is its mode meanwhile) or ``unconfirmed`` (out of attempts)."""

    action: str  # LAND | RTL
    outcome: str  # confirmed | retried | unconfirmed
    attempts: int  # sends so far
    after_s: float  # since the first send
    seen: str


@dataclass(slots=True)
class _FailsafeWatch:
    action: str
    command: int
    params: tuple[float, ...]
    started: float
    sent_at: float
    sends: int = 1


class StreamState(enum.Enum):
    WAITING = "waiting"  # not seen; asked for (again) when its turn comes
    ASKED = "asked"  # SET_MESSAGE_INTERVAL accepted, the message is awaited
    FALLBACK = "fallback"  # REQUEST_DATA_STREAM sent, the message is awaited
    SEEN = "seen"
    FAILED = "failed"


@dataclass(slots=True)
class _Stream:
    want: StreamWant
    state: StreamState = StreamState.WAITING
    interval_asks: int = 0
    stream_asks: int = 0
    deadline: float = 0.0
    last_seen: float | None = None
    hits: int = 0  # messages received this connection
    lapses: int = 0
    via: str | None = None  # "unasked", "interval", "data_stream"
    refusal: str | None = None


@dataclass(slots=True)
class _Command:
    command: int
    params: tuple[float, ...]
    sends: int = 0
    next_at: float = 0.0


@dataclass(slots=True)
class _Pending:
    """The SET_MESSAGE_INTERVAL in flight: its stream and when it was sent."""

    stream: _Stream
    sent_at: float
    texts: list[str] = field(default_factory=list)  # STATUSTEXTs meanwhile (ArduPilot says why it refuses)


class VehicleTracker:
    """The vehicle's identity, state and streams, from its messages; the requests it needs, by ``poll``."""

    def __init__(self, companion_sysid: int, companion_compid: int, streams: tuple[StreamWant, ...] = DEFAULT_STREAMS,
                 timing: Timing = Timing(), failsafe_timing: FailsafeTiming = FailsafeTiming()) -> None:
        self.companion = (companion_sysid, companion_compid)
        self.failsafe_timing = failsafe_timing
        self._failsafe: _FailsafeWatch | None = None
        self._failsafe_out: list[FailsafeOutcome] = []
        self._position_signed = False  # the last GLOBAL_POSITION_INT came signed with the link's key
        #: the only ids that are the vehicle: the drone's fleet sysid (the companion's own) and the autopilot's component
        self.autopilot_ids = (companion_sysid, AUTOPILOT_COMPID)
        self.timing = timing
        self.wants = streams
        self.sysid: int | None = None
        self.compid: int | None = None
        #: what the autopilot reports of itself (its frames only: ``autopilot_ids``)
        self.vehicle = VehicleReport()
        self.connected_at: float | None = None
        self.connections = 0  # 1 after connect; each reboot (or link back after a gap) adds one
        self.counters: Counter[str] = Counter()
        self._boot_ms: int | None = None
        self._streams = self._fresh_streams()
        self._pending: _Pending | None = None
        self._refused: tuple[_Stream, float] | None = None  # the last interval refused without a reason, when
        self._groups: dict[int, int] = {}  # REQUEST_DATA_STREAM group -> rate (Hz) asked this connection
        self._commands: list[_Command] = []

    # ------------------------------------------------------------------ state
    @property
    def fix(self) -> PositionFix:
        return self.vehicle.fix

    @property
    def armed(self) -> bool:
        return self.vehicle.armed

    @property
    def custom_mode(self) -> int:
        return self.vehicle.custom_mode

    @property
    def autopilot(self) -> str | None:
        """``"px4"``, ``"ardupilot"``, None (another autopilot, or none heard yet)."""
        return autopilot_name(self.vehicle.mav_autopilot)

    @property
    def last_heartbeat(self) -> float | None:
        return self.vehicle.heartbeat_at

    @property
    def position(self) -> GeoPoint | None:
        """The vehicle's position, None while the autopilot has none (no GPS fix, lat = lon = 0, or an
        estimate that is not absolute: ``PositionFix``)."""
        return self.fix.position

    @property
    def position_signed(self) -> bool:
        """The position held came in a frame signed with the link's key (False while there is none)."""
        return self._position_signed and self.position is not None

    def position_at(self, now: float) -> GeoPoint | None:
        """``position`` while it is fresh: reported within ``Timing.position_stale`` of ``now``, else None."""
        at = self.vehicle.position_at
        if at is None or now - at > self.timing.position_stale:
            return None
        return self.fix.position

    def position_signed_at(self, now: float) -> bool:
        """``position_signed``, for a position fresh at ``now`` (``position_at``)."""
        return self._position_signed and self.position_at(now) is not None

    def position_unknown(self, now: float) -> str | None:
        """Why ``position_at(now)`` is None (None: there is one)."""
        why, at = self.fix.unknown_because, self.vehicle.position_at
        if why is None and (at is None or now - at > self.timing.position_stale):
            return f"no position report for {now - at:.1f} s" if at is not None else "no position report"
        return why

    @property
    def mode(self) -> str:
        return mode_name(self.autopilot, self.custom_mode)

    def landed_state(self, now: float) -> int:
        """EXTENDED_SYS_STATE while it is fresh, else what HEARTBEAT says (``landed_from_heartbeat``)."""
        v = self.vehicle
        if v.landed_at is not None and now - v.landed_at <= self.timing.landed_stale:
            return v.landed_state
        if self.last_heartbeat is None:
            return mav.MAV_LANDED_STATE_UNDEFINED
        return landed_from_heartbeat(self.autopilot, v.system_status, v.armed)

    def stats(self, now: float | None = None) -> dict[str, Any]:
        """Per wanted stream: its state, how it came (unasked / interval / data_stream), asks and refusal;
        plus the counters (refusals, retries, failures, reboots); given ``now``, the position's age."""
        position = self.fix.describe()
        if now is not None:
            why = self.position_unknown(now)
            at = self.vehicle.position_at
            position.update(known=why is None, why=why, age_s=None if at is None else round(now - at, 3))
        return {"autopilot": self.autopilot, "connections": self.connections,
                "streams": {s.want.name: {"state": s.state.value, "via": s.via, "interval_asks": s.interval_asks,
                                          "stream_asks": s.stream_asks, "lapses": s.lapses, "refusal": s.refusal}
                            for s in self._streams.values()},
                "position": position, "counters": dict(self.counters)}

    # ------------------------------------------------------------------ input
    def on_message(self, msg: Any, now: float, signed: bool = False) -> None:
        """One message from the vehicle side (a pymavlink message, any dialect); ``signed``: it came
        signed with the link's key (checked by the link)."""
        t = msg.get_type()
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if t == "HEARTBEAT":
            self._on_heartbeat(msg, src, now)
            return
        if self.sysid is None or src[0] != self.sysid:
            return
        boot_ms = getattr(msg, "time_boot_ms", None)
        if isinstance(boot_ms, int) and src[1] == self.compid:
            if self._boot_ms is not None and boot_ms + self.timing.boot_back_ms < self._boot_ms:
                self._reconnect(now, f"boot time went back ({self._boot_ms} -> {boot_ms} ms)")
            self._boot_ms = boot_ms
        stream = self._streams.get(msg.get_msgId())
        if stream is not None:
            self._seen(stream, now)
        if src[1] == self.compid:  # only the autopilot's own word: another component of its system (a
            # local process taking its system id) must not say "on the ground", which confirms a failsafe
            for change in self.vehicle.on_message(msg, now):
                if isinstance(change, PositionReported):
                    self._position_signed = signed
                elif isinstance(change, TextHeard):
                    self._on_text(change.text, now)
        if t == "COMMAND_ACK":
            self._on_ack(msg, now)

    def _on_text(self, text: str, now: float) -> None:
        """A STATUSTEXT: the reason of the SET_MESSAGE_INTERVAL in flight, or of the one just refused
        (ArduPilot says why after its ACK)."""
        if self._pending is not None:
            self._pending.texts.append(text)
        elif self._refused is not None and now - self._refused[1] <= REASON_AFTER_ACK_S:
            stream, _ = self._refused
            self._refused = None
            stream.refusal = f"{stream.refusal}: {text}"
            log.warning("vehicle refused SET_MESSAGE_INTERVAL %s: %s", stream.want.name, text)

    def _on_heartbeat(self, msg: Any, src: tuple[int, int], now: float) -> None:
        if msg.autopilot == mav.MAV_AUTOPILOT_INVALID:
            return  # a GCS, a companion, a gimbal: not the autopilot
        if src != self.autopilot_ids:
            self.counters["foreign_heartbeat"] += 1  # another system claiming to be an autopilot
            if self.counters["foreign_heartbeat"] <= 3:
                log.warning("vehicle link: HEARTBEAT of an autopilot %d/%d ignored: the vehicle is %d/%d",
                            src[0], src[1], *self.autopilot_ids)
            return
        first, last = self.sysid is None, self.last_heartbeat
        self.sysid, self.compid = src
        self.vehicle.on_message(msg, now)
        if first:
            self._reconnect(now, "first heartbeat")
        elif last is not None and now - last > self.timing.reboot_gap:
            self._reconnect(now, f"heartbeats back after {now - last:.1f} s")

    def _fresh_streams(self) -> dict[int, _Stream]:
        return {w.msgid: _Stream(w) for w in self.wants if w.wanted_of(self.autopilot)}

    def _silent(self, now: float) -> bool:
        return self.last_heartbeat is None or now - self.last_heartbeat > self.timing.reboot_gap

    def _reconnect(self, now: float, why: str) -> None:
        self.connections += 1
        self.connected_at = now
        self._boot_ms = None
        self._pending = self._refused = None
        self._groups.clear()
        self.vehicle.restart()  # a rebooted autopilot has no fix yet; a link back: the next report says
        self._position_signed = False
        self._streams = self._fresh_streams()
        if self.connections > 1:
            self.counters["reconnects"] += 1
            log.warning("vehicle %s: %s: asking for its streams again", self.sysid, why)
        else:
            log.info("vehicle %s (%s): %s", self.sysid, self.autopilot or "autopilot", why)

    def _seen(self, s: _Stream, now: float) -> None:
        s.hits += 1
        s.last_seen = now
        if s.state is StreamState.SEEN:
            return
        if self._pending is not None and self._pending.stream is s:
            self._pending, s.via = None, "interval"  # arriving before the ACK
        elif s.via is None and s.hits < 2:
            return  # one message unasked is not a stream (a reply, a change): a second one is
        s.via = s.via or "unasked"
        if s.via != "unasked":
            log.info("stream %s arriving (%s)", s.want.name, s.via)
        s.state = StreamState.SEEN

    def _ours(self, msg: Any) -> bool:
        ts, tc = getattr(msg, "target_system", 0), getattr(msg, "target_component", 0)
        return ts in (0, self.companion[0]) and tc in (0, self.companion[1])

    def _on_ack(self, msg: Any, now: float) -> None:
        if not self._ours(msg):
            return  # a GS's or an application's command, relayed through us
        if msg.command == mav.MAV_CMD_SET_MESSAGE_INTERVAL and self._pending is not None:
            self._on_interval_ack(msg.result, now)
            return
        cmd = next((c for c in self._commands if c.command == msg.command), None)
        if cmd is None or msg.result == mav.MAV_RESULT_IN_PROGRESS:
            return
        if msg.result == mav.MAV_RESULT_ACCEPTED:
            self._commands.remove(cmd)
        elif msg.result == mav.MAV_RESULT_TEMPORARILY_REJECTED:
            self.counters[f"command_{cmd.command}_temporarily_rejected"] += 1
            cmd.next_at = now + self.timing.ack_timeout  # tried again
        else:
            self._commands.remove(cmd)
            self.counters[f"command_{cmd.command}_refused"] += 1
            log.warning("vehicle refused command %d: %s", cmd.command, _RESULT_NAMES.get(msg.result, msg.result))

    def _on_interval_ack(self, result: int, now: float) -> None:
        assert self._pending is not None
        s, texts = self._pending.stream, self._pending.texts
        self._pending = None
        if s.state is StreamState.SEEN:
            return
        if result in (mav.MAV_RESULT_ACCEPTED, mav.MAV_RESULT_IN_PROGRESS):
            s.state, s.deadline, s.via = StreamState.ASKED, now + self.timing.seen_within(s.want), "interval"
            return
        s.refusal = f"{_RESULT_NAMES.get(result, result)}" + (f": {texts[-1]}" if texts else "")
        self._refused = None if texts else (s, now)  # its reason may still come
        s.state = StreamState.WAITING  # no use asking again: the next poll falls back
        self.counters["interval_refused"] += 1
        log.warning("vehicle refused SET_MESSAGE_INTERVAL %s (%d): %s", s.want.name, s.want.msgid, s.refusal)

    # ------------------------------------------------------------------ output
    def command(self, command: int, params: tuple[float, ...], now: float) -> Any:
        """A COMMAND_LONG for the vehicle, to send now; resent by ``poll`` until acknowledged."""
        self._commands = [c for c in self._commands if c.command != command]
        cmd = _Command(command, tuple(params) + (0.0,) * (7 - len(params)))
        self._commands.append(cmd)
        return self._send_command(cmd, now)

    def _send_command(self, cmd: _Command, now: float) -> Any:
        cmd.sends += 1
        cmd.next_at = now + self.timing.ack_timeout
        return mav.MAVLink_command_long_message(self.sysid or 1, self.compid or 1, cmd.command,
                                                min(cmd.sends - 1, 255), *cmd.params)

    def watch_failsafe(self, action: str, command: int, params: tuple[float, ...], now: float) -> None:
        """Follow the failsafe ``action`` (LAND, RTL) just sent as ``command`` until the autopilot shows it."""
        self._failsafe = _FailsafeWatch(action, command, tuple(params), now, now)

    def failsafe_outcomes(self) -> list[FailsafeOutcome]:
        """The failsafe's outcomes since the last call (each handed out once)."""
        out, self._failsafe_out = self._failsafe_out, []
        return out

    @property
    def failsafe_pending(self) -> bool:
        return self._failsafe is not None

    def _failsafe_seen(self, w: _FailsafeWatch) -> str | None:
        """What shows the failsafe done (after its last send), or None."""
        if self.last_heartbeat is None or self.last_heartbeat < w.sent_at:
            return None
        if self.mode == w.action:
            return f"mode {w.action}"
        if not self.armed and self.landed_state(self.last_heartbeat) == mav.MAV_LANDED_STATE_ON_GROUND:
            return "on the ground, disarmed"
        return None

    def _poll_failsafe(self, now: float) -> list[Any]:
        w = self._failsafe
        if w is None:
            return []
        seen = self._failsafe_seen(w)
        if seen is not None:
            self._failsafe = None
            self.counters["failsafe_confirmed"] += 1
            self._failsafe_out.append(FailsafeOutcome(w.action, "confirmed", w.sends, round(now - w.started, 3), seen))
            log.warning("failsafe %s confirmed by the autopilot (%s) after %d send(s)", w.action, seen, w.sends)
            return []
        if now - w.sent_at < self.failsafe_timing.confirm_within:
            return []
        if w.sends >= self.failsafe_timing.attempts:
            self._failsafe = None
            self.counters["failsafe_unconfirmed"] += 1
            self._failsafe_out.append(FailsafeOutcome(w.action, "unconfirmed", w.sends, round(now - w.started, 3),
                                                      f"mode {self.mode}"))
            log.error("failsafe %s not confirmed by the autopilot after %d sends (mode %s)", w.action, w.sends, self.mode)
            return []
        w.sends += 1
        w.sent_at = now
        self.counters["failsafe_retried"] += 1
        self._failsafe_out.append(FailsafeOutcome(w.action, "retried", w.sends, round(now - w.started, 3),
                                                  f"mode {self.mode}"))
        log.warning("failsafe %s not shown by the autopilot (mode %s): sending it again (%d)", w.action, self.mode,
                    w.sends)
        return [self.command(w.command, w.params, now)]

    def poll(self, now: float) -> list[Any]:
        """The messages to send the vehicle now (stream requests, command retries, the failsafe's)."""
        if self.sysid is None or self.connected_at is None:
            return []
        out = [self._send_command(c, now) for c in self._due_commands(now)]
        out += self._poll_failsafe(now)
        for s in self._streams.values():
            if s.state in (StreamState.ASKED, StreamState.FALLBACK) and now >= s.deadline:
                asked_by = "interval" if s.state is StreamState.ASKED else "data_stream"
                self.counters[f"{asked_by}_not_streamed"] += 1
                s.state = StreamState.WAITING  # nothing came: ask again, or fall back
            elif s.state is StreamState.SEEN and s.last_seen is not None and not self._silent(now) \
                    and now - s.last_seen > self.timing.lapse_after(s.want) and s.lapses < self.timing.max_lapses:
                s.lapses += 1
                s.state, s.interval_asks, s.stream_asks, s.via, s.hits = StreamState.WAITING, 0, 0, None, 0
                self.counters["stream_lapsed"] += 1
                log.warning("stream %s stopped (%.1f s silent): asking again", s.want.name, now - s.last_seen)
        if self._pending is not None:
            if now - self._pending.sent_at < self.timing.ack_timeout:
                return out
            self.counters["interval_no_ack"] += 1
            self._pending.stream.state = StreamState.WAITING
            self._pending = None
        for s in self._streams.values():
            if s.state is not StreamState.WAITING or now - self.connected_at < self.timing.wait_before_asking(s.want):
                continue
            if s.interval_asks < self.timing.attempts and s.refusal is None and not s.stream_asks:
                s.interval_asks += 1
                self._pending = _Pending(s, now)
                log.info("asking vehicle for %s every %g s (SET_MESSAGE_INTERVAL, try %d)", s.want.name,
                         s.want.interval, s.interval_asks)
                msg = mav.MAVLink_command_long_message(self.sysid, self.compid or 1, mav.MAV_CMD_SET_MESSAGE_INTERVAL,
                                                       0, float(s.want.msgid), s.want.interval * 1e6, 0, 0, 0, 0, 0)
                out.append(msg)
                return out  # one SET_MESSAGE_INTERVAL in flight at a time
            fallback = self._fall_back(s, now)
            if fallback is not None:
                out.append(fallback)
        return out

    def _due_commands(self, now: float) -> list[_Command]:
        due = []
        for c in list(self._commands):
            if now < c.next_at:
                continue
            if c.sends >= self.timing.attempts:
                self._commands.remove(c)
                self.counters[f"command_{c.command}_unacknowledged"] += 1
                log.warning("vehicle did not acknowledge command %d after %d sends", c.command, c.sends)
                continue
            due.append(c)
        return due

    def _fall_back(self, s: _Stream, now: float) -> Any | None:
        """REQUEST_DATA_STREAM of the stream's group, or FAILED when none carries it or tries are out."""
        group = s.want.group
        if group is None or s.stream_asks >= self.timing.attempts:
            s.state = StreamState.FAILED
            self.counters["stream_failed"] += 1
            log.warning("vehicle does not stream %s (%s); asked %d times by interval, %d by data stream%s",
                        s.want.name, s.want.why, s.interval_asks, s.stream_asks,
                        f"; refused: {s.refusal}" if s.refusal else "")
            return None
        s.stream_asks += 1
        s.state, s.deadline, s.via = StreamState.FALLBACK, now + self.timing.seen_within(s.want), "data_stream"
        rate = max(1, math.ceil(1.0 / s.want.interval))
        if self._groups.get(group, 0) >= rate and s.stream_asks == 1:
            return None  # another stream's request already asked for this group at this rate: wait for it
        self._groups[group] = max(rate, self._groups.get(group, 0))
        self.counters["data_stream_requests"] += 1
        log.info("asking vehicle for stream group %d at %d Hz (REQUEST_DATA_STREAM, for %s)", group,
                 self._groups[group], s.want.name)
        return mav.MAVLink_request_data_stream_message(self.sysid or 1, self.compid or 1, group, self._groups[group], 1)
