"""TESTBED ONLY: attackers for the demo scenarios and the tests.

``no-key``: has GS A's *router* password (stolen) but not A's static key nor any link key. It
tries to pair as A with its own key, publishes unsealed MAVLink commands and forged envelopes on
``zdrone/<drone>/up/A``, and replays sealed frames it captured (with the drone's stolen router
password it can listen to ``up/A``; with A's it can publish there). Every attempt must end as a
counted drop at the drone (``unknown_epoch``, ``auth_failed``, ``replay``) or a failed handshake.
It also tries the router with a wrong password (refused at connect).

``unauthorized``: GS X, a fleet member with its own keys and router account, not authorized for the
drone. It tries to pair (refused by the handover authority), to fetch B's link key over the
backhaul (the router's ACL gives it no reply) and to publish on A's key (denied by the ACL).

Run: ``python -m zdrone.sil.rogue --mode no-key --fleet DIR --router EP --events FILE``.
"""

from __future__ import annotations

import argparse
import os
import queue
import signal
import sys
import time

from pymavlink.dialects.v20 import common as mav

from ..core.envelope import SecureLink
from ..core.fleet import ConfigError
from ..core.keys import Identity, LinkKey
from ..core.keyshare import KeyShareAsk
from ..core.mavlink import FrameCodec
from ..core.pairing import PairingInitiator
from ..fleetfiles import load_fleet, load_secret
from ..net import keyexprs as kx
from ..net.eventlog import EventLog
from ..net.session import open_client


def _land(sysid: int) -> bytes:
    return FrameCodec(sysid, 190).encode(
        mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_NAV_LAND, 0, 0, 0, 0, float("nan"), float("nan"), float("nan"), float("nan")))


def no_key(fleet_dir: str, router: str, drone: str, events: EventLog, duration: float, stop: list[bool]) -> None:
    fleet = load_fleet(fleet_dir)
    a_pw = load_secret(fleet_dir, "A").router_password   # stolen router passwords, nothing else
    d_pw = load_secret(fleet_dir, drone).router_password
    try:
        open_client(router, "A", "not-the-password").close()
        events.write("router_accepted_wrong_password")
    except ConfigError:
        events.write("router_refused", user="A")
    s_pub = open_client(router, "A", a_pw)
    s_cap = open_client(router, drone, d_pw)
    captured: queue.SimpleQueue[bytes] = queue.SimpleQueue()
    cap = s_cap.declare_subscriber(kx.up(drone, "A"), lambda smp: captured.put(smp.payload.to_bytes()))
    try:
        fake = Identity.generate()
        ini = PairingInitiator(fake, "A", drone, fleet.nodes[drone].public_bytes)
        replies = list(s_pub.get(kx.pair(drone, "A"), payload=ini.start(), timeout=3.0))
        events.write("pair_attempt", answered=sum(1 for r in replies if r.ok is not None))
        forged = SecureLink(key=LinkKey.from_secret(drone, "A", os.urandom(32)), role="gs", tx_keyexpr=kx.up(drone, "A"),
                            rx_keyexpr=kx.down(drone, "A"), peer_sysid=None, now=0.0)
        sysid_a = fleet.nodes["A"].sysid
        sent = {"plain": 0, "forged": 0, "replayed": 0}
        deadline = time.monotonic() + duration
        while time.monotonic() < deadline and not stop[0]:
            s_pub.put(kx.up(drone, "A"), _land(sysid_a))
            sent["plain"] += 1
            s_pub.put(kx.up(drone, "A"), forged.seal(_land(sysid_a)))
            sent["forged"] += 1
            for _ in range(4):
                try:
                    frame = captured.get_nowait()
                except queue.Empty:
                    break
                s_pub.put(kx.up(drone, "A"), frame)
                sent["replayed"] += 1
            time.sleep(0.2)
        events.write("attack_done", **sent)
    finally:
        cap.undeclare()
        s_cap.close()
        s_pub.close()


def unauthorized(fleet_dir: str, router: str, drone: str, events: EventLog, duration: float, stop: list[bool]) -> None:
    fleet = load_fleet(fleet_dir)
    me = load_secret(fleet_dir, "X", fleet)
    s = open_client(router, "X", me.router_password)
    try:
        deadline = time.monotonic() + duration
        tries = 0
        while time.monotonic() < deadline and not stop[0]:
            ini = PairingInitiator(me.identity, "X", drone, fleet.nodes[drone].public_bytes)
            refused = answered = 0
            for r in s.get(kx.pair(drone, "X"), payload=ini.start(), timeout=3.0):
                answered += r.ok is not None
                refused += r.err is not None
            keys = [r for r in s.get(kx.linkkey("B", drone), payload=KeyShareAsk(me.identity, "X", "B", fleet.nodes["B"].public_bytes, drone, 0.0).payload, timeout=2.0)
                    if r.ok is not None]
            s.put(kx.up(drone, "A"), _land(fleet.nodes["X"].sysid))  # denied by the router's ACL
            s.put(kx.up(drone, "X"), _land(fleet.nodes["X"].sysid))  # nobody listens: X has no link
            tries += 1
            events.write("unauthorized_attempt", pair_answered=answered, pair_refused=refused, linkkey_replies=len(keys))
            time.sleep(1.0)
        events.write("attack_done", tries=tries)
    finally:
        s.close()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m zdrone.sil.rogue", description="TESTBED ONLY attackers")
    p.add_argument("--mode", choices=["no-key", "unauthorized"], required=True)
    p.add_argument("--fleet", required=True)
    p.add_argument("--router", required=True)
    p.add_argument("--drone", default="d1")
    p.add_argument("--duration", type=float, default=20.0)
    p.add_argument("--events")
    args = p.parse_args(argv)
    events = EventLog(args.events, f"rogue-{args.mode}")
    stop = [False]
    signal.signal(signal.SIGTERM, lambda *_: stop.__setitem__(0, True))
    try:
        print(f"rogue {args.mode}: attacking {args.drone}", flush=True)
        (no_key if args.mode == "no-key" else unauthorized)(args.fleet, args.router, args.drone, events, args.duration, stop)
    except ConfigError as exc:
        print(f"rogue: error: {exc}", file=sys.stderr)
        return 2
    finally:
        events.write("closed")
        events.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
