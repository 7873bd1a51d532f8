"""TESTBED: ``zdrone demo`` starts router, simulator, drone and ground stations as separate OS
processes, flies the reference flight (or an attack / fault scenario), shows it live, writes the
event logs and a summary, and shuts everything down.

This module is the orchestration (``Demo``): the moments of the flight as the logs show them, the
attackers and faults a scenario ties to each, the end of the run. ``Demo`` runs its processes as
``zdrone.sil.children`` says (started in the run's folder, restarted, stopped in order) and its sites
as ``zdrone.sil.sitelinks`` says (a router per site, the radio and backhaul links). The rest of the
testbed is in rooms of its own, and importable without a process:

- ``zdrone.sil.moments``: the moments of a flight (triggers) and those a fault can move to;
- ``zdrone.sil.scenarios``: ``SCENARIO_TABLE``, one row a scenario (its attackers, faults, predicate);
- ``zdrone.sil.verdicts``: ``Outcome`` and the predicates every scenario builds on (``flight_unaffected``,
  ``safety_invariants``, ...); each scenario's own in ``attack_verdicts``, ``fault_verdicts``, ``operator_verdicts``;
- ``zdrone.sil.summary``: the summary and verdict of a run, from its logs (``summarize``);
- ``zdrone.sil.liveview``: the live view.

Their public names are also importable from here.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from zdrone.core.records import (AnyRecord, DroneStatus, Drop, LinkStateChanged, MissionFailed, MissionStarted,
                                 Subscribe, Unsubscribe, fields_of)
from zdrone.core.reference import DEFAULT_NODES
from zdrone.fleet.files import init_fleet
from zdrone.net.eventlog import EventLog, LogTail
from zdrone.sil import procs
from zdrone.sil.attack_verdicts import escrow_left_standing, insider_takeovers
from zdrone.sil.children import PY, Child, ChildProcesses, _exit_text
from zdrone.sil.liveview import LiveView, describe
from zdrone.sil.moments import (GSS_STARTED, AIRBORNE, BEFORE_DRONE, BEFORE_GS_A, DRONE_RESTARTED, FAILSAFE_FIRED, HANDOVERS_DONE,
                                HANDOVER_STARTED, MISSION_STARTED, MOMENTS, REGION_ENTERED, RETURNING, TRIGGERS)
from zdrone.sil.netns import NetnsTopology
from zdrone.sil.ports import free_port
from zdrone.sil.radiolink import SiteCoverage, SwitchedLink, TruthReceiver
from zdrone.sil.scenarios import (ATTACK_SCENARIOS, LINK_DOWN, LINK_UP, RESTART, REVOKE, REVOKE_BEHIND_CUT, ROTATE,
                                  SCENARIOS, SCENARIO_BY_NAME, SCENARIO_SITES, SCENARIO_TABLE, SCENARIO_TLS, Fault,
                                  RogueSpec, Scenario, scenario_help)
from zdrone.sil.sitelinks import SiteLinks
from zdrone.sil.summary import (NEAR_DELIVERY_M, RunFacts, RunLogs, authority_link, follow, repair_after_restart,
                                summarize, watch, watch_state)
from zdrone.sil.verdicts import (DELIVERY_RADIUS_M, FAILSAFE_LATE_MS, SILENT_AUTHORITY_S, Outcome, active_faults,
                                 delivered, delivered_at, fault_over_check, flight_completes, flight_unaffected,
                                 return_time, safety_invariants)

__all__ = [  # the orchestration, and the testbed's public names its callers import from here
    "Child", "Demo", "DemoOptions", "EXTERNAL_BOOT_S", "GCS_KEYS", "NEAR_DELIVERY_M", "run_demo",
    "AIRBORNE", "BEFORE_DRONE", "BEFORE_GS_A", "DRONE_RESTARTED", "FAILSAFE_FIRED", "HANDOVER_STARTED",
    "HANDOVERS_DONE", "MISSION_STARTED", "MOMENTS", "REGION_ENTERED", "RETURNING", "TRIGGERS",
    "ATTACK_SCENARIOS", "LINK_DOWN", "LINK_UP", "RESTART", "SCENARIO_BY_NAME", "SCENARIO_SITES", "SCENARIO_TABLE",
    "SCENARIO_TLS", "SCENARIOS", "Fault", "RogueSpec", "Scenario", "scenario_help",
    "DELIVERY_RADIUS_M", "FAILSAFE_LATE_MS", "SILENT_AUTHORITY_S", "Outcome", "active_faults", "delivered",
    "delivered_at", "escrow_left_standing", "fault_over_check", "flight_completes", "flight_unaffected",
    "insider_takeovers", "return_time", "safety_invariants",
    "RunFacts", "RunLogs", "authority_link", "follow", "repair_after_restart", "summarize", "watch", "watch_state",
    "LiveView", "free_port",
]

#: GS A's GCS application key file in the run folder (``Scenario.app_signing``), mode 0600.
GCS_KEYS = "gcs-keys"

#: The deadline of a flight with an autopilot already running (``--vehicle``) allows for its start-up.
EXTERNAL_BOOT_S = 60.0

#: How long a router started to take over from a running one waits for its port (``Demo.take_over``).
TAKE_OVER_S = 10.0


@dataclass
class DemoOptions:
    out: Path | None = None
    scenario: str = "nominal"
    speedup: float = 2.0
    live: bool | None = None  # None: only when stdout is a terminal
    timeout: float | None = None
    command_rate: float = 5.0
    report: bool = True
    # for the benches
    cipher: str = "zdrone"
    paper_heartbeat: bool = False
    tap: bool = False
    quiet: bool = False
    max_wall: float | None = None  # stop measuring after this many wall seconds (not a failure)
    mission: str = "reference"
    autopilot: str = "px4"  # personality of the built-in simulator
    radio: tuple[str, ...] = ()  # the drone's --sil-loss/--sil-bursts/--sil-delay-ms/--sil-jitter-ms options
    spec: "Scenario | None" = None  # a scenario made on the fly (bench chaos) instead of ``scenario``
    moment: str | None = None  # the scenario's fault moved to this moment (``MOMENTS``); None: its own
    sites: bool = False  # a router per GS site (two, meshed) instead of one
    tls: bool = False  # one router, mutual TLS only (a fleet CA and certificates)
    vehicle: str | None = None  # an autopilot already running (no simulator started)
    ready_after: float | None = None  # the built-in simulator's start-up, simulated s (None: its short default)
    netns: bool = False  # with sites: each site and the drone in their own network namespace (root)
    fc_signing: str = "prefer"  # the drone's --fc-signing (require | prefer | off)
    view: int | None = None  # serve the live web view (``zdrone view``) on this loopback port


@dataclass
class Demo(ChildProcesses, SiteLinks):
    opts: DemoOptions
    out: Path
    children: dict[str, Child] = field(default_factory=dict)
    t0: float = field(default_factory=time.monotonic)
    notes: list[str] = field(default_factory=list)
    progress: dict[str, Any] = field(default_factory=dict)
    router: str = ""
    gcs_port: int | None = None
    gcs_port_b: int | None = None  # GS B's gateway, for the operators
    gcs_port_x: int | None = None  # GS X's gateway (``consent-bound``)
    telem2_port: int | None = None  # the simulator's TELEM2 (UDP), when the scenario wants one
    vehicle_port: int | None = None  # the UDP port the companion listens on for its autopilot (``vehicle_udpin``)
    fired: set[str] = field(default_factory=set)
    fired_at: dict[str, float] = field(default_factory=dict)  # trigger -> time of day it came
    fault_log: list[dict[str, Any]] = field(default_factory=list)  # each fault injected: t, target, text, ends
    pending_go: set[str] = field(default_factory=set)
    restarting: dict[str, tuple[str, int]] = field(default_factory=dict)  # restarted child -> (ready line, count before)
    scheduled: list[tuple[float, Fault]] = field(default_factory=list)  # (monotonic due time, fault)
    sites: dict[str, dict[str, Any]] = field(default_factory=dict)  # with --sites: site -> endpoint, GSs
    links: dict[str, SwitchedLink] = field(default_factory=dict)  # with --sites: radio per site, backhaul per pair
    coverage: "SiteCoverage | None" = None
    truth: "TruthReceiver | None" = None
    radio_log: "EventLog | None" = None
    site_of_endpoint: dict[str, str] = field(default_factory=dict)  # the drone's path endpoint -> site
    netns: "NetnsTopology | None" = None  # with --netns: the namespaces of the sites and the drone
    _a_tail: "LogTail | None" = None  # GS A's log, read as it grows until the mission starts

    @property
    def spec(self) -> Scenario:
        spec = self.opts.spec or SCENARIO_BY_NAME[self.opts.scenario]
        return spec.at_moment(self.opts.moment) if self.opts.moment else spec

    # ----------------------------------------------------------------- running
    def start_core(self) -> None:
        """Fleet, router, simulator and drone node (every scenario and bench starts with these)."""
        o = self.opts
        rport, sport = free_port(socket.SOCK_STREAM), free_port(socket.SOCK_DGRAM)
        self.router = f"tcp/127.0.0.1:{rport}"
        if o.sites or self.spec.sites:  # a router per site, meshed; GS A (and X) at site 1, B at site 2
            self._start_sites(rport)
        else:
            tls = o.tls or self.spec.tls
            if tls:
                self.router = f"tls/127.0.0.1:{rport}"
            init_fleet(self.out / "fleet", tls=tls, nodes_spec=self._nodes_spec(), **self._lease())
            self._export_bundles(["router"])
            r = self.start("router", self._z() + ["router", "-c", "bundles/router/router/router.json5", "--listen", self.router]
                           + (["--tap", "tap.json"] if o.tap else []))
            self.wait_line(r, "listening", 20)
        telem2: list[str] = []
        if self.spec.telem2 and o.vehicle is None:
            self.telem2_port = free_port(socket.SOCK_DGRAM)
            telem2 = ["--telem2", f"udpin:127.0.0.1:{self.telem2_port}"]
        if o.vehicle is not None:
            vehicle = o.vehicle
        elif self.spec.vehicle_udpin:  # the companion listens, the simulator (either personality) sends to it
            self.vehicle_port = free_port(socket.SOCK_DGRAM)
            sim = self.start("sim", self._z() + ["sim", "--autopilot", o.autopilot, "--mavlink",
                                                 f"udpout:127.0.0.1:{self.vehicle_port}", "--speedup", str(o.speedup)]
                             + self._truth_args() + telem2 + self._ready_args(), ns=self._ns())
            self.wait_line(sim, "zdrone sim:", 20)
            vehicle = f"udpin:127.0.0.1:{self.vehicle_port}"
        elif o.autopilot == "ardupilot":  # like ArduPilot SITL: a TCP server that boots on the first client
            tport = free_port(socket.SOCK_STREAM)
            sim = self.start("sim", self._z() + ["sim", "--autopilot", "ardupilot", "--mavlink", f"tcpin:127.0.0.1:{tport}",
                                                 "--speedup", str(o.speedup)] + self._truth_args() + telem2
                             + self._ready_args(), ns=self._ns())
            self.wait_line(sim, "zdrone sim:", 20)
            vehicle = f"tcp:127.0.0.1:{tport}"
        else:
            sim = self.start("sim", self._z() + ["sim", "--autopilot", "px4", "--mavlink", f"udpin:127.0.0.1:{sport}",
                                                 "--speedup", str(o.speedup)] + self._truth_args() + telem2
                             + self._ready_args(), ns=self._ns())
            self.wait_line(sim, "zdrone sim:", 20)
            self._wait_coverage()
            vehicle = f"udpout:127.0.0.1:{sport}"
        # Timers are wall-clock while the simulator may run faster: scale the hand-over timeout so that
        # a failed hand-over is still noticed while the vehicle is inside the overlap (5 s at 1x).
        ho_timeout = max(1.5, 5.0 / o.speedup)
        coverage = [] if self.links else ["--sil-coverage"]  # with sites: the radio links are the coverage
        self._fire(BEFORE_DRONE, None)
        for r in self.spec.rogues:  # attackers racing the companion's start
            if r.launch == BEFORE_DRONE:
                self.wait_line(self.children[f"rogue-{r.mode}"], "rogue: ready", 30)
        trust: list[str] = []
        if o.fc_signing == "off":  # an unsigned link's positions grant no authority unless opted in (issue 29)
            trust = ["--trust-unsigned-position"]
            self.notes.append("--fc-signing off: the drone trusts unsigned positions (--trust-unsigned-position): "
                              "any process that can write into its vehicle link can move its authority")
        drone = self.start("drone", self._zn() + ["drone", "--id", "d1", *self._common(), "--vehicle", vehicle,
                                                  *coverage, "--events", "drone.jsonl", "--handover-timeout",
                                                  str(ho_timeout), "--fc-signing", o.fc_signing, *trust,
                                                  *self._bench_extra(),
                                                  *self.spec.radio, *o.radio],
                           ns=self._ns())
        self.wait_line(drone, "ready", 40)

    def _ready_args(self) -> list[str]:
        """The simulator's start-up (``--ready-after``), if one was given."""
        return [] if self.opts.ready_after is None else ["--ready-after", f"{self.opts.ready_after:g}"]

    def _nodes_spec(self) -> list[tuple[str, str, int, Any, list[str]]] | None:
        """The fleet's nodes: the reference fleet, with X authorized for d1 if the scenario says so."""
        if not self.spec.x_authorized:
            return None
        return [(n, r, sid, c, [*a, "X"] if n == "d1" else a) for n, r, sid, c, a in DEFAULT_NODES]

    def start_gs(self, gs: str, *extra: str) -> Child:
        child = self.start(f"gs{gs}", self._zn() + ["gs", "--id", gs, *self._common(gs), "--events", f"{gs}.jsonl", *extra],
                           ns=self._ns(gs))
        self.wait_line(child, f"zdrone gs {gs}", 20)
        return child

    def start_rogue(self, r: RogueSpec, duration: float | None = None) -> Child:
        args = ["-m", "zdrone.sil.rogue", "--mode", r.mode, "--fleet", "fleet", "--router", self._common(r.beside)[-1],
                "--duration", f"{duration if duration is not None else r.duration(self.opts.speedup):.2f}",
                "--events", "rogue.jsonl"]
        args += ["--wait-go"] if r.go else []
        args += ["--rate", str(r.rate)] if r.rate else []
        args += ["--gcs-port", str(self.gcs_port)] if self.gcs_port else []
        args += ["--fc-port", str(self.telem2_port)] if self.telem2_port else []
        args += ["--gcs-port-b", str(self.gcs_port_b)] if self.gcs_port_b else []
        args += ["--gcs-keys", GCS_KEYS] if self.spec.app_signing else []
        args += ["--vehicle-port", str(self.vehicle_port)] if self.vehicle_port else []
        return self.start(f"rogue-{r.mode}", args + list(r.args), ns=self._ns(r.beside))  # at that GS's site

    def run(self) -> dict[str, Any]:
        """Fly the run; whatever ends it (a child that fails to start, an exception, a signal turned
        into one) stops every process it started before the exception goes on."""
        try:
            return self._run()
        except BaseException as exc:  # a signal asks for a quick end: 1.5 s per group before SIGKILL, all
            # gone within 5 s of the signal (a loaded host's slow exits included)
            self.shutdown(timeout=1.5 if isinstance(exc, (KeyboardInterrupt, procs.Terminated)) else 10.0)
            raise

    def start_view(self, port: int) -> Child:
        """``zdrone view`` as the fleet's viewer V, from its bundle, on loopback ``port`` (the run's
        folder: its report is linked once written)."""
        child = self.start("view", self._z() + ["view", "--fleet", "bundles/V", "--router", self.router, "--port",
                                                str(port), "--run", "."], ns=self._ns("A") if self.netns else None)
        self.wait_line(child, "zdrone view:", 20)
        self.notes.append(f"live view: http://127.0.0.1:{port}/")
        return child

    def _run(self) -> dict[str, Any]:
        o, spec = self.opts, self.spec
        self.start_core()
        if o.view is not None:
            self.start_view(o.view)
        gs_extra = ["--command-rate", str(o.command_rate), *self._bench_extra()] + (["--paper-heartbeat"] if o.paper_heartbeat else [])
        b_extra = list(gs_extra)
        if spec.operators or spec.app_signing or spec.consent_ops:
            self.gcs_port_b = free_port(socket.SOCK_DGRAM)
            b_extra += ["--gcs", f"udpin:127.0.0.1:{self.gcs_port_b}"]
        self.start_gs("B", *b_extra)
        self._fire(BEFORE_GS_A, None)
        for r in spec.rogues:  # attackers that must be in place before A starts (and pairs)
            if r.launch == BEFORE_GS_A:
                self.wait_line(self.children[f"rogue-{r.mode}"], "rogue: ready", 30)
        a_extra = ["--pair", "--mission", o.mission, *gs_extra, *spec.gs_a_extra]
        if spec.app_signing:  # A's operator application's key, as an operator provisions one (gs.appkeys)
            keys = self.out / GCS_KEYS
            keys.write_text(f"opsA hex:{os.urandom(32).hex()}\n")
            keys.chmod(0o600)
            a_extra += ["--gcs-signing", "require", "--gcs-keys", GCS_KEYS]
        if spec.gcs_a or spec.operators or spec.app_signing or spec.consent_ops:
            self.gcs_port = free_port(socket.SOCK_DGRAM)
            a_extra += ["--gcs", f"udpin:127.0.0.1:{self.gcs_port}"]
        self.start_gs("A", *a_extra)
        if spec.x_authorized:  # a third authorized GS: its key comes from A's key sharing, its operator on a gateway
            self.gcs_port_x = free_port(socket.SOCK_DGRAM)
            self.start_gs("X", *gs_extra, "--gcs", f"udpin:127.0.0.1:{self.gcs_port_x}")
        elif spec.gs_x:
            self.start("gsX", self._z() + ["gs", "--id", "X", *self._common("X"), "--drone", "d1", "--pair", "--mission",
                                           "reference", "--events", "X.jsonl"], ns=self._ns("X"))
        self._operators_due(GSS_STARTED, None, None)  # their process starts while the fleet links, not mid-flight
        return self._watch()

    def _z(self) -> list[str]:
        return ["-m", "zdrone", "-v"]

    @property
    def _bench(self) -> bool:
        return self.opts.cipher != "zdrone" or self.opts.paper_heartbeat

    def _zn(self) -> list[str]:
        """The drone and GS command: production nodes have no cipher option, so the bench harness
        alone runs them with plain/Fernet (or the paper's separate heartbeat)."""
        return ["-m", "zdrone.harness", "-v"] if self._bench else self._z()

    def _bench_extra(self) -> list[str]:
        return ["--cipher", self.opts.cipher] if self._bench else []

    def _common(self, node: str | None = None) -> list[str]:
        """Fleet and router options of a node: with sites, a GS uses its site's router and the drone
        every site's (Zenoh moves it to another when its router dies)."""
        bundle = ["--fleet", f"bundles/{node or 'd1'}"]  # every node runs from its own bundle alone
        if self.sites and node is None:  # the drone: one session per site, through that site's radio
            return bundle + [a for ep in self.site_of_endpoint for a in ("--router", ep)]
        router = self.router
        if self.netns is not None:  # each GS reaches its own site's router inside the site's namespace
            return bundle + ["--router", router]
        if self.sites:
            router = next(s["endpoint"] for s in self.sites.values() if node in s["ground_stations"])
        return bundle + ["--router", router]

    def _export_bundles(self, routers: list[str]) -> None:
        """A bundle per host from the run's fleet (``bundles/<node>``: ``zdrone fleet export``), which
        each node and router runs from: nothing of the run's nodes sees another's secret. The
        attackers keep the whole fleet directory (they stand for stolen secrets)."""
        from zdrone.fleet.bundle import export_bundle
        from zdrone.fleet.files import load_fleet

        for node in [*load_fleet(self.out / "fleet").nodes, *routers]:
            export_bundle(self.out / "fleet", node, self.out / "bundles" / node)

    def _fire(self, trigger: str, live: "LiveView | None", t: float | None = None) -> None:
        """The flight reached ``trigger``: start, unleash or fault what the scenario ties to it."""
        if trigger in self.fired:
            return
        self.fired.add(trigger)
        self.fired_at[trigger] = time.time()
        spec = self.spec
        for r in spec.rogues:
            if r.launch == trigger:
                self.start_rogue(r)
                if live is not None:
                    live.event(t or time.time(), f"scenario: attacker {r.mode} starts")
            if r.go == trigger:
                self.pending_go.add(f"rogue-{r.mode}")
        for fault in spec.faults:
            if fault.trigger == trigger:
                self.scheduled.append((time.monotonic() + fault.after, fault))
        self._operators_due(trigger, t, live)
        self._inject_due(live)
        self._send_go(live)

    def _operators_due(self, trigger: str, t: float | None, live: "LiveView | None") -> None:
        """Start the scenario's operators' applications (``spec.operators`` / ``spec.consent_ops``) at
        ``trigger``."""
        spec = self.spec
        if spec.operators == trigger and self.gcs_port and self.gcs_port_b:
            self.start("operators", ["-m", "zdrone.sil.operator", "--a-port", str(self.gcs_port), "--b-port",
                                     str(self.gcs_port_b), "--events", "operator.jsonl"], ns=self._ns("A"))
            if live is not None:
                live.event(t or time.time(), "scenario: the operators of A and B start")
        if spec.consent_ops == trigger and self.gcs_port and self.gcs_port_b and self.gcs_port_x:
            self.start("operators", ["-m", "zdrone.sil.consent_ops", "--a-port", str(self.gcs_port), "--b-port",
                                     str(self.gcs_port_b), "--x-port", str(self.gcs_port_x), "--events", "operator.jsonl"],
                       ns=self._ns("A"))
            if live is not None:
                live.event(t or time.time(), "scenario: the operators of A, B and X start")

    def _inject_due(self, live: "LiveView | None") -> None:
        """Carry out the faults whose time has come."""
        now = time.monotonic()
        due = [f for (when, f) in self.scheduled if when <= now]
        self.scheduled = [(w, f) for (w, f) in self.scheduled if w > now]
        for fault in due:
            t = time.time()
            if live is not None:
                live.event(t, f"scenario: {fault.text}")
            ends_one = fault.sig in (LINK_UP, signal.SIGCONT)  # the end of an earlier fault, not one of its own
            if ends_one:
                for entry in reversed(self.fault_log):
                    if entry["target"] == fault.target and entry["ends"] is None:
                        entry["ends"] = t
                        break
            else:
                entry = {"t": t, "target": fault.target, "text": fault.text, "ends": None}  # SIGKILL: never ends
                self.fault_log.append(entry)
            if fault.sig in (LINK_DOWN, LINK_UP):
                self.link_fault(fault.target, fault.sig == LINK_UP)
            elif fault.sig in (REVOKE, ROTATE, REVOKE_BEHIND_CUT):
                self.revise(fault.target, rotate=fault.sig == ROTATE, behind_cut=fault.sig == REVOKE_BEHIND_CUT)
                entry["ends"] = time.time()
            elif fault.sig == RESTART:
                self.restart(fault.target, fault.down)
                entry["ends"] = time.time()
                self.notes.append(f"{fault.target} restarted after {fault.down} s down")
                if fault.target == "drone":
                    self._fire(DRONE_RESTARTED, live)
            else:
                self.signal(fault.target, fault.sig)
                self.children[fault.target].stopped = fault.sig != signal.SIGCONT

    def _lease(self) -> dict[str, float]:
        """The fleet's owner lease where the scenario sets one (``Scenario.revision_lease``)."""
        return {} if self.spec.revision_lease is None else {"revision_lease": self.spec.revision_lease}

    def revise(self, node: str, rotate: bool, behind_cut: bool = False) -> None:
        """The operator's revocation (or rotation) of ``node`` in flight, as docs/deploy.md says: the next
        signed revision made on the fleet machine (the run's fleet directory), published through a GS
        that is not ``node``; a rotated node's new secret dropped into its bundle before (its station
        adopts it when the revision arrives); after a revocation, each router restarted in turn on the
        regenerated files (the revoked node's password and certificate refused from then on). With
        ``behind_cut`` the backhaul is cut: only the routers on the publishing GS's side of it (site 1)
        get the new files; ``node``'s site knows nothing of the revision."""
        import shutil

        from zdrone.fleet import revise as rv

        fleet, bundles = self.out / "fleet", self.out / "bundles"
        if rotate:
            rv.rotate(fleet, node)
            shutil.copyfile(fleet / "secrets" / f"{node}.json", bundles / node / "secrets" / f"{node}.json")
        else:
            rv.revoke(fleet, node)
        via = next(g for g in ("A", "B") if g != node)
        router, ns = self._common(via)[-1], self._ns(via)
        prefix = self.netns.exec_prefix(ns) if (ns and self.netns) else []
        with open(self.out / "publish.log", "a") as log:
            subprocess.run([*prefix, PY, *self._z(), "fleet", "publish", "--fleet", f"bundles/{via}", "--revision",
                            "fleet/revision.json", "--id", via, "--router", router], cwd=self.out, stdout=log,
                           stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, timeout=30.0, check=False)
        self.notes.append(f"revision {'rotating' if rotate else 'revoking'} {node} published through {via}")
        if rotate:
            return
        routers = sorted(n for n in self.children if n.startswith("router"))
        if behind_cut:
            routers = routers[:1]
        for name, site in zip(routers, list(self.sites) if self.sites else ["router"]):
            cfg = "router" if site == "router" else site
            for f in (f"router/{cfg}.json5", "router/credentials.txt"):
                shutil.copyfile(fleet / f, bundles / site / f)
            self.take_over(name)
        self.notes.append(f"routers restarted on the files without {node}: {', '.join(routers)}")

    def take_over(self, name: str, timeout: float = 20.0) -> None:
        """Restart router ``name`` as docs/deploy.md's rolling restart says: a new process started
        beside the running one (``zdrone router --take-over``), the old one stopped (SIGTERM) once the
        new one is ready, the new one listening within a retry of its going. Both write to the
        router's log; ``children[name]`` is the new one from then on."""
        from zdrone.net.router import TAKE_OVER_LINE

        old = self.children[name]
        text = old.log.read_text(errors="replace")
        counts = {needle: text.count(needle) for needle in (TAKE_OVER_LINE, "listening")}
        args = old.args if "--take-over" in old.args else [*old.args, "--take-over", f"{TAKE_OVER_S:g}"]
        new = self.start(name, args, append=True, ns=old.ns)
        self._wait_more(new, TAKE_OVER_LINE, counts[TAKE_OVER_LINE], timeout)
        t_stop = time.monotonic()
        old.proc.terminate()
        try:
            old.proc.wait(10.0)
        except subprocess.TimeoutExpired:
            old.proc.kill()
            old.proc.wait(5.0)
            self.notes.append(f"{name}: the old router had to be killed")
        procs.forget(old.proc)
        t_gone = time.monotonic()
        self._wait_more(new, "listening", counts["listening"], timeout)
        self.notes.append(f"{name} taken over: the old one ended {1000 * (t_gone - t_stop):.0f} ms after SIGTERM, "
                          f"the new one listening {1000 * (time.monotonic() - t_gone):.0f} ms after that (its ready line seen)")

    def _send_go(self, live: "LiveView | None") -> None:
        """SIGUSR2 to each attacker whose moment came, once it has set up (its handler is in place)."""
        for name in sorted(self.pending_go):
            child = self.children.get(name)
            if child is None or child.proc.poll() is not None:
                continue
            if "rogue: ready" in child.log.read_text(errors="replace"):
                self.signal(name, signal.SIGUSR2)
                self.pending_go.discard(name)
                if live is not None:
                    live.event(time.time(), f"scenario: attacker {name.removeprefix('rogue-')} attacks")

    def _watch(self) -> dict[str, Any]:
        o = self.opts
        # the flight at the speed-up, plus a real autopilot's own start-up (ArduCopter: ~40 s until its EKF uses GPS)
        timeout = o.timeout or (60.0 + 240.0 / o.speedup + (EXTERNAL_BOOT_S if o.vehicle is not None else 0.0))
        deadline = time.monotonic() + timeout
        drone_log = self.out / "drone.jsonl"
        live = LiveView(o.scenario, enabled=o.live if o.live is not None else sys.stdout.isatty(), quiet=o.quiet)
        if o.max_wall is not None:
            deadline = min(deadline, time.monotonic() + o.max_wall)
        state = watch_state()
        self.progress = {}  # the last status as logged ("status"): read by the benches' progress displays
        drone_tail = LogTail(drone_log)  # only what is new each turn: the cost is flat in the flight's length
        with live:
            while time.monotonic() < deadline and not state["done"]:
                for ev in drone_tail.read():
                    self._on_event(ev, state, live)
                self._on_gs_events(live, state)
                self._inject_due(live)
                self._send_go(live)
                live.update(state["status"], time.monotonic() - self.t0)
                for name, child in self.children.items():
                    if child.proc.poll() is not None and name not in ("gsB", "gsA", "operators", "view") and not name.startswith("rogue") \
                            and not child.stopped:
                        self.notes.append(f"{name} exited early ({_exit_text(child.proc.returncode)})")
                        state["done"] = True
                time.sleep(0.1)
        drone_tail.close()
        if self._a_tail is not None:
            self._a_tail.close()
        wall = time.monotonic() - self.t0
        codes = self.shutdown()
        return self._summarize(state, wall, codes, timed_out=not state["done"] and o.max_wall is None)

    def _on_gs_events(self, live: "LiveView", state: dict[str, Any]) -> None:
        if MISSION_STARTED in self.fired:
            return
        if self._a_tail is None:
            self._a_tail = LogTail(self.out / "A.jsonl")
        for e in self._a_tail.read():
            if isinstance(e, MissionStarted):
                self._fire(MISSION_STARTED, live)
            elif isinstance(e, MissionFailed):  # the GS gave up (it said why): the demo ends, not ok
                self.notes.append(f"GS A: mission failed: {e.reason}")
                live.event(e.t, f"GS A: mission failed: {e.reason}")
                state["done"] = True
                state["mission_failed"] = e.reason
                return

    def _on_event(self, ev: AnyRecord, state: dict[str, Any], live: "LiveView") -> None:
        """Follow one drone event: the flight's progress in ``state``, the scenario's moments, the live view."""
        if isinstance(ev, DroneStatus):
            self.progress["status"] = fields_of(ev)  # the benches' displays read the status as logged
        for trigger in follow(state, ev, time.monotonic(), self.spec.linger):
            self._fire(trigger, live, ev.t)
        if isinstance(ev, DroneStatus):
            return
        quiet = isinstance(ev, (Subscribe, Unsubscribe, LinkStateChanged, Drop))
        if not quiet or (isinstance(ev, Drop) and len(live.lines) < 200):
            live.event(ev.t, describe(ev))

    # ----------------------------------------------------------------- summary
    def _summarize(self, state: dict[str, Any], wall: float, codes: dict[str, int | None], timed_out: bool) -> dict[str, Any]:
        """The run's summary from its logs and what the launcher saw (``zdrone.sil.summary``), written
        to ``summary.json``."""
        run = RunFacts(scenario=self.opts.scenario, speedup=self.opts.speedup, wall=wall, timed_out=timed_out,
                       ended_at=time.time(), moment=self.opts.moment, moments=self.fired_at, faults=self.fault_log,
                       notes=self.notes, exit_codes=codes,
                       stopped=frozenset(n for n, c in self.children.items() if c.stopped),
                       site_of_endpoint=self.site_of_endpoint)
        summary = summarize(self.spec, RunLogs.read(self.out), state, run)
        (self.out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
        return summary


def run_demo(opts: DemoOptions) -> int:
    if opts.scenario not in SCENARIOS:
        raise ValueError(opts.scenario)
    out = opts.out or Path("runs") / time.strftime(f"demo-{opts.scenario}-%Y%m%d-%H%M%S")
    out.mkdir(parents=True, exist_ok=True)
    out = out.resolve()
    print(f"zdrone demo: scenario {opts.scenario}, speed-up {opts.speedup:g}, output in {out}", flush=True)
    demo = Demo(opts, out)
    try:  # Demo.run has stopped every child whatever ends it
        summary = demo.run()
    except (RuntimeError, OSError) as exc:
        print(f"zdrone demo: failed: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("zdrone demo: interrupted; every process of the run stopped", file=sys.stderr)
        return 130
    except procs.Terminated as exc:
        print(f"zdrone demo: {exc}; every process of the run stopped", file=sys.stderr)
        return 128 + exc.signum
    if opts.report:
        try:
            from zdrone.report import write_report

            path = write_report(out)
            print(f"report: {path}")
        except ImportError:
            pass
    hv = ", ".join(f"{h['from']}->{h['to']}" for h in summary["handovers"]) or "none"
    print(f"{'OK' if summary['ok'] else 'FAILED'}: {opts.scenario} in {summary['wall_time_s']:.1f} s; hand-overs: {hv}; "
          f"authority gap {summary['authority_gap_ms']:.0f} ms; commands lost {summary['commands']['lost']}; "
          f"security drops {summary['security_drops']}; HA refusals {summary['ha_rejects']}; "
          f"failsafe {summary['failsafe']['detect_to_command_ms'] if summary['failsafe'] else '-'} ms; "
          f"final position {summary['distance_from_home_m']} m from home")
    radio = summary.get("radio_links") or {}
    if radio:
        lost = "; ".join(f"{x['site']} lost (noticed in {x['noticed_ms']} ms), carried on through "
                         f"{', '.join(x['other_paths_connected']) or 'nothing'}" for x in radio["site_losses"])
        print(f"radio links: {len(radio['changes'])} changes; {lost or 'no site lost'}; copies dropped at the drone "
              f"{radio['path_duplicates']}")
    print(f"summary: {out / 'summary.json'}; events: {out / 'drone.jsonl'}")
    return 0 if summary["ok"] else 1
