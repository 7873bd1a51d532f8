"""TESTBED ONLY: the attackers' command line: ``python -m zdrone.sil.rogue --mode MODE --fleet DIR
--router EP --events FILE`` runs one attacker (``zdrone.sil.attackers``, one module per class of
attacker, where each mode is described) as its own process.

Each attacker has real credentials taken from the demo's fleet directory (what it is allowed to
hold is stated per mode) and writes what it did to its events file, so that a scenario can check
both sides: what the attacker sent and what the nodes refused.

Modes that take ``--wait-go`` set up, print ``ready``, and attack when they receive SIGUSR2 (the
launcher sends it at the scenario's moment). All modes stop at SIGTERM or after ``--duration``.
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys

from zdrone.core.fleet import ConfigError
from zdrone.net.eventlog import EventLog
from zdrone.sil import testbed_records as trec
from zdrone.sil.attackers import ATTACKS, MODES, Ctx
from zdrone.sil.attackers.common import dangerous_messages
from zdrone.sil.attackers.companion_host import fake_autopilot_frames

__all__ = ["ATTACKS", "MODES", "Ctx", "dangerous_messages", "fake_autopilot_frames", "main"]


def main(argv: list[str] | None = None) -> int:
    import faulthandler

    from zdrone.crashes import stacks_on_crash
    from zdrone.net.shutdown import route_signals

    stacks_on_crash()  # a crash leaves every thread's stack in our log
    try:  # stuck at the end of a run: the launcher's SIGUSR1 prints every thread's stack to our log
        faulthandler.register(signal.SIGUSR1, all_threads=True)
    except (AttributeError, ValueError, OSError):
        pass
    p = argparse.ArgumentParser(prog="python -m zdrone.sil.rogue", description="TESTBED ONLY attackers")
    p.add_argument("--mode", choices=MODES, required=True)
    p.add_argument("--fleet", required=True)
    p.add_argument("--router", required=True)
    p.add_argument("--drone", default="d1")
    p.add_argument("--duration", type=float, default=20.0, help="seconds of attack")
    p.add_argument("--rate", type=float, default=2.0,
                   help="queries per second (linkkey-knockout, pair-flood; lease-stamper: stamps)")
    p.add_argument("--gcs-port", type=int, help="UDP port of the GCS gateway (gateway-flood)")
    p.add_argument("--gcs-port-b", type=int, help="UDP port of GS B's GCS gateway (local-app)")
    p.add_argument("--gcs-keys", help="GS A's GCS application key file (local-app: its operator's signed application)")
    p.add_argument("--wait-go", action="store_true", help="set up, then attack on SIGUSR2")
    p.add_argument("--after-go", type=float, default=0.0, help="seconds to wait after SIGUSR2 before attacking (0)")
    p.add_argument("--replies", type=int, default=1, help="key-injection: forged replies of each kind per query (1)")
    p.add_argument("--recorded", type=int, default=8,
                   help="stale-pairing: message 1s of A recorded in earlier flights (8)")
    p.add_argument("--fc-port", type=int, help="UDP port of the autopilot's TELEM2 (fc-radio)")
    p.add_argument("--vehicle-port", type=int,
                   help="UDP port the companion listens on for its autopilot (fake-autopilot)")
    p.add_argument("--size", type=int, default=40, help="junk-flood: bytes per junk envelope (40)")
    p.add_argument("--events")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    if args.rate <= 0 or args.duration <= 0 or not 2 <= args.size <= 1 << 20:
        print("rogue: error: --rate and --duration must be positive, --size 2..1048576", file=sys.stderr)
        return 2
    events = EventLog(args.events, f"rogue-{args.mode}")
    ctx = Ctx(args.fleet, args.router, args.drone, events, args.duration, args.rate, args.gcs_port, args.wait_go,
              max(1, args.replies), max(0, args.recorded), fc_port=args.fc_port, vehicle_port=args.vehicle_port,
              gcs_port_b=args.gcs_port_b, gcs_keys=args.gcs_keys, size=args.size,
              after_go=max(0.0, args.after_go))
    # on a thread of their own: a handler in the main thread setting an event the main thread waits on
    # can deadlock it (zdrone.net.shutdown); no thread runs yet (the sessions open in the attack)
    route_signals({signal.SIGTERM: ctx.stop.set, signal.SIGUSR2: ctx.go.set})
    try:
        print(f"rogue {args.mode}: attacking {args.drone}", flush=True)
        ATTACKS[args.mode](ctx)
    except ConfigError as exc:
        print(f"rogue: error: {exc}", file=sys.stderr)
        return 2
    finally:
        events.write_record(trec.Closed())
        events.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
