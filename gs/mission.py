"""The mission stages of one drone, as the GS flies it: a table, sans-IO.

Theory of operation
-------------------
While this GS holds a drone's authority (and no key grant of its is pending), ``StationCore`` hands
the drone's ``Mission`` its events; everything else about the drone (its link, its authority, the
hand-over) is not this machine's business. The vehicle's facts (its autopilot, armed state, mode,
landed state, pre-arm health, position fix, recent texts) come in as a ``VehicleFacts`` (the GS's
view of the drone), and MAVLink messages go out through ``send``, which seals them for the drone.

States (``Stage``): ``IDLE`` (waiting to know the autopilot) -> ``PREPARING`` (ArduPilot: "continue
after land" set and confirmed) -> ``UPLOADING`` -> ``WAITING_READY`` (pre-arm checks, a position
estimate, or the next try after a refusal) -> ``ARMING`` -> ``STARTING`` -> ``TAKING_OFF`` ->
``FLYING``; ``UPLOAD_WAIT`` (an upload that failed for a reason a new try may fix waits its
backoff with jitter, then ``UPLOADING`` again, until ``UPLOAD_DEADLINE_S``); ``REFUSED`` (an ARM or MISSION_START refused: its reasons are gathered a moment, then
back to ``WAITING_READY`` or, for a refusal waiting cannot fix, ``FAILED``).

Events (frozen): ``FlightTick`` (time passes: the stage's deadlines and what the vehicle reports),
``FlightAck`` (a COMMAND_ACK to this GS), ``FlightParam`` (a PARAM_VALUE). ``TABLE`` maps (stage,
event type) to (handler, the stages it may move to), a table of the machine engine
(``zdrone.core.machine``); a pair not in the table does nothing by definition. A handler moves by
``_set_state(stage, now=...)`` (the engine's): a move anywhere its row does not allow is a
programming error (``IllegalStage``, raised); every move is logged ``old -> new``, and the stage's
clock (``stage_time``, what its deadlines count from) starts at the move's ``now``.

The first upload and the first arming of each drone wait a draw of ``upload_spread_s`` /
``takeoff_spread_s`` (the GS's fleet spread over time); the draws come from ``seed``, randomness the
adapter gave (``jitter``), so the machine stays pure and a test or a checker replays it.

Timer: ``deadline()`` is when a ``FlightTick`` next matters if no input comes (a retry, a stage's
timeout, a refusal's classification, an upload's re-send); None while only an input can move it.
"""

from __future__ import annotations

import enum
import hashlib
import logging
import math
from collections import Counter
from dataclasses import dataclass
from typing import Any, Callable, Protocol

from pymavlink.dialects.v20 import common as mav

from zdrone.core import records as rec
from zdrone.core.machine import IllegalTransition, Machine, Table
from zdrone.vehicle.fix import PositionFix
from zdrone.vehicle.modes import mode_name, set_mode_params

from gs.actions import Action, Emit, ToOperator
from gs.planner import AUTOPILOTS, MissionUploader, PlannedItem, encode_mission

log = logging.getLogger(__name__)

#: ArduPilot's "continue after land" mission option (MIS_OPTIONS bit 2): the reference flight
#: lands at the delivery point and goes on.
ARDUPILOT_CONTINUE_AFTER_LAND = 4
#: Tries of an unconfirmed PARAM_SET before the mission is given up.
MAX_TRIES = 30
#: Refusals of ARM / MISSION_START that neither the vehicle's state nor its words explain, before the
#: mission is given up (a refusal while not ready never counts: the GS waits for the vehicle).
MAX_UNEXPLAINED = 5
RETRY_AFTER_S = 2.0
#: Without a pre-arm health report, try to arm after this long (the vehicle's refusal decides).
READY_WAIT_S = 3.0
#: A refusal is classified this long after its COMMAND_ACK (ArduPilot says why after the ACK) ...
REASON_WAIT_S = 0.5
#: ... from the texts since this long before the ACK.
REASON_BEFORE_S = 1.0
#: The autopilot's PreArm text shown while the pre-arm checks fail is at most this old.
PREARM_TEXT_S = 35.0
PREARM_PREFIXES = ("prearm", "arm:", "arming denied", "preflight fail")
#: Words of a refusal that says the vehicle is not ready yet (lower case) ...
NOT_READY = ("requires position", "prearm", "arm:", "not ready", "resolve system health", "need position",
             "ekf", "gps", "position estimate", "currently not available", "temporarily")
#: ... and of one that waiting cannot fix.
REFUSED_FOR_GOOD = ("mission rejected", "no valid mission", "missing takeoff")
#: ArduCopter's modes that cannot be armed in (AUTO 3, RTL 6, LAND 9): a GS arming again after an
#: auto-disarm in AUTO first switches to GUIDED.
ARDUPILOT_NOT_ARMABLE = frozenset({3, 6, 9})
MODE_SETTLE_S = 1.0
#: After the mission start: the vehicle must report leaving the ground (landed state, or this height)
#: within ``TAKEOFF_CONFIRM_S`` (said once if not), or a disarm on the ground starts it again; a
#: HEARTBEAT must report it armed within ``ARMED_REPORT_S``.
LEFT_GROUND_M = 1.0
TAKEOFF_CONFIRM_S = 5.0
ARMED_REPORT_S = 2.5
#: No answer to ARM / MISSION_START within this long: tried again once ready.
STAGE_TIMEOUT = 3.0
#: A mission upload that ends in one of these (the vehicle cancelled it: its GCS fell silent between
#: items; an error; an exchange out of step; or no answer at all, ``MissionUploader.timed_out``) is
#: tried again after ``backoff``, until ``UPLOAD_DEADLINE_S`` after the first try; any other result
#: (an item or a size the vehicle refuses) fails at once: the same mission would be refused again.
UPLOAD_RETRYABLE = frozenset({mav.MAV_MISSION_ERROR, mav.MAV_MISSION_INVALID_SEQUENCE, mav.MAV_MISSION_DENIED,
                              mav.MAV_MISSION_OPERATION_CANCELLED})
UPLOAD_BACKOFF_S = 2.0
UPLOAD_BACKOFF_MAX_S = 30.0
UPLOAD_DEADLINE_S = 180.0


def jitter(seed: bytes, *what: object) -> float:
    """A draw in [0, 1) for ``what`` from ``seed`` (fresh randomness the adapter gave the core): the same
    draw for the same seed and ``what``, unrelated draws otherwise; no state to copy or to order."""
    h = hashlib.blake2b(repr(what).encode(), key=seed[:64], digest_size=8).digest()
    return int.from_bytes(h, "big") / 2.0**64


def backoff(tries: int, u: float, base: float = UPLOAD_BACKOFF_S, cap: float = UPLOAD_BACKOFF_MAX_S) -> float:
    """The wait before try ``tries + 1``: doubling from ``base`` up to ``cap``, half of it fixed and half
    drawn (``u`` in [0, 1)): drones that failed together do not try again together."""
    d = min(cap, base * 2.0 ** min(max(tries - 1, 0), 30))
    return d / 2 + u * d / 2


class Stage(enum.Enum):
    """Where the GS is in flying its mission with one drone."""

    IDLE = "idle"  # waiting to know the autopilot (its HEARTBEAT)
    PREPARING = "preparing"  # ArduPilot: MIS_OPTIONS "continue after land" set and confirmed
    UPLOADING = "uploading"
    UPLOAD_WAIT = "upload_wait"  # a failed upload waits its backoff before the next try
    WAITING_READY = "waiting_ready"  # pre-arm checks, position estimate, or the next try after a refusal
    ARMING = "arming"
    STARTING = "starting"
    REFUSED = "refused"  # ARM or MISSION_START refused: the vehicle's reasons are gathered a moment
    TAKING_OFF = "taking_off"  # started: armed and leaving the ground is awaited
    FLYING = "flying"  # left the ground
    FAILED = "failed"


# ----------------------------------------------------------------------- events
@dataclass(frozen=True, slots=True)
class FlightTick:
    now: float


@dataclass(frozen=True, slots=True)
class FlightAck:
    now: float
    command: int
    accepted: bool
    result: int


@dataclass(frozen=True, slots=True)
class FlightParam:
    """A PARAM_VALUE from the vehicle."""

    now: float
    name: str
    value: float


FlightEvent = FlightTick | FlightAck | FlightParam


@dataclass(frozen=True, slots=True)
class PendingRefusal:
    """A refused ARM / MISSION_START awaiting its reasons."""

    what: str
    result: int
    at: float


class VehicleFacts(Protocol):
    """What the mission reads of the vehicle (the GS's view of the drone: ``gs.droneview.DroneView``)."""

    autopilot: str | None
    armed: bool
    disarmed_at: float | None
    custom_mode: int
    landed_state: int
    prearm_ok: bool | None
    texts: list[tuple[float, str]]
    fix: PositionFix


Send = Callable[[Any], "list[Action]"]  # seal one MAVLink message for the drone


#: A handler moved to a stage its table row does not allow: a programming error (the engine's one error).
IllegalStage = IllegalTransition


class Mission(Machine):
    """Where this GS stands in flying its mission with one drone (see the module docstring)."""

    _state_attr = "stage"
    _log = log

    def __init__(self, gs: str, drone: str, sysid: int, plan: list[PlannedItem] | None, *, seed: bytes = b"",
                 upload_spread_s: float = 0.0, takeoff_spread_s: float = 0.0,
                 counters: "Counter[str] | None" = None) -> None:
        self.gs, self.drone, self.sysid, self.plan = gs, drone, sysid, plan
        #: the route's first bad segment (``zdrone.core.routecheck``, checked by the session against the
        #: fleet in force): the mission is refused before upload
        self.route_problem: str | None = None
        self.seed = seed  # the adapter's randomness (``jitter``)
        self.upload_spread_s, self.takeoff_spread_s = upload_spread_s, takeoff_spread_s
        self.counters: Counter[str] = Counter() if counters is None else counters
        self.start_at: float | None = None  # the first upload's moment, spread over the GS's drones
        self.arm_at: float | None = None  # the first arming's moment, spread likewise
        self.upload_tries = 0  # failed uploads so far
        self.upload_first: float | None = None  # when the first upload began
        self.stage = Stage.IDLE
        self.stage_time = 0.0
        self.uploader: MissionUploader | None = None
        self.tries = 0  # of the current stage's command (arm, start, parameter)
        self.next_try = 0.0
        self.waiting: str | None = None  # what the GS last said it waits for before arming
        self.refusal: PendingRefusal | None = None
        self.restarts = 0  # armed and started again after a disarm on the ground
        self.unexplained = 0  # refusals neither the vehicle's words nor its state explain
        self.takeoff_late_said = False

    # ------------------------------------------------------------------ engine
    def handle(self, ev: FlightEvent, v: VehicleFacts, send: Send) -> list[Action]:
        """Apply ``ev``: the table's handler for (stage, event type), if any."""
        if self.plan is None:
            return []
        row = self._row(TABLE, ev)
        if row is None:
            return []
        return row[0](self, ev, v, send)

    def _machine_name(self, key: object = None) -> str:
        return f"mission {self.drone}"

    def _put_state(self, new: Stage, key: object = None, now: float | None = None) -> None:
        assert now is not None, "a mission's move names its time (the stage's clock starts then)"
        self.stage, self.stage_time = new, now

    def check_route(self, fleet: Any, drone: str) -> None:
        """The route against the coverages of the GSs authorized for ``drone`` in ``fleet``
        (``zdrone.core.routecheck``): one that leaves them, or crosses between two without an overlap long
        enough for a hand-over at its cruise speed, is refused before upload (``route_problem``)."""
        if self.plan is None:
            return
        from zdrone.core.reference import CRUISE_SPEED_MS
        from zdrone.core.routecheck import check_mission

        report = check_mission(self.plan, fleet, drone, None, CRUISE_SPEED_MS)
        self.route_problem = None if report.ok else report.problem.describe()  # type: ignore[union-attr]

    def deadline(self, now: float, v: VehicleFacts) -> float | None:
        """When, after ``now``, a ``FlightTick`` next matters if no input comes (None: only an input
        moves the mission now)."""
        if self.plan is None:
            return None
        s, t = self.stage, self.stage_time
        due: tuple[float, ...] = ()
        if s is Stage.IDLE and self.start_at is not None:
            due = (self.start_at,)
        elif s in (Stage.PREPARING, Stage.UPLOAD_WAIT):
            due = (self.next_try,)
        elif s is Stage.UPLOADING and self.uploader is not None:
            due = (self.uploader.last_activity + self.uploader.retry_s,)
        elif s is Stage.WAITING_READY:
            # ready (or not yet looked at) with no arming moment drawn: the next tick draws it, at once
            first = self.arm_at is None and self.waiting is None and self.next_try <= now
            due = (self.next_try, t + READY_WAIT_S, self.arm_at or 0.0, math.nextafter(now, math.inf) if first else 0.0)
        elif s in (Stage.ARMING, Stage.STARTING):
            due = (t + STAGE_TIMEOUT,)
        elif s is Stage.REFUSED and self.refusal is not None:
            due = (self.refusal.at + REASON_WAIT_S,)
        elif s is Stage.TAKING_OFF:
            due = (t + ARMED_REPORT_S, t + TAKEOFF_CONFIRM_S)
        later = [d for d in due if d > now]
        return min(later) if later else None

    def on_message(self, msg: Any, now: float, gcs_sysid: int, send: Send) -> list[Action]:
        """A decoded vehicle message: the mission upload's protocol answers it."""
        if self.uploader is None:
            return []
        out: list[Action] = []
        for m in self.uploader.on_message(msg, now, gcs_sysid):
            out += send(m)
        return out

    def _command(self, send: Send, command: int, *params: float) -> list[Action]:
        p = list(params) + [0.0] * (7 - len(params))
        return send(mav.MAVLink_command_long_message(self.sysid, 1, command, 0, *p))

    # ------------------------------------------------------------------ handlers
    def _reasons(self, v: VehicleFacts, since: float) -> list[str]:
        """What the vehicle said since ``since``: the reason of a refusal, as far as it gives one."""
        return [t for (when, t) in v.texts if when >= since]

    def _give_up(self, v: VehicleFacts, send: Send, now: float, reason: str) -> list[Action]:
        """The mission cannot be flown: say why, and leave the vehicle disarmed if it is on the ground."""
        self._set_state(Stage.FAILED, now=now)
        self.counters["mission_failed"] += 1
        out: list[Action] = [Emit(rec.MissionFailed(drone=self.drone, reason=reason)),
                             ToOperator(f"zdrone gs {self.gs}: mission for {self.drone} failed: {reason}")]
        if v.armed and v.landed_state != mav.MAV_LANDED_STATE_IN_AIR:
            out += self._command(send, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0)
        return out

    def _identify(self, ev: FlightTick, v: VehicleFacts, send: Send) -> list[Action]:
        """Wait for the autopilot's HEARTBEAT; ArduPilot first gets "continue after land"."""
        if v.autopilot is None:
            return []
        if self.start_at is None:  # not every drone of the GS at once
            self.start_at = ev.now + self.upload_spread_s * jitter(self.seed, self.drone, "upload")
        if ev.now < self.start_at:
            return []
        self.tries = 0
        if v.autopilot == "ardupilot":
            self._set_state(Stage.PREPARING, now=ev.now)
            return self._set_mis_options(send, ev.now)
        return self._start_upload(ev, v, send)

    def _set_mis_options(self, send: Send, now: float) -> list[Action]:
        self.next_try = now + RETRY_AFTER_S
        return send(mav.MAVLink_param_set_message(self.sysid, 1, b"MIS_OPTIONS", float(ARDUPILOT_CONTINUE_AFTER_LAND),
                                                  mav.MAV_PARAM_TYPE_INT16))

    def _preparing_tick(self, ev: FlightTick, v: VehicleFacts, send: Send) -> list[Action]:
        if ev.now < self.next_try:
            return []
        self.tries += 1
        if self.tries >= MAX_TRIES:
            return self._give_up(v, send, ev.now, "MIS_OPTIONS (continue after land) never confirmed")
        return self._set_mis_options(send, ev.now)

    def _preparing_param(self, ev: FlightParam, v: VehicleFacts, send: Send) -> list[Action]:
        if ev.name != "MIS_OPTIONS" or not int(ev.value) & ARDUPILOT_CONTINUE_AFTER_LAND:
            return []
        return [Emit(rec.VehicleParam(drone=self.drone, name=ev.name, value=ev.value)),
                *self._start_upload(FlightTick(ev.now), v, send)]

    def _start_upload(self, ev: FlightTick, v: VehicleFacts, send: Send) -> list[Action]:
        if self.route_problem is not None:  # refused before upload: the route leaves coverage or a crossing is short
            self.counters["mission_refused:route"] += 1
            return self._give_up(v, send, ev.now, f"route refused: {self.route_problem}")
        items = encode_mission(self.plan, v.autopilot if v.autopilot in AUTOPILOTS else "px4")
        self.uploader = MissionUploader(items, target=(self.sysid, 1))
        if self.upload_first is None:
            self.upload_first = ev.now
        out: list[Action] = []
        for m in self.uploader.start(ev.now):
            out += send(m)
        self._set_state(Stage.UPLOADING, now=ev.now)
        return out + [Emit(rec.MissionUpload(drone=self.drone, items=len(items), autopilot=v.autopilot))]

    def _upload_tick(self, ev: FlightTick, v: VehicleFacts, send: Send) -> list[Action]:
        assert self.uploader is not None
        out: list[Action] = []
        for m in self.uploader.tick(ev.now):
            out += send(m)
        if self.uploader.done:
            if self.uploader.accepted:
                self.tries, self.next_try = 0, 0.0
                self._set_state(Stage.WAITING_READY, now=ev.now)
            else:
                out += self._upload_failed(v, send, ev.now)
        return out

    def _upload_failed(self, v: VehicleFacts, send: Send, now: float) -> list[Action]:
        """The upload ended without the vehicle accepting it: tried again after ``backoff`` if a new try
        may succeed and ``UPLOAD_DEADLINE_S`` allows, else given up (said, logged, counted)."""
        up = self.uploader
        assert up is not None and up.result is not None
        result = up.result
        try:
            name = mav.enums["MAV_MISSION_RESULT"][result].name.removeprefix("MAV_MISSION_")
        except KeyError:
            name = "unknown"
        what = "no answer from the vehicle" if up.timed_out else f"MISSION_ACK {result} {name}"
        if result not in UPLOAD_RETRYABLE:
            self.counters["mission_upload_failed"] += 1
            return self._give_up(v, send, now, f"mission upload refused ({what})")
        self.upload_tries += 1
        wait = backoff(self.upload_tries, jitter(self.seed, self.drone, "upload", self.upload_tries))
        first = now if self.upload_first is None else self.upload_first
        if now + wait - first > UPLOAD_DEADLINE_S:
            self.counters["mission_upload_failed"] += 1
            return self._give_up(v, send, now, f"mission upload failed {self.upload_tries} times in "
                                                f"{now - first:.0f} s (last: {what})")
        self.uploader, self.next_try = None, now + wait
        self._set_state(Stage.UPLOAD_WAIT, now=now)
        self.counters["mission_upload_retry"] += 1
        return [Emit(rec.MissionRetry(drone=self.drone, what="upload", result=None if up.timed_out else result,
                                      try_=self.upload_tries, after=round(wait, 3))),
                ToOperator(f"zdrone gs {self.gs}: mission upload to {self.drone} failed ({what}); "
                           f"trying again in {wait:.1f} s")]

    def _upload_wait_tick(self, ev: FlightTick, v: VehicleFacts, send: Send) -> list[Action]:
        """A failed upload's backoff is over: the next try."""
        if ev.now < self.next_try:
            return []
        return self._start_upload(ev, v, send)

    # ------------------------------------------------------- ready, arm, start
    def not_ready(self, v: VehicleFacts, now: float) -> str | None:
        """What the vehicle still lacks to arm and fly its mission (None: nothing), in the operator's
        words: the pre-arm checks of SYS_STATUS (with the autopilot's own PreArm text) and, for the
        mission mode, an absolute horizontal position (ArduPilot: its EKF uses GPS; PX4: a global
        position estimate)."""
        if v.prearm_ok is False:
            said = next((t for (when, t) in reversed(v.texts)
                         if now - when <= PREARM_TEXT_S and t.lower().startswith(PREARM_PREFIXES)), None)
            return "pre-arm checks failing" + (f" ({said})" if said else "")
        if v.prearm_ok is None and now - self.stage_time < READY_WAIT_S:
            return "waiting for the pre-arm report (SYS_STATUS)"
        why = v.fix.unknown_because
        if why is None and v.fix.estimate_absolute:
            return None
        if why is not None and why.startswith(("no GPS fix", "position 0, 0")):
            return f"waiting for a GPS fix ({why})"
        if v.autopilot == "ardupilot" and v.fix.ekf_flags is not None:
            return "waiting for the EKF to use GPS (EKF_STATUS_REPORT: no absolute position)"
        if v.autopilot == "px4":
            return "waiting for a global position estimate"
        return f"waiting for a position ({why or 'estimate not absolute'})"

    def _show_waiting(self, waiting: str | None) -> list[Action]:
        """ToOperator what the GS waits for, once each time it changes."""
        if waiting == self.waiting:
            return []
        self.waiting = waiting
        text = f"{self.drone} ready: arming" if waiting is None else f"{self.drone} not ready: {waiting}"
        return [Emit(rec.VehicleWaiting(drone=self.drone, waiting=waiting)), ToOperator(f"zdrone gs {self.gs}: {text}")]

    def _airborne(self, v: VehicleFacts) -> bool:
        """The vehicle is armed and off the ground: its mission is being flown."""
        return v.armed and (v.landed_state in (mav.MAV_LANDED_STATE_IN_AIR, mav.MAV_LANDED_STATE_TAKEOFF) or (
            v.fix.position is not None and v.fix.position.alt > LEFT_GROUND_M))

    def _flying_already(self, now: float) -> list[Action]:
        """The start's answer was lost (a lossy radio) but the vehicle flies: the mission started. Never
        start it again (that would fly it from its first item)."""
        self._set_state(Stage.FLYING, now=now)
        return [Emit(rec.TakeoffConfirmed(drone=self.drone, restarts=self.restarts)),
                ToOperator(f"zdrone gs {self.gs}: {self.drone} is flying (its start's answer was lost)")]

    def _ready_tick(self, ev: FlightTick, v: VehicleFacts, send: Send) -> list[Action]:
        """Arm once the vehicle says it can fly the mission (``not_ready``); no retry counter runs out
        while it is not ready, the GS says what it waits for."""
        if self._airborne(v):
            return self._flying_already(ev.now)
        if ev.now < self.next_try:
            return []
        out = self._show_waiting(self.not_ready(v, ev.now))
        if self.waiting is not None:
            return out
        if self.arm_at is None:  # the first arming: not every drone of the GS at once
            self.arm_at = ev.now + self.takeoff_spread_s * jitter(self.seed, self.drone, "arm")
        if ev.now < self.arm_at:
            return out
        if v.armed:  # armed already (e.g. a start refused while armed): go on with the start
            self._set_state(Stage.STARTING, now=ev.now)
            return out + self._command(send, mav.MAV_CMD_MISSION_START, 0, 0)
        if v.autopilot == "ardupilot" and v.custom_mode in ARDUPILOT_NOT_ARMABLE:
            self.next_try = ev.now + MODE_SETTLE_S  # left in AUTO (or RTL, LAND) by a disarm: arm in GUIDED
            return out + self._command(send, mav.MAV_CMD_DO_SET_MODE, *set_mode_params("ardupilot", "GUIDED"))
        self._set_state(Stage.ARMING, now=ev.now)
        return out + self._command(send, mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)

    def _stage_timeout(self, ev: FlightTick, v: VehicleFacts, send: Send) -> list[Action]:
        """No answer to ARM / MISSION_START within ``STAGE_TIMEOUT``: tried again once ready."""
        if self.stage is Stage.STARTING and self._airborne(v):
            return self._flying_already(ev.now)
        if ev.now - self.stage_time <= STAGE_TIMEOUT:
            return []
        what = "arm" if self.stage is Stage.ARMING else "mission start"
        self.next_try = ev.now + RETRY_AFTER_S
        self._set_state(Stage.WAITING_READY, now=ev.now)
        return [Emit(rec.VehicleRefused(drone=self.drone, what=f"{what} (no answer)", result=None, try_=self.tries, texts=[]))]

    def _step_refused(self, ev: FlightAck, what: str) -> list[Action]:
        """A refusal: classified only after ``REASON_WAIT_S`` (ArduPilot says why after its ACK)."""
        self.refusal = PendingRefusal(what, ev.result, ev.now)
        self._set_state(Stage.REFUSED, now=ev.now)
        return []

    def _arm_ack(self, ev: FlightAck, v: VehicleFacts, send: Send) -> list[Action]:
        if ev.command != mav.MAV_CMD_COMPONENT_ARM_DISARM:
            return []
        if not ev.accepted:
            return self._step_refused(ev, "arm")
        v.armed = True  # the ACK says so before the next HEARTBEAT does
        self._set_state(Stage.STARTING, now=ev.now)
        return self._command(send, mav.MAV_CMD_MISSION_START, 0, 0)

    def _start_ack(self, ev: FlightAck, v: VehicleFacts, send: Send) -> list[Action]:
        if ev.command != mav.MAV_CMD_MISSION_START:
            return []
        if not ev.accepted:
            return self._step_refused(ev, "mission start")
        self._set_state(Stage.TAKING_OFF, now=ev.now)
        return [Emit(rec.MissionStarted(drone=self.drone, result=ev.result))]

    def _classify_refusal(self, ev: FlightTick, v: VehicleFacts, send: Send) -> list[Action]:
        """``REASON_WAIT_S`` after a refusal, with the texts that came before and after its ACK: not
        ready yet (its result code, its texts, or what the vehicle reports) is waited for; a refusal
        waiting cannot fix gives the mission up."""
        r = self.refusal
        assert r is not None
        if ev.now - r.at < REASON_WAIT_S:
            return []
        self.refusal = None
        texts = self._reasons(v, r.at - REASON_BEFORE_S)
        said = " ".join(texts).lower()
        self.tries += 1
        out: list[Action] = [Emit(rec.VehicleRefused(drone=self.drone, what=r.what, result=r.result, try_=self.tries, texts=texts))]
        reason = "; ".join(texts) or f"result {r.result}"
        final = any(p in said for p in REFUSED_FOR_GOOD)
        not_ready = (r.result == mav.MAV_RESULT_TEMPORARILY_REJECTED or any(p in said for p in NOT_READY)
                     or self.not_ready(v, ev.now) is not None)
        if not (final or not_ready):
            self.unexplained += 1
        if final or self.unexplained >= MAX_UNEXPLAINED:
            out.append(Emit(rec.MissionStartFailed(drone=self.drone, result=r.result, texts=texts)))
            return out + self._give_up(v, send, ev.now, f"{r.what} refused (result {r.result}): {reason}")
        self.next_try = ev.now + RETRY_AFTER_S
        self._set_state(Stage.WAITING_READY, now=ev.now)
        return out + [ToOperator(f"zdrone gs {self.gs}: {self.drone}: {r.what} refused ({reason}); "
                          f"{'not ready yet, waiting' if not_ready else 'trying again'}")]

    # ----------------------------------------------------------- take-off
    def _takeoff_tick(self, ev: FlightTick, v: VehicleFacts, send: Send) -> list[Action]:
        """After the start: the vehicle must leave the ground; if it disarmed on the ground (ArduCopter's
        auto-disarm, PX4's preflight disarm) it is armed and started again."""
        if self._airborne(v):
            self._set_state(Stage.FLYING, now=ev.now)
            return [Emit(rec.TakeoffConfirmed(drone=self.drone, restarts=self.restarts)),
                    ToOperator(f"zdrone gs {self.gs}: {self.drone} took off")]
        disarmed = (v.disarmed_at is not None and v.disarmed_at > self.stage_time) or (
            not v.armed and ev.now - self.stage_time > ARMED_REPORT_S)
        if disarmed:
            self.restarts += 1
            self.takeoff_late_said = False
            self.next_try = ev.now + RETRY_AFTER_S
            self._set_state(Stage.WAITING_READY, now=ev.now)
            reason = "disarmed on the ground before taking off (the autopilot's auto-disarm)"
            return [Emit(rec.TakeoffRestart(drone=self.drone, reason=reason, restarts=self.restarts)),
                    ToOperator(f"zdrone gs {self.gs}: {self.drone} {reason}: arming and starting again")]
        if ev.now - self.stage_time > TAKEOFF_CONFIRM_S and not self.takeoff_late_said:
            self.takeoff_late_said = True
            return [ToOperator(f"zdrone gs {self.gs}: {self.drone} started but still on the ground after "
                        f"{TAKEOFF_CONFIRM_S:g} s (mode {mode_name(v.autopilot, v.custom_mode)})")]
        return []


#: (stage, event type) -> (handler, the stages it may move to). Pairs not listed do nothing.
TABLE: Table[Stage] = {
    (Stage.IDLE, FlightTick): (Mission._identify, frozenset({Stage.PREPARING, Stage.UPLOADING, Stage.FAILED})),
    (Stage.PREPARING, FlightTick): (Mission._preparing_tick, frozenset({Stage.FAILED})),
    (Stage.PREPARING, FlightParam): (Mission._preparing_param, frozenset({Stage.UPLOADING, Stage.FAILED})),
    (Stage.UPLOADING, FlightTick): (Mission._upload_tick, frozenset({Stage.WAITING_READY, Stage.UPLOAD_WAIT, Stage.FAILED})),
    (Stage.UPLOAD_WAIT, FlightTick): (Mission._upload_wait_tick, frozenset({Stage.UPLOADING, Stage.FAILED})),
    (Stage.WAITING_READY, FlightTick): (Mission._ready_tick, frozenset({Stage.FLYING, Stage.STARTING, Stage.ARMING})),
    (Stage.ARMING, FlightTick): (Mission._stage_timeout, frozenset({Stage.WAITING_READY})),
    (Stage.STARTING, FlightTick): (Mission._stage_timeout, frozenset({Stage.FLYING, Stage.WAITING_READY})),
    (Stage.ARMING, FlightAck): (Mission._arm_ack, frozenset({Stage.REFUSED, Stage.STARTING})),
    (Stage.STARTING, FlightAck): (Mission._start_ack, frozenset({Stage.REFUSED, Stage.TAKING_OFF})),
    (Stage.REFUSED, FlightTick): (Mission._classify_refusal, frozenset({Stage.WAITING_READY, Stage.FAILED})),
    (Stage.TAKING_OFF, FlightTick): (Mission._takeoff_tick, frozenset({Stage.FLYING, Stage.WAITING_READY})),
}
# Not listed: FLYING and FAILED take no event (the mission is the autopilot's, or given up); an ACK
# or a parameter outside the stage that waits for it changes nothing.
