"""The simulated autopilot's mission: the MAVLink mission microservice, and flying the items.

Theory of operation: ``MissionProtocol`` holds the stored mission (``items``), the current item and
how far the flight has come (items reached, finished), and answers the mission microservice:

* upload: MISSION_COUNT starts an ``Upload``; the vehicle asks for each item in turn
  (MISSION_REQUEST_INT), checks it (``check_item``: supported command and frame, coordinates,
  altitude, params) and ends with a MISSION_ACK: ACCEPTED and the new mission, or the first
  problem and the old mission kept. A GCS that goes silent is asked again every second, five
  times, then the upload is CANCELLED (``retry_upload``, from the autopilot's step). A count of 0
  clears the mission. Only the plain mission type is stored (no fence, no rally points).
* download (MISSION_REQUEST_LIST, then MISSION_REQUEST_INT or MISSION_REQUEST per item), clear
  (MISSION_CLEAR_ALL), set current (MISSION_SET_CURRENT; DO_SET_MISSION_CURRENT comes through the
  command table); MISSION_CURRENT reports the current item and the mission state.
* the personality's rules: ArduPilot stores home as item 0, whatever was sent, and never flies it;
  PX4 checks feasibility after the ACK, and a refusal shows only at MISSION_START.

``fly(now)`` runs while the autopilot is in its mission mode and steers by the vehicle's ``Guidance``: DO items
(speed, gripper) complete at once; TAKEOFF climbs where the vehicle is; WAYPOINT flies there and
holds ``param1`` seconds inside the acceptance radius (``param2`` if given); RTL hands over to the
autopilot's return mode; LAND lands at the item, then ArduPilot disarms and the mission ends there
(unless MIS_OPTIONS bit 2 and a take-off next), while PX4 rests on the ground for
``DELIVERY_PAUSE_S`` (``paused_until``) and takes off for the next item. MISSION_ITEM_REACHED is
sent once per item. Any mode change ends a landing in progress (``landing_since``).

Bad input never raises: items for another peer or out of sequence, unsupported commands, frames and
mission types, NaN or out-of-range values get the MAV_MISSION_RESULT that says so, counted as
``mission_<result>``.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, Protocol

from pymavlink.dialects.v20 import common as mav

from zdrone.core.geometry import GeoPoint, ne_of
from zdrone.vehicle.personality import ModeRow, Say
from zdrone.vehicle.px4modes import FlightMode

if TYPE_CHECKING:
    from zdrone.vehicle.sim.vehicle import VehicleState
    from zdrone.vehicle.sim.guidance import Guidance
    from zdrone.vehicle.sim.outbox import Outbox
    from zdrone.vehicle.personality import ModeRow, Param


class MissionAutopilot(Protocol):
    """What the mission reads and does of its autopilot: all it may reach (``tests/unit/test_sim_parts.py``)."""

    out: Outbox
    p: Personality
    params: dict[str, Param]
    home: GeoPoint
    home_amsl: float
    guidance: Guidance
    vehicle: VehicleState
    mode: FlightMode

    def set_mode(self, mode: FlightMode, row: ModeRow | None = None) -> None: ...

    def disarm(self, text: str) -> None: ...

    def operate_gripper(self, action: float) -> None: ...

    def phys(self, what: str) -> float: ...


log = logging.getLogger(__name__)

MAX_MISSION_ITEMS = 500
DELIVERY_PAUSE_S = 3.0  # on the ground after a mid-mission landing before the next item
UPLOAD_RETRY_S = 1.0  # a silent GCS is asked again for the item after this long
UPLOAD_RETRIES = 5  # ... this many times, then the upload is cancelled
MAX_DISTANCE_M = 50_000  # farther from home is refused
NAV_COMMANDS = frozenset({mav.MAV_CMD_NAV_WAYPOINT, mav.MAV_CMD_NAV_TAKEOFF, mav.MAV_CMD_NAV_LAND,
                          mav.MAV_CMD_NAV_RETURN_TO_LAUNCH, mav.MAV_CMD_NAV_LOITER_TIME})
DO_COMMANDS = frozenset({mav.MAV_CMD_DO_CHANGE_SPEED, mav.MAV_CMD_DO_GRIPPER, mav.MAV_CMD_DO_JUMP})
MAX_JUMP_REPEAT = 32767  # ArduPilot keeps a DO_JUMP's repeat count in 16 bits (signed); -1 repeats for ever
GLOBAL_FRAMES = frozenset({mav.MAV_FRAME_GLOBAL, mav.MAV_FRAME_GLOBAL_INT, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT,
                           mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT})
DO_FRAMES = GLOBAL_FRAMES | {mav.MAV_FRAME_MISSION}


@dataclass(slots=True)
class MissionItem:
    """One stored item (mutable: ``current`` is set when it is sent in a download)."""

    seq: int
    frame: int
    command: int
    current: int
    autocontinue: int
    params: tuple[float, float, float, float]
    lat: float
    lon: float
    alt: float  # as given in ``frame``
    mission_type: int = 0

    def to_int_msg(self, target: tuple[int, int]) -> mav.MAVLink_mission_item_int_message:
        return mav.MAVLink_mission_item_int_message(
            target[0], target[1], self.seq, self.frame, self.command, self.current, self.autocontinue,
            *self.params, int(round(self.lat * 1e7)), int(round(self.lon * 1e7)), self.alt, self.mission_type)

    def to_float_msg(self, target: tuple[int, int]) -> mav.MAVLink_mission_item_message:
        return mav.MAVLink_mission_item_message(
            target[0], target[1], self.seq, self.frame, self.command, self.current, self.autocontinue,
            *self.params, self.lat, self.lon, self.alt, self.mission_type)


@dataclass(slots=True)
class Upload:
    """An upload in progress (vehicle side of the mission protocol)."""

    peer: tuple[int, int]
    count: int
    mission_type: int
    items: list[MissionItem] = field(default_factory=list)
    last_request: float = 0.0
    retries: int = 0


def relative_alt(frame: int, alt: float, home_amsl: float) -> float:
    """An altitude given in ``frame`` as metres above home."""
    return alt - home_amsl if frame in (mav.MAV_FRAME_GLOBAL, mav.MAV_FRAME_GLOBAL_INT) else alt


def home_item(home: GeoPoint, home_amsl: float) -> MissionItem:
    """Item 0 as ArduPilot stores it: home."""
    return MissionItem(0, mav.MAV_FRAME_GLOBAL, mav.MAV_CMD_NAV_WAYPOINT, 0, 1, (0.0, 0.0, 0.0, 0.0),
                       home.lat, home.lon, home_amsl)


def check_item(item: MissionItem, home: GeoPoint, home_amsl: float) -> int | None:
    """The MAV_MISSION_RESULT that refuses ``item``, or None if it can be flown."""
    if item.command not in NAV_COMMANDS and item.command not in DO_COMMANDS:
        return mav.MAV_MISSION_UNSUPPORTED
    positional = item.command in NAV_COMMANDS and item.command != mav.MAV_CMD_NAV_RETURN_TO_LAUNCH
    if item.frame not in (GLOBAL_FRAMES if positional else DO_FRAMES):
        return mav.MAV_MISSION_UNSUPPORTED_FRAME
    if positional:
        takeoff_or_land = item.command in (mav.MAV_CMD_NAV_TAKEOFF, mav.MAV_CMD_NAV_LAND)
        lat_ok = math.isfinite(item.lat) and -90 <= item.lat <= 90 and (item.lat != 0 or takeoff_or_land)
        lon_ok = math.isfinite(item.lon) and -180 <= item.lon <= 180 and (item.lon != 0 or takeoff_or_land)
        if not lat_ok:
            return mav.MAV_MISSION_INVALID_PARAM5_X
        if not lon_ok:
            return mav.MAV_MISSION_INVALID_PARAM6_Y
        if not math.isfinite(item.alt) or not -100 <= relative_alt(item.frame, item.alt, home_amsl) <= 1000:
            return mav.MAV_MISSION_INVALID_PARAM7
        if item.lat != 0 and math.hypot(*ne_of(home, GeoPoint(item.lat, item.lon))) > MAX_DISTANCE_M:
            return mav.MAV_MISSION_INVALID_PARAM5_X
    if item.command == mav.MAV_CMD_NAV_LOITER_TIME and not (math.isfinite(item.params[0]) and 0 <= item.params[0] <= 3600):
        return mav.MAV_MISSION_INVALID_PARAM1
    if item.command == mav.MAV_CMD_DO_CHANGE_SPEED and not (math.isfinite(item.params[1]) and -2 <= item.params[1] <= 25):
        return mav.MAV_MISSION_INVALID_PARAM2
    if item.command == mav.MAV_CMD_NAV_WAYPOINT and not (math.isnan(item.params[0]) or 0 <= item.params[0] <= 3600):
        return mav.MAV_MISSION_INVALID_PARAM1
    if item.command == mav.MAV_CMD_DO_JUMP:
        target, repeat = item.params[0], item.params[1]
        if not (math.isfinite(target) and target == int(target) and 0 <= target < item.seq):
            return mav.MAV_MISSION_INVALID_PARAM1  # only backwards, to an item already uploaded
        if not (math.isfinite(repeat) and repeat == int(repeat) and -1 <= repeat <= MAX_JUMP_REPEAT):
            return mav.MAV_MISSION_INVALID_PARAM2
    return None


def _peer(msg: Any) -> tuple[int, int]:
    return msg.get_srcSystem(), msg.get_srcComponent()


class MissionProtocol:
    """The stored mission of one autopilot, its microservice, and flying it (``ap`` is the autopilot)."""

    def __init__(self, ap: MissionAutopilot) -> None:
        self.ap = ap
        self.guidance = ap.guidance  # where the mission steers the vehicle
        self.items: list[MissionItem] = []
        self.current = 0
        self.finished = False
        self.refusal: Say | None = None  # why the stored mission cannot be flown (PX4 feasibility)
        self.reached: set[int] = set()
        self.jumps: dict[int, int] = {}  # DO_JUMP item -> jumps it made since the mission (re)started
        self.upload: Upload | None = None
        self.item_started: float | None = None
        self.reached_at = 0.0  # when the current waypoint was reached (its hold time runs from here)
        self.landing_since: float | None = None  # landing at a LAND item since
        self.paused_until = 0.0  # on the ground between a mission landing and the next item
        self.handlers: Mapping[str, Callable[[Any, float], None]] = MappingProxyType({
            "MISSION_COUNT": self.on_count,
            "MISSION_ITEM_INT": self.on_item,
            "MISSION_ITEM": self.on_item,
            "MISSION_REQUEST_LIST": self.on_request_list,
            "MISSION_REQUEST_INT": self.on_request,
            "MISSION_REQUEST": self.on_request,
            "MISSION_ACK": self.on_ack,
            "MISSION_CLEAR_ALL": self.on_clear,
            "MISSION_SET_CURRENT": self.on_set_current,
        })

    @property
    def first_flown(self) -> int:
        """Index of the first flown item (ArduPilot keeps item 0 as home)."""
        return 1 if self.ap.p.home_item0 else 0

    @property
    def flyable(self) -> bool:
        """There is an item to fly."""
        return len(self.items) > self.first_flown

    def ack(self, peer: tuple[int, int], result: int, mission_type: int) -> None:
        self.ap.out.send(mav.MAVLink_mission_ack_message(peer[0], peer[1], result, mission_type))
        if result != mav.MAV_MISSION_ACCEPTED:
            self.ap.out.count(f"mission_{mav.enums['MAV_MISSION_RESULT'][result].name.removeprefix('MAV_MISSION_').lower()}")

    # ------------------------------------------------------------------ upload
    def on_count(self, msg: Any, now: float) -> None:
        peer, mtype = _peer(msg), getattr(msg, "mission_type", 0)
        if mtype != mav.MAV_MISSION_TYPE_MISSION:
            return self.ack(peer, mav.MAV_MISSION_UNSUPPORTED, mtype)
        if msg.count > MAX_MISSION_ITEMS:
            return self.ack(peer, mav.MAV_MISSION_NO_SPACE, mtype)
        if msg.count == 0:
            self.clear()
            return self.ack(peer, mav.MAV_MISSION_ACCEPTED, mtype)
        self.upload = Upload(peer, msg.count, mtype, last_request=now)
        self._request_item(0)

    def _request_item(self, seq: int) -> None:
        up = self.upload
        assert up is not None
        self.ap.out.send(mav.MAVLink_mission_request_int_message(up.peer[0], up.peer[1], seq, up.mission_type))

    def on_item(self, msg: Any, now: float) -> None:
        up = self.upload
        peer = _peer(msg)
        if up is None or peer != up.peer:
            self.ap.out.count("mission_item_unexpected")
            return self.ack(peer, mav.MAV_MISSION_DENIED, getattr(msg, "mission_type", 0))
        expected = len(up.items)
        if msg.seq != expected:
            self.ap.out.count("mission_item_out_of_sequence", f"{msg.seq} != {expected}")
            if msg.seq < expected:
                return  # a duplicate of an item we have; our request for `expected` is outstanding
            return self._request_item(expected)
        is_int = msg.get_type() == "MISSION_ITEM_INT"
        lat = msg.x / 1e7 if is_int else msg.x
        lon = msg.y / 1e7 if is_int else msg.y
        item = MissionItem(msg.seq, msg.frame, msg.command, msg.current, msg.autocontinue,
                           (msg.param1, msg.param2, msg.param3, msg.param4), lat, lon, msg.z, up.mission_type)
        ap = self.ap
        if ap.p.home_item0 and item.seq == 0:
            item = home_item(ap.home, ap.home_amsl)  # ArduPilot stores home as item 0, whatever was sent
        else:
            problem = check_item(item, ap.home, ap.home_amsl)
            if problem is not None:
                log.info("sim: refusing mission item %d (command %d, frame %d)", item.seq, item.command, item.frame)
                self.upload = None
                return self.ack(up.peer, problem, up.mission_type)
        up.items.append(item)
        up.retries, up.last_request = 0, now
        if len(up.items) < up.count:
            return self._request_item(len(up.items))
        self.upload = None
        self.items = up.items
        self.current = self.first_flown if self.flyable else 0
        self.finished = False
        self.reached.clear()
        self.jumps.clear()
        self.ack(up.peer, mav.MAV_MISSION_ACCEPTED, up.mission_type)
        log.info("sim: mission of %d items accepted", len(self.items))
        # PX4 checks feasibility after the upload is ACKed; a refusal only shows at MISSION_START
        self.refusal = ap.p.feasibility(self.items)
        if self.refusal is not None:
            ap.out.say(self.refusal)
        self.send_current()

    def retry_upload(self, now: float) -> None:
        """Ask a silent GCS again for the item, or give the upload up."""
        up = self.upload
        if up is None or not now - up.last_request > UPLOAD_RETRY_S:
            return
        up.retries += 1
        up.last_request = now
        if up.retries > UPLOAD_RETRIES:
            self.ack(up.peer, mav.MAV_MISSION_OPERATION_CANCELLED, up.mission_type)
            self.upload = None
        else:
            self._request_item(len(up.items))

    # -------------------------------------------------------- download, clear, current
    def on_request_list(self, msg: Any, now: float) -> None:
        mtype = getattr(msg, "mission_type", 0)
        count = len(self.items) if mtype == mav.MAV_MISSION_TYPE_MISSION else 0
        peer = _peer(msg)
        self.ap.out.send(mav.MAVLink_mission_count_message(peer[0], peer[1], count, mtype))

    def on_request(self, msg: Any, now: float) -> None:
        mtype = getattr(msg, "mission_type", 0)
        peer = _peer(msg)
        if mtype != mav.MAV_MISSION_TYPE_MISSION or not 0 <= msg.seq < len(self.items):
            return self.ack(peer, mav.MAV_MISSION_INVALID_SEQUENCE, mtype)
        item = self.items[msg.seq]
        item.current = int(msg.seq == self.current)
        self.ap.out.send(item.to_int_msg(peer) if msg.get_type() == "MISSION_REQUEST_INT" else item.to_float_msg(peer))

    def on_ack(self, msg: Any, now: float) -> None:
        pass  # end of a download; nothing to do

    def on_clear(self, msg: Any, now: float) -> None:
        mtype = getattr(msg, "mission_type", 0)
        if mtype in (mav.MAV_MISSION_TYPE_MISSION, mav.MAV_MISSION_TYPE_ALL):
            self.clear()
        self.ack(_peer(msg), mav.MAV_MISSION_ACCEPTED, mtype)  # other types: nothing stored

    def clear(self) -> None:
        self.items, self.current, self.reached, self.jumps = [], 0, set(), {}
        self.refusal = None
        if self.ap.mode is FlightMode.MISSION:
            self.ap.set_mode(FlightMode.HOLD)

    def on_set_current(self, msg: Any, now: float) -> None:
        if not 0 <= msg.seq < len(self.items):
            return self.ack(_peer(msg), mav.MAV_MISSION_INVALID_SEQUENCE, 0)
        self.set_current(msg.seq)

    def set_current(self, seq: int) -> None:
        self.current = max(seq, self.first_flown) if self.flyable else seq
        self.finished = False
        self.item_started = None
        self.landing_since = None
        self.send_current()

    def start(self, first: int, row: ModeRow | None = None) -> None:
        """Enter the mission mode (shown as ``row``) flying from item ``first``."""
        first = max(first, self.first_flown)
        if self.finished or first != self.current:
            self.reached.clear()
            self.jumps.clear()
            self.finished = False
            self.current = first
        self.item_started = None
        self.ap.set_mode(FlightMode.MISSION, row)
        self.send_current()

    def send_current(self) -> None:
        """MISSION_CURRENT: the current item and the mission state."""
        if self.finished:
            state = mav.MISSION_STATE_COMPLETE
        elif not self.flyable:
            state = mav.MISSION_STATE_NO_MISSION
        elif self.ap.mode is FlightMode.MISSION and self.ap.vehicle.armed:
            state = mav.MISSION_STATE_ACTIVE
        else:
            state = mav.MISSION_STATE_NOT_STARTED
        total = len(self.items) - self.first_flown if self.items else 0
        self.ap.out.send(mav.MAVLink_mission_current_message(self.current, total, state, 0))

    # ------------------------------------------------------------------ flying
    def _item_reached(self, seq: int) -> None:
        if seq not in self.reached:
            self.reached.add(seq)
            self.ap.out.send(mav.MAVLink_mission_item_reached_message(seq))

    def _advance(self) -> None:
        self._item_reached(self.current)
        self.item_started = None
        self.landing_since = None
        if self.current + 1 >= len(self.items):
            self.finished = True
            log.info("sim: mission finished")
            if not self.ap.vehicle.landed:
                k = self.ap.vehicle.k
                self.guidance.fly_to(k.north, k.east, k.alt)
        else:
            self.current += 1
        self.send_current()

    def _jump(self, item: MissionItem) -> None:
        """DO_JUMP: back to item param1, param2 times in all (-1: for ever), then on to the next item."""
        done, repeat = self.jumps.get(item.seq, 0), int(item.params[1])
        if repeat >= 0 and done >= repeat:
            self._advance()
            return
        self.jumps[item.seq] = done + 1
        self._item_reached(item.seq)
        target = max(int(item.params[0]), self.first_flown)
        self.reached -= {s for s in self.reached if s >= target}  # the items ahead are reached again
        self.current, self.item_started, self.landing_since = target, None, None
        self.send_current()

    def fly(self, now: float) -> None:
        """Fly the current item: set the vehicle's target, complete items, move on."""
        ap, g = self.ap, self.guidance
        k = ap.vehicle.k
        if self.finished or not self.flyable or not ap.vehicle.armed:
            if not ap.vehicle.landed and g.target is None:
                g.fly_to(k.north, k.east, k.alt)
            return
        self.current = max(self.current, self.first_flown)
        for _ in range(len(self.items)):  # DO items complete at once; stop at the first NAV item
            item = self.items[self.current]
            if item.command == mav.MAV_CMD_DO_CHANGE_SPEED:
                if item.params[1] > 0:
                    g.set_speed(item.params[1])
                self._advance()
                continue
            if item.command == mav.MAV_CMD_DO_GRIPPER:
                ap.operate_gripper(item.params[1])
                self._advance()
                continue
            if item.command == mav.MAV_CMD_DO_JUMP:
                self._jump(item)
                continue
            break
        if self.finished:
            return
        item = self.items[self.current]
        if self.item_started is None:
            self.item_started = now
        here_n, here_e = k.north, k.east
        if item.command == mav.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            self._item_reached(item.seq)
            self.finished = True
            self.send_current()
            ap.set_mode(FlightMode.RTL)
            return
        if item.command == mav.MAV_CMD_NAV_TAKEOFF:
            alt = relative_alt(item.frame, item.alt, ap.home_amsl)
            north, east = ((here_n, here_e) if g.target is None or self.item_started == now
                           else (g.target[0], g.target[1]))
            g.fly_to(north, east, alt)
            if k.alt >= alt - 0.5:
                self._advance()
            return
        n, e = ne_of(ap.home, GeoPoint(item.lat, item.lon)) if item.lat or item.lon else (here_n, here_e)
        if item.command == mav.MAV_CMD_NAV_LAND:
            self._land_at(item, n, e, now)
            return
        alt = relative_alt(item.frame, item.alt, ap.home_amsl)
        g.fly_to(n, e, alt)
        radius = ap.phys("accept_radius")
        if item.command == mav.MAV_CMD_NAV_WAYPOINT and item.params[1] > 0:
            radius = item.params[1]  # the waypoint's own acceptance radius
        dist = math.hypot(n - here_n, e - here_e, alt - k.alt)
        if dist <= radius:
            hold = item.params[0] if math.isfinite(item.params[0]) else 0.0
            if item.seq not in self.reached:
                self._item_reached(item.seq)
                self.reached_at = now
            if now - self.reached_at >= hold:
                self._advance()

    def _land_at(self, item: MissionItem, n: float, e: float, now: float) -> None:
        """A LAND item: fly over it at 5 m at least, descend, and on the ground end or go on."""
        ap = self.ap
        k = ap.vehicle.k
        far = math.hypot(n - k.north, e - k.east) > ap.phys("accept_radius")
        if far and not ap.vehicle.landed and self.landing_since is None:
            self.guidance.fly_to(n, e, max(k.alt, 5.0))
            return
        if self.landing_since is None:
            self.landing_since = now
        self.guidance.fly_to(n, e, -1.0)
        if not ap.vehicle.landed:
            return
        mis_options = int(ap.params["MIS_OPTIONS"].value) if "MIS_OPTIONS" in ap.params else 0
        if not ap.p.continues_after_land(mis_options, self.items, self.current):
            # ArduCopter: disarm at touchdown; the mission stops at this item
            log.info("sim: landed at mission item %d: mission ends here", item.seq)
            self.finished = True
            ap.disarm("disarmed_landing")
            self.send_current()
            return
        log.info("sim: landed at mission item %d", item.seq)
        self._advance()
        if not self.finished:
            self.paused_until = now + DELIVERY_PAUSE_S  # on the ground (delivery) before the next item
