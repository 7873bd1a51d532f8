"""The ``zdrone`` command. Errors are one line on stderr and exit code 2, never a traceback."""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path
from typing import Callable, Sequence

from zdrone.core.errors import ConfigError, UsageError

log = logging.getLogger("zdrone")


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, exit 2
        where = self.prog.removeprefix("zdrone").strip()
        raise UsageError(f"{where}: {message}" if where else message)


def _fleet_init(args: argparse.Namespace) -> int:
    from zdrone.fleet.files import init_fleet

    sites = [s for s in args.sites.split(",") if s] if args.sites else None
    if args.revision_lease < 0:
        raise UsageError(f"fleet init: --revision-lease {args.revision_lease:g}: must be 0 (none) or more")
    fleet = init_fleet(args.dir, force=args.force, tls=args.tls, sites=sites, revision_lease=args.revision_lease)
    print(f"wrote {args.dir}/fleet.json5 with nodes: " + ", ".join(
        f"{n} ({v.role}, sysid {v.sysid})" for n, v in fleet.nodes.items()))
    print(f"secrets in {args.dir}/secrets/ (mode 0600), router credentials in {args.dir}/router/")
    return 0


def _fleet_export(args: argparse.Namespace) -> int:
    from zdrone.fleet.bundle import export_bundle

    b = export_bundle(args.dir, args.node, args.out)
    print(f"wrote {args.out}: the bundle of {b.node} ({b.role}{', TLS' if b.tls else ''}): " + ", ".join(b.files))
    return 0


def _fleet_show(args: argparse.Namespace) -> int:
    from pathlib import Path

    from zdrone.fleet.bundle import BUNDLE_FILE, check_bundle
    from zdrone.fleet.files import fleet_path, load_fleet, load_secret

    if (fleet_path(args.dir).parent / BUNDLE_FILE).is_file():
        b = check_bundle(fleet_path(args.dir).parent) if args.check_secrets else None
        if b is not None:
            print(f"bundle of {b.node} ({b.role}{', TLS' if b.tls else ''}): its own secrets only, "
                  f"files: {', '.join(b.files)}")
    elif args.check_secrets and (Path(fleet_path(args.dir).parent) / "tls" / "ca.key").exists():
        print("a whole fleet directory (every node's secret and the CA key): for the issuing machine, not a host; "
              "give each host its bundle (zdrone fleet export NODE)")
    fleet = load_fleet(args.dir)
    in_bundle = (fleet_path(args.dir).parent / BUNDLE_FILE).is_file()
    for name, node in fleet.nodes.items():
        load_secret(args.dir, name, fleet) if args.check_secrets and not in_bundle else None
        extra = f" authorized: {','.join(node.authorized_gs) or '-'}" if node.role == "drone" else (
            f" coverage: {node.coverage.lat:.6f},{node.coverage.lon:.6f} r={node.coverage.radius_m:g} m" if node.coverage else "")
        print(f"{name:6} {node.role:5} sysid {node.sysid:3}{extra}")
    return 0


def _service(args: argparse.Namespace) -> int:
    import os
    import shutil

    from zdrone.fleet.service import render_unit, service_spec
    from zdrone.vehicle.transport import parse_endpoint

    if args.vehicle and not args.vehicle.startswith("/dev/"):
        parse_endpoint(args.vehicle)  # a bad connection is a usage error
    if not 0.01 <= args.events_max_mb <= 100_000:
        raise UsageError(f"--events-max-mb {args.events_max_mb:g}: must be 0.01..100000")
    exe = args.exec or shutil.which("zdrone") or os.path.abspath(sys.argv[0])
    if not os.path.isabs(exe):
        raise UsageError(f"--exec {exe}: must be an absolute path")
    import shlex

    extra = tuple(shlex.split(args.node_options or ""))
    print(render_unit(service_spec(args.node, args.bundle, exe, router=args.router, vehicle=args.vehicle,
                                   events_max_mb=args.events_max_mb, extra=extra)), end="")
    return 0


def _emit(args: argparse.Namespace, result: dict, render: Callable[[dict], None]) -> None:
    """Every bench prints a table for people, or ``--json`` for tools."""
    from zdrone.bench import table

    if args.json:
        table.print_json(result)
    else:
        render(result)


def _bench_crypto(args: argparse.Namespace) -> int:
    from zdrone.bench import crypto

    _emit(args, crypto.run(quick=args.quick), crypto.render)
    return 0


def _bench_traffic(args: argparse.Namespace) -> int:
    from pathlib import Path

    from zdrone.bench import traffic

    result = traffic.run(quick=args.quick, out=Path(args.out) if args.out else None, progress=not args.json,
                         autopilot=args.autopilot)
    _emit(args, result, traffic.render)
    return 0 if all("error" not in r for r in result["rows"]) else 1


def _bench_link(args: argparse.Namespace) -> int:
    from zdrone.bench import link

    _emit(args, link.run(quick=args.quick, progress=not args.json), link.render)
    return 0


def _bench_handover(args: argparse.Namespace) -> int:
    from zdrone.bench import handover

    for name in ("crossings", "trials"):
        v = getattr(args, name)
        if v is not None and not 1 <= v <= 50:
            raise UsageError(f"--{name} {v}: must be 1..50")
    result = handover.run(quick=args.quick, crossings=args.crossings, trials=args.trials, progress=not args.json)
    _emit(args, result, handover.render)
    return 0


def _bench_scale(args: argparse.Namespace) -> int:
    from zdrone.bench import scale

    _emit(args, scale.run_cli(args), scale.render)
    return 0


def _bench_overhead(args: argparse.Namespace) -> int:
    from zdrone.bench import overhead

    try:
        ks = overhead.parse_drones(args.drones, args.quick)
        overhead.check_args(args.sites, args.stations, args.flight)
    except overhead.OverheadArgsError as exc:
        raise UsageError(str(exc)) from None
    if args.speedup is not None and not 0.5 <= args.speedup <= 8.0:
        raise UsageError(f"--speedup {args.speedup:g}: must be 0.5..8")
    if args.hosts_nice is not None and not 0 <= args.hosts_nice <= 19:
        raise UsageError(f"--hosts-nice {args.hosts_nice}: must be 0..19")
    if args.from_json is not None:
        try:
            result = json.loads(Path(args.from_json).read_text())
        except (OSError, ValueError) as exc:
            raise UsageError(f"--from-json {args.from_json}: {exc}") from None
    else:
        if not 1 <= args.runs <= 10:
            raise UsageError(f"--runs {args.runs}: must be 1..10")
        if not 1 <= args.drone_hosts <= 8:
            raise UsageError(f"--drone-hosts {args.drone_hosts}: must be 1..8")
        result = overhead.run(ks, stations=args.stations, sites=args.sites, flight=args.flight, quick=args.quick,
                              speedup=args.speedup, progress=not args.json, hosts_nice=args.hosts_nice,
                              runs=args.runs, drone_hosts=args.drone_hosts)
    if args.plot is not None:
        from zdrone.bench.overheadplot import plot

        log.info("CPU per drone plotted to %s", plot(result, Path(args.plot)))
    _emit(args, result, overhead.render)
    return 0 if all(not r.get("errors") for r in result["rows"]) else 1


def _bench_soak(args: argparse.Namespace) -> int:
    from pathlib import Path

    from zdrone.bench import soak
    from gs.planner import MAX_SHUTTLE_CROSSINGS

    if not 1 <= args.crossings <= MAX_SHUTTLE_CROSSINGS:
        raise UsageError(f"--crossings {args.crossings}: must be 1..{MAX_SHUTTLE_CROSSINGS}")
    if not 1.0 <= args.speedup <= 8.0:
        raise UsageError(f"--speedup {args.speedup:g}: must be 1..8 (the hand-over timers are wall-clock)")
    result = soak.run(crossings=args.crossings, speedup=args.speedup, quick=args.quick, progress=not args.json,
                      out=Path(args.out) if args.out else None)
    result["missed"] = soak.verdict(result, growth=not args.quick)
    _emit(args, result, soak.render)
    return 0 if result["flight_ok"] and not result["missed"] else 1


def _bench_chaos(args: argparse.Namespace) -> int:
    from zdrone.bench import chaos

    if not 1 <= args.runs <= 1000:
        raise UsageError(f"--runs {args.runs}: must be 1..1000")
    if not 1 <= args.jobs <= 8:
        raise UsageError(f"--jobs {args.jobs}: must be 1..8")
    result = chaos.run(args.runs, args.seed, quick=args.quick, progress=not args.json, sites=args.sites, jobs=args.jobs)
    _emit(args, result, chaos.render)
    return 0 if result["violations"] == 0 else 1


def _bench_restart(args: argparse.Namespace) -> int:
    from zdrone.bench import restart

    if not 1 <= args.runs <= 200:
        raise UsageError(f"--runs {args.runs}: must be 1..200")
    result = restart.run(args.runs, quick=args.quick, progress=not args.json)
    _emit(args, result, restart.render)
    return 0 if result["ok"] else 1


def _bench_revoke(args: argparse.Namespace) -> int:
    from zdrone.bench import revoke

    if args.drones is not None and not 1 <= args.drones <= 150:
        raise UsageError(f"--drones {args.drones}: must be 1..150")
    actions = [a for a in (args.only or "revoke,rotate").split(",") if a]
    if not actions or any(a not in ("revoke", "rotate") for a in actions):
        raise UsageError(f"--only {args.only}: revoke, rotate or both (revoke,rotate)")
    result = revoke.run(args.quick, args.drones, actions=actions)
    _emit(args, result, revoke.render)
    return 0 if all("error" not in row for row in result["rows"]) else 1


def _bench_sweep(args: argparse.Namespace) -> int:
    from pathlib import Path

    from zdrone.bench import sweep
    from zdrone.sil.launcher import MOMENTS, SCENARIO_BY_NAME

    names = [n for n in (args.scenarios or "").split(",") if n]
    bad = [n for n in names if n not in SCENARIO_BY_NAME]
    if bad:
        raise UsageError(f"--scenarios: unknown scenario {bad[0]!r}")
    moments = [m for m in (args.moments or "").split(",") if m]
    if any(m not in MOMENTS for m in moments):
        raise UsageError(f"--moments: one of {', '.join(MOMENTS)}")
    try:
        speedups = [float(x) for x in (args.speedups or "").split(",") if x]
    except ValueError:
        raise UsageError(f"--speedups {args.speedups}: numbers, e.g. 1,2,4") from None
    if not 1 <= args.jobs <= 8:
        raise UsageError(f"--jobs {args.jobs}: must be 1..8")
    result = sweep.run(quick=args.quick, jobs=args.jobs, scenarios=names, speedups=speedups, moments=moments,
                       out=Path(args.out) if args.out else None, progress=not args.json, sites=args.sites)
    _emit(args, result, sweep.render)
    return 0 if result["failed"] == 0 and result["cells"] > 0 else 1


def _bench_view(args: argparse.Namespace) -> int:
    from pathlib import Path

    from zdrone.bench import view

    if args.crossings is not None and not 1 <= args.crossings <= 500:
        raise UsageError(f"--crossings {args.crossings}: must be 1..500")
    if args.drones is not None and not 1 <= args.drones <= 300:
        raise UsageError(f"--drones {args.drones}: must be 1..300")
    if args.clients is not None and not 1 <= args.clients <= 10_000:
        raise UsageError(f"--clients {args.clients}: must be 1..10000")
    if args.forged_rate is not None and not 0 < args.forged_rate <= 20_000:
        raise UsageError(f"--forged-rate {args.forged_rate:g}: must be more than 0, at most 20000")
    only = view.DEFAULT_PARTS
    if args.only is not None:
        only = tuple(p for p in args.only.split(",") if p)
        bad = [p for p in only if p not in view.PARTS]
        if bad or not only:
            raise UsageError(f"--only {args.only}: one or more of {','.join(view.PARTS)}")
    if args.flood_rate is not None and not 0 <= args.flood_rate <= 100_000:
        raise UsageError(f"--flood-rate {args.flood_rate:g}: must be 0 (no limit) .. 100000")
    result = view.run(quick=args.quick, crossings=args.crossings, drones=args.drones, progress=not args.json,
                      out=Path(args.out) if args.out else None, only=only, clients=args.clients,
                      forged_rate=args.forged_rate, flood_rate=args.flood_rate)
    _emit(args, result, view.render)
    return 1 if view.failed(result) else 0


def _bench_attack(args: argparse.Namespace) -> int:
    from zdrone.bench import attack
    from zdrone.sil.launcher import ATTACK_SCENARIOS

    names = None
    if args.scenarios is not None:
        names = [n for n in args.scenarios.split(",") if n] if args.scenarios else []
        bad = [n for n in names if n not in ATTACK_SCENARIOS]
        if bad:
            raise UsageError(f"--scenarios: unknown {bad[0]!r} (attack scenarios: {', '.join(ATTACK_SCENARIOS)})")
    if args.trials is not None and not 0 <= args.trials <= 20:
        raise UsageError(f"--trials {args.trials}: must be 0..20")
    if args.junk_trials is not None and not 0 <= args.junk_trials <= 20:
        raise UsageError(f"--junk-trials {args.junk_trials}: must be 0..20")
    if not 1.0 <= args.rate <= 100_000.0:
        raise UsageError(f"--rate {args.rate:g}: must be 1..100000 queries/s")
    if not 1.0 <= args.junk_rate <= 1_000_000.0:
        raise UsageError(f"--junk-rate {args.junk_rate:g}: must be 1..1000000 puts/s")
    sizes = None
    if args.radio_sizes is not None:
        try:
            sizes = [int(x) for x in args.radio_sizes.split(",") if x]
        except ValueError:
            raise UsageError(f"--radio-sizes {args.radio_sizes!r}: expected byte counts like 500,1000,60000") from None
        if not all(2 <= x <= 1 << 20 for x in sizes):
            raise UsageError("--radio-sizes: each 2..1048576 bytes")
    result = attack.run(quick=args.quick, scenarios=names, trials=args.trials, rate=args.rate, progress=not args.json,
                        junk_rate=args.junk_rate, junk_trials=args.junk_trials, radio_sizes=sizes,
                        sessions=tuple(args.sessions) if args.sessions is not None else None)
    _emit(args, result, attack.render)
    return 0 if result["all_ok"] else 1


def _check(args: argparse.Namespace) -> int:
    from zdrone.check import run as check

    if args.depth < 1 or args.faults < 0:
        raise UsageError("check: --depth must be >= 1 and --faults >= 0")
    result = check.run(args.depth, args.faults, args.flaw, args.max_states, cores=args.cores, consent=args.consent)
    _emit(args, result, check.render)
    return 0 if result["ok"] else 1


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="zdrone", description="Secure hand-over of a drone's command authority over Zenoh.")
    p.add_argument("-v", "--verbose", action="count", default=0, help="more logging (-vv for debug)")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True

    fleet = sub.add_parser("fleet", help="make and check fleet identities and keys")
    fsub = fleet.add_subparsers(dest="fleet_command", metavar="ACTION", parser_class=_Parser)
    fsub.required = True
    fi = fsub.add_parser("init", help="write fleet.json5, per-node secret files and router credentials")
    fi.add_argument("--dir", default="fleet", help="fleet directory (default: ./fleet)")
    fi.add_argument("--force", action="store_true", help="overwrite an existing fleet")
    fi.add_argument("--sites", metavar="EP,EP,…",
                    help="a router per ground-station site, meshed: one endpoint per site (e.g. "
                         "tcp/127.0.0.1:7447,tcp/127.0.0.1:7448); writes router/site-N.json5 and router/sites.json")
    fi.add_argument("--tls", action="store_true",
                    help="also a fleet CA and a certificate per node and router; the router then requires them (mutual TLS)")
    from zdrone.fleet.files import DEFAULT_REVISION_LEASE_S

    fi.add_argument("--revision-lease", type=float, default=DEFAULT_REVISION_LEASE_S, metavar="S",
                    help="the owners' lease: from its first pairing, a drone's owner keeps authority only while the "
                         "drone hears a signed revision stamp from another GS authorized for it within S seconds "
                         "(default %(default)g; 0: none)")
    fi.set_defaults(func=_fleet_init)
    fs = fsub.add_parser("show", help="validate and list a fleet")
    fs.add_argument("--dir", default="fleet", help="fleet directory or fleet.json5 path")
    fs.add_argument("--check-secrets", action="store_true",
                    help="also load and check every secret file; on a bundle: say whose it is, and refuse it if it "
                         "holds any other node's secret or the CA key")
    fs.set_defaults(func=_fleet_show)
    from zdrone.checkroute import add_parser as add_check_route

    add_check_route(fsub)  # check-route: a mission's route before take-off
    fe = fsub.add_parser("export", help="write one host's bundle: exactly the files that node (or the router) needs")
    fe.add_argument("node", metavar="NODE", help="a node of the fleet (d1, A, …), router, or a site router (site-1, …)")
    fe.add_argument("--dir", default="fleet", help="the fleet directory (default: ./fleet)")
    fe.add_argument("--out", required=True, metavar="DIR", help="the bundle's folder (new or empty)")
    fe.set_defaults(func=_fleet_export)
    from zdrone.fleet.revise import add_parsers as add_revision_parsers
    from zdrone.net.revisions import publish_command

    add_revision_parsers(fsub, publish_command)  # revoke, rotate, revise, publish (signed fleet revisions)

    sv = sub.add_parser("service", help="print a hardened systemd unit that runs one host's node from its bundle")
    sv.add_argument("node", metavar="NODE", help="the node the bundle is for (d1, A, router, site-1, …)")
    sv.add_argument("--bundle", required=True, metavar="DIR",
                    help="the bundle's folder on that host (zdrone fleet export), e.g. /etc/zdrone/d1, owned by the "
                         "user zdrone")
    sv.add_argument("--vehicle", metavar="CONN",
                    help="drone only: the flight controller, e.g. /dev/ttyACM0,921600 (the unit allows that device "
                         "only) or udpin:0.0.0.0:14540 (default udpout:127.0.0.1:14580, zdrone sim)")
    sv.add_argument("--router", metavar="ENDPOINT",
                    help="the router the node connects to (default tcp/127.0.0.1:7447, tls/… with a TLS bundle); for "
                         "a router, the endpoint it listens on instead of its config's")
    sv.add_argument("--events-max-mb", type=float, default=64.0, metavar="MB", help="event log rotation size (64)")
    sv.add_argument("--exec", metavar="PATH", help="the zdrone command on that host (default: this one's full path)")
    sv.add_argument("--node-options", metavar="'OPTIONS'",
                    help="further options of the node command, e.g. --node-options='--pair --gcs udpin:0.0.0.0:14550' "
                         "(a --gcs endpoint is added to the unit's IP allow-list; 0.0.0.0 lifts it)")
    sv.set_defaults(func=_service)

    bench = sub.add_parser("bench", help="measure sizes, speeds and hand-over figures")
    bsub = bench.add_subparsers(dest="bench_command", metavar="BENCH", parser_class=_Parser)
    bsub.required = True
    bc = bsub.add_parser("crypto", help="bytes added and seal+open cost per MAVLink frame")
    bc.add_argument("--json", action="store_true", help="print JSON instead of a table")
    bc.add_argument("--quick", action="store_true", help="few iterations (proves it runs)")
    bc.set_defaults(func=_bench_crypto)

    bt = bsub.add_parser("traffic", help="packets/min and mean packet size: plain vs zdrone vs the paper (Table 1)")
    bt.add_argument("--json", action="store_true", help="print JSON instead of a table")
    bt.add_argument("--quick", action="store_true", help="15 s per variant instead of whole flights")
    bt.add_argument("--out", metavar="DIR", help="keep the runs here")
    bt.add_argument("--autopilot", choices=("px4", "ardupilot"), default="px4",
                    help="personality of the simulator the three stacks fly (default px4, as the paper's figures)")
    bt.set_defaults(func=_bench_traffic)

    bl = bsub.add_parser("link", help="GS -> vehicle latency p50/p99 and frames/s through the router, with and without security")
    bl.add_argument("--json", action="store_true", help="print JSON instead of a table")
    bl.add_argument("--quick", action="store_true", help="few frames (proves it runs)")
    bl.set_defaults(func=_bench_link)

    bh = bsub.add_parser("handover", help="repeated hand-overs under a 20 Hz command stream; link-loss to LAND latency")
    bh.add_argument("--json", action="store_true", help="print JSON instead of a table")
    bh.add_argument("--quick", action="store_true", help="2 crossings and 1 link-loss trial")
    bh.add_argument("--crossings", type=int, metavar="N", help="overlap crossings (default 6)")
    bh.add_argument("--trials", type=int, metavar="M", help="link-loss trials (default 3)")
    bh.set_defaults(func=_bench_handover)

    bs = bsub.add_parser("scale", help="K drones x G ground stations through one router (or a router per site), "
                                       "each drone doing hand-overs; CPU per process and message rates")
    bs.add_argument("--json", action="store_true", help="print JSON instead of a table")
    bs.add_argument("--quick", action="store_true", help="3 drones only (with --sites: the sites run only)")
    bs.add_argument("--drones", metavar="K,K,…", help="drone counts to try (default 10,25,50; with --sites 25,50,100)")
    bs.add_argument("--stations", default="3", metavar="G", help="ground stations (default 3; a corridor: G,G,… a row each)")
    bs.add_argument("--layout", choices=("line", "corridor"), default="line",
                    help="corridor: the GSs along --length km, half the drones flying it each way, links following them")
    bs.add_argument("--length", type=float, default=40.0, metavar="KM", help="the corridor's length (default 40)")
    bs.add_argument("--speedup", type=float, default=None, metavar="S",
                    help="the simulators' speed-up (default by K: 4 up to 100 drones, 1 above; the vehicles' "
                         "telemetry grows with it)")
    bs.add_argument("--sites", type=int, metavar="N",
                    help="N site routers meshed over mutual TLS (site n connects to sites 1..n-1), GS i at site i; "
                         "each K is also flown through one TLS router for comparison; the load table adds the "
                         "mesh's message rate")
    bs.add_argument("--drone-router", choices=("spread", "all"),
                    help="with --sites: spread = drone i connects to site (i mod N)'s router (default); "
                         "all = every drone is given every site's endpoint and Zenoh picks one")
    bs.add_argument("--inbox-senders", type=int, metavar="N",
                    help="what-if: raise the GSs' inbox bound on (kind, sender) queues holding items at once "
                         "(default: 4 per fleet node, at least 256; a drained queue is freed) to at least N in "
                         "the GSs host; every row says so")
    bs.add_argument("--drone-hosts", type=int, default=1, metavar="H",
                    help="what-if: step the drones in H processes, the i-th drone in host i mod H (default 1; "
                         "with --sites spread over N sites, H = N gives each site's drones a host)")
    bs.add_argument("--hosts-nice", type=int, default=None, metavar="N",
                    help="the niceness of the drones and GSs hosts (default 10: they stand in for other machines "
                         "and give way to the routers; 0: all equal)")
    bs.add_argument("--sites-only", action="store_true",
                    help="with --sites: fly the site routers only, not also through one TLS router")
    bs.add_argument("--gs-processes", action="store_true", help="each GS in a process of its own (default: one for all)")
    bs.add_argument("--restart-gs", metavar="GS", help="GS crashes 3 s after the take-off and starts again with no key "
                    "(a GS per process): how soon it is linked with every drone again, and the flight still correct")
    bs.set_defaults(func=_bench_scale)

    bo = bsub.add_parser("overhead", help="the same fleet flown as bare Zenoh and as zdrone: CPU, memory and latency "
                                          "per process class, zdrone / bare")
    bo.add_argument("--json", action="store_true", help="print JSON instead of a table")
    bo.add_argument("--quick", action="store_true", help="25 drones, 30 s of flight each")
    bo.add_argument("--drones", metavar="K,K,…", help="drone counts (default 100,300; --quick 25)")
    bo.add_argument("--sites", type=int, default=0, metavar="N",
                    help="N site routers meshed (zdrone: mutual TLS; bare: plain TCP), GS i at site i, drone i at "
                         "site i mod N (default 0: one router)")
    bo.add_argument("--stations", type=int, default=3, metavar="G", help="ground stations (default 3)")
    bo.add_argument("--flight", type=float, metavar="S",
                    help="seconds of flight measured per half, from the take-off (default 120; --quick 30)")
    bo.add_argument("--speedup", type=float, default=None, metavar="S",
                    help="the simulators' speed-up (default by K, as bench scale: 4 up to 100 drones, 1 above)")
    bo.add_argument("--hosts-nice", type=int, default=None, metavar="N",
                    help="the niceness of the drones and GSs hosts in both halves (default 10, as bench scale)")
    bo.add_argument("--plot", metavar="PNG", help="also draw the CPU per drone against K, per class, to this file")
    bo.add_argument("--from-json", metavar="FILE", help="show (and --plot) a result saved with --json; fly nothing")
    bo.add_argument("--runs", type=int, default=1, metavar="R",
                    help="fly each K this many times (both halves); the table adds the spread (min, median, max)")
    bo.add_argument("--drone-hosts", type=int, default=1, metavar="N",
                    help="step the drones in N host processes in both halves (drone i in host i mod N), so that no "
                         "host runs saturated (above 0.6 of a core: the table says so where one does)")
    bo.set_defaults(func=_bench_overhead)

    ba = bsub.add_parser("attack", help="every attack scenario measured; failsafe lateness and CPU under a pairing flood; "
                                          "the authority's link under junk on another GS's key")
    ba.add_argument("--json", action="store_true", help="print JSON instead of a table")
    ba.add_argument("--quick", action="store_true", help="the pair-flood scenario and 1 flood trial only")
    ba.add_argument("--scenarios", metavar="S,S,…", help="attack scenarios to fly (default: all; '' for none)")
    ba.add_argument("--trials", type=int, metavar="N", help="failsafe-under-flood trials (default 3)")
    ba.add_argument("--rate", type=float, default=2500.0, metavar="Q", help="pairing queries per second of the flood (2500)")
    ba.add_argument("--junk-trials", type=int, metavar="N",
                    help="trials of A's link under junk on B's key (default 3; --quick: none)")
    ba.add_argument("--junk-rate", type=float, default=80_000.0, metavar="P", help="junk puts per second on up/B (80000)")
    ba.add_argument("--sessions", type=int, nargs="*", metavar="K",
                    help="parallel sessions per credential to flood with (default 1 4 16; --quick 1 4; none: skip)")
    ba.add_argument("--radio-sizes", metavar="B,B,…",
                    help="junk floods on up/B over a 4 Mbit/s shaped radio (root), bytes per envelope "
                         "(default 500,1000,60000; --quick: none; '' for none)")
    ba.set_defaults(func=_bench_attack)
    bk = bsub.add_parser("soak", help="one long shuttle flight under a 20 Hz command stream; memory, descriptors, "
                                      "threads and CPU of every process over it")
    bk.add_argument("--json", action="store_true", help="print JSON instead of a table")
    bk.add_argument("--quick", action="store_true", help="2 crossings, a sample a second (proves it runs)")
    bk.add_argument("--crossings", type=int, default=500, metavar="N", help="overlap crossings (500)")
    bk.add_argument("--speedup", type=float, default=4.0, metavar="S", help="simulator speed-up (4)")
    bk.add_argument("--out", metavar="DIR", help="keep the run here")
    bk.set_defaults(func=_bench_soak)
    bc = bsub.add_parser("chaos", help="seeded random fault schedules over the reference flight; safety invariants")
    bc.add_argument("--json", action="store_true", help="print JSON instead of a table")
    bc.add_argument("--quick", action="store_true", help="5 schedules at most")
    bc.add_argument("--runs", type=int, default=50, metavar="N", help="schedules to fly (default 50, ~40 s each)")
    bc.add_argument("--seed", type=int, default=1, help="seed of the first schedule (the next ones count up)")
    bc.add_argument("--sites", action="store_true",
                    help="a router per site: site routers killed and hung, the backhaul cut, radio links flapping; "
                         "and the flight completes when the faults are over")
    bc.add_argument("--jobs", type=int, default=1, metavar="N", help="schedules flown at once (default 1)")
    bc.set_defaults(func=_bench_chaos)
    br = bsub.add_parser("restart", help="companion restarts in flight: time for the owner to re-pair (worst of N)")
    br.add_argument("--json", action="store_true", help="print JSON instead of a table")
    br.add_argument("--quick", action="store_true", help="2 runs at most")
    br.add_argument("--runs", type=int, default=20, metavar="N", help="flights, two at a time (default 20, ~40 s each)")
    br.set_defaults(func=_bench_restart)
    bv = bsub.add_parser("revoke", help="K drones x 3 GSs in flight, GS B revoked by a signed revision: time to apply it "
                                          "(p50, p99), where B's drones went, commands of others lost, failsafes")
    bv.add_argument("--json", action="store_true", help="print JSON instead of a table")
    bv.add_argument("--quick", action="store_true", help="3 drones (default 100)")
    bv.add_argument("--drones", type=int, metavar="K", help="drones (1..150)")
    bv.add_argument("--only", metavar="A,A", help="the runs: revoke (B, a drone out of reach 30 s), rotate (A's keys); "
                    "default both")
    bv.set_defaults(func=_bench_revoke)
    bvw = bsub.add_parser("view", help="the live web view in headless chromium: drone record -> page DOM latency "
                                       "(p50/p95), one page following the scale fleet, the server's memory over a flight, "
                                       "the view under attack (stream clients and forged parts: RSS, CPU, picture gap), "
                                       "the view under half-open heads and TLS handshakes from one address")
    bvw.add_argument("--json", action="store_true", help="print JSON instead of a table")
    bvw.add_argument("--quick", action="store_true", help="2 crossings, and 25 drones for 10 s once the page shows them all, "
                                                         "and 10 s windows of 50 clients and 100 forged parts/s "
                                                         "(default: 60 crossings, about 10 minutes, 300 drones for "
                                                         "120 s from take-off, 30 s windows of 1000 clients and "
                                                         "1000 forged parts/s; flood: 8 s windows, default 30 s)")
    bvw.add_argument("--crossings", type=int, metavar="N", help="crossings of the shuttle flight (latency, memory)")
    bvw.add_argument("--drones", type=int, metavar="K", help="drones of the scale fleet the page follows (1..300)")
    bvw.add_argument("--only", metavar="P,P", help="only these parts: flight (latency, memory), fleet, attack (the view "
                                                   "under stream clients and X's forged parts), flood (half-open heads "
                                                   "and TLS handshakes from one address: the operator's page and stream "
                                                   "served, the view's RSS; no browser); default all four; corridor: 100 drones x 20 GSs")
    bvw.add_argument("--clients", type=int, metavar="N", help="attack: clients of the picture stream (default 1000, "
                                                              "--quick 50)")
    bvw.add_argument("--forged-rate", type=float, metavar="R", help="attack: X's forged parts a second (default 1000, "
                                                                    "--quick 100)")
    bvw.add_argument("--flood-rate", type=float, metavar="R", help="flood: the half-open connections' connects a "
                                                                   "second at most (default 2000; 0: no limit)")
    bvw.add_argument("--out", metavar="DIR", help="keep the runs here")
    bvw.set_defaults(func=_bench_view)
    bw = bsub.add_parser("sweep", help="every scenario at speed-ups 1, 2, 4 and each fault at every moment of the flight")
    bw.add_argument("--json", action="store_true", help="print JSON instead of a table")
    bw.add_argument("--quick", action="store_true", help="3 cells (~80 s, 2 at a time): the CI subset")
    bw.add_argument("--jobs", type=int, default=2, metavar="N", help="flights at once (default 2)")
    bw.add_argument("--scenarios", metavar="S,S,…", help="only these scenarios")
    bw.add_argument("--speedups", metavar="X,X,…", help="only these speed-ups (of 1,2,4)")
    bw.add_argument("--moments", metavar="M,M,…", help="only these fault moments")
    bw.add_argument("--out", metavar="DIR", help="folder of the runs and cells.jsonl (default: a fresh temporary one)")
    bw.add_argument("--sites", action="store_true", help="fly every cell over a router per site (zdrone demo --sites)")
    bw.set_defaults(func=_bench_sweep)

    ck = sub.add_parser("check", help="exhaustive bounded exploration of the authority protocol's decisions "
                        "(every interleaving of honest moves, faults and attackers), with invariants")
    ck.add_argument("--depth", type=int, default=7, metavar="N", help="moves per trace at most (default 7: CI bound)")
    ck.add_argument("--faults", type=int, default=2, metavar="N", help="faults per trace at most (default 2)")
    ck.add_argument("--max-states", type=int, default=None, metavar="N", help="stop after N distinct states")
    ck.add_argument("--flaw", choices=("heir-without-position", "promotion-over-live", "unstamped-pairing",
                                       "pairing-without-position", "forgetful-ground-restart", "close-covering",
                                       "consent-to-last-asker", "window-across-epochs", "consent-without-reading"),
                    help="plant a known flaw (the checker must find it; the last three are in the consent world)")
    ck.add_argument("--cores", action="store_true",
                    help="explore the shipped cores themselves (DroneCore, StationCores A and B, real crypto, in memory) "
                         "instead of the abstract world; much slower: use --depth 3 to 5")
    ck.add_argument("--consent", action="store_true",
                    help="explore operator consent instead: the shipped OperatorControl at three authorized GSs and the "
                         "drone's authority machine (who may be granted control, in which epoch)")
    ck.add_argument("--json", action="store_true", help="print JSON instead of text")
    ck.set_defaults(func=_check)

    from zdrone.commands import NODE_COMMANDS

    for add in NODE_COMMANDS:
        add(sub)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``zdrone`` console script."""
    import faulthandler
    import signal

    from zdrone.crashes import stacks_on_crash

    stacks_on_crash()  # a crash leaves every thread's stack on stderr, here and in every process started from here
    try:  # `kill -USR1 PID` prints every thread's stack, even if one is stuck in C
        faulthandler.register(signal.SIGUSR1, all_threads=True)
    except (AttributeError, ValueError, OSError):  # no SIGUSR1, or stderr is not a real file (tests)
        pass
    try:
        args = build_parser().parse_args(argv)
    except (UsageError, ConfigError) as exc:
        print(f"zdrone: error: {exc}", file=sys.stderr)
        return 2
    return run_parsed(args)


#: Commands that start processes of their own: they stop them however they end (``zdrone.sil.procs``).
LAUNCHER_COMMANDS = ("demo", "bench")


def run_parsed(args: argparse.Namespace) -> int:
    """Run a parsed subcommand: logging, signal thread, one-line errors with exit code 2."""
    try:
        from zdrone.commands import SIGNAL_THREAD_COMMANDS

        if getattr(args, "func", None) in SIGNAL_THREAD_COMMANDS:
            from zdrone.net.shutdown import block_signals

            block_signals()  # before any library starts a thread: see zdrone.net.shutdown
        level = logging.WARNING - 10 * min(args.verbose, 2)
        import os

        # under systemd (stderr is the journal, which stamps each line): plain lines, no time of ours
        journal = bool(os.environ.get("JOURNAL_STREAM")) and os.environ.get("INVOCATION_ID") is not None
        logging.basicConfig(level=level, format="%(name)s %(levelname)s %(message)s" if journal
                            else "%(asctime)s %(name)s %(levelname)s %(message)s")
        if getattr(args, "command", None) in LAUNCHER_COMMANDS:
            from zdrone.sil.procs import on_signals

            with on_signals():  # SIGTERM/SIGHUP unwind like Ctrl-C; every child is stopped on the way out
                code = args.func(args)
        else:
            code = args.func(args)
    except (UsageError, ConfigError) as exc:
        print(f"zdrone: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except BaseException as exc:
        from zdrone.sil.procs import Terminated

        if isinstance(exc, Terminated):
            print(f"zdrone: {exc}", file=sys.stderr)
            return 128 + exc.signum
        raise
    if getattr(args, "func", None) in SIGNAL_THREAD_COMMANDS:
        _exit_now(int(code or 0))
    return int(code or 0)


def _exit_now(code: int) -> None:
    """End a node process once it has closed its session and its event log: flush, then exit without
    the interpreter's finalization, during which a late Zenoh callback (a query reply arriving after
    the close) could call into a half-torn-down interpreter and abort the process."""
    import os

    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)


if __name__ == "__main__":
    sys.exit(main())
