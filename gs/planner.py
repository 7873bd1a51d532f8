"""Mission planning on the ground station: the reference mission, QGroundControl ``.plan`` files,
the encoding of a planned mission for one autopilot, and a sans-IO mission uploader (the GCS side of
the MAVLink mission protocol).

A planned mission is autopilot-neutral: take-offs where the vehicle must leave the ground,
including after a mid-mission landing. ``encode_mission`` turns it into what each autopilot flies:

* PX4 refuses any NAV_TAKEOFF after an item with a position ("Mission rejected: takeoff not first
  waypoint item", at MISSION_START) and takes off again by itself after a mid-mission landing: only
  the first take-off stays.
* ArduPilot keeps item 0 as home and never flies it: a placeholder at home goes first. After a
  mid-mission NAV_LAND it continues only with ``MIS_OPTIONS`` bit 2 set *and* a NAV_TAKEOFF as the
  next navigation item (otherwise it disarms at touchdown): the take-offs stay.

Theory of operation of ``MissionUploader``: ``start(now)`` returns MISSION_COUNT; each
MISSION_REQUEST_INT / MISSION_REQUEST from the vehicle is answered with that item; MISSION_ACK ends
the transfer (``result``). ``tick(now)`` resends MISSION_COUNT if the vehicle said nothing for
``retry_s`` and gives up after ``max_retries``. Messages in and out are pymavlink message objects;
the station seals and sends them.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import common as mav

from zdrone.core.fleet import ConfigError
from zdrone.core.geometry import GeoPoint
from zdrone.core.reference import CRUISE_ALT_M, CRUISE_SPEED_MS, DELIVERY, HOME

REL = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
NAN = float("nan")


@dataclass(frozen=True, slots=True)
class PlannedItem:
    frame: int
    command: int
    params: tuple[float, float, float, float]
    lat: float
    lon: float
    alt: float

    def message(self, seq: int, target: tuple[int, int]) -> mav.MAVLink_mission_item_int_message:
        lat = 0 if math.isnan(self.lat) else int(round(self.lat * 1e7))
        lon = 0 if math.isnan(self.lon) else int(round(self.lon * 1e7))
        return mav.MAVLink_mission_item_int_message(target[0], target[1], seq, self.frame, self.command, int(seq == 0), 1,
                                                    *self.params, lat, lon, self.alt)


def _nav(cmd: int, p: GeoPoint, alt: float, params: tuple[float, float, float, float] = (0.0, 0.0, 0.0, NAN)) -> PlannedItem:
    return PlannedItem(REL, cmd, params, p.lat, p.lon, alt)


#: the autopilots ``encode_mission`` knows
AUTOPILOTS = ("px4", "ardupilot")
#: commands PX4 does not count as "an item with a position" when it checks that a take-off comes
#: first (its FeasibilityChecker); every other command does
_PX4_NON_POSITIONAL = frozenset({
    0, 93, 177, 178, 179, 189, 2003, 203, 2000, 2001, 2500, 2501, 200, 204, 205, 1000, 1001, 201, 195, 196, 197,
    206, 260, 214, 530, 531, 532, 3000})


def encode_mission(items: list[PlannedItem], autopilot: str = "px4", home: GeoPoint = HOME) -> list[PlannedItem]:
    """``items`` as ``autopilot`` flies them (see the module docstring); a DO_JUMP's target follows
    its item to where it lands; ``ValueError`` for an autopilot not in ``AUTOPILOTS``."""
    if autopilot == "px4":
        out: list[PlannedItem] = []
        where: list[int] = []  # index in ``out`` of each planned item (a dropped one: the next item's)
        positional = False
        for it in items:
            where.append(len(out))
            if it.command == mav.MAV_CMD_NAV_TAKEOFF and positional:
                continue  # PX4 would refuse the whole mission; it takes off again by itself
            positional = positional or it.command not in _PX4_NON_POSITIONAL
            out.append(it)
        return [_jump_moved(it, where) for it in out]
    if autopilot == "ardupilot":
        where = list(range(1, len(items) + 1))
        return [_nav(mav.MAV_CMD_NAV_WAYPOINT, home, 0.0, (0.0, 0.0, 0.0, 0.0)),  # item 0: home
                *(_jump_moved(it, where) for it in items)]
    raise ValueError(f"autopilot {autopilot!r}: expected one of {', '.join(AUTOPILOTS)}")


def _jump_moved(it: PlannedItem, where: list[int]) -> PlannedItem:
    """A DO_JUMP aimed at the planned item's new index (any other item as it is)."""
    if it.command != mav.MAV_CMD_DO_JUMP or not 0 <= int(it.params[0]) < len(where):
        return it
    return dataclasses.replace(it, params=(float(where[int(it.params[0])]), *it.params[1:]))


def reference_plan(home: GeoPoint = HOME, delivery: GeoPoint = DELIVERY, alt: float = CRUISE_ALT_M,
                   speed: float = CRUISE_SPEED_MS) -> list[PlannedItem]:
    """The reference flight, autopilot-neutral: take off at A, fly to the delivery point in B's
    area, land, release, take off, return, land."""
    do = mav.MAV_FRAME_MISSION
    return [
        _nav(mav.MAV_CMD_NAV_TAKEOFF, home, alt),
        PlannedItem(do, mav.MAV_CMD_DO_CHANGE_SPEED, (1.0, speed, -1.0, 0.0), NAN, NAN, 0.0),
        _nav(mav.MAV_CMD_NAV_WAYPOINT, delivery, alt),
        _nav(mav.MAV_CMD_NAV_LAND, delivery, 0.0),
        PlannedItem(do, mav.MAV_CMD_DO_GRIPPER, (1.0, float(mav.GRIPPER_ACTION_RELEASE), 0.0, 0.0), NAN, NAN, 0.0),
        _nav(mav.MAV_CMD_NAV_TAKEOFF, delivery, alt),
        _nav(mav.MAV_CMD_NAV_WAYPOINT, home, alt),
        _nav(mav.MAV_CMD_NAV_LAND, home, 0.0),
    ]


def reference_mission(home: GeoPoint = HOME, delivery: GeoPoint = DELIVERY, alt: float = CRUISE_ALT_M,
                      speed: float = CRUISE_SPEED_MS, autopilot: str = "px4") -> list[PlannedItem]:
    """The reference flight encoded for ``autopilot`` (PX4 by default)."""
    return encode_mission(reference_plan(home, delivery, alt, speed), autopilot, home)


#: the most crossings a shuttle mission flies: its loop is one DO_JUMP, whose repeat count the
#: autopilots keep in 16 bits (ArduPilot: signed, at most 32767 repeats of two crossings each)
MAX_SHUTTLE_CROSSINGS = 65_000


def shuttle_mission(crossings: int, home: GeoPoint = HOME, alt: float = CRUISE_ALT_M,
                    speed: float = CRUISE_SPEED_MS, far_east_m: float = 440.0, autopilot: str = "px4") -> list[PlannedItem]:
    """Fly back and forth across the hand-over region ``crossings`` times, then land at home. The
    back-and-forth is one pair of waypoints and a DO_JUMP, so the mission stays 7 items long
    however many crossings it flies (a mission's size is bounded: 500 items in the simulator)."""
    from zdrone.core.geometry import offset

    if not 1 <= crossings <= MAX_SHUTTLE_CROSSINGS:
        raise ValueError(f"{crossings} crossings: must be 1..{MAX_SHUTTLE_CROSSINGS} (the loop is one DO_JUMP, "
                         f"whose repeat count autopilots keep in 16 bits)")
    near_a, near_b = offset(home, 0.0, 80.0), offset(home, 0.0, far_east_m)
    do = mav.MAV_FRAME_MISSION
    items = [_nav(mav.MAV_CMD_NAV_TAKEOFF, home, alt),
             PlannedItem(do, mav.MAV_CMD_DO_CHANGE_SPEED, (1.0, speed, -1.0, 0.0), NAN, NAN, 0.0)]
    loop = len(items)  # where the loop starts in the neutral plan
    pairs, odd = divmod(crossings, 2)
    if pairs:
        items += [_nav(mav.MAV_CMD_NAV_WAYPOINT, near_b, alt), _nav(mav.MAV_CMD_NAV_WAYPOINT, near_a, alt)]
        if pairs > 1:  # the pair once, then pairs - 1 times again
            items.append(PlannedItem(do, mav.MAV_CMD_DO_JUMP, (float(loop), float(pairs - 1), 0.0, 0.0), NAN, NAN, 0.0))
    if odd:
        items.append(_nav(mav.MAV_CMD_NAV_WAYPOINT, near_b, alt))
    items += [_nav(mav.MAV_CMD_NAV_WAYPOINT, home, alt), _nav(mav.MAV_CMD_NAV_LAND, home, 0.0)]
    return encode_mission(items, autopilot, home)


def corridor_mission(start: GeoPoint, end: GeoPoint, alt: float = CRUISE_ALT_M,
                     speed: float = CRUISE_SPEED_MS, back: bool = False) -> list[PlannedItem]:
    """Along a corridor, autopilot-neutral: take off at ``start``, fly to ``end`` at ``speed`` and land
    there, or (``back``) fly back to ``start`` and land there."""
    do = mav.MAV_FRAME_MISSION
    items = [_nav(mav.MAV_CMD_NAV_TAKEOFF, start, alt),
             PlannedItem(do, mav.MAV_CMD_DO_CHANGE_SPEED, (1.0, speed, -1.0, 0.0), NAN, NAN, 0.0),
             _nav(mav.MAV_CMD_NAV_WAYPOINT, end, alt)]
    last = start if back else end
    if back:
        items.append(_nav(mav.MAV_CMD_NAV_WAYPOINT, start, alt))
    return items + [_nav(mav.MAV_CMD_NAV_LAND, last, 0.0)]


def load_plan(path: str | Path) -> list[PlannedItem]:
    """Read the mission of a QGroundControl ``.plan`` file (SimpleItems only)."""
    p = Path(path)
    try:
        raw: Any = json.loads(p.read_text())
    except FileNotFoundError:
        raise ConfigError(f"{p}: no such file") from None
    except (ValueError, OSError) as exc:
        raise ConfigError(f"{p}: not a readable JSON .plan file: {str(exc).splitlines()[0]}") from None
    if not isinstance(raw, dict) or raw.get("fileType") != "Plan":
        raise ConfigError(f"{p}: field $.fileType: not \"Plan\"")
    items = raw.get("mission", {}).get("items")
    if not isinstance(items, list) or not items:
        raise ConfigError(f"{p}: field $.mission.items: no mission items")
    out: list[PlannedItem] = []
    for i, it in enumerate(items):
        where = f"{p}: field $.mission.items[{i}]"
        if not isinstance(it, dict) or it.get("type") != "SimpleItem":
            raise ConfigError(f"{where}: only SimpleItem is supported (got {it.get('type') if isinstance(it, dict) else it!r})")
        prm = it.get("params")
        if not isinstance(prm, list) or len(prm) != 7:
            raise ConfigError(f"{where}.params: need 7 values")
        try:
            vals = [NAN if v is None else float(v) for v in prm]
            out.append(PlannedItem(int(it["frame"]), int(it["command"]), tuple(vals[:4]), vals[4], vals[5], vals[6]))  # type: ignore[arg-type]
        except (KeyError, TypeError, ValueError) as exc:
            raise ConfigError(f"{where}: {exc}") from None
    return out


class MissionUploader:
    """The GCS side of a mission upload, sans-IO."""

    def __init__(self, items: list[PlannedItem], target: tuple[int, int] = (1, 1), retry_s: float = 1.5,
                 max_retries: int = 5) -> None:
        self.items = items
        self.target = target
        self.retry_s, self.max_retries = retry_s, max_retries
        self.result: int | None = None
        self.last_activity = 0.0
        self.retries = 0
        self.started = False
        self.timed_out = False  # the vehicle never answered: the CANCELLED result is ours, not its

    @property
    def done(self) -> bool:
        return self.result is not None

    @property
    def accepted(self) -> bool:
        return self.result == mav.MAV_MISSION_ACCEPTED

    def start(self, now: float) -> list[Any]:
        self.started, self.last_activity = True, now
        return [mav.MAVLink_mission_count_message(self.target[0], self.target[1], len(self.items), 0)]

    def on_message(self, msg: Any, now: float, my_sysid: int) -> list[Any]:
        if not self.started or self.done or getattr(msg, "target_system", my_sysid) != my_sysid:
            return []
        t = msg.get_type()
        if t in ("MISSION_REQUEST_INT", "MISSION_REQUEST") and 0 <= msg.seq < len(self.items):
            self.last_activity = now
            return [self.items[msg.seq].message(msg.seq, self.target)]
        if t == "MISSION_ACK":
            self.result = msg.type
        return []

    def tick(self, now: float) -> list[Any]:
        if not self.started or self.done or now - self.last_activity < self.retry_s:
            return []
        self.retries += 1
        if self.retries > self.max_retries:
            self.result, self.timed_out = mav.MAV_MISSION_OPERATION_CANCELLED, True
            return []
        return self.start(now)
