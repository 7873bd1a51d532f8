"""A whole flight in memory: the drone's core, two ground stations' cores and the simulated autopilot,
wired the way the node adapters wire them, with simulated time and no sockets, threads or processes.

The radio is the fleet's coverage: a frame between the drone and a GS gets through only while the
vehicle is inside that GS's coverage circle (a GS that is ``down`` neither sends nor hears). Pairing
and key-sharing queries are answered at once; a query that gets no answer (the drone out of range,
the asked GS down) is answered by nothing, and the asker's own timeout runs.

``speedup`` runs the autopilot that many times faster than the nodes' clocks, as ``zdrone sim
--speedup`` does: the vehicle covers more ground in each second of the protocol's timers.
``restart_drone`` takes the companion down for a while (it neither hears nor sends, its queries go
unanswered) and starts a new drone core from the authority it persisted, as a restarted node does.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import common as mav

from gs.actions import Ask, AskKind, Checkpoint, Emit, FrameUp, Put, ToOperator
from gs.core import CoreOptions, StationCore
from gs.planner import reference_plan
from zdrone.core import records as rec
from zdrone.core.geometry import GeoPoint
from zdrone.core.mavlink import FrameCodec
from zdrone.core.reference import HOME
from zdrone.core.revision import make_push, split_push
from zdrone.fleet.revisions import STAMP_PERIOD_S
from zdrone.fleet.files import init_fleet, load_fleet, load_secret
from zdrone.core.outputs import dispatch
from zdrone.core.pairing import query_answer
from zdrone.nodes.drone_actions import CommandVehicle, Countersign, Listen, Persist, ToVehicle
from zdrone.nodes.drone_core import DroneCore, DroneCoreOptions
from zdrone.vehicle.link import COMPANION_COMPID
from zdrone.vehicle.modes import ARDUPILOT, set_mode_params
from zdrone.vehicle.personality import PX4, Personality
from zdrone.vehicle.sim import SimAutopilot
from zdrone.vehicle.tracker import VehicleTracker

#: Time of day at simulated time 0 (pairing and key-sharing stamps are times of day).
WALL0 = 1_800_000_000.0
DRONE = "d1"


@dataclass
class Station:
    core: StationCore
    down: bool = False  # crashed or hung: neither ticks nor hears nor answers
    logs: list[tuple[float, str, dict[str, Any]]] = field(default_factory=list)


class CoreFlight:
    """The reference flight of ``d1`` between GS A (which pairs and flies the mission) and GS B."""

    def __init__(self, fleet_dir: Path, personality: Personality = PX4, handover_timeout: float = 2.0,
                 command_rate: float = 2.0, dt: float = 0.05, speedup: float = 1.0,
                 stations: dict[str, CoreOptions] | None = None) -> None:
        """``stations``: each GS's options (default: A pairs and flies the reference mission, B)."""
        if not (fleet_dir / "fleet.json5").exists():
            init_fleet(fleet_dir)
        fleet = load_fleet(fleet_dir)
        self.fleet, self.dt, self.now, self.speedup = fleet, dt, 0.0, speedup
        self.sim = SimAutopilot(HOME, sysid=fleet.nodes[DRONE].sysid, personality=personality)
        self._drone_identity = load_secret(fleet_dir, DRONE, fleet).identity
        self._drone_opts = DroneCoreOptions(handover_timeout=handover_timeout)
        self.drone = DroneCore(fleet, DRONE, self._drone_identity, self._drone_opts, started_wall=WALL0)
        self.drone_down_until: float | None = None  # the companion is restarting until then
        self.restarts: list[float] = []
        self.gs: dict[str, Station] = {}
        # each GS's signed revision stamp every push period (zdrone.fleet.revisions): the owner's lease
        stations = stations or {"A": CoreOptions(pair=True, mission=reference_plan(), command_rate=command_rate),
                                "B": CoreOptions(command_rate=command_rate)}
        self._signing = {g: load_secret(fleet_dir, g, fleet).signing for g in stations}
        self._next_stamp = 0.0
        for name, opts in stations.items():
            self.gs[name] = Station(StationCore(name, fleet, load_secret(fleet_dir, name, fleet).identity, (DRONE,), opts))
        self.coverage = {g: fleet.nodes[g].coverage.circle() for g in self.gs}
        # the drone's vehicle link: the companion's own frames (heartbeat, stream requests, the failsafe)
        self.companion_ids = (fleet.nodes[DRONE].sysid, COMPANION_COMPID)  # as the drone node's VehicleLink
        self.companion = FrameCodec(*self.companion_ids)
        self.tracker = VehicleTracker(*self.companion_ids)
        self._companion_hb = float("-inf")
        self.listening: frozenset[str] = frozenset()
        self.records: list[tuple[float, rec.Record]] = []
        self.commands: list[CommandVehicle] = []
        self.persisted: list[Persist] = []
        self.countersign: list[Countersign] = []  # GSs' checkpoints the drone's adapter is to countersign
        self.was_armed = False
        self.lost_frames: Counter[str] = Counter()  # per GS: frames the radio did not carry
        self.statuses: list[tuple[float, str | None, int, str]] = []  # (now, owner, epoch, state) at each step
        self.vehicle_codec = FrameCodec(*self.companion_ids)
        self.handle(self.drone.on_vehicle(self._pos(), self._on_ground(), 0.0))

    # ------------------------------------------------------------------ the radio
    def in_range(self, gs: str) -> bool:
        if self.drone_down_until is not None:
            return False  # the companion is down: nothing goes either way
        p = self.sim.position
        return not self.gs[gs].down and self.coverage[gs].contains(GeoPoint(p.lat, p.lon))

    def _pos(self) -> tuple[float, float, float] | None:
        """Where the vehicle says it is (None before its position fix), as the drone node reads it."""
        p = self.tracker.position
        return (round(p.lat, 7), round(p.lon, 7), round(p.alt, 2)) if p else None

    def _on_ground(self) -> bool:
        return not self.tracker.armed or self.tracker.landed_state(self.now) == mav.MAV_LANDED_STATE_ON_GROUND

    def _to_vehicle(self, msg: Any) -> None:
        self.sim.receive(self.companion.encode(msg), self.sim.t)

    # ------------------------------------------------------------------ carrying out
    def handle(self, outs: list[Any]) -> None:
        """Carry out the drone core's outputs."""
        dispatch(outs, {Put: self._put_down, ToVehicle: lambda o: self.sim.receive(o.frame, self.sim.t),
                        CommandVehicle: self._command_vehicle, Emit: lambda o: self.records.append((self.now, o.record)),
                        Listen: self._listen, Persist: self.persisted.append, Countersign: self.countersign.append})

    def _put_down(self, o: Put) -> None:
        if self.in_range(o.peer):
            self.station(o.peer, self.gs[o.peer].core.on_envelope(DRONE, o.payload, self.now))
        else:
            self.lost_frames[o.peer] += 1

    def _listen(self, o: Listen) -> None:
        self.listening = o.gss

    def _command_vehicle(self, o: CommandVehicle) -> None:
        self.commands.append(o)  # as VehicleLink.command_land / command_rtl
        params = set_mode_params(self.tracker.autopilot, o.command) if self.tracker.autopilot == ARDUPILOT else None
        if params is not None:
            self._to_vehicle(self.tracker.command(mav.MAV_CMD_DO_SET_MODE, tuple(params), self.now))
        else:
            cmd = mav.MAV_CMD_NAV_LAND if o.command == "LAND" else mav.MAV_CMD_NAV_RETURN_TO_LAUNCH
            self._to_vehicle(self.tracker.command(cmd, (0.0,) * 7, self.now))

    def station(self, name: str, actions: list[Any]) -> None:
        """Carry out GS ``name``'s actions."""
        st = self.gs[name]

        def put(a: Put) -> None:
            assert a.peer == DRONE, a.peer
            if name in self.listening and self.in_range(name):
                self.handle(self.drone.on_envelope(name, a.payload, self.now))
            else:
                self.lost_frames[name] += 1

        dispatch(actions, {Put: put, Ask: lambda a: self._ask(name, a),
                           Emit: lambda a: st.logs.append((self.now, a.kind, a.fields)),
                           FrameUp: lambda a: None, ToOperator: lambda a: None, Checkpoint: lambda a: None})  # gateway, console, audit

    def _ask(self, name: str, a: Ask) -> None:
        st = self.gs[name]
        if a.kind is AskKind.PAIR:
            if self.in_range(name):
                ans, outs = self.drone.on_pair_query(name, a.payload, self.now, bytes(32), WALL0 + self.now)
                self.handle(outs)
                answer = query_answer(ans)
                if answer is not None:
                    self.station(name, st.core.on_pair_reply(DRONE, *answer, self.now))
            return
        other = self.gs[a.gs]
        if not other.down:  # the backhaul: no radio involved
            answer, logs = other.core.on_linkkey_query(DRONE, a.payload, self.now, bytes([len(self.records) % 256]) * 32,
                                                       WALL0 + self.now)
            self.station(a.gs, logs)
            if answer.reply is not None or answer.error is not None:
                self.station(name, st.core.on_linkkey_reply(DRONE, a.gs, answer.reply, answer.error, self.now))

    # ------------------------------------------------------------------ time
    def restart_drone(self, down_for: float) -> None:
        """The companion's node is killed now and is back ``down_for`` seconds later."""
        self.drone_down_until = self.now + down_for
        self.restarts.append(self.now)

    def _drone_back(self) -> None:
        """A new drone core, as the node starts: its vehicle heard, the saved authority restored, ready."""
        self.drone_down_until = None
        saved = self.persisted[-1] if self.persisted else None
        self.drone = DroneCore(self.fleet, DRONE, self._drone_identity, self._drone_opts, started_wall=WALL0 + self.now)
        self.handle(self.drone.on_vehicle(self._pos(), self._on_ground(), self.now))
        if saved is not None:
            self.handle(self.drone.restore(saved.owner, saved.epoch, saved.state, self.now))
        self.drone.ready(WALL0 + self.now)

    def step(self) -> None:
        self.now = round(self.now + self.dt, 6)
        self.sim.step(round(self.now * self.speedup, 6))
        if self.drone_down_until is not None:
            for frame in self.sim.drain():  # nobody reads the vehicle meanwhile
                pass
            if self.now >= self.drone_down_until:
                self._drone_back()
            self._stations()
            return
        for frame in self.sim.drain():
            msg = self.vehicle_codec.decode(frame)
            if msg is not None:
                self.tracker.on_message(msg, self.now)
            self.handle(self.drone.on_telemetry(frame, self.now))
        if self.now - self._companion_hb >= 1.0:
            self._companion_hb = self.now
            self._to_vehicle(mav.MAVLink_heartbeat_message(mav.MAV_TYPE_ONBOARD_CONTROLLER, mav.MAV_AUTOPILOT_INVALID,
                                                          0, 0, mav.MAV_STATE_ACTIVE, 3))
        for msg in self.tracker.poll(self.now):
            self._to_vehicle(msg)
        self.handle(self.drone.on_vehicle(self._pos(), self._on_ground(), self.now))
        if self.now >= self._next_stamp:
            self._next_stamp = self.now + STAMP_PERIOD_S
            for name, st in self.gs.items():
                if not st.down:
                    stamp, _ = split_push(make_push(name, self.fleet.revision, self.now, self._signing[name], None,
                                                    (DRONE,)))
                    self.handle(self.drone.on_revision_stamp(stamp, self.now, carrier=name))
        timer = self.drone.get_timer()
        if timer is not None and self.now >= timer:
            self.handle(self.drone.handle_timer(self.now))
        self._stations()

    def _stations(self) -> None:
        for name, st in self.gs.items():
            if not st.down and self.now >= st.core.get_timer():
                self.station(name, st.core.handle_timer(self.now, WALL0 + self.now))
        self.was_armed |= self.sim.armed
        if self.drone_down_until is None:
            m = self.drone.machine
            self.statuses.append((self.now, m.owner, m.epoch, m.state.value))

    def run_until(self, pred, timeout: float) -> bool:
        end = self.now + timeout
        while self.now < end:
            if pred():
                return True
            self.step()
        return pred()

    # ------------------------------------------------------------------ outcomes
    def of(self, kind: type) -> list[tuple[float, Any]]:
        return [(t, r) for t, r in self.records if isinstance(r, kind)]

    def gs_logs(self, name: str, kind: str) -> list[tuple[float, dict[str, Any]]]:
        return [(t, f) for t, k, f in self.gs[name].logs if k == kind]

    def flown(self) -> bool:
        """The mission is over: the vehicle flew it all and is on the ground, disarmed."""
        return self.sim.mission_finished and not self.sim.armed

    def landed(self) -> bool:
        """The vehicle flew and is on the ground again, disarmed (where the mission ended or not)."""
        return self.was_armed and not self.sim.armed and self.sim.landed
