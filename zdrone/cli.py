"""The ``zdrone`` command. Errors are one line on stderr and exit code 2, never a traceback."""

from __future__ import annotations

import argparse
import logging
import sys
from typing import Callable, Sequence

from .core.fleet import ConfigError

log = logging.getLogger("zdrone")


class UsageError(Exception):
    """Bad command-line input; printed as one line, exit 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, exit 2
        where = self.prog.removeprefix("zdrone").strip()
        raise UsageError(f"{where}: {message}" if where else message)


def _fleet_init(args: argparse.Namespace) -> int:
    from .fleetfiles import init_fleet

    fleet = init_fleet(args.dir, force=args.force)
    print(f"wrote {args.dir}/fleet.json5 with nodes: " + ", ".join(
        f"{n} ({v.role}, sysid {v.sysid})" for n, v in fleet.nodes.items()))
    print(f"secrets in {args.dir}/secrets/ (mode 0600), router credentials in {args.dir}/router/")
    return 0


def _fleet_show(args: argparse.Namespace) -> int:
    from .fleetfiles import load_fleet, load_secret

    fleet = load_fleet(args.dir)
    for name, node in fleet.nodes.items():
        load_secret(args.dir, name, fleet) if args.check_secrets else None
        extra = f" authorized: {','.join(node.authorized_gs) or '-'}" if node.role == "drone" else (
            f" coverage: {node.coverage.lat:.6f},{node.coverage.lon:.6f} r={node.coverage.radius_m:g} m" if node.coverage else "")
        print(f"{name:6} {node.role:5} sysid {node.sysid:3}{extra}")
    return 0


def _bench_crypto(args: argparse.Namespace) -> int:
    from .bench import crypto, table

    result = crypto.run(quick=args.quick)
    if args.json:
        table.print_json(result)
    else:
        crypto.render(result)
    return 0


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
    fi.set_defaults(func=_fleet_init)
    fs = fsub.add_parser("show", help="validate and list a fleet")
    fs.add_argument("--dir", default="fleet", help="fleet directory or fleet.json5 path")
    fs.add_argument("--check-secrets", action="store_true", help="also load and check every secret file")
    fs.set_defaults(func=_fleet_show)

    bench = sub.add_parser("bench", help="measure sizes, speeds and hand-over figures")
    bsub = bench.add_subparsers(dest="bench_command", metavar="BENCH", parser_class=_Parser)
    bsub.required = True
    bc = bsub.add_parser("crypto", help="bytes added and seal+open cost per MAVLink frame")
    bc.add_argument("--json", action="store_true", help="print JSON instead of a table")
    bc.add_argument("--quick", action="store_true", help="few iterations (proves it runs)")
    bc.set_defaults(func=_bench_crypto)

    for extra in _EXTRA_COMMANDS:
        extra(sub)
    return p


#: Later modules register their subcommands here (name -> adder of a subparser).
_EXTRA_COMMANDS: list[Callable[[argparse._SubParsersAction], None]] = []


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``zdrone`` console script."""
    from . import commands  # noqa: F401  (registers the node subcommands)

    try:
        args = build_parser().parse_args(argv)
        level = logging.WARNING - 10 * min(args.verbose, 2)
        logging.basicConfig(level=level, format="%(asctime)s %(name)s %(levelname)s %(message)s")
        code = args.func(args)
    except (UsageError, ConfigError) as exc:
        print(f"zdrone: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    return int(code or 0)


if __name__ == "__main__":
    sys.exit(main())
