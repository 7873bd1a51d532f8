"""The bare half of ``zdrone bench overhead``: the same fleet on plain Zenoh, without zdrone.

The same processes as ``bench scale``'s run (one router, or one router per site meshed site n to sites
1..n-1; a process hosting the K drones, each with its own Zenoh session and an in-process simulator,
each stepped by one loop at its own deadline or input, as zdrone's (``zdrone.bench.stepping``); a process hosting the G GSs, each with its own session),
the same keys, the same QoS and the same application traffic, and nothing else:

* **routers**: plain TCP (the mesh too), no authentication, no access control, no downsampling, no
  size filter (a Zenoh router in Python, as ``zdrone router`` is);
* **a drone**: its vehicle's MAVLink frames, as they come (no envelope), in one bundle per GS and pass
  (``zdrone.core.bundle``: the same framing and publication count as zdrone's) on
  ``zdrone/<drone>/down/<gs>``, congestion control DROP; the full stream to the GS it is "with" (the
  nearest GS whose coverage holds it; the last one while none does), each periodic stream message at
  most once a second (``StandbyStream``) to the other GSs whose coverage holds it, as zdrone streams to a
  standby GS; it hears the same GSs a zdrone drone hears (the radio gate: those whose coverage holds it,
  plus the one it is with), subscribed to their uplinks' lanes (``zdrone/<drone>/up/<gs>/*``) and no
  others, and every frame that comes on them goes to the vehicle; its take-off moment is drawn over
  the same spread as a zdrone GS's (``gs.core.TAKEOFF_SPREAD_PER_DRONE_S``). No authority machine, no
  pairing, no key sharing, no status beacon, no revision, no event log;
* **a GS**: a MAVLink HEARTBEAT at 2 Hz, spread over zdrone's slots (``gs.core.HEARTBEAT_SLOTS``), to every drone it has heard (as zdrone's GS heartbeats the drones it
  holds a live link with: a link becomes live when the drone first speaks under it), and to each drone it is "with" (the same rule,
  on the positions it hears) and that is armed a command at 1 Hz (REQUEST_MESSAGE HOME_POSITION,
  zdrone's command stream, each drone's on its own clock from when it armed), paced on the uplink's
  lanes by the same rule (``zdrone.net.pacing``: a frame per lane at once, each lane's frames
  ``UPLINK_LANE_GAP_S`` apart), at zdrone's link priority, not express, DROP; every frame it gets is
  decoded with pymavlink as zdrone's GS decodes it (``FrameCodec.decode``; the position and the
  HEARTBEAT's armed bit read from the message), in Zenoh's callback; and every ``revisions.STAMP_PERIOD_S`` one backhaul put of a revision stamp's size to the
  other GSs (zdrone's GSs' own traffic to each other in flight);
* **the flight**: the shuttle of ``bench scale``, uploaded into each simulator in-process before the
  take-off (zdrone's GS A uploads it over the link on the ground), armed and started at take-off by a
  command frame as from A, at the same speed-up; it ends ``LANDED_TAIL_S`` after the last vehicle has
  landed, as zdrone's does, or at the time limit.

CPU is measured as in ``bench scale``: the drones host's own over the flight, the others' from
``/proc`` over the same window; latency as in ``zdrone.bench.latency``.
"""

from __future__ import annotations

import argparse
import collections
import gc
import heapq
import itertools
import json
import logging
import random
import signal
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import zenoh

from zdrone.bench.latency import LatencyLog
from zdrone.bench.stepping import MIN_STEP_GAP_S, StepLateness, StepSchedule, worst_lateness
from zdrone.core.bundle import unpack
from zdrone.core.geometry import GeoPoint, distance_m
from zdrone.fleet import keyexprs
from zdrone.net.runtime import LINK_EXPRESS, LINK_PRIORITY
from zdrone.net.pump import PumpedSubscriber

log = logging.getLogger(__name__)

#: The GSs' heartbeat and command rates (``gs.core``: ``heartbeat_hz`` 2; ``bench scale``: command_rate 1).
HEARTBEAT_HZ = 2.0
COMMAND_HZ = 1.0
#: A revision stamp push's size (bytes): the GSs' backhaul in flight (``zdrone.core.revision``).
STAMP_BYTES = 120
#: A vehicle that has not armed after the take-off command is asked again this often (it may still be
#: waiting for its GPS fix).
ARM_RETRY_S = 1.0
#: After the last vehicle has landed the flight ends this much later (zdrone's: the GSs count what they
#: sent, ``scalehosts.LANDED_DRAIN_S`` after that the drones host stops).
LANDED_TAIL_S = 2.5
#: How long the stations host and routers may take to start.
START_TIMEOUT_S = 60.0
#: The drones host's ready line.
READY = "bare drones host: ready"


def client_config(router: str) -> zenoh.Config:
    """A client of ``router``: scouting off, no authentication, no TLS (``zdrone.net.session``
    without them)."""
    from zdrone.fleet.routerconfig import MAX_MESSAGE_SIZE

    cfg = {"mode": "client",
           "connect": {"endpoints": [router], "timeout_ms": 5000, "exit_on_failure": True},
           "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
           "transport": {"link": {"rx": {"max_message_size": MAX_MESSAGE_SIZE}}, "shared_memory": {"enabled": False}}}
    return zenoh.Config.from_json5(json.dumps(cfg))


def router_config(listen: str, connect: list[str]) -> dict[str, Any]:
    """A bare router: plain TCP, nothing checked or limited; ``connect``: the other sites' routers."""
    from zdrone.fleet.routerconfig import MAX_MESSAGE_SIZE

    cfg: dict[str, Any] = {
        "mode": "router", "listen": {"endpoints": [listen]},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
        "transport": {"link": {"rx": {"max_message_size": MAX_MESSAGE_SIZE}}, "shared_memory": {"enabled": False}}}
    if connect:
        cfg["connect"] = {"endpoints": connect,
                          "retry": {"period_init_ms": 100, "period_max_ms": 1000, "period_increase_factor": 1.5}}
    return cfg


# ------------------------------------------------------------------ the application's rule
def nearest_covering(pos: Any, circles: dict[str, Any], last: str | None) -> str | None:
    """The GS a vehicle at ``pos`` is with: the nearest whose coverage holds it, else ``last``."""
    best, best_d = None, float("inf")
    for g, c in circles.items():
        d = distance_m(c.centre, pos)
        if d <= c.radius_m and d < best_d:
            best, best_d = g, d
    return best if best is not None else last


def msgid_of(frame: bytes) -> int:
    """The message id of a MAVLink frame (v2: three bytes at 7; v1: one at 5); -1 if too short."""
    if len(frame) >= 10 and frame[0] == 0xFD:
        return frame[7] | frame[8] << 8 | frame[9] << 16
    return frame[5] if len(frame) >= 6 else -1


# ------------------------------------------------------------------ routers
def _router(args: argparse.Namespace) -> int:
    stop = [False]
    signal.signal(signal.SIGTERM, lambda *_: stop.__setitem__(0, True))
    cfg = router_config(args.listen, [c for c in (args.connect or "").split(",") if c])
    session = zenoh.open(zenoh.Config.from_json5(json.dumps(cfg)))
    print(f"bare router: listening on {args.listen}, zid {session.info.zid()}", flush=True)
    try:
        while not stop[0]:
            time.sleep(0.2)
    finally:
        session.close()
    return 0


# ------------------------------------------------------------------ drones
class BareDrone:
    """One drone: its session, its vehicle, what came up for it."""

    def __init__(self, name: str, router: str, vehicle: Any, gss: list[str], lat: LatencyLog | None = None,
                 woken: "collections.deque[BareDrone] | None" = None, wake: threading.Event | None = None) -> None:
        from zdrone.core.bundle import BundleWriter
        from zdrone.core.standby import StandbyStream

        self.name, self.vehicle, self.gss = name, vehicle, gss
        self.session = zenoh.open(client_config(router))
        self.inq: collections.deque[tuple[str, bytes]] = collections.deque()
        self.delivered = 0
        self.bundles = BundleWriter()
        self.standby = StandbyStream()
        self.owner: str | None = None
        self.armed_seen = False
        self.takeoff_at = float("inf")  # its take-off moment, drawn over the spread at the take-off
        self.next_arm = 0.0  # when to send ARM and MISSION_START again if it has not armed
        self.pos_key: tuple[float, float] | None = None
        self.inside: list[str] = []
        self.subs: dict[str, Any] = {}  # GS -> the subscriber of its uplink's lanes (the radio gate)
        inq = self.inq

        def on_up(sample: zenoh.Sample) -> None:  # Zenoh's thread: hand over and return
            data = sample.payload.to_bytes()
            if lat is not None:
                lat.note("up", "arrived", name, data, time.monotonic())
            inq.append((keyexprs.gs_of_uplink(sample.key_expr), data))
            self.delivered += 1
            if woken is not None:
                woken.append(self)
            if wake is not None:
                wake.set()

        self._on_up = on_up

    def hear(self) -> None:
        """The radio gate, as a zdrone drone's: subscribed to the uplinks of the GSs whose coverage
        holds it and of the one it is with, and no others (called when those change)."""
        want = set(self.inside) | ({self.owner} if self.owner is not None else set())
        for g in [g for g in self.subs if g not in want]:
            self.subs.pop(g).undeclare()
        for g in sorted(want - set(self.subs)):
            self.subs[g] = self.session.declare_subscriber(
                f"{keyexprs.up(self.name, g)}/*", zenoh.handlers.Callback(self._on_up, indirect=False))

    def take_uplink(self, lat: LatencyLog | None) -> None:
        """Every frame that came up goes to the vehicle (at the drone's turn, and between turns as
        ``scalehosts.WAKE_EVERY`` says, as zdrone's host does)."""
        inq, vehicle = self.inq, self.vehicle
        while inq:
            gs, frame = inq.popleft()
            if lat is not None:
                lat.note("up", "got", self.name, frame, time.monotonic())
            vehicle.send(frame)

    def close(self) -> None:
        try:
            for sub in self.subs.values():
                sub.undeclare()
            self.session.close()
        except Exception as exc:  # closing is best effort at the end of a run
            log.warning("%s: close: %s", self.name, exc)


def _host_drones(args: argparse.Namespace) -> int:
    from gs.planner import shuttle_mission

    from zdrone.bench.procstats import _memory_mb
    from gs.core import TAKEOFF_SPREAD_PER_DRONE_S
    from zdrone.bench.scalehosts import CROSSINGS, PASS_S, WAKE_EVERY
    from zdrone.core.mavlink import FrameCodec
    from zdrone.core.reference import HOME
    from zdrone.fleet.files import load_fleet
    from zdrone.net.runtime import freeze_start_up
    from zdrone.vehicle.inproc import InProcessVehicle

    fleet = load_fleet(args.fleet)
    gss = sorted(fleet.ground_stations())
    circles = {g: fleet.nodes[g].coverage.circle() for g in gss}  # type: ignore[union-attr]
    routers = args.router.split(",")
    gcs = FrameCodec(fleet.nodes[gss[0]].sysid, 190)  # the GS that flies them (A), for the set-up frames
    mission = shuttle_mission(CROSSINGS, far_east_m=500.0 * (len(gss) - 1) - 60.0)
    lat = LatencyLog() if args.latency else None
    woken: collections.deque[BareDrone] = collections.deque()  # drones a GS's frame reached since last served
    wake = threading.Event()  # set with each
    drones = []
    for i in range(args.part, args.k, args.parts):  # this host's share (drone i in host i mod parts, as zdrone's)
        name = f"d{i + 1}"
        vehicle = InProcessVehicle(HOME, sysid=fleet.nodes[name].sysid, speedup=args.speedup, seed=i)
        vehicle.sim.step(vehicle._sim_time())
        if not vehicle.upload(mission, gcs):
            print(f"bare drones host: {name} refused the mission", file=sys.stderr, flush=True)
            return 2
        d = BareDrone(name, routers[i % len(routers)], vehicle, gss, lat, woken, wake)
        p = vehicle.sim.position
        d.inside = [g for g, c in circles.items() if c.contains(p)]
        d.owner = nearest_covering(p, circles, None)
        d.hear()
        drones.append(d)
    spread = TAKEOFF_SPREAD_PER_DRONE_S * max(len(drones) - 1, 0)  # as a zdrone GS spreads its take-offs
    draw = random.Random(7)
    freeze_start_up()
    print(f"{READY}: {len(drones)} drones", flush=True)
    stop, go = [False], [False]
    signal.signal(signal.SIGTERM, lambda *_: stop.__setitem__(0, True))
    signal.signal(signal.SIGUSR1, lambda *_: go.__setitem__(0, True))  # take-off
    t0 = cpu0 = 0.0
    deadline = float("inf")
    baseline = 0
    loops = 0.0
    worst_pass = 0.0
    landed_at: float | None = None
    put_opts = {"congestion_control": zenoh.CongestionControl.DROP}
    # each drone stepped at its own next deadline or when a GS's frame comes, as zdrone's host does
    sched = StepSchedule(len(drones), time.monotonic())
    index = {id(d): i for i, d in enumerate(drones)}
    steps_at_t0, next_check = 0, 0.0

    def served(d: BareDrone) -> None:  # what came up goes to the vehicle; its answer is due at once
        d.take_uplink(lat)
        sched.bring_forward(index[id(d)], d.vehicle.next_due())

    try:
        while not stop[0] and time.monotonic() < deadline:
            wake.wait(max(0.0, min(sched.next_due(), next_check) - time.monotonic()))
            wake.clear()
            if time.monotonic() >= next_check:
                next_check = time.monotonic() + PASS_S
                if go[0] and t0 == 0.0:
                    t0, cpu0 = time.monotonic(), time.process_time()
                    deadline = t0 + args.duration
                    baseline = sum(d.delivered for d in drones)
                    steps_at_t0 = sched.steps
                    sched.lateness = StepLateness()  # from the take-off, as the steps
                    for i, d in enumerate(drones):
                        d.takeoff_at = t0 + draw.uniform(0.0, spread)
                        sched.bring_forward(i, d.takeoff_at)
                    if lat is not None:
                        lat.start(t0)
                    print("bare drones host: take-off", flush=True)
                if landed_at is None and t0 and all(d.armed_seen for d in drones) and not any(d.vehicle.armed for d in drones):
                    landed_at = time.monotonic()
                    print("bare drones host: all landed", flush=True)
                if landed_at is not None and time.monotonic() - landed_at >= LANDED_TAIL_S:
                    break
            pass_start = time.monotonic()
            while woken:
                served(woken.popleft())
            for j, i in enumerate(sched.take(pass_start)):
                if j and j % WAKE_EVERY == 0:
                    while woken:
                        served(woken.popleft())
                d = drones[i]
                now = time.monotonic()
                sched.started(i, now)
                vehicle = d.vehicle
                d.take_uplink(lat)
                if t0 and not d.armed_seen and now >= d.takeoff_at:
                    if vehicle.armed:
                        d.armed_seen = True
                    elif now >= d.next_arm:
                        d.next_arm = now + ARM_RETRY_S
                        vehicle.arm_and_start(gcs)
                frames = vehicle.recv(0.0)
                due = vehicle.next_due()
                if t0 and not d.armed_seen:
                    due = min(due, max(d.takeoff_at, d.next_arm))
                sched.set(i, max(due, time.monotonic() + MIN_STEP_GAP_S))
                if not frames:
                    continue
                if lat is not None:  # as the vehicle gives them, after its step (as zdrone's drone notes them)
                    lat.note_many("down", "sent", d.name, frames, time.monotonic())
                p = vehicle.sim.position
                key = (p.lat, p.lon)
                if key != d.pos_key:
                    d.pos_key = key
                    inside, owner = [g for g, c in circles.items() if c.contains(p)], nearest_covering(p, circles, d.owner)
                    if inside != d.inside or owner != d.owner:
                        d.inside, d.owner = inside, owner
                        d.hear()
                owner, bundles = d.owner, d.bundles
                for f in frames:
                    if owner is not None:
                        bundles.add(owner, f)
                    if len(d.inside) > 1 or owner not in d.inside:
                        mid = msgid_of(f)
                        for g in d.inside:
                            if g != owner and d.standby.allow(g, mid, now):
                                bundles.add(g, f)
                for g, b in bundles.take():
                    d.session.put(keyexprs.down(d.name, g), b, **put_opts)
                if lat is not None:
                    lat.note_many("down", "put", d.name, frames, time.monotonic())
            worst_pass = max(worst_pass, time.monotonic() - pass_start)
        loops = (sched.steps - steps_at_t0) / max(1, len(drones))  # steps a drone, from the take-off
        flight_s = time.monotonic() - t0 if t0 else 0.0
        cpu_s = time.process_time() - cpu0 if t0 else 0.0
        out = Path(args.out)
        suffix = "" if args.parts == 1 else f"-{args.part}"
        if lat is not None:
            lat.dump(out / f"latency-drones{suffix}.json")
        (out / f"drones{suffix}.json").write_text(json.dumps({
            "flight_s": flight_s, "cpu_s": cpu_s, "memory_mb": _memory_mb("self"), "loops": loops,
            "step_late": sched.lateness.report(), "worst_pass_s": round(worst_pass, 3), "flew": sum(d.armed_seen for d in drones), "landed": landed_at is not None,
            "delivered": sum(d.delivered for d in drones) - baseline}))
    finally:
        for d in drones:
            d.close()
    return 0


# ------------------------------------------------------------------ ground stations
class BareStation:
    """One GS: its session, what it knows of each drone (position, armed), its timer thread."""

    def __init__(self, name: str, sysid: int, router: str, drones: dict[str, int], circles: dict[str, Any],
                 lat: LatencyLog | None) -> None:
        from zdrone.core.mavlink import FrameCodec

        self.name, self.drones, self.circles, self.lat = name, drones, circles, lat
        from zdrone.fleet.routerconfig import UPLINK_LANE_GAP_S
        from zdrone.net.pacing import Pacer

        self.codec = FrameCodec(sysid, 190)
        self.decoder = FrameCodec(sysid, 190)  # what the drones send (Zenoh's thread only)
        self.seq: dict[str, int] = {d: 0 for d in drones}  # each link's MAVLink sequence number
        self.refused = collections.Counter[str]()
        self.pacer = Pacer(UPLINK_LANE_GAP_S, lambda why: self.refused.update([why]), burst=keyexprs.UP_LANES)
        self.lanes: dict[str, Any] = {}
        self.arming: collections.deque[str] = collections.deque()  # drones seen arming (Zenoh's thread -> the GS's)
        self.heard: set[str] = set()  # drones whose frames reached it (zdrone: a live link): heartbeated
        self.pos: dict[str, Any] = {}
        self.armed: dict[str, bool] = {}
        self.owner: dict[str, str | None] = {}
        self.delivered = 0
        self.backhaul = 0
        self.sent = collections.Counter[str]()
        self.session = zenoh.open(client_config(router))
        self.subs = [
            PumpedSubscriber(self.session, keyexprs.down("*", name), self._on_down),  # as zdrone's GS (``zdrone.net.pump``)
            self.session.declare_subscriber("backhaul/*/stamp", zenoh.handlers.Callback(self._on_backhaul, indirect=False))]
        self.running = True
        self.error: str | None = None

    def _on_down(self, sample: zenoh.Sample) -> None:
        self.delivered += 1
        drone = keyexprs.drone_of(sample.key_expr)
        self.heard.add(drone)  # a link of its, from now on (zdrone's GS heartbeats the drones it holds a live link with)
        frames = unpack(sample.payload.to_bytes()) or []
        now = time.monotonic()
        if self.lat is not None:
            self.lat.note_many("down", "arrived", drone, frames, now)  # in its pump's hands
            self.lat.note_many("down", "got", drone, frames, now)
        decode = self.decoder.decode
        for f in frames:
            msg = decode(f)  # every frame decoded, as zdrone's GS decodes it (``gs.session``)
            if msg is None:
                continue
            t = msg.get_type()
            if t == "GLOBAL_POSITION_INT":
                p = GeoPoint(msg.lat / 1e7, msg.lon / 1e7)
                self.pos[drone] = p
                self.owner[drone] = nearest_covering(p, self.circles, self.owner.get(drone))
            elif t == "HEARTBEAT" and msg.get_srcComponent() == 1:  # the autopilot's: armed?
                armed = bool(msg.base_mode & 0x80)
                if armed and not self.armed.get(drone):
                    self.arming.append(drone)  # its command clock starts (the GS's thread takes it)
                self.armed[drone] = armed

    def _on_backhaul(self, sample: zenoh.Sample) -> None:
        if not str(sample.key_expr).startswith(f"backhaul/{self.name}/"):
            self.backhaul += 1

    def _put(self, drone: str, msg: Any, now: float) -> None:
        codec = self.codec
        codec.mav.seq = self.seq[drone]
        frame = codec.encode(msg)
        self.seq[drone] = codec.mav.seq
        if self.lat is not None:
            self.lat.note("up", "sent", drone, frame, now)  # the pass's start, as zdrone's (before sealing)
        uplink = keyexprs.up(drone, self.name)
        if self.pacer.offer(uplink, frame, now):  # the same pacing rule on the same lanes as zdrone's GS
            self._put_on_lane(uplink, frame)

    def _put_on_lane(self, uplink: str, frame: bytes) -> None:
        if self.lat is not None:  # on its lane, after the GS's pass and its pacing (as zdrone's)
            self.lat.note("up", "put", uplink.split("/")[1], frame, time.monotonic())
        lanes = self.lanes.get(uplink)
        if lanes is None:
            lanes = self.lanes[uplink] = itertools.cycle([keyexprs.lane_of(uplink, i) for i in range(keyexprs.UP_LANES)])
        self.session.put(next(lanes), frame, congestion_control=zenoh.CongestionControl.DROP,
                         priority=LINK_PRIORITY, express=LINK_EXPRESS)

    def run(self) -> None:
        try:
            self._run()
        except Exception as exc:  # the host reports it (a GS that stopped sending makes the run worthless)
            log.exception("GS %s", self.name)
            self.error = f"GS {self.name}: {exc.__class__.__name__}: {exc}"

    def _run(self) -> None:
        from pymavlink.dialects.v20 import common as mav

        from gs.core import HEARTBEAT_SLOTS
        from zdrone.fleet.revisions import STAMP_PERIOD_S

        hb = mav.MAVLink_heartbeat_message(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, mav.MAV_STATE_ACTIVE, 3)
        now = time.monotonic()
        next_hb, next_stamp = now, now
        slots = max(1, min(HEARTBEAT_SLOTS, len(self.drones)))  # zdrone's GS's slots, the same drones in each
        groups, slot, step = [sorted(self.drones)[i::slots] for i in range(slots)], 0, 1.0 / HEARTBEAT_HZ / slots
        commands: list[tuple[float, str]] = []  # (due, drone): each armed drone's command clock
        period = 1.0 / COMMAND_HZ
        while self.running:
            now = time.monotonic()
            while self.arming:
                heapq.heappush(commands, (now + period, self.arming.popleft()))
            for _ in groups:  # the slots that are due, each once (``StationCore.handle_timer``'s rule)
                if now < next_hb:
                    break
                heard = [d for d in groups[slot] if d in self.heard]
                for d in heard:
                    self._put(d, hb, now)
                self.sent["heartbeat"] += len(heard)
                slot, next_hb = (slot + 1) % slots, next_hb + step
            if next_hb <= now:
                next_hb = now + step
            while commands and commands[0][0] <= now:
                due, d = heapq.heappop(commands)
                if not self.armed.get(d):
                    continue  # landed: its clock stops
                heapq.heappush(commands, (max(due + period, now), d))
                if self.owner.get(d) == self.name:
                    self._put(d, mav.MAVLink_command_long_message(self.drones[d], 1, mav.MAV_CMD_REQUEST_MESSAGE, 0,
                                                                  mav.MAVLINK_MSG_ID_HOME_POSITION, 0, 0, 0, 0, 0, 0), now)
                    self.sent["command"] += 1
            if now >= next_stamp:
                next_stamp = max(next_stamp + STAMP_PERIOD_S, now)
                self.session.put(f"backhaul/{self.name}/stamp", bytes(STAMP_BYTES),
                                 congestion_control=zenoh.CongestionControl.DROP)
                self.sent["backhaul"] += 1
            for uplink, frame in self.pacer.due(now):
                self._put_on_lane(uplink, frame)
            wake = [next_hb, next_stamp, commands[0][0] if commands else next_hb, now + 0.05]
            paced = self.pacer.next_due()
            if paced is not None:
                wake.append(paced)
            time.sleep(max(0.0, min(wake) - time.monotonic()))

    def close(self) -> None:
        try:
            for s in self.subs:
                s.undeclare()
            self.session.close()
        except Exception as exc:
            log.warning("GS %s: close: %s", self.name, exc)


def _host_stations(args: argparse.Namespace) -> int:
    from zdrone.bench.procstats import _memory_mb
    from zdrone.fleet.files import load_fleet
    from zdrone.net.runtime import freeze_start_up

    fleet = load_fleet(args.fleet)
    gss = sorted(fleet.ground_stations())[:args.stations]
    circles = {g: fleet.nodes[g].coverage.circle() for g in gss}  # type: ignore[union-attr]
    drones = {n: v.sysid for n, v in fleet.nodes.items() if v.role == "drone"}
    routers = args.router.split(",")
    lat = LatencyLog() if args.latency else None
    stations = [BareStation(g, fleet.nodes[g].sysid, routers[i % len(routers)], drones, circles, lat)
                for i, g in enumerate(gss)]
    baseline = [0]

    def took_off(*_: Any) -> None:
        baseline[0] = sum(st.delivered for st in stations)
        if lat is not None:
            lat.start(time.monotonic())

    signal.signal(signal.SIGUSR1, took_off)
    stop = [False]
    signal.signal(signal.SIGTERM, lambda *_: stop.__setitem__(0, True))
    freeze_start_up()
    threads = [threading.Thread(target=st.run, daemon=True) for st in stations]
    for t in threads:
        t.start()
    print(f"bare stations host: {len(stations)} stations ready", flush=True)
    while not stop[0]:
        time.sleep(0.2)
    for st in stations:
        st.running = False
    for t in threads:
        t.join(5)
    out = Path(args.out)
    if lat is not None:
        lat.dump(out / "latency-stations.json")
    (out / "stations.json").write_text(json.dumps({
        "delivered": sum(st.delivered for st in stations) - baseline[0], "memory_mb": _memory_mb("self"),
        "sent": {st.name: dict(st.sent) for st in stations},
        "paced_refused": {st.name: dict(st.refused) for st in stations if st.refused}, "backhaul_heard": {st.name: st.backhaul for st in stations},
        "errors": [st.error for st in stations if st.error]}))
    for st in stations:
        st.close()
    return 0


# ------------------------------------------------------------------ one run
def one(k: int, g: int, base: Path, flight_s: float, sites: int = 0, speedup: float = 4.0,
        hosts_nice: int = 10, latency: bool = True, drone_hosts: int = 1) -> dict[str, Any]:
    """One bare run: K drones x G GSs through one router, or ``sites`` meshed routers (GS i at site
    i, drone i at site i mod N), flying ``flight_s`` seconds from the take-off. The row has what the
    bench compares: CPU (100 % = one core) and RSS per process, samples delivered per second, latency."""
    from zdrone.bench import latency as lat
    from zdrone.bench.procstats import _memory_mb
    from zdrone.bench.scale import _free_ports, _wait_line, give_way
    from zdrone.bench.stallwatch import cpu_seconds
    from zdrone.fleet.files import init_fleet, scale_nodes
    from zdrone.sil.procs import spawn, stop_in_order

    n_routers = max(1, sites)
    d = base / f"bare-k{k}-{f'sites{sites}' if sites else 'one'}"
    d.mkdir(parents=True, exist_ok=True)
    init_fleet(d / "fleet", nodes_spec=scale_nodes(k, g))  # the layout (coverage, sysids); no key is used
    ports = _free_ports(n_routers)
    endpoints = [f"tcp/127.0.0.1:{p}" for p in ports]
    py = [sys.executable, "-m", "zdrone.bench.bare"]
    hpy = (["nice", "-n", str(hosts_nice)] if hosts_nice else []) + py
    routers = {("router" if not sites else f"router site-{i + 1}"): ["router", "--listen", ep, "--connect", ",".join(endpoints[:i])]
               for i, ep in enumerate(endpoints)}
    gs_routers = [endpoints[i % n_routers] for i in range(g)]
    hosts = ["drones"] if drone_hosts == 1 else [f"drones-{i}" for i in range(drone_hosts)]
    logs = {n: open(d / f"{n.replace(' ', '-')}.log", "w") for n in (*routers, *hosts, "stations")}
    procs: dict[str, subprocess.Popen] = {}
    row: dict[str, Any] = {"k": k, "g": g, "sites": sites or 1, "speedup": speedup, "runs": str(d)}
    t_start = time.monotonic()
    try:
        for name, cmd in routers.items():
            procs[name] = spawn(py + cmd, stdout=logs[name], stderr=subprocess.STDOUT)
        for name in routers:
            if _wait_line(d / f"{name.replace(' ', '-')}.log", "listening", START_TIMEOUT_S, procs[name]) is None:
                raise RuntimeError(f"bare {name} did not start; see {d}")
        common = ["--fleet", str(d / "fleet"), "--out", str(d)] + (["--latency"] if latency else [])
        for part, h in enumerate(hosts):
            procs[h] = spawn(hpy + ["host-drones", "--k", str(k), "--speedup", str(speedup), "--duration", str(flight_s),
                                    "--router", ",".join(endpoints), "--part", str(part), "--parts", str(len(hosts)),
                                    *common], stdout=logs[h], stderr=subprocess.STDOUT)
        procs["stations"] = spawn(hpy + ["host-stations", "--stations", str(g), "--router", ",".join(gs_routers), *common],
                                  stdout=logs["stations"], stderr=subprocess.STDOUT)
        row["hosts_given_way"] = {h: give_way(procs[h].pid, hosts_nice) for h in (*hosts, "stations")}
        from zdrone.bench.scale import READY_TIMEOUT_S

        for h in hosts:
            if _wait_line(d / f"{h}.log", READY, READY_TIMEOUT_S, procs[h]) is None:
                raise RuntimeError(f"bare drones host did not start; see {d / f'{h}.log'}")
        if _wait_line(d / "stations.log", "stations ready", START_TIMEOUT_S, procs["stations"]) is None:
            raise RuntimeError(f"bare stations host did not start; see {d / 'stations.log'}")
        row["ground_s"] = round(time.monotonic() - t_start, 1)
        others = {**{n: procs[n].pid for n in routers}, "stations host": procs["stations"].pid}
        t0, cpu0 = time.monotonic(), {n: cpu_seconds(p) for n, p in others.items()}
        procs["stations"].send_signal(signal.SIGUSR1)
        for h in hosts:
            procs[h].send_signal(signal.SIGUSR1)
        try:
            for h in hosts:
                procs[h].wait(flight_s + 60)
        except subprocess.TimeoutExpired:
            row["error"] = "bare drones host did not finish"
        t1, cpu1 = time.monotonic(), {n: cpu_seconds(p) for n, p in others.items()}
        memory = {n: _memory_mb(p) for n, p in others.items()}
    except RuntimeError as exc:
        row["error"] = str(exc)
        return row
    finally:
        stop_in_order(procs, ("stations", *hosts, *routers))
        for f in logs.values():
            f.close()
    row["wall_s"] = round(time.monotonic() - t_start, 1)
    try:
        parts = [json.loads((d / f"{h}.json").read_text()) for h in hosts]
        drones = {"flight_s": max(p["flight_s"] for p in parts), "cpu_s": sum(p["cpu_s"] for p in parts),
                  "memory_mb": None if any(p["memory_mb"] is None for p in parts) else
                  {k: round(sum(p["memory_mb"][k] for p in parts), 1) for k in ("rss", "peak")},
                  "flew": sum(p["flew"] for p in parts),
                  "landed": all(p["landed"] for p in parts), "worst_pass_s": max(p["worst_pass_s"] for p in parts),
                  "delivered": sum(p["delivered"] for p in parts),
                  "passes_per_s": min(round(p["loops"] / max(p["flight_s"], 1e-6), 1) for p in parts),
                  "step_late": worst_lateness([p.get("step_late") for p in parts]),
                  "shares": {h: round(p["cpu_s"] / max(1e-6, p["flight_s"]), 2) for h, p in zip(hosts, parts)}}
        stations = json.loads((d / "stations.json").read_text())
    except (OSError, ValueError) as exc:
        row["error"] = row.get("error") or f"no results ({exc}); see {d}"
        return row
    if stations.get("errors"):
        row["error"] = "; ".join(stations["errors"])
    span = max(1e-6, t1 - t0)
    cpu = {n: round(100.0 * (cpu1[n] - c) / span, 1) if c is not None and cpu1[n] is not None else None
           for n, c in cpu0.items()}
    cpu["drones host"] = round(100.0 * drones["cpu_s"] / max(1e-6, drones["flight_s"]), 1)
    row.update({"window_s": round(span, 1), "cpu_percent": cpu,
                "memory_mb": {**memory, "drones host": drones["memory_mb"]},
                "samples_per_s": round((drones["delivered"] + stations["delivered"]) / span, 1),
                "flew": drones["flew"], "landed": drones["landed"], "worst_pass_s": drones["worst_pass_s"], "sent": stations["sent"],
                "drones_host_passes_per_s": drones["passes_per_s"],
                "drones_host_step_late": drones["step_late"], "drone_host_shares": drones["shares"], "drone_hosts": len(hosts),
                "backhaul_heard": stations["backhaul_heard"]})
    if latency:
        files = [d / ("latency-drones.json" if h == "drones" else f"latency-{h}.json") for h in hosts] + [d / "latency-stations.json"]
        row["latency"], row["messages_per_s"] = lat.summary(lat.load(files)), lat.rates(files, span)
    return row


def main(argv: list[str] | None = None) -> int:
    from zdrone.crashes import stacks_on_crash

    stacks_on_crash()
    p = argparse.ArgumentParser(prog="python -m zdrone.bench.bare")
    sub = p.add_subparsers(dest="role", required=True)
    r = sub.add_parser("router")
    r.add_argument("--listen", required=True)
    r.add_argument("--connect", default="", help="other routers' endpoints, comma-separated")
    hd = sub.add_parser("host-drones")
    hd.add_argument("--k", type=int, required=True)
    hd.add_argument("--speedup", type=float, required=True)
    hd.add_argument("--duration", type=float, required=True, help="flight from the take-off (SIGUSR1), s")
    hd.add_argument("--part", type=int, default=0, help="this host's part: drones i with i mod parts = part")
    hd.add_argument("--parts", type=int, default=1, help="how many drones hosts share the fleet")
    hs = sub.add_parser("host-stations")
    hs.add_argument("--stations", type=int, required=True)
    for sp in (hd, hs):
        sp.add_argument("--fleet", required=True)
        sp.add_argument("--router", required=True, help="router endpoint(s), comma-separated")
        sp.add_argument("--out", required=True)
        sp.add_argument("--latency", action="store_true", help="note messages for the latency (zdrone.bench.latency)")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    gc.collect()
    return {"router": _router, "host-drones": _host_drones, "host-stations": _host_stations}[args.role](args)


if __name__ == "__main__":
    sys.exit(main())
