"""TESTBED: ``zdrone demo`` starts router, simulator, drone and ground stations as separate OS
processes, flies the reference flight (or an attack / fault scenario), shows it live, writes the
event logs and a summary, and shuts everything down.

Scenarios and what counts as success:

* ``nominal``: both hand-overs (A->B, B->A), landing at the take-off point, no violation.
* ``rogue-no-key``: as nominal while an attacker with A's stolen router password (no keys) tries to
  pair, command and replay; every attempt is dropped by the security module.
* ``rogue-unauthorized``: as nominal while GS X (in the fleet, not authorized) tries to pair and
  command; the handover authority refuses it.
* ``link-loss``: GS A goes silent (SIGSTOP) after take-off; the drone's failsafe commands LAND.
* ``gs-crash``: GS B dies (SIGKILL) as the drone enters the hand-over region; authority stays with
  A, which brings the drone home.
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

from ..core.geometry import GeoPoint, distance_m
from ..core.reference import HOME
from ..fleetfiles import init_fleet
from ..net.eventlog import read_events

SCENARIOS = ("nominal", "rogue-no-key", "rogue-unauthorized", "link-loss", "gs-crash")
PY = sys.executable


def free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


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


@dataclass
class Child:
    name: str
    proc: subprocess.Popen
    log: Path
    stopped: bool = False


@dataclass
class Demo:
    opts: DemoOptions
    out: Path
    children: dict[str, Child] = field(default_factory=dict)
    t0: float = field(default_factory=time.monotonic)
    notes: list[str] = field(default_factory=list)
    progress: dict[str, Any] = field(default_factory=dict)

    # --------------------------------------------------------------- processes
    def start(self, name: str, args: list[str]) -> Child:
        log = self.out / f"{name}.log"
        fh = open(log, "w")
        proc = subprocess.Popen([PY, *args], stdout=fh, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                cwd=self.out, start_new_session=True)
        fh.close()
        child = Child(name, proc, log)
        self.children[name] = child
        return child

    def wait_line(self, child: Child, needle: str, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if needle in child.log.read_text(errors="replace"):
                return
            if child.proc.poll() is not None:
                raise RuntimeError(f"{child.name} exited ({child.proc.returncode}): {child.log.read_text()[-600:]}")
            time.sleep(0.05)
        raise RuntimeError(f"{child.name}: {needle!r} not seen within {timeout:.0f} s")

    def signal(self, name: str, sig: int) -> None:
        child = self.children.get(name)
        if child is not None and child.proc.poll() is None:
            os.kill(child.proc.pid, sig)

    def shutdown(self, timeout: float = 10.0) -> dict[str, int | None]:
        """SIGTERM the nodes first (so they close their sessions while the router is still up), then
        the simulator and the router; SIGKILL only what does not exit in time; return exit codes."""
        codes: dict[str, int | None] = {}
        nodes = [c for n, c in self.children.items() if n not in ("sim", "router")]
        infra = [c for n, c in self.children.items() if n in ("sim", "router")]
        for group in (nodes, infra):
            for child in reversed(group):
                if child.proc.poll() is None:
                    try:
                        os.kill(child.proc.pid, signal.SIGCONT)  # a stopped process cannot handle SIGTERM
                        child.proc.terminate()
                    except ProcessLookupError:
                        pass
            deadline = time.monotonic() + timeout
            for child in group:
                try:
                    child.proc.wait(max(0.1, deadline - time.monotonic()))
                except subprocess.TimeoutExpired:
                    try:
                        os.kill(child.proc.pid, signal.SIGUSR1)  # its stacks go to its log, for diagnosis
                        time.sleep(0.5)
                    except ProcessLookupError:
                        pass
                    child.proc.kill()
                    child.proc.wait(5)
                    self.notes.append(f"{child.name} had to be killed (stacks in {child.log.name})")
                codes[child.name] = child.proc.returncode
        return {n: codes.get(n) for n in self.children}

    # ----------------------------------------------------------------- running
    def run(self) -> dict[str, Any]:
        o = self.opts
        fleet_dir = self.out / "fleet"
        init_fleet(fleet_dir)
        rport, sport = free_port(socket.SOCK_STREAM), free_port(socket.SOCK_DGRAM)
        router = f"tcp/127.0.0.1:{rport}"
        z = ["-m", "zdrone", "-v"]
        common = ["--fleet", "fleet", "--router", router]
        r = self.start("router", z + ["router", "-c", "fleet/router/router.json5", "--listen", router]
                       + (["--tap", "tap.json"] if o.tap else []))
        self.wait_line(r, "listening", 20)
        sim = self.start("sim", z + ["sim", "--mavlink", f"udpin:127.0.0.1:{sport}", "--speedup", str(o.speedup)])
        self.wait_line(sim, "zdrone sim:", 20)
        # Timers are wall-clock while the simulator may run faster: scale the hand-over timeout so that
        # a failed hand-over is still noticed while the vehicle is inside the overlap (5 s at 1x).
        ho_timeout = max(1.5, 5.0 / o.speedup)
        # Production nodes have no cipher option: the bench harness alone runs them with plain/Fernet.
        bench = o.cipher != "zdrone" or o.paper_heartbeat
        zn = ["-m", "zdrone.bench.nodes", "-v"] if bench else z
        bench_extra = ["--cipher", o.cipher] if bench else []
        drone = self.start("drone", zn + ["drone", "--id", "d1", *common, "--vehicle", f"udpout:127.0.0.1:{sport}",
                                          "--sil-coverage", "--events", "drone.jsonl", "--handover-timeout", str(ho_timeout),
                                          *bench_extra])
        gs_extra = bench_extra + (["--paper-heartbeat"] if o.paper_heartbeat else [])
        self.wait_line(drone, "ready", 40)
        b = self.start("gsB", zn + ["gs", "--id", "B", *common, "--events", "B.jsonl", "--command-rate", str(o.command_rate),
                                   *gs_extra])
        self.wait_line(b, "zdrone gs B", 20)
        a = self.start("gsA", zn + ["gs", "--id", "A", *common, "--pair", "--mission", o.mission,
                                   "--events", "A.jsonl", "--command-rate", str(o.command_rate), *gs_extra])
        self.wait_line(a, "zdrone gs A", 20)
        if o.scenario == "rogue-unauthorized":
            self.start("gsX", z + ["gs", "--id", "X", *common, "--drone", "d1", "--pair", "--mission", "reference",
                                   "--events", "X.jsonl"])
        return self._watch()

    def _watch(self) -> dict[str, Any]:
        o = self.opts
        timeout = o.timeout or (60.0 + 240.0 / o.speedup)
        deadline = time.monotonic() + timeout
        drone_log = self.out / "drone.jsonl"
        live = LiveView(o.scenario, enabled=o.live if o.live is not None else sys.stdout.isatty(), quiet=o.quiet)
        if o.max_wall is not None:
            deadline = min(deadline, time.monotonic() + o.max_wall)
        state: dict[str, Any] = {"handovers": [], "failsafe": None, "armed_seen": False, "status": {}, "region_entered": 0,
                                 "mission_started": False, "done": False, "rogue_started": False, "hook_done": False}
        self.progress = state  # read by the benches' progress displays
        seen = 0
        with live:
            while time.monotonic() < deadline and not state["done"]:
                events = read_events(drone_log) if drone_log.exists() else []
                for ev in events[seen:]:
                    self._on_event(ev, state, live)
                seen = len(events)
                self._on_gs_events(state)
                live.update(state["status"], time.monotonic() - self.t0)
                for name, child in self.children.items():
                    if child.proc.poll() is not None and name not in ("gsB", "gsA", "rogue") and not child.stopped:
                        self.notes.append(f"{name} exited early ({child.proc.returncode})")
                        state["done"] = True
                time.sleep(0.1)
        wall = time.monotonic() - self.t0
        codes = self.shutdown()
        return self._summarize(state, wall, codes, timed_out=not state["done"] and o.max_wall is None)

    def _on_gs_events(self, state: dict[str, Any]) -> None:
        a_log = self.out / "A.jsonl"
        if not state["mission_started"] and a_log.exists():
            if any(e["type"] == "mission_started" for e in read_events(a_log)):
                state["mission_started"] = True
                if self.opts.scenario == "rogue-no-key" and not state["rogue_started"]:
                    state["rogue_started"] = True
                    self.start("rogue", ["-m", "zdrone.sil.rogue", "--mode", "no-key", "--fleet", "fleet", "--router",
                                         self._router(), "--duration", str(max(10.0, 40.0 / self.opts.speedup)),
                                         "--events", "rogue.jsonl"])
                if self.opts.scenario == "rogue-unauthorized" and not state["rogue_started"]:
                    state["rogue_started"] = True
                    self.start("rogue", ["-m", "zdrone.sil.rogue", "--mode", "unauthorized", "--fleet", "fleet", "--router",
                                         self._router(), "--duration", str(max(8.0, 30.0 / self.opts.speedup)),
                                         "--events", "rogue.jsonl"])

    def _router(self) -> str:
        args = self.children["router"].proc.args
        return args[args.index("--listen") + 1]  # type: ignore[union-attr]

    def _on_event(self, ev: dict[str, Any], state: dict[str, Any], live: "LiveView") -> None:
        t = ev["type"]
        sc = self.opts.scenario
        if t == "status":
            state["status"] = ev
            pos = ev.get("position")
            if ev.get("armed"):
                state["armed_seen"] = True
                if sc == "link-loss" and not state["hook_done"] and pos and pos[2] > 15.0:
                    state["hook_done"] = True
                    self.signal("gsA", signal.SIGSTOP)
                    self.children["gsA"].stopped = True
                    live.event(ev["t"], "scenario: GS A goes silent (SIGSTOP)")
            landed = ev.get("landed_state") == 1 and not ev.get("armed")
            if state["armed_seen"] and landed and ev.get("mode") in ("MISSION", "HOLD", "LAND", "RTL"):
                state["done"] = True
                state["final_position"] = pos
            return
        if t == "region_entered":
            state["region_entered"] += 1
            if sc == "gs-crash" and not state["hook_done"]:
                state["hook_done"] = True
                self.signal("gsB", signal.SIGKILL)
                self.children["gsB"].stopped = True
                live.event(ev["t"], "scenario: GS B crashes (SIGKILL)")
        if t == "handover_complete":
            state["handovers"].append({k: ev.get(k) for k in ("from", "to", "epoch", "time", "kind", "position")})
        if t == "failsafe":
            state["failsafe"] = ev
        shown = t not in ("subscribe", "unsubscribe", "link_state", "drop") or (t == "drop" and len(live.lines) < 200)
        if shown:
            live.event(ev["t"], _describe(ev))

    # ----------------------------------------------------------------- summary
    def _summarize(self, state: dict[str, Any], wall: float, codes: dict[str, int | None], timed_out: bool) -> dict[str, Any]:
        sc = self.opts.scenario
        drone_events = read_events(self.out / "drone.jsonl") if (self.out / "drone.jsonl").exists() else []
        final = next((e for e in reversed(drone_events) if e["type"] == "stop"), state["status"])
        gs_final = {}
        for g in ("A", "B", "X"):
            p = self.out / f"{g}.jsonl"
            if p.exists():
                evs = read_events(p)
                gs_final[g] = next((e for e in reversed(evs) if e["type"] in ("stop", "status")), {})
        sent = {g: sum(int(v) for v in (f.get("drones", {}).get("d1", {}).get("commands_sent") or {}).values())
                for g, f in gs_final.items()}
        forwarded = final.get("forwarded_commands", {}) if final else {}
        ha_drops = final.get("ha_drops", {}) if final else {}
        drops: dict[str, int] = {}
        for link in (final.get("links") or {}).values():
            for reason, n in link.get("dropped", {}).items():
                drops[reason] = drops.get(reason, 0) + n
        pos = state.get("final_position") or (final.get("position") if final else None)
        home_dist = distance_m(HOME, GeoPoint(pos[0], pos[1])) if pos else None
        pairs = [(h["from"], h["to"]) for h in state["handovers"]]
        violations = [f"authority to {h['to']}" for h in state["handovers"] if h["to"] not in ("A", "B")]
        violations += [f"paired with {e['gs']}" for e in drone_events if e["type"] == "paired" and e["gs"] not in ("A", "B")]
        history = [(e["t"], e.get("owner")) for e in drone_events if e["type"] == "status"]
        gap_ms = 0.0
        first_owned = next((i for i, (_, o) in enumerate(history) if o), None)
        if first_owned is not None:
            for (t1, o1), (t2, _) in zip(history[first_owned:], history[first_owned + 1:]):
                if not o1:
                    gap_ms += (t2 - t1) * 1000
        cmd_sent = sum(sent.get(g, 0) for g in ("A", "B"))
        cmd_fwd = sum(int(forwarded.get(g, 0)) for g in ("A", "B"))
        expected = {
            "nominal": pairs == [("A", "B"), ("B", "A")],
            "rogue-no-key": pairs == [("A", "B"), ("B", "A")] and drops.get("auth_failed", 0) + drops.get("unknown_epoch", 0) > 0,
            "rogue-unauthorized": pairs == [("A", "B"), ("B", "A")],
            "link-loss": state["failsafe"] is not None,
            "gs-crash": all(h["to"] != "B" or h["kind"] == "emergency" for h in state["handovers"])
                        and (final or {}).get("owner") == "A",
        }[sc]
        landed_home = home_dist is not None and home_dist < 5.0
        why: list[str] = []
        if timed_out:
            why.append("timed out")
        if not expected:
            why.append(f"scenario outcome not met (hand-overs {pairs}, failsafe {state['failsafe'] is not None})")
        if violations:
            why.append("security violations")
        if sc in ("nominal", "rogue-no-key", "rogue-unauthorized", "gs-crash") and not landed_home:
            why.append(f"not landed at home ({home_dist} m)")
        bad_exit = {n: c for n, c in codes.items() if c != 0 and not self.children[n].stopped}
        if bad_exit:
            why.append(f"non-zero exit codes {bad_exit}")
        ok = not why
        summary = {
            "scenario": sc, "ok": ok, "timed_out": timed_out, "wall_time_s": round(wall, 2), "speedup": self.opts.speedup,
            "handovers": state["handovers"], "authority_gap_ms": gap_ms,
            "failsafe": None if state["failsafe"] is None else {k: state["failsafe"].get(k) for k in ("action", "reason", "detect_to_command_ms", "position")},
            "final_position": pos, "distance_from_home_m": None if home_dist is None else round(home_dist, 2),
            "commands": {"sent_as_authority": sent, "forwarded": forwarded, "lost": cmd_sent - cmd_fwd - int(ha_drops.get("not_authority", 0)),
                         "refused_not_authority": ha_drops.get("not_authority", 0)},
            "security_drops": drops, "ha_drops": ha_drops, "ha_rejects": (final or {}).get("rejects", {}),
            "pairing": (final or {}).get("counters", {}), "out_of_coverage": (final or {}).get("out_of_coverage", {}),
            "violations": violations, "exit_codes": codes, "notes": self.notes, "why_not_ok": why,
        }
        (self.out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
        return summary


def _describe(ev: dict[str, Any]) -> str:
    t = ev["type"]
    if t in ("handover_complete", "authority"):
        return f"authority {ev.get('from')} -> {ev.get('to')} (epoch {ev.get('epoch')}, {ev.get('kind')})"
    if t == "failsafe":
        return f"FAILSAFE {ev.get('action')}: {ev.get('reason')} ({ev.get('detect_to_command_ms', 0) or 0:.0f} ms after threshold)"
    if "detail" in ev:
        return f"{t}: {ev['detail']}"
    if "gs" in ev:
        return f"{t}: {ev['gs']}" + (f" ({ev['reason']})" if "reason" in ev else "")
    return t


class LiveView:
    """A rich live panel when on a terminal; plain event lines otherwise."""

    def __init__(self, scenario: str, enabled: bool, quiet: bool = False) -> None:
        self.scenario = scenario
        self.enabled = enabled and not quiet
        self.quiet = quiet
        self.lines: list[str] = []
        self._live: Any = None
        self._t0: float | None = None

    def __enter__(self) -> "LiveView":
        if self.enabled:
            from rich.live import Live

            self._live = Live(self._render({}, 0.0), refresh_per_second=4, transient=False)
            self._live.__enter__()
        return self

    def __exit__(self, *exc: Any) -> None:
        if self._live is not None:
            self._live.__exit__(*exc)

    def event(self, t: float, text: str) -> None:
        if self._t0 is None:
            self._t0 = t
        line = f"{t - self._t0:7.2f}s  {text}"
        self.lines.append(line)
        if not self.enabled and not self.quiet:
            print(line, flush=True)

    def update(self, status: dict[str, Any], elapsed: float) -> None:
        if self._live is not None:
            self._live.update(self._render(status, elapsed))

    def _render(self, st: dict[str, Any], elapsed: float) -> Any:
        from rich.console import Group
        from rich.table import Table

        top = Table(title=f"zdrone demo — {self.scenario} — {elapsed:5.1f} s", show_header=False, expand=True)
        top.add_column(style="bold")
        top.add_column()
        pos = st.get("position")
        if pos:
            n_e = _ne(pos)
            top.add_row("position", f"{pos[0]:.6f}, {pos[1]:.6f}  alt {pos[2]:.1f} m  ({n_e[1]:+.0f} m east of A)")
        top.add_row("authority", f"{st.get('owner')} (epoch {st.get('epoch')}, {st.get('state')})"
                    + (f" -> {st['pending_to']}" if st.get("pending_to") else ""))
        top.add_row("vehicle", f"{'ARMED' if st.get('armed') else 'disarmed'}  mode {st.get('mode')}  region {'yes' if st.get('in_region') else 'no'}")
        links = Table(title="links (TBM)", expand=True)
        for col in ("GS", "state", "silence s", "opened", "sent", "dropped"):
            links.add_column(col)
        for gs, ln in (st.get("links") or {}).items():
            links.add_row(gs, ln["state"], f"{ln['since_last']:.2f}", str(ln["opened"]), str(ln["sent"]),
                          ", ".join(f"{k}={v}" for k, v in ln.get("dropped", {}).items()) or "-")
        ev = Table(title="events", show_header=False, expand=True)
        ev.add_column()
        for line in self.lines[-10:]:
            ev.add_row(line)
        return Group(top, links, ev)


def _ne(pos: list[float]) -> tuple[float, float]:
    from ..core.geometry import ne_of

    return ne_of(HOME, GeoPoint(pos[0], pos[1]))


def run_demo(opts: DemoOptions) -> int:
    if opts.scenario not in SCENARIOS:
        raise ValueError(opts.scenario)
    out = opts.out or Path("runs") / time.strftime(f"demo-{opts.scenario}-%Y%m%d-%H%M%S")
    out.mkdir(parents=True, exist_ok=True)
    out = out.resolve()
    print(f"zdrone demo: scenario {opts.scenario}, speed-up {opts.speedup:g}, output in {out}", flush=True)
    demo = Demo(opts, out)
    try:
        summary = demo.run()
    except (RuntimeError, OSError) as exc:
        demo.shutdown()
        print(f"zdrone demo: failed: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        demo.shutdown()
        return 130
    if opts.report:
        try:
            from ..bench.report import write_report

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
    print(f"summary: {out / 'summary.json'}; events: {out / 'drone.jsonl'}")
    return 0 if summary["ok"] else 1
