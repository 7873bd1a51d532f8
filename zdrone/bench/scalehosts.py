"""The two host processes of ``zdrone bench scale``'s run (``python -m zdrone.bench.scale host-drones |
host-stations``): the drones host steps its share of the K drone nodes (each with its own Zenoh session
and an in-process simulator) in one loop, holds them on the ground until every drone has every GS's
key, and notes each drone's hand-overs, authority-link silences and deliveries; the stations host runs
the G ground stations, each in a thread of its own, and counts the commands they sent. Each writes its
results as JSON into the run's directory for the bench to read (``drones_file``, ``merge_drone_hosts``).
"""

from __future__ import annotations

import argparse
import collections
import json
import logging
import os
import signal
import threading
import time
from collections import Counter
from dataclasses import replace
from pathlib import Path
from typing import Any

from zdrone.bench.latency import LatencyLog
from zdrone.bench.procstats import _memory_mb
from zdrone.bench.stallwatch import FrameGaps, GcClock, LoopTimer, PassClock, StallWatch
from zdrone.bench.stepping import MIN_STEP_GAP_S, StepLateness, StepSchedule, worst_lateness
from zdrone.net.runtime import freeze_start_up

#: Crossings of the shuttle each drone flies (A's area to the last GS's area, and back).
CROSSINGS = 2
#: Between the steps of this many drones the host hands every drone that got a GS's frame meanwhile
#: its inputs (``DroneNode.take_inputs``; the bare half does the same), as a drone on its own companion
#: wakes on one: the frame waits for the step under way, not for other drones' steps (at 10 it waited
#: for up to ten, 9 ms at p99 at 100 drones in zdrone's half, whose steps cost more, 1 ms in bare's).
WAKE_EVERY = 1
#: The drones host steps each drone at its own next deadline or when an input comes for it
#: (``zdrone.bench.stepping``), and makes its own checks (take-off, landing) every PASS_S.
PASS_S = 0.01
#: After the last vehicle has landed the GSs stop commanding and count what they sent (``COUNTED``
#: file), and the drones host steps on this long after that, so what is still on its way arrives: a
#: command sent to a drone whose host had stopped was counted lost, one sent after the GSs had counted
#: but forwarded before the host stopped was "-1 lost" (7 drones of 300).
LANDED_DRAIN_S = 2.0
#: Written by the stations host once it stopped commanding and counted; the drones host waits for it
#: this long at most after the landing.
COUNTED = "stations.counted"
COUNTED_WAIT_S = 30.0
#: Readiness of a held vehicle (simulated seconds after boot before it may arm): never, until released.
HOLD_READY_AFTER = 1e9


log = logging.getLogger(__name__)


class DeliveryCounter:
    """Samples delivered to one node, per sender: wraps its inbox's ``put``, which every subscribed
    sample reaches (called from Zenoh's threads); query replies (pairing, key sharing) are not counted."""

    DATA_KINDS = frozenset({"up", "down"})

    def __init__(self, inbox: Any, gaps: FrameGaps | None = None, node: str = "") -> None:
        self.lock = threading.Lock()
        self.by_sender: Counter[str] = Counter()
        original = inbox.put

        def counted(kind: str, peer: str, data: Any) -> None:
            if kind in self.DATA_KINDS:
                with self.lock:
                    self.by_sender[peer] += 1
                if gaps is not None and kind == "up":  # a GS's frame reached this drone's callback
                    gaps.note(peer, node, time.monotonic())
            original(kind, peer, data)

        inbox.put = counted

    def snapshot(self) -> dict[str, int]:
        with self.lock:
            return dict(self.by_sender)

    def since(self, baseline: dict[str, int]) -> dict[str, int]:
        """Samples delivered since ``baseline`` (an earlier snapshot)."""
        return {peer: n - baseline.get(peer, 0) for peer, n in self.snapshot().items()}


def _router_zid(session: Any) -> str | None:
    """The router this client session is connected to."""
    try:
        zids = session.info.routers_zid()
        return str(zids[0]) if zids else None
    except Exception as exc:  # a closed session: nothing to report
        log.warning("router zid: %s", exc)
        return None


def drones_file(part: int, parts: int) -> str:
    """The results of one drones host (``drones.json`` when it is the only one)."""
    return "drones.json" if parts == 1 else f"drones-{part}.json"


def merge_drone_hosts(parts: list[dict[str, Any]]) -> dict[str, Any]:
    """The drones hosts' results as one: every drone's, the slowest pass and step of any host, CPU and
    memory summed (``cpu_percent``: each host's CPU over its own flight, added)."""
    for p in parts:  # each host's share of a core over its flight, and its passes a second
        p.setdefault("share", round(p["cpu_s"] / max(1e-6, p["flight_s"]), 2))
        p.setdefault("passes_per_s", round(p["loops"] / max(1e-6, p["flight_s"]), 1))
    if len(parts) == 1:
        parts[0]["shares"] = [parts[0]["share"]]
        return parts[0]
    slow = [p["slow"] for p in parts]
    worst_step = max(slow, key=lambda x: x["worst_step_s"])
    return {
        "results": {n: r for p in parts for n, r in p["results"].items()}, "loops": min(p["loops"] for p in parts),
        "step_late": worst_lateness([p.get("step_late") for p in parts]),
        "shares": [p["share"] for p in parts], "passes_per_s": min(p["passes_per_s"] for p in parts),
        "timed_out": any(p["timed_out"] for p in parts), "flight_s": max(p["flight_s"] for p in parts),
        "cpu_s": sum(p["cpu_s"] for p in parts),
        "cpu_percent": round(sum(100.0 * p["cpu_s"] / max(1e-6, p["flight_s"]) for p in parts), 1),
        "memory_mb": {k: round(sum((p["memory_mb"] or {}).get(k, 0.0) for p in parts), 1) for k in ("rss", "peak")},
        "ground_s": max(p["ground_s"] for p in parts),
        "released": "keys" if all(p["released"] == "keys" for p in parts) else "hold timeout",
        "router_zid": {n: z for p in parts for n, z in p["router_zid"].items()},
        "slow": {"hosts": len(parts), "worst_pass_s": max(x["worst_pass_s"] for x in slow),
                 "passes_over_0_5s": sum(x["passes_over_0_5s"] for x in slow),
                 "worst_step_s": worst_step["worst_step_s"], "worst_step_node": worst_step["worst_step_node"],
                 "listen_worst_s": max(x["listen_worst_s"] for x in slow), "listen_total_s": round(sum(x["listen_total_s"] for x in slow), 2),
                 "stalls": [s for x in slow for s in x.get("stalls", [])], "stalls_seen": sum(x.get("stalls_seen", 0) for x in slow),
                 "watch_late_worst_s": max(x.get("watch_late_worst_s", 0.0) for x in slow),
                 "slow_passes": [s for x in slow for s in x.get("slow_passes", [])]},
        "delivered": {n: c for p in parts for n, c in p["delivered"].items()}}


def merge_station_hosts(parts: list[dict[str, Any]]) -> dict[str, Any]:
    """The GS hosts' results as one (a GS per process): each GS's counts; the loops and collections per host."""
    if len(parts) == 1:
        return parts[0]
    merged: dict[str, Any] = {key: {g: v for p in parts for g, v in p.get(key, {}).items()}
                              for key in ("commands_sent", "commands_sent_epochs", "router_zid", "delivered", "counters",
                                          "linked_all")}
    merged["gc"] = [p.get("gc") for p in parts]
    merged["loops"] = [p.get("loops") for p in parts]
    return merged


def note_drone_latency(node: Any, latency: LatencyLog) -> None:
    """``bench overhead``'s opt-in hook (``--latency``) on one drone node: the vehicle's frames as its
    loop takes them (vehicle -> GS, sent), each GS envelope as Zenoh's callback hands it to the inbox
    (GS -> vehicle, arrived), and each frame the core forwards to the vehicle, under the CRC of the
    envelope it came in (GS -> vehicle, got). Wraps the node's own callables on the instance;
    nothing changes without ``--latency``."""
    from zdrone.nodes.drone_actions import ToVehicle

    name, envelope = node.name, [b""]
    on_envelope, recv, inbox_put = node.core.on_envelope, node.vehicle.recv, node.rt.inbox.put

    def arrived(kind: str, peer: str, data: Any) -> None:  # Zenoh's thread: the envelope as it came
        if kind == "up":
            latency.note("up", "arrived", name, data, time.monotonic())
        inbox_put(kind, peer, data)

    def opened(gs: str, data: bytes, now: float) -> Any:
        envelope[0] = data
        return on_envelope(gs, data, now)

    core, catch_up = node.core, node.core._catch_up
    taken: dict[bytes, float] = {}  # a vehicle frame -> when the vehicle gave it (the newest kept)
    stepped: list[bytes] = []  # the frames taken (and caught up) since the last put of the bundles
    flush_down = node.flush_down

    def received(timeout: float = 0.0) -> list[bytes]:
        frames = recv(timeout)
        now = time.monotonic()
        latency.note_many("down", "sent", name, frames, now)
        stepped.extend(frames)
        if latency.on:
            if len(taken) > 1024:  # the newest frame of each stream message is all a catch-up sends
                latest = set(core._latest.values())
                for f in [f for f in taken if f not in latest]:
                    del taken[f]
            taken.update(dict.fromkeys(frames, now))
        return frames

    def caught_up() -> Any:  # a new owner's (or heir's) catch-up (``catch_up_frames``): sent again now
        before = core.counters["catch_up_frames"]
        out = catch_up()
        if core.counters["catch_up_frames"] != before:
            now = time.monotonic()
            latency.note_catch_up(name, [(f, taken.get(f, now)) for f in core._latest.values()], now)
            stepped.extend(core._latest.values())
        return out

    def flushed(now: float) -> None:  # the step's bundles put: its frames are on their way
        flush_down(now)
        if stepped:
            latency.note_many("down", "put", name, stepped, time.monotonic())
            stepped.clear()

    handlers = node._handlers  # the adapter's output handlers (built once, on first use)
    to_vehicle = handlers[ToVehicle]

    def forwarded(o: Any) -> None:
        latency.note("up", "got", name, envelope[0], time.monotonic())
        to_vehicle(o)

    node.core.on_envelope, node.vehicle.recv, handlers[ToVehicle] = opened, received, forwarded
    node.core._catch_up = caught_up
    node.flush_down = flushed
    node.rt.inbox.put = arrived


def wake_on_uplink(node: Any, woken: "collections.deque[Any]", wake: threading.Event | None = None) -> None:
    """``node`` goes into ``woken`` when a GS's frame reaches its inbox, and ``wake`` is set (Zenoh's
    thread: one append, one set)."""
    put = node.rt.inbox.put

    def woke(kind: str, peer: str, data: Any) -> None:
        put(kind, peer, data)
        if kind == "up":
            woken.append(node)
            if wake is not None:
                wake.set()

    node.rt.inbox.put = woke


def serve_woken(woken: "collections.deque[Any]", after: Any = None) -> None:
    """Hand each drone woken by a GS's frame its inputs (``WAKE_EVERY``), then ``after(drone)``."""
    while woken:
        n = woken.popleft()
        n.take_inputs()
        if after is not None:
            after(n)


def note_station_latency(station: Any, latency: LatencyLog) -> None:
    """The same on a GS: each envelope its core hands the adapter to put (GS -> vehicle, sent), timed
    when the core's timer pass that made it began, before any frame of the pass was sealed (the bare
    half notes its frames at its pass's start likewise); each vehicle frame out of an envelope
    (``FrameUp``) (vehicle -> GS, got)."""
    from gs.actions import FrameUp
    from zdrone.core.outputs import Put

    handlers = station._handlers
    put, frame_up = handlers[Put], handlers[FrameUp]
    core, do = station.core, station._do
    timer = core.handle_timer
    began: list[float | None] = [None]

    def timed(now: float, wall: float | None = None) -> Any:
        began[0] = time.monotonic()  # before the pass seals anything
        return timer(now, wall)

    def done(actions: Any) -> None:
        try:
            do(actions)
        finally:
            began[0] = None  # what comes another way is timed as it is put

    core.handle_timer, station._do = timed, done

    def sent(a: Any) -> None:
        t = began[0]
        latency.note("up", "sent", a.peer, a.payload, time.monotonic() if t is None else t)
        put(a)

    # vehicle -> GS: a frame "arrived" when the bundle it came in reached the GS's inbox (its pump's hand)
    bundles: dict[bytes, float] = {}
    arrival: list[float | None] = [None]
    inbox_put, on_inbox = station.rx.put, station._on_inbox

    def came(kind: str, drone: str, data: Any) -> None:  # the pump's thread
        if kind == "down" and latency.on:
            if len(bundles) > 5_000:  # bundles the inbox refused are never taken (counted by the inbox)
                bundles.clear()
            bundles[data] = time.monotonic()
        inbox_put(kind, drone, data)

    def taken(kind: str, drone: str, data: Any, now: float) -> None:  # the GS's loop
        arrival[0] = bundles.pop(data, None) if kind == "down" else None
        try:
            on_inbox(kind, drone, data, now)
        finally:
            arrival[0] = None

    def got(a: Any) -> None:
        latency.note("down", "got", a.drone, a.frame, time.monotonic())
        if arrival[0] is not None:
            latency.note("down", "arrived", a.drone, a.frame, arrival[0])
        frame_up(a)

    handlers[Put], handlers[FrameUp] = sent, got
    station.rx.put, station._on_inbox = came, taken


def _host_drones(args: argparse.Namespace) -> int:
    from zdrone.core.authority import HaDrop
    from zdrone.core.geometry import offset
    from zdrone.core.reference import HOME
    from zdrone.core.tbm import LinkState
    from zdrone.fleet.files import load_fleet
    from zdrone.nodes.drone import DroneNode, DroneOptions
    from zdrone.sil.coverage import CoverageGate
    from zdrone.vehicle.inproc import InProcessVehicle

    routers = args.router.split(",")
    fleet = load_fleet(args.fleet)
    nodes = []
    for i in range(args.part, args.k, args.parts):  # this host's share of the fleet (the i-th drone spread as in one host)
        name = f"d{i + 1}"
        home = HOME if not args.corridor or corridor_eastbound(i) else offset(HOME, 0.0, args.corridor)
        router = routers[i % len(routers)] if args.drone_router == "spread" else args.router
        opts = DroneOptions(drone=name, fleet=args.fleet, router=router, vehicle="inproc", gate=CoverageGate(fleet),
                            events=str(Path(args.out) / f"{name}.jsonl"), handover_timeout=max(1.5, 5.0 / args.speedup),
                            status_period=2.0)
        nodes.append(DroneNode(opts, vehicle=InProcessVehicle(home, sysid=fleet.nodes[name].sysid, speedup=args.speedup, seed=i)))
    arrivals = FrameGaps()  # a GS's frames at each drone's Zenoh callback (where a silence begins)
    deliveries = {n.name: DeliveryCounter(n.rt.inbox, arrivals, n.name) for n in nodes}
    latency = LatencyLog() if args.latency else None  # ``bench overhead``: noted from the take-off on
    if latency is not None:
        for n in nodes:
            note_drone_latency(n, latency)
    woken: collections.deque[Any] = collections.deque()
    wake = threading.Event()  # a GS's frame came for one of the drones (``woken``)
    for n in nodes:
        wake_on_uplink(n, woken, wake)
    router_zids = {n.name: _router_zid(n.rt.session) for n in nodes}
    gss = {n.name: set(n.fleet.nodes[n.name].authorized_gs) for n in nodes}
    for n in nodes:  # pre-flight hold: not ready to arm (SYS_STATUS says so; the GS waits) until released
        n.vehicle.sim.ready_after = HOLD_READY_AFTER
    freeze_start_up()  # as every node does (``NodeRuntime.serve``): a full collection of 300 drones took 0.64 s
    print(f"drones host: {len(nodes)} drones ready", flush=True)
    stop = [False]
    signal.signal(signal.SIGTERM, lambda *_: stop.__setitem__(0, True))
    mended: list[float | None] = [None]
    jam: list[bool | None] = [None]  # --jam: SIGUSR1 cuts that drone's radio (every GS out of reach), SIGUSR2 mends it
    if args.jam:
        signal.signal(signal.SIGUSR1, lambda *_: jam.__setitem__(0, True))
        signal.signal(signal.SIGUSR2, lambda *_: jam.__setitem__(0, False))
    armed_seen = [False] * len(nodes)
    landed_at: float | None = None
    counted_at: float | None = None  # the GSs stopped commanding and counted (``COUNTED``)
    # where the host's time goes when a pass is slow: a pass over every drone, one drone's step, its
    # uplink subscriptions (declared when a GS's coverage is entered: Zenoh calls in the loop)
    slow: dict[str, Any] = {"worst_pass_s": 0.0, "passes_over_0_5s": 0, "worst_step_s": 0.0, "worst_step_node": None}
    # which call a slow step waits in (``ZDRONE_STALL_NATIVE=dir``: with py-spy's native stacks there)
    watch = StallWatch(native_dir=os.environ.get("ZDRONE_STALL_NATIVE"))
    # a slow pass: the loop on a CPU, waiting for one, or asleep (not in ``bench overhead``, whose bare
    # half has no such clock: two reads of /proc a pass cost as much as a drone's step at K = 1)
    clock = PassClock(on=not args.latency)
    worst_owner_silence = [0.0] * len(nodes)
    worst_at: list[dict[str, Any] | None] = [None] * len(nodes)
    owner_lost = [0] * len(nodes)
    # the drone's own judgement: its owner's link reported DEGRADED or LOST in flight (times it went so)
    owner_judged_silent, owner_silent_now = [0] * len(nodes), [False] * len(nodes)
    t_ready = time.monotonic()
    t0, cpu0 = t_ready, time.process_time()
    deadline = t_ready + args.hold + args.duration
    released: str | None = None
    baseline: dict[str, dict[str, int]] = {}
    loops = 0
    # each drone stepped at its own next deadline or when a GS's frame comes (``zdrone.bench.stepping``)
    sched = StepSchedule(len(nodes), time.monotonic())
    index = {id(n): i for i, n in enumerate(nodes)}
    steps_at_t0 = 0
    next_check = 0.0  # the host's own checks (take-off, landing, --jam), every PASS_S

    def served(n: Any) -> None:  # its inputs handled: what it answers goes now, its step comes forward
        now = time.monotonic()
        n.flush_down(now)
        sched.bring_forward(index[id(n)], n.next_deadline(now))

    try:
        while not stop[0] and time.monotonic() < deadline:
            wake.wait(max(0.0, min(sched.next_due(), next_check) - time.monotonic()))
            wake.clear()
            if time.monotonic() >= next_check:
                next_check = time.monotonic() + PASS_S
                # (a corridor: each drone linked with its owner; its links follow it from there)
                if released is None and (all((n.machine.owner is not None and n.machine.owner in n.core.links)
                                             if args.corridor else gss[n.name] <= set(n.core.links) for n in nodes)
                                         or time.monotonic() - t_ready >= args.hold):
                    released = "keys" if time.monotonic() - t_ready < args.hold else "hold timeout"
                    for i, n in enumerate(nodes):
                        n.vehicle.sim.ready_after = 0.0
                        sched.bring_forward(i, time.monotonic())
                    t0, cpu0 = time.monotonic(), time.process_time()
                    deadline = t0 + args.duration
                    steps_at_t0 = sched.steps
                    sched.lateness = StepLateness()  # from the take-off, as the steps
                    baseline = {d: c.snapshot() for d, c in deliveries.items()}
                    if latency is not None:
                        latency.start(t0)
                    print(f"drones host: take-off ({released}, {t0 - t_ready:.1f} s on the ground)", flush=True)
                if jam[0] is not None:
                    gate = next(n.gate for n in nodes if n.name == args.jam)
                    if gate.jammed != jam[0]:
                        gate.jammed = jam[0]
                        mended[0] = None if jam[0] else time.monotonic()
                        print(f"drones host: {args.jam} {'out of' if jam[0] else 'back in'} reach at {time.time():.3f}",
                              flush=True)
                if landed_at is None and all(armed_seen) and all(not n.vehicle.armed for n in nodes) and (
                        not args.jam or mended[0] is not None and time.monotonic() > mended[0] + 10.0):
                    # (--jam: not before the cut-off drone has been back in reach for 10 s)
                    landed_at = time.monotonic()  # the GSs count what they sent now; what is on its way still arrives
                    print("drones host: all landed", flush=True)
                if landed_at is not None:
                    # (several hosts: the GSs count once every host has landed, so wait for them as long as a flight)
                    counted = len(list(Path(args.out).glob(COUNTED.replace(".", "*.", 1))))
                    if counted_at is None and (counted >= args.station_hosts or time.monotonic() - landed_at
                                               >= (COUNTED_WAIT_S if args.parts == 1 else max(COUNTED_WAIT_S, args.duration))):
                        counted_at = time.monotonic()
                    if counted_at is not None and time.monotonic() - counted_at >= LANDED_DRAIN_S:
                        break
            pass_start = time.monotonic()
            clock.begin()
            serve_woken(woken, served)
            for j, i in enumerate(sched.take(pass_start)):
                if j and j % WAKE_EVERY == 0:
                    serve_woken(woken, served)
                n = nodes[i]
                step_start = time.monotonic()
                sched.started(i, step_start)
                watch.begin(n.name)
                n.step(0.0)
                watch.end()
                done = time.monotonic()
                sched.set(i, max(n.next_deadline(done), done + MIN_STEP_GAP_S))
                step_s = done - step_start
                if step_s > slow["worst_step_s"]:
                    slow["worst_step_s"], slow["worst_step_node"] = round(step_s, 3), n.name
                m = n.machine
                if n.vehicle.armed:
                    armed_seen[i] = True
                    link = n.core.links.get(m.owner or "")
                    if link is not None:
                        now = time.monotonic()
                        silence = link.tbm.since_last(now)
                        if silence > worst_owner_silence[i]:  # when, and under which epoch (a hand-over's?)
                            worst_owner_silence[i] = silence
                            worst_at[i] = {"after_takeoff_s": round(now - t0, 2), "owner": m.owner, "epoch": m.epoch,
                                           "state": m.state.value}
                        if link.tbm.state(now) is LinkState.LOST:
                            owner_lost[i] += 1
                    judged = m.links.get(m.owner or "")
                    silent = judged is not None and judged.state is not LinkState.OK
                    owner_judged_silent[i] += silent and not owner_silent_now[i]
                    owner_silent_now[i] = silent
            pass_s = time.monotonic() - pass_start
            clock.end(pass_start - t0)
            slow["worst_pass_s"] = max(slow["worst_pass_s"], round(pass_s, 3))
            slow["passes_over_0_5s"] += pass_s > 0.5
        loops = (sched.steps - steps_at_t0) / max(1, len(nodes))  # steps a drone, from the take-off
        flight_s, cpu_s = time.monotonic() - t0, time.process_time() - cpu0
        results = {}
        for i, n in enumerate(nodes):
            m = n.machine
            results[n.name] = {
                "handovers": max(0, m.epoch - 1),  # epoch 1 at pairing, +1 per hand-over
                "links_peak": n.core.links_peak, "links_closed": n.core.counters["link_closed"],
                "owners": [o for _, o, _ in m.history], "epochs": [[o, e] for _, o, e in m.history],
                "state": m.state.value, "flew": armed_seen[i],
                "landed": not n.vehicle.armed and n.vehicle.landed_state == 1,
                "forwarded": dict(n.core.forwarded), "forwarded_epochs": dict(n.core.forwarded_epochs),
                "not_authority": m.drops[HaDrop.NOT_AUTHORITY], "in_failsafe": m.drops[HaDrop.FAILSAFE],
                "worst_owner_silence_s": round(worst_owner_silence[i], 3), "worst_owner_silence_at": worst_at[i],
                "owner_lost_samples": owner_lost[i], "owner_judged_silent": owner_judged_silent[i],
                "security_drops": {gs: {r.value: c for r, c in ln.drops.items() if c} for gs, ln in n.core.links.items()},
                # the testbed's radio: frames it stopped, out of a GS's coverage ("up:A": A's to the drone)
                "radio_blocked": dict(n.gate.blocked) if n.gate is not None else {}}
        if latency is not None:
            latency.dump(Path(args.out, f"latency-{drones_file(args.part, args.parts)}"))
        Path(args.out, f"gaps-{drones_file(args.part, args.parts)}").write_text(
            json.dumps({"t0": t0, **arrivals.report()}))
        Path(args.out, drones_file(args.part, args.parts)).write_text(json.dumps({
            "results": results, "loops": loops, "step_late": sched.lateness.report(), "timed_out": time.monotonic() >= deadline, "flight_s": flight_s,
            "cpu_s": cpu_s, "memory_mb": _memory_mb("self"), "ground_s": round(t0 - t_ready, 1), "released": released, "router_zid": router_zids,
            "slow": {**slow, "listen_worst_s": round(max(n.listen_worst_s for n in nodes), 3),
                     "listen_total_s": round(sum(n.listen_total_s for n in nodes), 2),
                     **watch.report(), "slow_passes": clock.slow}, "delivered": {d: c.since(baseline.get(d, {})) for d, c in deliveries.items()}}))
    finally:
        watch.close()
        for n in nodes:
            n.close()
    return 0


def corridor_eastbound(i: int) -> bool:
    """A corridor's drone ``d{i+1}`` flies east from A (even ``i``) or west from the last GS (odd)."""
    return i % 2 == 0


def _host_stations(args: argparse.Namespace) -> int:
    from gs.planner import corridor_mission, shuttle_mission
    from gs.station import GroundStation, StationOptions
    from zdrone.core.geometry import offset
    from zdrone.core.reference import HOME

    deliveries: dict[str, DeliveryCounter] = {}
    baseline: dict[str, dict[str, int]] = {}
    # the drones took off (from the bench, at once): count deliveries from now on
    loops = LoopTimer()  # where a GS's slow pass went (its heartbeats to every drone wait for it)

    latency = LatencyLog() if args.latency else None  # ``bench overhead``: noted from the take-off on

    def took_off(*_: Any) -> None:
        baseline.update({g: c.snapshot() for g, c in deliveries.items()})
        loops.mark()
        if latency is not None:
            latency.start(time.monotonic())

    signal.signal(signal.SIGUSR1, took_off)
    if args.inbox_senders:  # testbed what-if: the GS inbox's bound on (kind, sender) queues
        from zdrone.net import inbox

        inbox.MAX_SENDERS = args.inbox_senders
    names = [chr(ord("A") + i) for i in range(args.stations)]
    hosted = set(args.only.split(",")) if args.only else set(names)  # this host's GSs (the others: own processes)
    suffix = f"-{args.only.replace(',', '')}" if args.only else ""  # its result files' names
    routers = args.router.split(",")  # one for all, or one per station in order
    mission = shuttle_mission(CROSSINGS, far_east_m=500.0 * (args.stations - 1) - 60.0)
    first, last = names[0], names[-1]
    pair: dict[str, frozenset[str] | None] = {first: None}
    missions: dict[str, dict[str, Any]] = {}
    if args.corridor:  # each way's first GS pairs its drones and flies their missions; the others only link
        west_end = offset(HOME, 0.0, args.corridor)
        drones = [f"d{i + 1}" for i in range(args.k)]
        east = frozenset(d for i, d in enumerate(drones) if corridor_eastbound(i))
        pair = {first: east, last: frozenset(drones) - east}
        to_east, to_west = (corridor_mission(HOME, west_end, speed=args.corridor_speed, back=args.round_trip),
                            corridor_mission(west_end, HOME, speed=args.corridor_speed, back=args.round_trip))
        missions = {first: {d: to_east for d in east}, last: {d: to_west for d in pair[last]}}  # type: ignore[union-attr]
    stations = [GroundStation(StationOptions(gs=g, fleet=args.fleet, router=routers[i % len(routers)], pair=g in pair,
                                             pair_drones=pair.get(g), missions=missions.get(g),
                                             mission=mission if g == "A" and not args.corridor else None,
                                             command_rate=1.0, events=None)) for i, g in enumerate(names) if g in hosted]
    deliveries.update({st.name: DeliveryCounter(st.rt.inbox) for st in stations})
    puts = FrameGaps()  # each GS's frames to each drone as it puts them (where a silence begins)
    for st in stations:
        put_on_lane = st.rt._put_on_lane

        def noted(uplink: str, payload: bytes, gs: str = st.name, put_on_lane: Any = put_on_lane) -> None:
            drone, now = uplink.split("/")[1], time.monotonic()  # keyexprs.up: zdrone/<drone>/up/<gs>
            puts.note(gs, drone, now)
            if latency is not None:  # GS -> vehicle: on its lane, after the GS's pass and its pacing
                latency.note("up", "put", drone, payload, now)
            put_on_lane(uplink, payload)

        st.rt._put_on_lane = noted
    if latency is not None:
        for st in stations:
            note_station_latency(st, latency)
    router_zids = {st.name: _router_zid(st.rt.session) for st in stations}
    freeze_start_up()  # as every node does (``NodeRuntime.serve``)
    gcs = GcClock()
    for st in stations:
        loops.watch(st)
    started = time.time()  # when each GS is linked with every drone it serves, from here (``--restart-gs``)
    relinked: dict[str, float | None] = {st.name: None for st in stations}
    print(f"stations host: {len(stations)} stations ready", flush=True)
    # one thread per station: a GS's blocking backhaul query must not wait on another GS's loop
    threads = [threading.Thread(target=st.run, daemon=True) for st in stations]
    for t in threads:
        t.start()
    # a plain flag: a handler setting an event the main thread is waiting on can deadlock it
    # (zdrone.net.shutdown); ``pause`` is never set
    stop, pause, landed = [False], threading.Event(), [False]
    signal.signal(signal.SIGTERM, lambda *_: stop.__setitem__(0, True))
    signal.signal(signal.SIGUSR2, lambda *_: landed.__setitem__(0, True))  # every vehicle has landed

    def count_sent() -> tuple[dict[str, Any], dict[str, Any]]:
        return ({st.name: {d: st.commands_sent(d) for d in st.drones} for st in stations},
                {st.name: {d: {str(e): c for e, c in st.core.sessions[d].commands_sent.items()} for d in st.drones}
                 for st in stations})  # per epoch the GS believed it commanded in (bench revoke's attribution)

    counted: tuple[dict[str, Any], dict[str, Any]] | None = None
    doomed = next((st for st in stations if st.name == args.kill_owner), None)
    owned_since: float | None = None
    while not stop[0]:
        pause.wait(0.2)
        for st in stations:  # a GS linked with every drone it serves (its link confirmed by the drone): when, once
            if relinked[st.name] is None and all(st.core.sessions[d].link is not None for d in st.drones):
                relinked[st.name] = time.time()
                print(f"stations host: {st.name} linked with all {len(st.drones)} drones "
                      f"{relinked[st.name] - started:.2f} s after its start", flush=True)
        if doomed is not None:  # ``--kill-owner``: that GS dies once it has owned a drone in the air that long
            flying = [d for d, v in doomed.core.sessions.items() if v.owner == doomed.name and v.armed and not v.stale]
            owned_since = (owned_since or time.monotonic()) if flying else None
            if owned_since is not None and time.monotonic() - owned_since >= args.kill_after:
                print(f"stations host: GS {doomed.name} killed while it owned {', '.join(flying)} at {time.time():.3f}",
                      flush=True)
                Path(args.out, "killed.json").write_text(json.dumps({"gs": doomed.name, "owned": flying,
                                                                      "t": time.time()}))
                doomed.kill()
                doomed = None
        if landed[0] and counted is None:
            for st in stations:  # no command after the count: every command counted is one the drones can forward
                st.core.opts = replace(st.core.opts, command_rate=0.0)
            pause.wait(0.3)  # a tick that began before the freeze has sent what it sends
            counted = count_sent()  # what was sent while the drones were still there to forward it
            Path(args.out, COUNTED.replace(".", f"{suffix}.", 1)).touch()
    sent, sent_epochs = counted or count_sent()
    counters = {st.name: {**dict(st.counters), **{f"inbox:{k}": v for k, v in st.rx.stats().items()}} for st in stations}
    delivered = {g: c.since(baseline.get(g, {})) for g, c in deliveries.items()}
    for st in stations:
        if not st.killed:
            st.stop()
    for t in threads:
        t.join(15)
    Path(args.out, f"gaps-stations{suffix}.json").write_text(json.dumps(puts.report()))
    if latency is not None:
        latency.dump(Path(args.out, f"latency-stations{suffix}.json"))
    Path(args.out, f"stations{suffix}.json").write_text(json.dumps({"commands_sent": sent, "commands_sent_epochs": sent_epochs,
                                                           "linked_all": relinked,
                                                           "router_zid": router_zids,
                                                           "delivered": delivered, "counters": counters,
                                                           "gc": gcs.report(), "loops": loops.report()}))
    return 0

