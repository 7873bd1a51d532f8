"""Registration of the node subcommands (router, sim, drone, gs, demo, report)."""

from __future__ import annotations

import argparse
import math

from .cli import _EXTRA_COMMANDS, UsageError
from .core.geometry import GeoPoint


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
    from .core.reference import HOME
    from .vehicle.simserver import SimOptions, run_sim

    home = parse_home(args.home) if args.home else HOME
    if not 1 <= args.sysid <= 255:
        raise UsageError(f"--sysid {args.sysid}: must be 1..255")
    return run_sim(SimOptions(mavlink=args.mavlink, home=home, speedup=args.speedup, seed=args.seed,
                              sysid=args.sysid, gps_noise=args.gps_noise, duration=args.duration))


def add_sim(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sim", help="built-in MAVLink multicopter simulator (PX4-type autopilot)")
    p.add_argument("--mavlink", default="udpin:127.0.0.1:14580", metavar="CONN",
                   help="udpin:|udpout:|tcpin:|tcp:HOST:PORT (default udpin:127.0.0.1:14580)")
    p.add_argument("--speedup", type=positive, default=1.0, help="simulated seconds per wall second")
    p.add_argument("--seed", type=int, default=0, help="seed of the sensor noise")
    p.add_argument("--gps-noise", type=float, default=0.0, metavar="M", help="GPS noise, metres 1-sigma")
    p.add_argument("--home", metavar="LAT,LON[,ALT]", help="take-off point (default: the reference home)")
    p.add_argument("--sysid", type=int, default=1, help="MAVLink system id (default 1)")
    p.add_argument("--duration", type=positive, default=None, help="stop after this many wall seconds")
    p.set_defaults(func=_sim)


_EXTRA_COMMANDS.append(add_sim)


def _router(args: argparse.Namespace) -> int:
    from .net.router import run_router

    return run_router(args.config, args.listen)


def add_router(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("router", help="Zenoh router with the fleet's auth and access control")
    p.add_argument("-c", "--config", default="router.json5", help="router config (JSON5; also valid for zenohd -c)")
    p.add_argument("--listen", metavar="ENDPOINT", help="override listen endpoint, e.g. tcp/127.0.0.1:7447")
    p.set_defaults(func=_router)


_EXTRA_COMMANDS.append(add_router)
