"""The node subcommands (sim, router, drone, gs, demo, report), listed in ``NODE_COMMANDS``."""

from __future__ import annotations

import argparse
import ipaddress
import logging
import math
from pathlib import Path
from typing import Any, Callable

from zdrone.core.errors import UsageError
from zdrone.core.geometry import GeoPoint

log = logging.getLogger(__name__)


def parse_home(text: str) -> GeoPoint:
    parts = text.split(",")
    try:
        vals = [float(p) for p in parts]
    except ValueError:
        vals = []
    if len(vals) not in (2, 3) or not all(math.isfinite(v) for v in vals) or not (-90 <= vals[0] <= 90 and -180 <= vals[1] <= 180):
        raise UsageError(f"--home {text!r}: expected LAT,LON[,ALT] in degrees and metres")
    return GeoPoint(vals[0], vals[1], vals[2] if len(vals) == 3 else 0.0)


def positive(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"{text!r} must be a positive number")
    return v


def _sim(args: argparse.Namespace) -> int:
    from zdrone.core.reference import HOME
    from zdrone.vehicle.personality import personality
    from zdrone.vehicle.simserver import SimOptions, run_sim

    home = parse_home(args.home) if args.home else HOME
    if not 1 <= args.sysid <= 255:
        raise UsageError(f"--sysid {args.sysid}: must be 1..255")
    if args.ready_after is not None and not (math.isfinite(args.ready_after) and 0 <= args.ready_after <= 3600):
        raise UsageError(f"--ready-after {args.ready_after:g}: must be 0..3600 simulated seconds")
    truth = None
    if args.truth is not None:
        host, _, port = args.truth.rpartition(":")
        try:
            ipaddress.IPv4Address(host)
        except ValueError:
            host = ""
        if not host or not port.isdigit() or not 0 < int(port) < 65536:
            raise UsageError(f"--truth {args.truth}: must be IPv4:PORT (e.g. 127.0.0.1:9000)")
        truth = (host, int(port))
    return run_sim(SimOptions(mavlink=args.mavlink, home=home, speedup=args.speedup, seed=args.seed,
                              sysid=args.sysid, gps_noise=args.gps_noise, duration=args.duration,
                              personality=personality(args.autopilot), ready_after=args.ready_after, truth=truth,
                              telem2=args.telem2, storage=args.storage, signing=not args.no_signing))


def add_sim(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sim", help="built-in MAVLink multicopter simulator (PX4- or ArduPilot-like autopilot)")
    p.add_argument("--autopilot", choices=("px4", "ardupilot"), default="px4",
                   help="the autopilot it behaves like: PX4 v1.16 or ArduCopter 4.7 (default px4)")
    p.add_argument("--mavlink", default=None, metavar="CONN",
                   help="udpin:|udpout:|tcpin:|tcp:HOST:PORT (default: the autopilot's own endpoint, px4: "
                        "udpin:127.0.0.1:14580 sending to 127.0.0.1:14540 as well; ardupilot: tcpin:127.0.0.1:5760, "
                        "booting when the first client connects)")
    p.add_argument("--ready-after", type=float, default=None, metavar="S",
                   help="simulated seconds after boot before arming is allowed (ArduPilot: and a position "
                        "estimate for AUTO); default 1 for px4, 6 for ardupilot (the real ones: ~10 and 20-40)")
    p.add_argument("--speedup", type=positive, default=1.0, help="simulated seconds per wall second")
    p.add_argument("--seed", type=int, default=0, help="seed of the sensor noise")
    p.add_argument("--gps-noise", type=float, default=0.0, metavar="M", help="GPS noise, metres 1-sigma")
    p.add_argument("--home", metavar="LAT,LON[,ALT]", help="take-off point (default: the reference home)")
    p.add_argument("--sysid", type=int, default=1, help="MAVLink system id (default 1)")
    p.add_argument("--duration", type=positive, default=None, help="stop after this many wall seconds")
    p.add_argument("--truth", metavar="IPV4:PORT", default=None,
                   help="testbed only: send the true position there (UDP JSON, 20/s), for radio links from coverage")
    p.add_argument("--telem2", metavar="CONN", default=None,
                   help="a second MAVLink endpoint, the autopilot's TELEM2 (a telemetry radio), e.g. udpin:127.0.0.1:14590")
    p.add_argument("--storage", metavar="DIR", default=None,
                   help="the autopilot's persistent storage: its MAVLink signing key and timestamp survive a restart")
    p.add_argument("--no-signing", action="store_true",
                   help="an autopilot without MAVLink signing (PX4 before 1.17): SETUP_SIGNING ignored, nothing signed")
    p.set_defaults(func=_sim)




def _router(args: argparse.Namespace) -> int:
    from zdrone.net.router import run_router

    if args.take_over is not None and not 0 < args.take_over <= 600:
        raise UsageError(f"--take-over {args.take_over:g}: must be more than 0 and at most 600 seconds")
    return run_router(args.config, args.listen, args.tap, args.connect, args.take_over)


def add_router(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("router", help="Zenoh router with the fleet's auth and access control")
    p.add_argument("-c", "--config", default="router.json5", help="router config (JSON5; also valid for zenohd -c)")
    p.add_argument("--listen", metavar="ENDPOINT", action="append",
                   help="listen here instead of the config's endpoints, e.g. tcp/127.0.0.1:7447 (repeatable)")
    p.add_argument("--connect", metavar="ENDPOINT", action="append",
                   help="connect to these routers instead of the config's (other sites reached another way; repeatable)")
    p.add_argument("--tap", metavar="FILE", help="count packets and bytes per key expression into FILE (JSON, every second)")
    p.add_argument("--take-over", metavar="SECONDS", type=float, nargs="?", const=10.0,
                   help="replace a running router on the same endpoints: get ready, print 'taking over', then wait "
                        "up to SECONDS (default 10) for the port; stop the old router (SIGTERM) once that line is "
                        "out: this one listens within one retry (50 ms) of its going (a rolling restart, docs/deploy.md)")
    p.set_defaults(func=_router)




def _thresholds(args: argparse.Namespace):
    from zdrone.core.tbm import TbmThresholds

    try:
        return TbmThresholds(args.degraded_after, args.lost_after)
    except ValueError as exc:
        raise UsageError(f"--degraded-after/--lost-after: {exc}") from None


def _event_limits(args: argparse.Namespace) -> None:
    """Every event log of this node process rotates at ``--events-max-mb`` (``net.eventlog``)."""
    from zdrone.net.eventlog import configure

    if not 0.01 <= args.events_max_mb <= 100_000:
        raise UsageError(f"--events-max-mb {args.events_max_mb:g}: must be 0.01..100000")
    configure(max_bytes=int(args.events_max_mb * 1024 * 1024))


def _add_event_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--events", metavar="FILE", help="write a JSONL event log")
    p.add_argument("--events-max-mb", type=float, default=64.0, metavar="MB",
                   help="rotate the event log at this size: FILE.1 .. FILE.3 are kept, older ones dropped (64); "
                        "events a peer can trigger are also rate-limited per type and reason, with exact counts "
                        "of what was left out ('suppressed' lines)")


def _drone(args: argparse.Namespace) -> int:
    from zdrone.nodes.drone import DroneOptions, run_drone

    _event_limits(args)
    routers = args.router or ["tcp/127.0.0.1:7447"]
    router: str | tuple[str, ...] = routers[0] if len(routers) == 1 else tuple(routers)
    return run_drone(DroneOptions(drone=args.id, fleet=args.fleet, router=router, vehicle=args.vehicle,
                                  thresholds=_thresholds(args), failsafe=args.failsafe,
                                  handover_timeout=args.handover_timeout, gate=_gate(args),
                                  events=args.events, cipher=getattr(args, "cipher", "zdrone"), radio=_radio(args),
                                  fc_signing=args.fc_signing, rotate_fc_key=args.rotate_fc_key,
                                  trust_unsigned_position=args.trust_unsigned_position,
                                  revision_lease=args.revision_lease))


def _gate(args: argparse.Namespace) -> "Any":
    """The emulated radio coverage (testbed only), or None."""
    if not args.sil_coverage:
        return None
    from zdrone.fleet.files import load_fleet
    from zdrone.sil.coverage import CoverageGate

    return CoverageGate(load_fleet(args.fleet))


def _radio(args: argparse.Namespace) -> "Any":
    """The emulated radio's impairments (testbed only), or None for a perfect one."""
    from zdrone.sil.radio import RadioChannel, parse_models

    if not (args.sil_loss or args.sil_bursts or args.sil_delay_ms or args.sil_jitter_ms):
        return None
    try:
        default, per_gs = parse_models(args.sil_loss or [], args.sil_bursts or [], args.sil_delay_ms, args.sil_jitter_ms)
    except ValueError as exc:
        raise UsageError(f"--sil-loss/--sil-bursts/--sil-delay-ms/--sil-jitter-ms: {exc}") from None
    return RadioChannel(default, per_gs, seed=args.sil_seed)


def add_drone(sub: argparse._SubParsersAction, bench: bool = False) -> None:
    """``zdrone drone``; with ``bench`` (the bench harness only) also ``--cipher``."""
    p = sub.add_parser("drone", help="onboard companion: vehicle link + security module + handover authority")
    p.add_argument("--id", default="d1", help="drone name in the fleet (default d1)")
    p.add_argument("--fleet", default="fleet", help="fleet directory (default ./fleet)")
    p.add_argument("--router", action="append", metavar="ENDPOINT",
                   help="Zenoh router endpoint (default tcp/127.0.0.1:7447). Several comma-separated: one session "
                        "that Zenoh moves to another when its router dies. Repeated (one per site): a session through "
                        "each at once, so losing a site costs no interruption")
    p.add_argument("--vehicle", default="udpout:127.0.0.1:14580", metavar="CONN",
                   help="autopilot: udpout:127.0.0.1:14580 (zdrone sim), udpin:0.0.0.0:14540 (PX4 SITL), "
                        "tcp:127.0.0.1:5760 (ArduPilot SITL), /dev/ttyACM0,921600")
    p.add_argument("--degraded-after", type=positive, default=1.0, metavar="S", help="TBM DEGRADED threshold (1 s)")
    p.add_argument("--lost-after", type=positive, default=3.0, metavar="S", help="TBM LOST threshold (3 s)")
    p.add_argument("--failsafe", choices=["LAND", "RTL"], default="LAND", help="action when the authority link is lost")
    p.add_argument("--handover-timeout", type=positive, default=5.0, metavar="S", help="hand-over timeout (5 s)")
    p.add_argument("--fc-signing", choices=("require", "prefer", "off"), default="prefer",
                   help="MAVLink 2 signing of the link to the autopilot (key kept in secrets/<id>.fc-signing.json): "
                        "require = refuse to fly an autopilot that does not sign back; prefer = go on unsigned then, "
                        "said and counted (default); off = never sign")
    p.add_argument("--rotate-fc-key", action="store_true",
                   help="install a new signing key in the autopilot (on the ground only), signed with the old one")
    p.add_argument("--trust-unsigned-position", action="store_true",
                   help="let a position that did not come over a signed autopilot link grant authority (an heir, a "
                        "pairing that needs coverage): needed to fly with --fc-signing off or an autopilot that does "
                        "not sign; then any process that can write into the vehicle link can move the drone's "
                        "authority (README, threat model)")
    p.add_argument("--revision-lease", type=float, default=0.0, metavar="S",
                   help="where the fleet sets no lease: from the first pairing, authority stands only while a revision "
                        "stamp naming the drone from another GS authorized for it was heard within S seconds (each GS "
                        "stamps every 5 s: give S more than that); else it lapses as a lost authority link: an heir "
                        "covering the drone takes over, else the failsafe (default 0: off; docs/deploy.md)")
    p.add_argument("--sil-coverage", action="store_true", help="TESTBED ONLY: emulate radio coverage from fleet circles")
    p.add_argument("--sil-loss", action="append", metavar="[GS=]P",
                   help="TESTBED ONLY: lose each frame with probability P (every GS link, or GS's); repeatable")
    p.add_argument("--sil-bursts", action="append", metavar="[GS=]GOOD_S:BAD_S",
                   help="TESTBED ONLY: bursty loss: good periods of mean GOOD_S, lossy periods of mean BAD_S seconds")
    p.add_argument("--sil-delay-ms", type=float, default=0.0, metavar="MS", help="TESTBED ONLY: radio delay")
    p.add_argument("--sil-jitter-ms", type=float, default=0.0, metavar="MS", help="TESTBED ONLY: radio jitter (±MS)")
    p.add_argument("--sil-seed", type=int, default=0, help="TESTBED ONLY: seed of the radio's randomness")
    _add_event_options(p)
    if bench:
        p.add_argument("--cipher", choices=["zdrone", "fernet", "plain"], default="zdrone",
                       help="envelope; fernet/plain exist only to measure against (bench traffic)")
    p.set_defaults(func=_drone)


def mission_from_arg(value: str | None) -> list | None:
    """A mission named on the command line: a QGroundControl .plan, 'reference', or 'shuttle:N' (None:
    none); a bad one is a ``UsageError`` or the plan's ``ConfigError``."""
    from gs.planner import load_plan, reference_plan

    if not value:
        return None
    if value == "reference":
        return reference_plan()  # autopilot-neutral: the GS encodes it for the autopilot it finds
    if value.startswith("shuttle:"):
        from gs.planner import shuttle_mission

        try:
            crossings = int(value.split(":", 1)[1])
        except ValueError:
            raise UsageError(f"--mission {value}: expected shuttle:N with N crossings") from None
        try:
            return shuttle_mission(crossings)
        except ValueError as exc:
            raise UsageError(f"--mission {value}: {exc}") from None
    return load_plan(value)


def _gs(args: argparse.Namespace) -> int:
    from gs.station import StationOptions, run_station

    from zdrone.vehicle.transport import parse_endpoint

    for conn in args.gcs or ():
        parse_endpoint(conn)  # a bad endpoint is a usage error before anything connects
    if args.gcs_signing == "off" and args.gcs_keys:
        raise UsageError("--gcs-keys with --gcs-signing off: the keys would not be used (prefer or require)")
    if args.gcs_keys and not args.gcs:
        raise UsageError("--gcs-keys: no --gcs endpoint to use them on")
    if args.gcs_keys:
        from gs.appkeys import load_gs_keys, weak_key_warning, weak_keys

        # a bad or exposed key file, or a key another GS of the fleet also holds, is an error before anything connects
        for weak in weak_keys(load_gs_keys(args.gcs_keys, args.id, args.fleet)):
            log.warning("%s", weak_key_warning(weak, args.gcs_keys))
    _event_limits(args)
    mission = mission_from_arg(args.mission)
    return run_station(StationOptions(gs=args.id, fleet=args.fleet, router=args.router,
                                      drones=tuple(args.drone or ()), pair=args.pair, mission=mission,
                                      heartbeat_hz=args.heartbeat_hz, command_rate=args.command_rate,
                                      events=args.events, cipher=getattr(args, "cipher", "zdrone"),
                                      paper_heartbeat=getattr(args, "paper_heartbeat", False),
                                      gcs=tuple(args.gcs or ()), take_control=args.take_control,
                                      allow_takeover=args.allow_takeover, gcs_signing=args.gcs_signing,
                                      gcs_keys=args.gcs_keys))


def add_gs(sub: argparse._SubParsersAction, bench: bool = False) -> None:
    """``zdrone gs``; with ``bench`` (the bench harness only) also ``--cipher`` and ``--paper-heartbeat``."""
    p = sub.add_parser("gs", help="ground station: pairing, key sharing, heartbeat, mission, hand-over")
    p.add_argument("--id", required=True, help="ground station name in the fleet (A, B, ...)")
    p.add_argument("--fleet", default="fleet", help="fleet directory (default ./fleet)")
    p.add_argument("--router", default="tcp/127.0.0.1:7447", help="Zenoh router endpoint")
    p.add_argument("--drone", action="append", help="drone(s) to serve (default: all it is authorized for)")
    p.add_argument("--pair", action="store_true", help="pair with the drone(s) on start (the take-off GS)")
    p.add_argument("--mission", metavar="PLAN",
                   help="fly this QGroundControl .plan, 'reference', or 'shuttle:N' (N overlap crossings, for bench handover)")
    p.add_argument("--heartbeat-hz", type=positive, default=2.0, help="sealed HEARTBEAT rate (2 Hz)")
    p.add_argument("--command-rate", type=float, default=0.0, metavar="HZ",
                   help="while in authority, send a harmless command stream (for hand-over checks)")
    _add_event_options(p)
    p.add_argument("--take-control", action="store_true",
                   help="the operator's standing request: if the drone enters its failsafe, take control back as soon as "
                        "this GS's link is proven (the vehicle goes on with the failsafe action until commanded)")
    p.add_argument("--allow-takeover", action="store_true",
                   help="MAVLink operator control: while this GS holds authority, another authorized GS's request "
                        "takes it at once (CONTROL_STATUS says takeover allowed); without it, this GS's operator is "
                        "asked and must consent (its GCS applications can change the setting with p2 of "
                        "MAV_CMD_REQUEST_OPERATOR_CONTROL)")
    if bench:
        p.add_argument("--cipher", choices=["zdrone", "fernet", "plain"], default="zdrone",
                       help="envelope; fernet/plain exist only to measure against (bench traffic)")
        p.add_argument("--paper-heartbeat", action="store_true", help="also send the paper's separate 2 Hz security heartbeat")
    p.add_argument("--gcs", action="append", metavar="CONN",
                   help="GCS gateway endpoint for QGroundControl/MAVProxy/MAVSDK: udpin:HOST:PORT (apps connect here), "
                        "udpout:127.0.0.1:14550 (QGroundControl's default), tcpin:HOST:PORT; repeatable")
    p.add_argument("--gcs-signing", choices=["off", "prefer", "require"],
                   help="MAVLink 2 signing of the GCS applications: require (only applications signing with a key of "
                        "--gcs-keys may command or consent, release, allow takeover; unsigned ones are read-only), "
                        "prefer (signed applications are named by their key, unsigned ones still command), off; "
                        "default: require with --gcs-keys, else prefer")
    p.add_argument("--gcs-keys", metavar="FILE",
                   help="the GCS applications' signing keys, one per line: NAME hex:<64 hex> | qgc:<passphrase> | "
                        "<passphrase> (MAVProxy's 'signing key <passphrase>'); mode 0600")
    p.set_defaults(func=_gs)




def _demo(args: argparse.Namespace) -> int:
    from pathlib import Path

    from zdrone.sil.launcher import SCENARIO_BY_NAME, SCENARIO_SITES, SCENARIO_TLS, DemoOptions, run_demo

    live = True if args.live else (False if args.no_live else None)
    moment = None
    from zdrone.sil.scenarios import CORRIDOR_SCENARIOS

    if args.scenario in CORRIDOR_SCENARIOS:  # the corridor's own processes (``zdrone.bench.corridordemo``)
        given = [o for o, v in (("--vehicle", args.vehicle), ("--netns", args.netns), ("--moment", args.moment),
                                ("--radio", args.radio), ("--view", args.view), ("--ready-after", args.ready_after)) if v]
        if given:
            raise UsageError(f"{given[0]}: not for scenario {args.scenario} (its eight GSs and drone are "
                             "the corridor bench's processes)")
        from zdrone.bench import corridordemo

        return corridordemo.main(args.scenario, Path(args.out) if args.out else None, args.speedup or 4.0)
    spec = SCENARIO_BY_NAME[args.scenario]
    if spec.plain_router and (args.tls or args.sites or args.netns):
        option = "--tls" if args.tls else ("--sites" if args.sites else "--netns")
        raise UsageError(f"{option}: scenario {args.scenario}'s attacker holds router passwords only; with mutual TLS "
                         "(a router per site has it) it has no certificate to connect with: run it without "
                         f"{option}, or scenario rogue-no-cert for that attacker against TLS")
    if args.moment:
        if args.moment not in spec.moments():
            raise UsageError(f"--moment {args.moment}: scenario {args.scenario} can move its fault to "
                             f"{', '.join(spec.moments()) or 'no other moment'}")
        moment = args.moment if args.moment != spec.own_moment() else None
    if args.netns:
        from zdrone.sil.netns import netns_refusal

        refusal = netns_refusal()
        if refusal:
            raise UsageError(f"--netns: {refusal}; without it the same topology runs on loopback")
        if args.vehicle:
            raise UsageError("--netns: the built-in simulator runs in the drone's namespace; no --vehicle")
    if args.vehicle:
        from zdrone.vehicle.transport import parse_endpoint

        parse_endpoint(args.vehicle)  # a bad connection is a usage error before anything starts
    if args.ready_after is not None:
        if args.vehicle:
            raise UsageError("--ready-after: the built-in simulator's start-up; an autopilot given by --vehicle has its own")
        if not (math.isfinite(args.ready_after) and 0 <= args.ready_after <= 3600):
            raise UsageError(f"--ready-after {args.ready_after:g}: must be 0..3600 simulated seconds")
    if args.view is not None and not 1 <= args.view <= 65535:
        raise UsageError(f"--view {args.view}: a port, 1..65535")
    # an autopilot already running flies in real time: its speed-up (deadline, timers) is 1 unless given
    speedup = args.speedup if args.speedup is not None else (1.0 if args.vehicle else 2.0)
    return run_demo(DemoOptions(out=Path(args.out) if args.out else None, scenario=args.scenario, speedup=speedup,
                                live=live, timeout=args.timeout, command_rate=args.command_rate, report=not args.no_report,
                                autopilot=args.autopilot, vehicle=args.vehicle, radio=tuple(args.radio or ()),
                                ready_after=args.ready_after,
                                sites=args.sites or args.netns or SCENARIO_SITES.get(args.scenario, False),
                                netns=args.netns, fc_signing=args.fc_signing,
                                tls=args.tls or SCENARIO_TLS.get(args.scenario, False), moment=moment, view=args.view))


def add_demo(sub: argparse._SubParsersAction) -> None:
    from zdrone.sil.launcher import MOMENTS, SCENARIOS, scenario_help

    p = sub.add_parser("demo", help="fly the reference flight with router, sim, drone and two GSs as processes",
                       epilog=scenario_help(), formatter_class=argparse.RawDescriptionHelpFormatter)
    from zdrone.sil.scenarios import CORRIDOR_SCENARIOS

    p.add_argument("--scenario", choices=SCENARIOS + tuple(CORRIDOR_SCENARIOS), default="nominal", metavar="NAME",
                   help="nominal flight, or an attack / fault case (listed below)")
    p.add_argument("--out", metavar="DIR", help="output folder (default: a fresh runs/demo-... folder)")
    p.add_argument("--speedup", type=positive, default=None,
                   help="simulator speed-up (default 2; with --vehicle 1: a real autopilot runs in real time)")
    p.add_argument("--timeout", type=positive, default=None, metavar="S", help="give up after S wall seconds")
    p.add_argument("--ready-after", type=float, default=None, metavar="S",
                   help="the built-in simulator's start-up in simulated seconds (GPS fix, position estimate, ready to "
                        "arm, in the real order; real: PX4 ~10, ArduCopter ~40; default: a few seconds)")
    p.add_argument("--moment", choices=tuple(MOMENTS), metavar="M",
                   help=f"land the scenario's fault at another moment of the flight: {', '.join(MOMENTS)}")
    p.add_argument("--command-rate", type=float, default=5.0, metavar="HZ",
                   help="command stream of the authority GS, to check none is lost across hand-overs (5 Hz)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--live", action="store_true", help="force the live view")
    g.add_argument("--no-live", action="store_true", help="plain event lines (default when not a terminal)")
    p.add_argument("--no-report", action="store_true", help="do not write the HTML flight report")
    p.add_argument("--view", type=int, default=None, metavar="PORT",
                   help="also serve the live web view (zdrone view) on 127.0.0.1:PORT, beside the rich view")
    p.add_argument("--netns", action="store_true",
                   help="with --sites (implied): each site and the drone in their own network namespace, radios and "
                        "backhaul as veth pairs (root only; without it, loopback relays)")
    p.add_argument("--tls", action="store_true",
                   help="mutual TLS on every hop: a fleet CA and a certificate per node and router (--sites has it too)")
    p.add_argument("--sites", action="store_true",
                   help="a Zenoh router per ground-station site (two, meshed over the backhaul): GS A at site 1, B at "
                        "site 2; the drone reaches both and moves to the other when one dies")
    p.add_argument("--radio", action="append", metavar="OPTION",
                   help="TESTBED ONLY: an option of the drone's emulated radio, e.g. --radio=--sil-loss=0.6 "
                        "(see zdrone drone --help: --sil-loss, --sil-bursts, --sil-delay-ms, --sil-jitter-ms); repeatable")
    p.add_argument("--fc-signing", choices=("require", "prefer", "off"), default="prefer",
                   help="the drone's MAVLink signing of its autopilot link (default prefer; off: the fc-rogue-radio control)")
    v = p.add_mutually_exclusive_group()
    v.add_argument("--autopilot", choices=("px4", "ardupilot"), default="px4",
                   help="personality of the built-in simulator (default px4)")
    v.add_argument("--vehicle", metavar="CONN",
                   help="fly an autopilot that is already running at the reference home instead of the simulator: "
                        "udpin:127.0.0.1:14540 (PX4 SITL), tcp:127.0.0.1:5760 (ArduPilot SITL), a serial port")
    p.set_defaults(func=_demo)




def _report(args: argparse.Namespace) -> int:
    from zdrone.report import write_report

    print(write_report(args.log))
    return 0


def add_report(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("report", help="HTML flight report (track, TBM, altitude, events, drops) from an event log")
    p.add_argument("log", help="a run folder written by zdrone demo, or its drone.jsonl")
    p.set_defaults(func=_report)


def _audit_verify(args: argparse.Namespace) -> int:
    from zdrone.fleet.revisions import signing_key_epochs
    from zdrone.report import audit_files, run_expected, run_fleet, run_fleet_dir, verify_audit

    files = audit_files(args.targets)
    fleet = run_fleet(args.targets, args.fleet)
    runs = [Path(t) for t in args.targets if Path(t).is_dir()]
    results = verify_audit(files, fleet, signing_key_epochs(run_fleet_dir(args.targets, args.fleet)),
                           expect=run_expected(args.targets, fleet), where=runs[0] if runs else None)
    if args.json:
        import json

        print(json.dumps([{"file": str(f), "node": r.node, "ok": r.ok, "entries": r.entries,
                           "signed_through": r.signed_through, "witnessed_through": r.witnessed_through,
                           "unwitnessed": r.unwitnessed, "kind": r.kind, "first_bad": r.first_bad,
                           "problem": r.problem} for f, r in results], indent=2))
    else:
        for f, r in results:
            print(f"{'ok ' if r.ok else 'BAD'} {f}: {r.summary()}")
    bad = not all(r.ok for _, r in results)
    return 1 if bad or (args.require_witnessed and any(r.unwitnessed for _, r in results)) else 0


def add_audit(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("audit", help="the signed, hash-chained record of every authority decision")
    asub = p.add_subparsers(dest="audit_command", required=True)
    v = asub.add_parser("verify", help="check authority records offline against the fleet's public keys and each "
                                       "other's countersignatures; names the first bad entry (modified, deleted, "
                                       "reordered, truncated) or a record missing from a run; exit 1 if any")
    v.add_argument("targets", nargs="+", metavar="RUN_DIR|FILE",
                   help="a run folder (its *.audit.jsonl; every drone of the fleet, its fleet/ or --fleet, and every "
                        "node with an event log there must have its record) or authority record files")
    v.add_argument("--fleet", help="the fleet folder (its public fleet.json5 and its revisions: each checkpoint and "
                                   "countersignature is checked against the key in force at its time); default: "
                                   "RUN_DIR/fleet")
    v.add_argument("--require-witnessed", action="store_true",
                   help="exit 1 also if a node's record has decisions after the last entry another node "
                        "countersigned")
    v.add_argument("--json", action="store_true", help="one object per record instead of lines")
    v.set_defaults(func=_audit_verify)


#: The node subcommands, in ``zdrone --help`` order (the fleet and bench commands live in ``cli``).
def _view(args: argparse.Namespace) -> int:
    from zdrone.view.server import view_command

    return view_command(args)


def add_view(sub: argparse._SubParsersAction) -> None:
    from zdrone.view.server import add_view as add

    add(sub, _view)


NODE_COMMANDS: tuple[Callable[[argparse._SubParsersAction], None], ...] = (
    add_sim, add_router, add_drone, add_gs, add_demo, add_view, add_report, add_audit)
#: Commands whose SIGTERM/SIGINT are served by a signal thread (``zdrone.net.shutdown``).
SIGNAL_THREAD_COMMANDS: tuple[Callable[[argparse.Namespace], int], ...] = (_drone, _gs, _router, _view)
