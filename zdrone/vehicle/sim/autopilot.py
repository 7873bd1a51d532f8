"""The built-in multicopter simulator: a kinematic vehicle behind a PX4- or ArduPilot-like autopilot.

Theory of operation: ``SimAutopilot`` is sans-IO. ``receive(frame, now)`` handles one MAVLink
frame from a GCS; ``step(now)`` advances the physics to ``now`` (simulated seconds) and emits the
telemetry streams that are due; ``drain()`` returns the frames to send. The socket adapter
(``zdrone.vehicle.simserver``) owns the clock (``--speedup``) and the sockets.

What the autopilot is — PX4 v1.16 or ArduCopter 4.7 — is a ``Personality``
(``zdrone.vehicle.personality``), a frozen table the simulator consults wherever the two differ:
identity and mode numbers, texts (and PX4's EVENTs), readiness after boot, mission rules, auto-disarm,
streams, parameters, the link-loss failsafe.

This class is the autopilot itself: the flight mode and the rules that join it to the vehicle. The
vehicle's own state (where it is, battery, armed or not, on the ground or flying) is a
``VehicleState`` (``vehicle``) that only the autopilot changes; where the vehicle flies to (its
target, cruise speed, take-off altitude) is its ``Guidance`` (``guidance``), which the flight mode,
the commands and the mission steer by. Each part reaches the autopilot through a narrow interface
it declares (a ``Protocol`` in its module). The flight mode is a ``FlightMode``
behaviour shown as one of the personality's mode rows; each sets a target (TAKEOFF climbs where the
vehicle is, LAND descends there, RTL climbs to the return altitude, flies home and lands, HOLD stays,
MISSION lets the mission fly its items) and the kinematics (``kinematics``) move the vehicle toward
it within speed, climb-rate and acceleration limits, in steps of at most 50 ms. Take-off and
touchdown are detected from the altitude; the autopilot disarms after a landing and, if armed but
never lifted off, after the preflight timeout.

A mode changes on request through ``request_mode`` (the public API: a behaviour or a row, True if
accepted) or, from a GCS, ``change_mode`` (the MAV_RESULT): the personality's checks (position
estimate, armed, a mission to fly, ArduPilot's take-off item), then the switch. The MAVLink
protocols are modules of their own, each with its state, acting on the autopilot through
``arm``/``disarm``/``set_mode``/``change_mode`` and its public state: the command table
(``commands``), the mission microservice and flying the items (``mission``), parameters
(``params``), streams and messages (``telemetry``), the GCS link and its failsafe (``gcslink``);
all send through one ``Outbox``.

Readiness is simulated time since boot: until ``ready_after`` seconds have passed arming is refused
with the autopilot's own texts (ArduPilot: AUTO also needs its position estimate). The default here
is 0 (ready at boot, for tests and in-process benches); ``zdrone sim`` passes a short per-autopilot
default, the real autopilots need about 10 s (PX4) and 20-40 s (ArduPilot).

Bad input never raises: undecodable bytes, unknown ids, frames for another system, NaN or
out-of-range values and unsupported mission items get the MAVLink-correct answer (COMMAND_ACK or
MISSION_ACK code), are counted in ``counters`` and logged.
"""

from __future__ import annotations

import logging
import math
import random
from collections.abc import Callable
from typing import Any

from pymavlink.dialects.v20 import common as mav

from zdrone.core.geometry import GeoPoint, offset
from zdrone.core import fcsign
from zdrone.core.mavlink import FrameCodec, split_frames
from zdrone.vehicle.personality import PX4, ModeRow, Param, Personality, Say, ardupilot_takeoff_next
from zdrone.vehicle.px4modes import FlightMode
from zdrone.vehicle.sim.commands import CommandProtocol
from zdrone.vehicle.sim.gcslink import GcsLink
from zdrone.vehicle.sim.guidance import Guidance
from zdrone.vehicle.sim.vehicle import VehicleState
from zdrone.vehicle.sim.kinematics import SUBSTEP_S, Kinematics, Limits, advance, battery_after
from zdrone.vehicle.sim.mission import MissionItem, MissionProtocol
from zdrone.vehicle.sim.outbox import Outbox
from zdrone.vehicle.sim.params import ParamProtocol
from zdrone.vehicle.sim.signing import RULES as SIGNING_RULES, SimSigning
from zdrone.vehicle.sim.telemetry import Telemetry

log = logging.getLogger(__name__)

MAX_STREAM_BUFFER = 4096  # bytes of an unfinished frame kept by ``receive_bytes``
TAKEOFF_DETECTED_M = 0.05  # above this the vehicle has lifted off


class SimAutopilot:
    """A multicopter autopilot with a personality (PX4 by default), sans-IO. Time is simulated
    seconds passed as ``now``; ``ready_after`` is how long after boot it refuses to arm."""

    def __init__(self, home: GeoPoint, sysid: int = 1, compid: int = 1, seed: int = 0, now: float = 0.0,
                 home_amsl: float = 488.0, personality: Personality = PX4, ready_after: float = 0.0,
                 signing: SimSigning | None = None) -> None:
        self.p = personality
        self.ready_after = max(0.0, ready_after) if math.isfinite(ready_after) else 0.0
        self.home = home
        self.home_amsl = home_amsl
        self.sysid, self.compid = sysid, compid
        self.codec = FrameCodec(sysid, compid)
        self.rng = random.Random(seed)
        self.t = now
        self.boot = now
        self.out = Outbox(self.codec, personality, now, lambda: self.t)
        self.counters = self.out.counters  # bad input and refusals, by name
        self.events = self.out.events  # (time, text) of everything said
        self.param_protocol = ParamProtocol(personality, sysid, self.out,
                                            lambda name, now: self.telemetry.after_param_set(name, now))
        self.params: dict[str, Param] = self.param_protocol.params
        self.param_names = self.param_protocol.names
        # the vehicle
        self.vehicle = VehicleState()  # its own state: the parts read it, the autopilot changes it
        # what it is flying
        self.mode_row: ModeRow = personality.modes.by_name(personality.boot_mode)
        self.mode: FlightMode = self.mode_row.behaviour
        self.guidance = Guidance(self.phys("takeoff_alt"))  # where it flies to: the parts steer by it
        self._rtl_descend = False
        # readiness announcements
        self._said_ready = self._said_position = self._said_origin = False
        self._next_prearm = now
        # the protocols
        self.mission_protocol = MissionProtocol(self)
        self.telemetry = Telemetry(self, now)
        self.gcs_link = GcsLink(self)
        self.command_protocol = CommandProtocol(self)
        #: MAVLink 2 signing (``sim.signing``): the personality's rules, no storage, the simulated clock
        self.signing = signing if signing is not None else SimSigning(SIGNING_RULES.get(personality.name),
                                                                      sim_time=lambda: self.t)
        self._buffer = b""
        self._handlers: dict[str, Callable[[Any, float], None]] = {
            **self.gcs_link.handlers,
            **self.command_protocol.handlers,
            "SET_MODE": self._on_set_mode,
            **self.mission_protocol.handlers,
            **self.param_protocol.handlers,
            **self.telemetry.handlers,
        }

    # ----------------------------------------------------------- the sans-IO interface
    def receive_bytes(self, data: bytes, now: float) -> None:
        """Feed a chunk of a byte stream (TCP/serial); whole frames are handled, the rest kept."""
        frames, self._buffer, skipped = split_frames(self._buffer + data)
        if skipped:
            self.out.count("malformed", f"{skipped} stream bytes skipped")
        if len(self._buffer) > MAX_STREAM_BUFFER:
            self.out.count("malformed", "stream buffer overflow")
            self._buffer = b""
        for f in frames:
            self.receive(f, now)

    def receive(self, frame: bytes, now: float, link: int = 0) -> None:
        """Handle one MAVLink frame that came on ``link`` (0: the main endpoint, 1: TELEM2). Never
        raises on bad input. With a signing key, unsigned or wrongly signed frames go no further."""
        refused = self.signing.admit(frame, link)
        if refused is not None:
            self.out.count("signing_refused", f"{refused} on link {link}")
            return
        msg = self.codec.decode(frame)
        if msg is None:
            self.out.count("malformed", f"{len(frame)} bytes")
            return
        name = msg.get_type()
        target = getattr(msg, "target_system", None)
        if target not in (None, 0, self.sysid):
            self.out.count("not_for_us", f"{name} for system {target}")
            return
        if name == "SETUP_SIGNING":
            say = self.signing.setup(msg, fcsign.is_signed(frame) and self.signing.active, self.vehicle.armed, link)
            if say is not None:
                self.out.say(say)
            return
        handler = self._handlers.get(name)
        if handler is None:
            self.out.count("ignored", name)
            return
        try:
            handler(msg, now)
        except Exception:  # a programming error in a handler must not kill the vehicle
            log.exception("sim: handler for %s failed", name)
            self.out.count("handler_error", name)

    def step(self, now: float) -> None:
        """Advance the simulation to ``now`` and emit the streams that are due."""
        while self.t < now:  # fixed small steps keep the kinematics stable at any speed-up
            dt = min(SUBSTEP_S, now - self.t)
            self._fly(dt, self.t + dt)
            self.t += dt
        self._announce_readiness(now)
        self.signing.tick()
        self.gcs_link.check(now)
        self.mission_protocol.retry_upload(now)
        self.telemetry.stream(now)

    def drain(self) -> list[bytes]:
        """Frames to send, oldest first."""
        return self.out.drain()

    # ------------------------------------------------------------------- the state
    # the vehicle as callers outside the simulator read it (tests, the in-process benches)
    @property
    def armed(self) -> bool:
        return self.vehicle.armed

    @property
    def landed(self) -> bool:
        return self.vehicle.landed

    @property
    def k(self) -> Kinematics:
        return self.vehicle.k

    @property
    def battery(self) -> float:
        return self.vehicle.battery

    @property
    def payload_released(self) -> bool:
        return self.vehicle.payload_released

    @property
    def position(self) -> GeoPoint:
        """True position of the vehicle."""
        return offset(self.home, self.vehicle.k.north, self.vehicle.k.east, self.vehicle.k.alt)

    @property
    def mission(self) -> list[MissionItem]:
        """The stored mission."""
        return self.mission_protocol.items

    @property
    def mission_finished(self) -> bool:
        """The last item has been flown (or the mission ended at a landing)."""
        return self.mission_protocol.finished

    def landed_state(self) -> int:
        """MAV_LANDED_STATE."""
        if self.vehicle.landed:
            return mav.MAV_LANDED_STATE_ON_GROUND
        if self.mode is FlightMode.LAND or self.mission_protocol.landing_since is not None:
            return mav.MAV_LANDED_STATE_LANDING
        if self.mode is FlightMode.TAKEOFF:
            return mav.MAV_LANDED_STATE_TAKEOFF
        return mav.MAV_LANDED_STATE_IN_AIR

    def phys(self, what: str) -> float:
        """A quantity of the vehicle model: a live parameter or the personality's constant."""
        src = self.p.physics[what]
        return self.params[src].value if isinstance(src, str) else src

    def _send_mission_current(self) -> None:
        """One MISSION_CURRENT now, as after a mission upload."""
        self.mission_protocol.send_current()

    # ---------------------------------------------------------------- readiness
    def ready_to_arm(self, now: float | None = None) -> bool:
        """True once the arming checks pass (``ready_after`` scaled stages of the personality)."""
        now = self.t if now is None else now
        return self.p.readiness.arm_refusal(now - self.boot, self.ready_after) is None

    def gps_fixed(self, now: float | None = None) -> bool:
        """True once the GPS has a 3D fix (before the estimate uses it)."""
        now = self.t if now is None else now
        return now - self.boot >= self.p.readiness.gps_fix_at * self.ready_after

    def position_ok(self, now: float | None = None) -> bool:
        """True once the autopilot has a position estimate (ArduPilot: EKF using GPS)."""
        now = self.t if now is None else now
        return now - self.boot >= self.p.readiness.position_at * self.ready_after

    def arm_refusal(self, now: float, forced: bool) -> Say | None:
        """Why arming now is refused (the personality's text), None if it is allowed."""
        if forced:
            return None
        say = self.p.readiness.arm_refusal(now - self.boot, self.ready_after)
        if say is not None:
            return say
        if not self.mode_row.armable:
            return self.p.text("arm_mode_not_armable")
        return None

    def _announce_readiness(self, now: float) -> None:
        r = self.p.readiness
        if not self._said_ready and self.ready_to_arm(now):
            self._said_ready = True
            if r.on_ready is not None:
                self.out.say(r.on_ready)
        if (not self._said_origin and r.origin_at is not None
                and now - self.boot >= r.origin_at * self.ready_after):
            self._said_origin = True
            if r.on_origin is not None:
                self.out.say(r.on_origin)
        if not self._said_position and self.position_ok(now):
            self._said_position = True
            if r.on_position is not None:
                self.out.say(r.on_position)
        if r.prearm_every > 0 and not self.vehicle.armed and now >= self._next_prearm:
            stage = r.stage(now - self.boot, self.ready_after)
            if stage is not None and stage.prearm is not None:
                self.out.say(stage.prearm)
            self._next_prearm = now + r.prearm_every

    # ------------------------------------------------------------ arming, payload
    def arm(self, now: float, text: str) -> None:
        """Arm (the checks passed), saying ``text`` (a personality text key)."""
        self.vehicle.armed = True
        self.vehicle.armed_at = now
        self.vehicle.taken_off = not self.vehicle.landed
        self.mission_protocol.finished = False
        self.out.say(text)

    def disarm(self, text: str) -> None:
        """Disarm, saying ``text`` if it was armed; the vehicle stops where it is."""
        if self.vehicle.armed:
            self.vehicle.armed = False
            self.out.say(text)
        self.vehicle.armed_at = None
        self.vehicle.k = self.vehicle.k.halted()
        if self.p.hold_after_touchdown and self.mode is not FlightMode.MISSION:
            self.set_mode(FlightMode.HOLD)
        self.guidance.stop()

    def operate_gripper(self, action: float) -> None:
        """DO_GRIPPER's action: release (or 0) drops the payload."""
        if action == mav.GRIPPER_ACTION_RELEASE or action == 0:
            self.vehicle.payload_released = True
            self.out.say("payload_released")

    # -------------------------------------------------------------------- modes
    def request_mode(self, mode: FlightMode | ModeRow) -> bool:
        """Switch to ``mode`` as a GCS's mode request would, now: a behaviour (shown as the
        personality's row for it) or one of the personality's rows. False if the autopilot refuses."""
        row = mode if isinstance(mode, ModeRow) else self.p.modes.by_name(self.p.modes.shown[mode])
        return self.change_mode(row, self.t) == mav.MAV_RESULT_ACCEPTED

    def change_mode(self, row: ModeRow, now: float, first: int | None = None) -> int:
        """A GCS asks for mode ``row`` (the mission mode from item ``first``): the personality's
        checks, then the switch. Returns the MAV_RESULT."""
        ok, refused = mav.MAV_RESULT_ACCEPTED, self.p.denied_result
        checks = self.vehicle.armed or not self.p.modes_free_when_disarmed  # ArduPilot: anything goes disarmed
        if checks and self.vehicle.armed and row.needs_position and not self.position_ok(now):
            self.out.say("mode_requires_position", label=row.label)
            return refused
        if row.behaviour is FlightMode.MISSION:
            mission = self.mission_protocol
            start = max(mission.current if first is None else first, mission.first_flown)
            if self.p.auto_needs_takeoff_when_landed:  # ModeAuto::init
                if not mission.flyable and checks:
                    self.out.say("mode_init_failed", label=row.label)
                    return refused
                if checks and self.vehicle.armed and self.vehicle.landed and not ardupilot_takeoff_next(mission.items, start):
                    self.out.say("auto_missing_takeoff")
                    self.out.say("mode_init_failed", label=row.label)
                    return refused
            elif not mission.items or mission.refusal is not None:
                self.out.say("mode_refused", label=row.label)
                return refused
            mission.start(start, row)
            return ok
        if (not self.p.modes_free_when_disarmed and row.behaviour in (FlightMode.RTL, FlightMode.LAND, FlightMode.TAKEOFF)
                and (not self.vehicle.armed or (self.vehicle.landed and row.behaviour is not FlightMode.TAKEOFF))):
            return refused
        if row.behaviour is FlightMode.TAKEOFF:
            self.guidance.set_takeoff_alt(self.phys("takeoff_alt"))
        self.set_mode(row.behaviour, row)
        return ok

    def set_mode(self, mode: FlightMode, row: ModeRow | None = None) -> None:
        """Switch to ``mode`` (shown as ``row``, else as the personality shows it), no checks."""
        row = row or self.p.modes.row_for(mode, self.mode_row)
        if row is not self.mode_row or mode is not self.mode:
            log.info("sim: mode %s -> %s", self.mode_row.name, row.name)
        self.mode, self.mode_row = mode, row
        self.mission_protocol.landing_since = None
        k, g = self.vehicle.k, self.guidance
        if mode is FlightMode.LAND:  # land where we are, not at the last target
            g.fly_to(k.north, k.east, -1.0)
        if (mode is FlightMode.HOLD or mode is FlightMode.POSCTL) and self.vehicle.landed:
            g.stop()
        elif mode is FlightMode.HOLD or mode is FlightMode.POSCTL:
            g.fly_to(k.north, k.east, k.alt)

    def _on_set_mode(self, msg: Any, now: float) -> None:
        row = self.p.modes.by_custom(msg.custom_mode) if msg.base_mode & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED else None
        if row is None:
            self.out.count("bad_mode", str(msg.custom_mode))
            return
        self.change_mode(row, now)

    # ------------------------------------------------------------------- flying
    def _fly(self, dt: float, now: float) -> None:
        """One step of ``dt`` seconds ending at ``now``: the battery, auto-disarm, the mode's target,
        the kinematics, take-off and touchdown."""
        if self.vehicle.armed:
            self.vehicle.battery = battery_after(self.vehicle.battery, self.phys("bat_drain"), dt)
        if not self.vehicle.armed:
            return
        preflight = self.phys("disarm_preflight")
        if (self.vehicle.landed and not self.vehicle.taken_off and self.vehicle.armed_at is not None and preflight > 0
                and now - self.vehicle.armed_at >= preflight):
            self.disarm("disarmed_preflight")  # armed on the ground and never took off
            return
        if self.mission_protocol.paused_until > now:
            return
        self._aim(now)
        if not self.vehicle.armed:
            return
        if self.vehicle.landed and self.vehicle.touchdown_at is not None:
            mission_continues = self.mode is FlightMode.MISSION and not self.mission_protocol.finished
            if not mission_continues and now - self.vehicle.touchdown_at >= self.phys("disarm_land"):
                self.vehicle.touchdown_at = None
                self.disarm("disarmed_landing")
                return
        if self.guidance.target is None:
            self.vehicle.k = self.vehicle.k.halted()
            return
        talt = self.guidance.target[2]
        self.vehicle.k = advance(self.vehicle.k, self.guidance.target, self._limits(), dt)
        if self.vehicle.k.alt > TAKEOFF_DETECTED_M and self.vehicle.landed:
            self.vehicle.landed = False
            self.vehicle.taken_off = True
            self.vehicle.touchdown_at = None
            self.out.say("takeoff_detected")
        if self.vehicle.k.alt <= 0.0 and not self.vehicle.landed and talt <= 0.0:
            self.vehicle.landed = True
            self.vehicle.k = self.vehicle.k.touched_down()
            self.vehicle.touchdown_at = now
            self.out.say("landing_detected")
            if self.mode in (FlightMode.LAND, FlightMode.RTL):
                if self.p.hold_after_touchdown:
                    self.set_mode(FlightMode.HOLD)
                self.guidance.stop()
                self._rtl_descend = False

    def _aim(self, now: float) -> None:
        """Set the target of the current mode (the mission sets its own)."""
        k, g = self.vehicle.k, self.guidance
        mode = self.mode
        if mode is FlightMode.MISSION:
            self.mission_protocol.fly(now)
            if not self.vehicle.armed:  # the mission ended in a disarm
                return
        elif mode is FlightMode.TAKEOFF:
            alt = g.takeoff_alt
            if g.target is None or self.vehicle.landed:
                g.fly_to(k.north, k.east, alt)
            if k.alt >= alt - 0.3:
                self.set_mode(FlightMode.HOLD)
        elif mode is FlightMode.LAND:
            north, east = (g.target[0], g.target[1]) if g.target else (k.north, k.east)
            g.fly_to(north, east, -1.0)
        elif mode is FlightMode.RTL:
            rtl_return = self.phys("rtl_alt")
            rtl_alt = max(rtl_return, k.alt) if not self._rtl_descend else -1.0
            if math.hypot(k.north, k.east) > self.phys("accept_radius") and not self._rtl_descend:
                g.fly_to(*((0.0, 0.0) if k.alt >= rtl_return - 1 else (k.north, k.east)), rtl_alt)
            else:
                self._rtl_descend = True
                g.fly_to(0.0, 0.0, -1.0)
        if mode is not FlightMode.RTL:
            self._rtl_descend = False

    def _limits(self) -> Limits:
        return Limits(up=self.phys("up"), down=self.phys("down"), acc=self.phys("acc"),
                      speed=self.guidance.cruise_speed or self.phys("cruise"))
