"""``zdrone bench scale``: K drones x G ground stations through one router, or through a router per
site (``--sites N``), on this machine.

Layout: the router (or one router per site, meshed over QUIC with mutual TLS: site n connects to sites
1..n-1); one process hosting the K drone nodes (``--drone-hosts H``: H processes, the i-th drone in
host i mod H: with the default spread over sites, one host per site's drones), each drone with its
own Zenoh session, authority machine, security module and an in-process simulator (no sockets; a
host's drones all stepped by its one loop); one process
hosting the G ground stations, each with its own session, serving all K drones. GSs stand 500 m
apart eastwards (A, B, C, …); with sites, GS i belongs to site i (``router/sites.json``) and
connects to its site's router, and drone i to site (i mod N)'s router (``spread``) or to the list of
every site's router (``all``: Zenoh picks one). Coverage stays the in-process gate. Every drone is
paired by A and gets the other GSs' keys over the backhaul on the ground: each GS shares at most five
link keys per second with an asker (bursts of 10), so the vehicles report "not ready to arm" until
every drone holds every GS's key (about K/5 s; the table shows it), then all take off at once and fly
a shuttle from A's area to the last GS's area and back, so each makes 2 x (G - 1) hand-overs; each
authority GS sends it a 1 Hz command stream. A drone is *correct* if it made every hand-over, never
had an authority gap, lost no command, never entered failsafe, and its authority link stayed
healthy (TBM never LOST).

Load, over the flight (take-off -> drones host done): CPU of every process (100 % = one
core, from ``/proc/<pid>/stat``; each drones host measures its own, summed); samples delivered to the nodes
per second, and those whose sender is on another site's router (each crossed one mesh link),
counted per (receiver, sender) in the hosts and placed by each session's router; the routers' TCP
client links (data segments, from ``ss -ti``). The mesh runs over QUIC (UDP): no per-link byte
counters there, and Zenoh 1.x's admin space (``@/<zid>/router``) lists sessions and links but
carries no message counters in the Python build (no ``stats`` feature).

The two host processes are ``zdrone.bench.scalehosts`` (started as ``python -m zdrone.bench.scale
host-drones | host-stations``); what is read of the processes from outside, ``zdrone.bench.procstats``.
"""

from __future__ import annotations

import argparse
import json
import logging
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

from zdrone.bench.procstats import _memory_mb, _tcp_sockets, _traffic
from zdrone.bench.scalehosts import _host_drones, _host_stations, drones_file, merge_drone_hosts, merge_station_hosts
from zdrone.bench.stallwatch import CpuSampler, cpu_seconds
from zdrone.core.errors import UsageError

SPEEDUP = 4.0
#: Without ``--speedup`` a run of K drones flies at ``SPEEDUP`` up to this K, at 1 above it: the
#: vehicles' telemetry grows with K x speed-up (docs/results.md: 100 x 3 flew 100 of 100 at 4; 300 x 3
#: flies 300 of 300 at 1 and 0 of 300 at 4).
FAST_MAX_K = 100


def speedup_for(k: int) -> float:
    """The simulators' speed-up for K drones when none is given (``FAST_MAX_K``)."""
    return SPEEDUP if k <= FAST_MAX_K else 1.0

#: How long the drones host may take to open its K sessions before the run counts as failed.
READY_TIMEOUT_S = 180.0
#: The fleet target's worst authority-link silence (a drone's link is DEGRADED after 1 s).
SILENCE_TARGET_S = 1.0
#: The niceness the drones and GSs hosts run at (their threads and their session's scheduling group,
#: ``give_way``; the routers at the machine's own, 0). The hosts stand in for 300 companion computers
#: and three GS machines on two cores and keep them about 1.4 cores busy, in bursts a full core each:
#: a site router then waited for a CPU behind them (``cpu_busiest``: its threads waiting 1.6-3.2
#: thread-seconds a second during a silence while it ran 0.12-0.2 of a core). On a site of its own a
#: router has its CPU; here the hosts give way to it. It makes no node faster: the hosts' own loops,
#: and with them the drones' and GSs' code measured, only wait longer when a router runs.
HOSTS_NICE = 10
#: The flight's time limit from take-off, in simulated seconds (150 wall seconds at speed-up 4).
FLIGHT_SIM_S = 600.0


def give_way(pid: int, nice: int) -> str:
    """Make the process ``pid`` (started in a session of its own) give way to the others: ``nice`` for
    its threads (set by ``nice -n`` as it started) and for its session's scheduling group, where the
    kernel has them (``/proc/<pid>/autogroup``): with autogroups on, the CPU is shared between
    sessions first, and a process's own niceness counts only against its session's other processes
    (measured: runs 27-32 at ``nice -n 10`` alone, the routers waited for a CPU as much as at 0).
    Returns how: "autogroup", "threads only" (no autogroups here) or "no" (nice 0)."""
    if not nice:
        return "no"
    try:
        Path(f"/proc/{pid}/autogroup").write_text(str(nice))
        return "autogroup"
    except OSError as exc:
        log.info("process %d: autogroup nice not set (%s); its threads' nice only", pid, exc)
        return "threads only"


def hold_limit(k: int) -> float:
    """The longest pre-flight hold: each GS shares at most five link keys per second with an asker
    (bursts of 10, ``gs.linking.LINKKEY_RATE``), so A needs about K/5 s to get B's (and, in
    parallel, C's) keys for K drones; the rest is margin for a loaded machine."""
    return 60.0 + 1.0 * k


log = logging.getLogger(__name__)


def _wait_line(path: Path, text: str, timeout: float, proc: subprocess.Popen) -> str | None:
    """The first line of ``path`` holding ``text`` (None if ``proc`` ended or the time ran out)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            for line in path.read_text(errors="replace").splitlines():
                if text in line:
                    return line
        except OSError:
            pass
        if proc.poll() is not None:
            return None
        time.sleep(0.1)
    return None


def _free_ports(n: int) -> list[int]:
    from zdrone.sil.launcher import free_port

    ports: list[int] = []
    while len(ports) < n:
        p = free_port(socket.SOCK_STREAM)
        if p not in ports:
            ports.append(p)
    return ports


def _one(k: int, g: int, base: Path, timeout: float, sites: int = 0, tls: bool = False,
         drone_router: str = "spread", inbox_senders: int | None = None, speedup: float = SPEEDUP,
         drone_hosts: int = 1, hosts_nice: int = HOSTS_NICE, latency: bool = False,
         corridor: float = 0.0, round_trip: bool = False, kill: tuple[str, float] | None = None,
         gs_processes: bool = False, restart: str | None = None) -> dict[str, Any]:
    """One run: K drones x G GSs through one router, or through ``sites`` meshed site routers (``corridor``:
    the G GSs along that many metres, half the drones flying it each way, their links following them);
    ``latency``: the hosts note messages for ``zdrone.bench.latency`` (``latency-*.json`` in the run's
    directory, ``runs``)."""
    from zdrone.fleet.files import corridor_layout, corridor_nodes, init_fleet, load_sites, scale_nodes
    from zdrone.sil.procs import spawn, stop_in_order  # dies with the bench, however it ends

    layout = f"{sites} sites" if sites else ("1 router, TLS" if tls else "1 router")
    d = base / f"k{k}-g{g}-{f'sites{sites}' if sites else 'one'}"
    d.mkdir(parents=True, exist_ok=True)
    ports = _free_ports(max(1, sites))
    scheme = "tls" if tls or sites else "tcp"
    endpoints = [f"{scheme}/127.0.0.1:{p}" for p in ports]
    if corridor:
        init_fleet(d / "fleet", nodes_spec=corridor_nodes(k, g, corridor), tls=tls, sites=endpoints if sites else None,
                   coverage_radius_m=corridor_layout(g, corridor)[1])
    else:
        init_fleet(d / "fleet", nodes_spec=scale_nodes(k, g), tls=tls, sites=endpoints if sites else None)
    gs_names = [chr(ord("A") + i) for i in range(g)]
    py = [sys.executable, "-m"]
    hpy = (["nice", "-n", str(hosts_nice)] if hosts_nice else []) + py  # the hosts behind the routers
    if sites:
        site_map = load_sites(d / "fleet")
        router_cmds = {site: ["zdrone", "router", "-c", str(d / "fleet" / "router" / f"{site}.json5")] for site in site_map}
        gs_routers = [next(s["endpoint"] for s in site_map.values() if gs in s["ground_stations"]) for gs in gs_names]
    else:
        router_cmds = {"router": ["zdrone", "router", "-c", str(d / "fleet/router/router.json5"), "--listen", endpoints[0]]}
        gs_routers = endpoints[:1]
    hosts = ["drones"] if drone_hosts == 1 else [f"drones-{i}" for i in range(drone_hosts)]
    # the GSs: one process for all, or (``gs_processes``, ``restart``) one each, as real GSs run
    gs_parts = {f"stations-{gs}": [gs] for gs in gs_names} if gs_processes or restart else {"stations": gs_names}
    logs = {n: open(d / f"{n}.log", "w") for n in (*router_cmds, *hosts, *gs_parts)}
    procs: dict[str, subprocess.Popen] = {}
    t0 = time.monotonic()
    error = ""
    window: dict[str, Any] = {}
    zid_site: dict[str, str] = {}
    router_pids: set[int] = set()
    sampler: CpuSampler | None = None
    niced: dict[str, str] = {}  # how each host gives way to the routers (``give_way``)
    try:
        for name, cmd in router_cmds.items():
            procs[name] = spawn(py + cmd, stdout=logs[name], stderr=subprocess.STDOUT)
        for name in router_cmds:
            line = _wait_line(d / f"{name}.log", "listening", 20, procs[name])
            if line is None:
                raise RuntimeError(f"router {name} did not start; see {d / f'{name}.log'}")
            zid = re.search(r"zid (\w+)", line)
            zid_site[zid.group(1) if zid else name] = name
        router_pids = {procs[n].pid for n in router_cmds}
        common = (["--fleet", str(d / "fleet"), "--out", str(d)] + (["--latency"] if latency else [])
                  + (["--corridor", str(corridor)] if corridor else []) + (["--round-trip"] if round_trip else []))
        for part, host in enumerate(hosts):
            procs[host] = spawn(hpy + ["zdrone.bench.scale", "host-drones", "--k", str(k), "--speedup", str(speedup),
                                      "--duration", str(timeout), "--hold", str(hold_limit(k)),
                                      "--router", ",".join(endpoints), "--part", str(part), "--parts", str(len(hosts)),
                                      "--station-hosts", str(len(gs_parts)),
                                      "--drone-router", drone_router, *common],
                                stdout=logs[host], stderr=subprocess.STDOUT)
        killing = ["--kill-owner", kill[0], "--kill-after", str(kill[1])] if kill else []

        def start_gss(part: str, log: Any) -> subprocess.Popen:
            only = ["--only", ",".join(gs_parts[part])] if len(gs_parts) > 1 else []
            return spawn(hpy + ["zdrone.bench.scale", "host-stations", "--stations", str(g), "--k", str(k), *killing, *only,
                                "--router", ",".join(gs_routers), *common,
                                *(["--inbox-senders", str(inbox_senders)] if inbox_senders else [])],
                         stdout=log, stderr=subprocess.STDOUT)

        for part in gs_parts:
            procs[part] = start_gss(part, logs[part])
        niced = {h: give_way(procs[h].pid, hosts_nice) for h in (*hosts, *gs_parts)}
        others = {**{f"router {n}" if sites else "router": procs[n].pid for n in router_cmds},
                  **{"stations host" if part == "stations" else f"{part} host": procs[part].pid for part in gs_parts}}
        def every_host(line: str, within: float) -> bool:
            return all(_wait_line(d / f"{h}.log", line, within, procs[h]) is not None for h in hosts)

        if every_host("drones ready", READY_TIMEOUT_S) and every_host("take-off", hold_limit(k) + 30):
            for part in gs_parts:
                procs[part].send_signal(signal.SIGUSR1)
            window["t"], window["cpu"] = time.monotonic(), {n: cpu_seconds(p) for n, p in others.items()}
            window["socks"] = _tcp_sockets(router_pids)
            # each process's busiest half-seconds (a mesh pause with the routers short of a CPU, or not)
            sampler = CpuSampler({**others, **{f"{h} host" if h == "drones" else h: procs[h].pid for h in hosts}})
            if restart:  # GS ``restart`` crashes in flight and starts again with no key: re-linked how soon
                from zdrone.bench.gsrestart import restart_gs

                window["restart"] = restart_gs(d, procs, f"stations-{restart}", start_gss, hosts_nice, _wait_line, give_way)
                others[f"stations-{restart} host"] = procs[f"stations-{restart}"].pid
                window["cpu"][f"stations-{restart} host"] = None  # two processes: its CPU is not one figure
            if every_host("all landed", timeout + 60):
                for part in gs_parts:
                    procs[part].send_signal(signal.SIGUSR2)  # count the commands sent until now
            try:
                for h in hosts:
                    procs[h].wait(timeout + 60)
            except subprocess.TimeoutExpired:
                error = "drones host did not finish"
            window["t_end"], window["cpu_end"] = time.monotonic(), {n: cpu_seconds(p) for n, p in others.items()}
            window["memory"] = {n: _memory_mb(p) for n, p in others.items()}
            window["socks_end"] = _tcp_sockets(router_pids)
            sampler.close()
            window["cpu_busiest"] = sampler.report(window["t"])
            window["sampler"], sampler = sampler, None
    except RuntimeError as exc:
        error = str(exc)
    finally:
        if sampler is not None:
            sampler.close()
        stop_in_order(procs, (*gs_parts, *router_cmds, *hosts))
        for f in logs.values():
            f.close()
    wall = time.monotonic() - t0
    try:
        drones = merge_drone_hosts([json.loads((d / drones_file(i, len(hosts))).read_text()) for i in range(len(hosts))])
        stations = merge_station_hosts([json.loads((d / f"{part}.json").read_text()) for part in gs_parts])
    except (OSError, ValueError) as exc:
        return {"layout": layout, "k": k, "g": g, "error": error or f"no results ({exc}); see {d}"}
    sent = stations["commands_sent"]
    # a corridor: a hand-over at each GS after the first, each way flown
    expected = (g - 1) * (2 if round_trip else 1) if corridor else 2 * (g - 1)
    per: dict[str, Any] = {}
    for name, r in drones["results"].items():
        s = sum(sent.get(gs, {}).get(name, 0) for gs in sent)
        f = sum(r["forwarded"].values())
        why = []
        if r["handovers"] != expected:
            why.append(f"{r['handovers']}/{expected} hand-overs")
        if r["state"] == "failsafe":
            why.append("failsafe")
        if r["owner_lost_samples"]:
            why.append(f"authority link LOST ({r['worst_owner_silence_s']} s)")
        if s - f:
            why.append(f"{s - f} commands lost")
        if not r["landed"]:
            why.append("not landed")
        per[name] = {"ok": not why, "why": why, "worst_owner_silence_s": r["worst_owner_silence_s"],
                     "at": r.get("worst_owner_silence_at")}
    ok = sum(1 for v in per.values() if v["ok"])
    handovers = [r["handovers"] for r in drones["results"].values()]
    row: dict[str, Any] = {
        "layout": layout, "sites": sites or 1, "tls": bool(tls or sites), "drone_router": drone_router if sites else None,
        "gs_inbox_senders": inbox_senders, "gs_inbox_drops": {g: {k: v for k, v in c.items() if k.startswith("inbox:")}
                                                              for g, c in stations.get("counters", {}).items()},
        "k": k, "g": g, "drone_hosts": len(hosts), "hosts_nice": hosts_nice, "hosts_given_way": niced, "correct": ok,
        "all_correct": ok == k and not drones["timed_out"] and not error and drones.get("released") == "keys",
        "wall_s": round(wall, 1), "ground_s": drones.get("ground_s"), "released": drones.get("released"),
        "worst_owner_silence_s": max(v["worst_owner_silence_s"] for v in per.values()),
        "owner_silence_p50_p90_s": _p50_p90([v["worst_owner_silence_s"] for v in per.values()]),
        # the target (worst silence <= 1 s) per drone, and the drones' own judgement of it: how many
        # reported their owner's link DEGRADED (or LOST) in flight at least once
        "within_silence_target": sum(1 for v in per.values() if v["worst_owner_silence_s"] <= SILENCE_TARGET_S),
        "owner_judged_silent_drones": sum(1 for r in drones["results"].values() if r.get("owner_judged_silent")),
        # the five worst drones' silences: when (after take-off), under which owner and epoch
        "worst_owner_silences": sorted(({"drone": n, "s": v["worst_owner_silence_s"], **(v["at"] or {})}
                                        for n, v in per.items()), key=lambda x: -x["s"])[:5],
        "handovers": {"expected_each": expected, "min": min(handovers), "max": max(handovers), "total": sum(handovers)},
        "failures": {n: v["why"] for n, v in per.items() if not v["ok"]}, "runs": str(d),
        # the most live links any drone held at once, and the links closed (links that follow the drone)
        "links_max_per_drone": max(r.get("links_peak", 0) for r in drones["results"].values()),
        "links_closed": sum(r.get("links_closed", 0) for r in drones["results"].values())}
    if corridor:
        row["corridor"] = {"length_m": corridor, "spacing_m": round(corridor_layout(g, corridor)[0]),
                           "radius_m": round(corridor_layout(g, corridor)[1]), "links_max": 3,
                           "start_to_takeoff_s": drones.get("ground_s")}
    if error:
        row["error"] = error
    refused = {g: sum(v for k, v in c.items() if k.endswith("too_many_senders")) for g, c in row["gs_inbox_drops"].items()}
    row["notes"] = [f"GS {g}'s inbox refused {n} items from senders beyond its queue bound" for g, n in refused.items() if n]
    row.update(_load(drones, stations, window, zid_site, sites))
    if "restart" in window:
        from zdrone.bench.gsrestart import relinked

        row["restart"] = {**window["restart"], **relinked(d, k, window["restart"], stations)}
        row["gs_processes"] = len(gs_parts)
    row["worst_silences_seen_before"] = _gaps_before(d, len(hosts), row["worst_owner_silences"])
    if (sampled := window.get("sampler")) is not None:  # each process's CPU and wait for one during them
        row["machine_during_worst_silences"] = {
            str(w["after_takeoff_s"]): sampled.around(window["t"], w["after_takeoff_s"], before=w["s"])
            for w in row["worst_owner_silences"] if "after_takeoff_s" in w}
    return row


def _gaps_before(d: Path, parts: int, worst: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """For each of the worst owner silences (a drone's loop saw it), the same GS's gap to that drone
    at the drone's Zenoh callback and at the GS's put, if one ended within a second of it
    (``FrameGaps``): where the silence began."""
    try:
        drones = [json.loads((d / f"gaps-{drones_file(i, parts)}").read_text()) for i in range(parts)]
        puts = json.loads((d / "gaps-stations.json").read_text())["gaps"]
    except (OSError, ValueError, KeyError):
        return []
    t0 = drones[0]["t0"]
    arrived = [g for x in drones for g in x["gaps"]]
    out = []
    for w in worst:
        if "after_takeoff_s" not in w:
            continue
        end = t0 + w["after_takeoff_s"]

        def near(gaps: list[list[Any]]) -> float | None:
            found = [g[2] for g in gaps if g[0] == w["owner"] and g[1] == w["drone"] and abs(g[3] - end) <= 1.0]
            return max(found) if found else None

        out.append({"drone": w["drone"], "s": w["s"], "at_callback_s": near(arrived), "at_put_s": near(puts)})
    return out


def _p50_p90(xs: list[float]) -> list[float]:
    """The median and 90th percentile of the drones' worst silences (nearest rank)."""
    ys = sorted(xs)
    return [ys[(len(ys) - 1) // 2], ys[min(len(ys) - 1, int(0.9 * len(ys)))]] if ys else []


def _load(drones: dict[str, Any], stations: dict[str, Any], window: dict[str, Any], zid_site: dict[str, str],
          sites: int) -> dict[str, Any]:
    """CPU per process and message rates over the flight window."""
    if "t_end" not in window:
        return {}
    span = max(1e-6, window["t_end"] - window["t"])
    cpu = {n: round(100.0 * (window["cpu_end"][n] - c) / span, 1) if c is not None and window["cpu_end"][n] is not None else None
           for n, c in window["cpu"].items()}
    cpu["drones host"] = drones.get("cpu_percent", round(100.0 * drones["cpu_s"] / max(1e-6, drones["flight_s"]), 1))
    memory = {**window.get("memory", {}), "drones host": drones.get("memory_mb")}
    parts = [n for n in cpu if n.startswith("stations-")]
    if parts:  # a GS per process: the class is their sum (unknown if one restarted)
        each = [cpu[n] for n in parts]
        cpu["stations host"] = None if None in each else round(sum(each), 1)  # type: ignore[arg-type]
        mems = [memory.get(n) for n in parts]
        memory["stations host"] = None if None in mems else {  # type: ignore[index]
            k: round(sum(m[k] for m in mems), 1) for k in ("rss", "peak")}
    zids = {**drones["router_zid"], **stations["router_zid"]}
    site_of = {node: zid_site.get(z or "", "?") for node, z in zids.items()}
    delivered = across = 0
    for receiver, by_sender in [*drones["delivered"].items(), *stations["delivered"].items()]:
        for sender, n in by_sender.items():
            delivered += n
            across += n if site_of.get(sender) != site_of.get(receiver) else 0
    out: dict[str, Any] = {
        "window_s": round(span, 1), "cpu_percent": cpu, "memory_mb": memory, "cpu_busiest": window.get("cpu_busiest"),
        "drones_host_slow": drones.get("slow"),
        "stations_host_gc": stations.get("gc"),
        "stations_host_loops": stations.get("loops"),
        "drone_host_shares": drones.get("shares"), "drones_host_passes_per_s": drones.get("passes_per_s"),
        "drones_host_step_late": drones.get("step_late"),
        "drones_per_site": dict(Counter(site_of[n] for n in drones["router_zid"])),
        "samples_per_s": round(delivered / span, 1)}
    before, after = window.get("socks"), window.get("socks_end")
    if after is not None:
        routers = _traffic(before, after, list(after))  # the routers' client links (the mesh is QUIC: UDP)
        out["routers_tcp_segments_per_s"] = round(routers["segments"] / span, 1)
    if sites:
        out["mesh"] = {"samples_per_s": round(across / span, 1)}
    return out


def run(quick: bool = False, ks: list[int] | None = None, stations: int = 3, progress: bool = True, sites: int = 0,
        drone_router: str = "spread", inbox_senders: int | None = None, speedup: float | None = None,
        drone_hosts: int = 1, compare: bool = True, hosts_nice: int = HOSTS_NICE,
        corridor: float = 0.0, station_counts: list[int] | None = None, gs_processes: bool = False,
        restart: str | None = None) -> dict[str, Any]:
    """Fly each K; with ``sites``, each K through the site routers and (unless ``quick`` or not
    ``compare``) through one TLS router for comparison; ``inbox_senders`` lifts the GSs' inbox bound (a what-if, reported).
    ``speedup``: the simulators' (the flight's sim time per wall second; the telemetry's rate grows with it);
    None: by K (``speedup_for``), each row saying its own.
    ``drone_hosts``: processes the drones are stepped in (a what-if, reported: on 2 cores, three hosts of
    100 drones made slower passes than one host of 300). ``hosts_nice``: the niceness of the drones and
    GSs hosts (``HOSTS_NICE``). ``corridor``: the GSs along that many metres (``station_counts``: each a row,
    e.g. 5, 10, 20 at a fixed K), half the drones flying it each way at ``CORRIDOR_SPEED_MS``, one way each.
    ``gs_processes``: each GS in a process of its own; ``restart``: that GS crashes after the take-off and
    starts again with no key (``_restart_gs``)."""
    if corridor:
        return _run_corridor(ks or [10], station_counts or [stations], corridor, sites, speedup, drone_hosts,
                             hosts_nice, progress)
    ks = ks or ([3] if quick else ([25, 50, 100] if sites else [10, 25, 50]))
    base = Path(tempfile.mkdtemp(prefix="zdrone-bench-scale-"))
    rows = []
    from zdrone.bench.table import ProgressLine

    status = ProgressLine(progress)
    try:
        for k in ks:
            sp = speedup if speedup is not None else speedup_for(k)
            flight_s = FLIGHT_SIM_S / sp
            at = len(rows)
            if sites:
                status.say(f"{k} drones x {stations} GSs flying over {sites} site routers (speed-up {sp:g})…")
                rows.append(_one(k, stations, base, timeout=flight_s, sites=sites, drone_router=drone_router,
                                 inbox_senders=inbox_senders, speedup=sp, drone_hosts=drone_hosts, hosts_nice=hosts_nice,
                                 gs_processes=gs_processes, restart=restart))
                if compare and not quick:
                    status.say(f"{k} drones x {stations} GSs flying through one router (TLS), for comparison…")
                    rows.append(_one(k, stations, base, timeout=flight_s, tls=True, inbox_senders=inbox_senders,
                                     speedup=sp, drone_hosts=drone_hosts, hosts_nice=hosts_nice))
            else:
                status.say(f"{k} drones x {stations} GSs flying (speed-up {sp:g})…")
                rows.append(_one(k, stations, base, timeout=flight_s, inbox_senders=inbox_senders, speedup=sp,
                                 drone_hosts=drone_hosts, hosts_nice=hosts_nice, gs_processes=gs_processes,
                                 restart=restart))
            for row in rows[at:]:
                row["speedup"] = sp
    finally:
        status.close()

    def largest(of: list[dict[str, Any]]) -> int:
        good = [r["k"] for r in of if r.get("all_correct")]
        return max(good) if good else 0

    main_rows = [r for r in rows if r.get("sites", 1) == (sites or 1)]
    result: dict[str, Any] = {"rows": rows, "largest_k_all_correct": largest(main_rows), "stations": stations,
                              "gs_inbox_senders": inbox_senders, "speedup": speedup,
                              "speedup_by_k": speedup is None, "drone_hosts": drone_hosts,
                              "hosts_nice": hosts_nice}
    if sites:
        result.update({"sites": sites, "drone_router": drone_router,
                       "largest_k_all_correct_one_router": largest([r for r in rows if r.get("sites") == 1]),
                       "layout": f"{sites} site routers meshed over mutual TLS (GS i at site i; drones "
                                 f"{'spread round-robin over the sites' if drone_router == 'spread' else 'given every site'}) | "
                                 "one process hosting K drone nodes (in-process simulators) | one hosting the G GSs",
                       "target": {"k": 300, "g": 3, "sites": 3}})
    else:
        result.update({"layout": "router | one process hosting K drone nodes (in-process simulators) | one hosting the G GSs",
                       "target": {"k": 300, "g": 3}})
    return result


#: A corridor's drones cruise at this speed (m/s): 40 km one way in 2 000 simulated seconds.
CORRIDOR_SPEED_MS = 20.0


def _run_corridor(ks: list[int], counts: list[int], length: float, sites: int, speedup: float | None,
                  drone_hosts: int, hosts_nice: int, progress: bool) -> dict[str, Any]:
    """``bench scale --layout corridor``: for each K and each GS count, one flight along the corridor."""
    from zdrone.bench.table import ProgressLine

    base = Path(tempfile.mkdtemp(prefix="zdrone-bench-corridor-"))
    rows: list[dict[str, Any]] = []
    status = ProgressLine(progress)
    try:
        for k in ks:
            for g in counts:
                sp = speedup if speedup is not None else speedup_for(k)
                status.say(f"corridor {length / 1000:g} km: {k} drones x {g} GSs over {sites or 1} site router(s) "
                           f"(speed-up {sp:g})…")
                row = _one(k, g, base, timeout=(length / CORRIDOR_SPEED_MS + 300.0) / sp, sites=sites, speedup=sp,
                           drone_hosts=drone_hosts, hosts_nice=hosts_nice, corridor=length)
                rows.append({**row, "speedup": sp})
    finally:
        status.close()
    for r in rows:  # CPU per drone of each process class (ms of CPU per second, per drone)
        r["cpu_ms_per_s_per_drone"] = {n: round(10.0 * v / r["k"], 3) for n, v in r.get("cpu_percent", {}).items()
                                       if v is not None}
    return {"rows": rows, "layout": f"corridor of {length / 1000:g} km", "stations": counts, "sites": sites,
            "largest_k_all_correct": max([r["k"] for r in rows if r.get("all_correct")], default=0),
            "speedup": speedup, "drone_hosts": drone_hosts, "hosts_nice": hosts_nice,
            "links_max_per_drone": max((r.get("links_max_per_drone", 0) for r in rows), default=0),
            "target": {"k": 100, "g": 20, "sites": 4, "links_max": 3}}


def render(r: dict[str, Any]) -> None:
    from zdrone.bench.table import print_table

    if r.get("layout", "").startswith("corridor"):
        return _render_corridor(r)

    def layout(x: dict[str, Any]) -> str:
        return f"{x['sites']} sites" if x.get("sites", 1) > 1 else "1 router"

    def rate(v: Any) -> str:
        return "-" if v is None else f"{v:,.0f}"

    def failures(x: dict[str, Any]) -> str:
        """The failures grouped by reason (first drones named), then the GS inbox's refusals."""
        by_why: dict[str, list[str]] = {}
        for name, why in x.get("failures", {}).items():
            by_why.setdefault(", ".join(why), []).append(name)
        parts = [f"{why}: {', '.join(names[:3])}{'…' if len(names) > 3 else ''}" for why, names in by_why.items()]
        refused = {g: sum(v for k, v in c.items() if k.endswith("too_many_senders")) for g, c in x.get("gs_inbox_drops", {}).items()}
        parts += [f"GS {g} inbox: {n} refused (sender bound)" for g, n in refused.items() if n]
        return "; ".join(parts) or x.get("error", "")

    rows = [[layout(x) if "sites" in x else x.get("layout", "-"), f"{x['k']} x {x['g']}", x.get("correct", "error"),
             "yes" if x.get("all_correct") else "no", x.get("worst_owner_silence_s", "-"), x.get("ground_s", "-"),
             x.get("wall_s", "-"), failures(x)] for x in r["rows"]]
    target = r["target"]
    where = f"over {r['sites']} site routers" if r.get("sites") else "through one router"
    caption = (f"largest K with all hand-overs correct and TBM healthy: {r['largest_k_all_correct']} "
               f"(target {target['k']} x {target['g']}); simulators at speed-up "
               + "/".join(sorted({f"{x.get('speedup', r.get('speedup') or SPEEDUP):g}" for x in r["rows"]}, key=float))
               + (f" (by K: {SPEEDUP:g} up to {FAST_MAX_K} drones, 1 above)" if r.get("speedup_by_k") else ""))
    if r.get("sites"):
        if any(x.get("sites") == 1 for x in r["rows"]):
            caption += f"; through one router: {r['largest_k_all_correct_one_router']}"
        caption += "; every link mutual TLS"
    if r.get("gs_inbox_senders"):
        caption += f"; what-if: GS inbox bound set to {r['gs_inbox_senders']} (kind, sender) queues with items"
    if r.get("drone_hosts", 1) > 1:
        caption += f"; what-if: the drones stepped in {r['drone_hosts']} processes"
    caption += f"; drones and GSs hosts at nice {r.get('hosts_nice', 0)} (their threads and session)"
    for x in r["rows"]:
        if "restart" in x:  # ``--restart-gs``
            rs = x["restart"]
            caption += (f"; {x['k']} x {x['g']}: GS {rs['gs']} crashed {rs['killed_after_takeoff_s']:g} s after the take-off and "
                        f"started again with no key: up in {rs.get('up_s', '-')} s; every drone held its new key "
                        f"{rs.get('relinked_s', '-')} s after the crash (median {rs.get('relinked_p50_s', '-')} s; "
                        f"{rs.get('drones_relinked', '-')} of {x['k']}), each confirmed to it by the drone's first "
                        f"words in its radio, all by {rs.get('confirmed_s', '-')} s"
                        f"{'; ' + rs['error'] if rs.get('error') else ''}")
    print_table(f"Scale: drones x ground stations {where}", ["layout", "K x G", "correct", "all correct",
                "worst authority silence s", "ground s", "wall s", "failures"], rows,
                caption=caption + "; ground: key sharing before take-off")

    def cpu(x: dict[str, Any], which: str) -> str:
        vals = [v for n, v in x.get("cpu_percent", {}).items() if n.startswith(which)]
        return "/".join("-" if v is None else f"{v:.0f}" for v in vals) or "-"

    def mesh(x: dict[str, Any], field: str) -> str:
        return rate(x.get("mesh", {}).get(field)) if x.get("sites", 1) > 1 else "-"

    def mem(x: dict[str, Any], which: str) -> str:
        vals = [v for n, v in x.get("memory_mb", {}).items() if n.startswith(which)]
        return "/".join("-" if v is None else f"{v['rss']:.0f} ({v['peak']:.0f})" for v in vals) or "-"

    load = [[layout(x), f"{x['k']} x {x['g']}", cpu(x, "router"), mem(x, "router"), cpu(x, "drones host"), cpu(x, "stations host"),
             rate(x.get("samples_per_s")), mesh(x, "samples_per_s")]
            for x in r["rows"] if "cpu_percent" in x]
    if load:
        print_table("Load over the flight (CPU: 100 % = one core)", ["layout", "K x G", "CPU % routers", "RSS MB routers (peak)", "CPU % drones",
                    "CPU % GSs", "samples /s", "mesh samples /s"], load,
                    caption="CPU: each router, the drones hosts (summed), the GSs host; RSS: each router's resident memory at the end of the flight (its peak); samples: pub/sub samples delivered to the "
                            "nodes; mesh samples: those from a node on another site's router (each crossed one "
                            "router-to-router link, QUIC with mutual TLS; --json: every router's TCP client sockets)")


def _render_corridor(r: dict[str, Any]) -> None:
    from zdrone.bench.table import print_table

    def cpu(x: dict[str, Any], which: str) -> str:
        vals = [v for n, v in x.get("cpu_ms_per_s_per_drone", {}).items() if n.startswith(which)]
        return "/".join(f"{v:.2f}" for v in vals) or "-"

    rows = [[f"{x['k']} x {x['g']}", x.get("sites", 1), x.get("correct", "error"), x.get("links_max_per_drone", "-"),
             x.get("links_closed", "-"), x.get("ground_s", "-"), x.get("worst_owner_silence_s", "-"),
             cpu(x, "drones host"), cpu(x, "stations host"), cpu(x, "router"), x.get("wall_s", "-"),
             "; ".join(f"{n}: {', '.join(w)}" for n, w in list(x.get("failures", {}).items())[:3]) or x.get("error", "")]
            for x in r["rows"]]
    print_table(f"Corridor: {r['layout']}, links following the drones (at most 3 each)",
                ["K x G", "sites", "correct", "links max/drone", "links closed", "start to take-off s",
                 "worst authority silence s", "CPU ms/s/drone drones", "GSs", "routers", "wall s", "failures"], rows,
                caption="half the drones fly east from A, half west from the last GS, one hand-over at each GS; correct: "
                        "every hand-over, no authority gap, no command lost, no failsafe, landed; CPU per drone of each "
                        "process class (each router apart)")


def run_cli(args: argparse.Namespace) -> dict[str, Any]:
    """``zdrone bench scale``: its options checked (``UsageError``: one line, exit 2), then ``run``."""
    try:
        ks = [int(x) for x in args.drones.split(",")] if args.drones else None
    except ValueError:
        raise UsageError(f"--drones {args.drones!r}: expected numbers like 10,25,50") from None
    from zdrone.fleet.files import MAX_SCALE_DRONES

    try:
        counts = [int(x) for x in str(args.stations).split(",")]
    except ValueError:
        raise UsageError(f"--stations {args.stations!r}: expected numbers like 3 or 5,10,20") from None
    if ks and not all(1 <= k <= MAX_SCALE_DRONES for k in ks) or not all(2 <= g <= 26 for g in counts):
        raise UsageError(f"--drones: each 1..{MAX_SCALE_DRONES}; --stations: 2..26")
    if len(counts) > 1 and args.layout != "corridor":
        raise UsageError("--stations G,G,…: only with --layout corridor")
    args.stations = min(counts)
    if args.sites is not None and not 2 <= args.sites <= args.stations:
        raise UsageError(f"--sites {args.sites}: must be 2..{args.stations} (a site per ground station at most)")
    if args.drone_router is not None and args.sites is None:
        raise UsageError("--drone-router: only with --sites")
    if args.hosts_nice is not None and not 0 <= args.hosts_nice <= 19:
        raise UsageError(f"--hosts-nice {args.hosts_nice}: must be 0..19")
    if args.sites_only and args.sites is None:
        raise UsageError("--sites-only: only with --sites")
    if args.inbox_senders is not None and not 64 <= args.inbox_senders <= 100_000:
        raise UsageError(f"--inbox-senders {args.inbox_senders}: must be 64..100000")
    if args.speedup is not None and not 0.5 <= args.speedup <= 8.0:
        raise UsageError(f"--speedup {args.speedup:g}: must be 0.5..8")
    if args.speedup is not None and args.speedup > 1.0 and any(k > FAST_MAX_K for k in ks or ()):
        print(f"zdrone bench scale: note: --speedup {args.speedup:g} with more than {FAST_MAX_K} drones: their "
              f"telemetry grows with the speed-up (300 drones flew 0 of 300 at 4); without --speedup they fly at 1",
              file=sys.stderr)
    if not 1 <= args.drone_hosts <= 8:
        raise UsageError(f"--drone-hosts {args.drone_hosts}: must be 1..8")
    if args.restart_gs is not None and (args.layout != "line" or args.restart_gs not in
                                        [chr(ord("A") + i) for i in range(1, args.stations)]):
        raise UsageError(f"--restart-gs {args.restart_gs}: a GS of the line other than A (B..{chr(ord('A') + args.stations - 1)})")
    return run(quick=args.quick, ks=ks, stations=args.stations, progress=not args.json, sites=args.sites or 0,
               drone_router=args.drone_router or "spread", inbox_senders=args.inbox_senders,
               speedup=args.speedup, drone_hosts=args.drone_hosts, compare=not args.sites_only,
               hosts_nice=HOSTS_NICE if args.hosts_nice is None else args.hosts_nice,
               corridor=args.length * 1000.0 if args.layout == "corridor" else 0.0, station_counts=counts,
               gs_processes=args.gs_processes, restart=args.restart_gs)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m zdrone.bench.scale")
    sub = p.add_subparsers(dest="role", required=True)
    hd = sub.add_parser("host-drones")
    hd.add_argument("--k", type=int, required=True)
    hd.add_argument("--speedup", type=float, default=SPEEDUP)
    hd.add_argument("--duration", type=float, default=150.0, help="flight time limit, from take-off")
    hd.add_argument("--hold", type=float, default=60.0, help="longest pre-flight hold (key sharing), s")
    hd.add_argument("--jam", metavar="DRONE", help="SIGUSR1 cuts this drone's radio, SIGUSR2 mends it (bench revoke)")
    hd.add_argument("--part", type=int, default=0, help="with --parts P: host the drones d(i+1) with i mod P == this")
    hd.add_argument("--parts", type=int, default=1, help="drones hosts sharing the fleet (one process each)")
    hd.add_argument("--station-hosts", type=int, default=1, help="GS host processes (each says when it has counted)")
    hd.add_argument("--drone-router", choices=("spread", "all"), default="spread",
                    help="spread: drone i uses the (i mod N)-th router of --router; all: every drone gets the whole list")
    hs = sub.add_parser("host-stations")
    hs.add_argument("--stations", type=int, required=True)
    hs.add_argument("--inbox-senders", type=int, help="lift the GS inbox's bound on (kind, sender) queues to this")
    hs.add_argument("--k", type=int, default=0, help="the fleet's drones (a corridor's two ways)")
    hs.add_argument("--corridor-speed", type=float, default=CORRIDOR_SPEED_MS)
    hs.add_argument("--kill-owner", metavar="GS", help="kill this GS once it has owned a drone in the air --kill-after s")
    hs.add_argument("--kill-after", type=float, default=2.0)
    hs.add_argument("--only", metavar="G[,G…]", help="host only these GSs (the others run in processes of their own)")
    for sp in (hd, hs):
        sp.add_argument("--latency", action="store_true",
                        help="note messages for one-way latency from the take-off on (bench overhead; zdrone.bench.latency)")
        sp.add_argument("--fleet", required=True)
        sp.add_argument("--corridor", type=float, default=0.0, metavar="M",
                        help="a corridor this long (m): half the drones fly it east from A, half west from the last GS")
        sp.add_argument("--round-trip", action="store_true", help="a corridor's drones fly back to where they took off")
        sp.add_argument("--router", required=True, help="router endpoint(s), comma-separated")
        sp.add_argument("--out", required=True)
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    return _host_drones(args) if args.role == "host-drones" else _host_stations(args)


if __name__ == "__main__":
    sys.exit(main())
