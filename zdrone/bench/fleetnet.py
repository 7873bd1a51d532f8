"""An in-memory fleet (like h11's ConnectionPair, for a whole fleet): the drone's pure ``DroneCore``
and the ground stations' pure ``StationCore``s wired by a synchronous network, with the real crypto,
explicit time, no sockets. Pairing, key sharing and hand-overs run in milliseconds. Used by the unit
tests and by ``zdrone check --concrete``; testbed only.

``FleetNet.step(dt)`` advances time: every GS ticks, the drone handles its timer and the vehicle's
position (and a GLOBAL_POSITION_INT telemetry frame), and every message each of them emits is
delivered at once (an uplink only while the drone listens to it; ``cut`` blocks a GS both ways).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from pymavlink.dialects.v20 import common as mav

from gs.actions import Ask, AskKind, Checkpoint, Emit, FrameUp, Put, ToOperator
from gs.core import CoreOptions, StationCore
from zdrone.core.geometry import GeoPoint
from zdrone.core.mavlink import FrameCodec
from zdrone.core.errors import ConfigError
from zdrone.core.revision import make_push, split_push
from zdrone.fleet.files import init_fleet, load_fleet, load_secret
from zdrone.fleet.revisions import STAMP_PERIOD_S
from zdrone.core.outputs import dispatch
from zdrone.core.pairing import query_answer
from zdrone.nodes.drone_actions import CommandVehicle, Countersign, Listen, Out, Persist, ToVehicle
from zdrone.nodes.drone_core import DroneCore, DroneCoreOptions

WALL0 = 1_800_000_000.0  # the time of day at now = 0


def _ignored(_: object) -> None:
    """The GS's records, its frames for the gateway, its console lines and its countersignatures: not needed here."""


def make_fleet(directory: Path) -> Path:
    init_fleet(directory)
    return directory


@dataclass
class FleetNet:
    fleet_dir: Path
    gss: dict[str, StationCore] = field(default_factory=dict)
    drone: DroneCore | None = None
    now: float = 0.0
    position: GeoPoint | None = None
    on_ground: bool = True
    listening: frozenset[str] = frozenset()
    cut: set[str] = field(default_factory=set)  # GSs whose radio is down (both ways)
    hung: set[str] = field(default_factory=set)  # GSs that neither tick nor answer
    to_vehicle: list[bytes] = field(default_factory=list)
    commands: list[CommandVehicle] = field(default_factory=list)
    records: list = field(default_factory=list)
    persisted: Persist | None = None
    captured_pairings: list[tuple[str, bytes]] = field(default_factory=list)  # (gs, message 1) seen on the wire
    captured_up: dict[str, bytes] = field(default_factory=dict)  # gs -> the last envelope it sent up (for replays)
    #: each GS's signed revision stamp every push period, as its station pushes it (``zdrone.fleet.revisions``):
    #: heard from every GS that is neither hung nor cut
    stamps: bool = True
    next_stamp: float = 0.0
    #: the drone seals each step's messages to a GS as one envelope, put at the step's end (as its node
    #: does per pass: ``DroneCoreOptions.batch``)
    batch: bool = False

    def __post_init__(self) -> None:
        self.fleet = load_fleet(self.fleet_dir)
        self.codec = FrameCodec(1, 1)
        if self.drone is None:
            self.drone = self.new_drone()
        home = self.fleet.home
        self.position = GeoPoint(home.lat, home.lon)

    def new_drone(self) -> DroneCore:
        ident = load_secret(self.fleet_dir, "d1", self.fleet).identity
        return DroneCore(self.fleet, "d1", ident, DroneCoreOptions(batch=self.batch), started_wall=WALL0 + self.now)

    def add_gs(self, name: str, **opts) -> StationCore:
        fleet = self.fleet
        core = StationCore(name, fleet, load_secret(self.fleet_dir, name, fleet).identity, ("d1",), CoreOptions(**opts))
        self.gss[name] = core
        return core

    def centre(self, gs: str) -> GeoPoint:
        cov = self.fleet.nodes[gs].coverage
        assert cov is not None
        return GeoPoint(cov.lat, cov.lon)

    def between(self, a: GeoPoint, b: GeoPoint, f: float) -> GeoPoint:
        return GeoPoint(a.lat + (b.lat - a.lat) * f, a.lon + (b.lon - a.lon) * f)

    # ------------------------------------------------------------------ delivery
    def drone_outs(self, outs: list[Out]) -> None:
        dispatch(outs, {Put: self._put_down, Listen: self._listen, ToVehicle: lambda o: self.to_vehicle.append(o.frame),
                        CommandVehicle: self.commands.append, Emit: lambda o: self.records.append(o.record),
                        Persist: self._persist, Countersign: lambda o: None})  # no audit record here

    def _put_down(self, o: Put) -> None:
        if o.peer not in self.cut and o.peer in self.gss and o.peer not in self.hung:
            self.gs_outs(o.peer, self.gss[o.peer].on_envelope("d1", o.payload, self.now))

    def _listen(self, o: Listen) -> None:
        self.listening = o.gss

    def _persist(self, o: Persist) -> None:
        self.persisted = o

    def gs_outs(self, gs: str, outs: list) -> None:
        dispatch(outs, {Put: lambda a: self._put_up(gs, a), Ask: lambda a: self._ask(gs, a),
                        Emit: _ignored, FrameUp: _ignored, ToOperator: _ignored, Checkpoint: _ignored})

    def _put_up(self, gs: str, a: Put) -> None:
        assert self.drone is not None and a.peer == "d1", a.peer
        self.captured_up[gs] = a.payload
        if gs not in self.cut and gs in self.listening:
            self.drone_outs(self.drone.on_envelope(gs, a.payload, self.now))

    def _ask(self, gs: str, a: Ask) -> None:
        assert self.drone is not None
        if a.kind is AskKind.PAIR:
            self.captured_pairings.append((gs, a.payload))
            if gs in self.cut:
                return
            ans, outs = self.drone.on_pair_query(gs, a.payload, self.now, os.urandom(32), WALL0 + self.now)
            self.drone_outs(outs)
            answer = query_answer(ans)
            if answer is not None:
                self.gs_outs(gs, self.gss[gs].on_pair_reply("d1", *answer, self.now))
            return
        owner = self.gss.get(a.gs)
        if owner is None or a.gs in self.hung:
            return
        answer, _logs = owner.on_linkkey_query("d1", a.payload, self.now, os.urandom(32), WALL0 + self.now)
        if answer.reply is not None or answer.error is not None:
            self.gs_outs(gs, self.gss[gs].on_linkkey_reply("d1", a.gs, answer.reply, answer.error, self.now))

    # ---------------------------------------------------------------------- time
    def step(self, dt: float = 0.1) -> None:
        assert self.drone is not None
        self.now = round(self.now + dt, 6)
        for name, core in self.gss.items():
            if name not in self.hung and self.now >= core.get_timer():
                self.gs_outs(name, core.handle_timer(self.now, WALL0 + self.now))
        pos = None if self.position is None else (self.position.lat, self.position.lon, 30.0)
        self.drone_outs(self.drone.on_vehicle(pos, self.on_ground, self.now))
        if self.position is not None:
            frame = self.codec.encode(mav.MAVLink_global_position_int_message(
                int(self.now * 1000), int(self.position.lat * 1e7), int(self.position.lon * 1e7), 30000, 30000,
                0, 0, 0, 0))
            self.drone_outs(self.drone.on_telemetry(frame, self.now))
        if self.stamps and self.now >= self.next_stamp:
            self.next_stamp = self.now + STAMP_PERIOD_S
            for name in self.gss:
                if name not in self.hung and name not in self.cut:
                    self.drone_outs(self.drone.on_revision_stamp(self.stamp(name), self.now, carrier=name))
        timer = self.drone.get_timer()
        if timer is not None and self.now >= timer:
            self.drone_outs(self.drone.handle_timer(self.now))
        self.drone_outs(self.drone.flush())  # the pass's batches (``batch``; nothing otherwise)

    def stamp(self, gs: str, wall: float | None = None, drones: tuple[str, ...] = ("d1",)) -> bytes:
        """GS ``gs``'s signed revision stamp at time of day ``wall`` (default: now) naming ``drones``,
        under its key in force."""
        try:
            key = load_secret(self.fleet_dir, gs, self.drone.fleet).signing
        except ConfigError:  # a rotated GS that has not adopted its new key signs with its old one
            key = load_secret(self.fleet_dir, gs).signing
        stamp, _ = split_push(make_push(gs, self.drone.fleet.revision, self.now if wall is None else wall, key, None,
                                        drones))
        assert stamp is not None
        return stamp

    def run(self, seconds: float, dt: float = 0.1) -> None:
        for _ in range(int(round(seconds / dt))):
            self.step(dt)

    def fly(self, a: GeoPoint, b: GeoPoint, seconds: float, dt: float = 0.1) -> None:
        """Move the vehicle from ``a`` to ``b`` in ``seconds``."""
        n = int(round(seconds / dt))
        for i in range(1, n + 1):
            self.position = self.between(a, b, i / n)
            self.step(dt)

    def restart_drone(self) -> None:
        """The companion restarts (all keys lost), coming back with the authority it had persisted."""
        p = self.persisted
        self.drone = self.new_drone()
        self.listening = frozenset()
        pos = None if self.position is None else (self.position.lat, self.position.lon, 30.0)
        self.drone_outs(self.drone.on_vehicle(pos, self.on_ground, self.now))
        if p is not None:
            self.drone_outs(self.drone.restore(p.owner, p.epoch, p.state, self.now))

    def record_types(self) -> list[str]:
        return [type(r).__struct_config__.tag for r in self.records]
