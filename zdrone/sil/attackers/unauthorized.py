"""TESTBED ONLY: a fleet GS not authorized for the drone, with its own keys and router account.

``unauthorized``: GS X, a fleet member with its own keys and router account, not authorized for the
drone. It tries to pair (refused by the handover authority), to fetch B's link key over the
backhaul (the router's ACL gives it no reply) and to publish on A's key (denied by the ACL).
"""

from __future__ import annotations

import time


from zdrone.core.keyshare import KeyShareAsk
from zdrone.core.pairing import PairingInitiator
from zdrone.fleet.files import load_secret
from zdrone.fleet import keyexprs
from zdrone.sil import testbed_records as trec
from zdrone.net.session import open_client
from zdrone.sil.attackers.common import Ctx, land_frame, next_up


def unauthorized(c: Ctx) -> None:
    fleet, drone = c.fleet, c.drone
    me = load_secret(c.fleet_dir, "X", fleet)
    s = open_client(c.router, "X", me.router_password)
    try:
        c.ready()
        going = c.attack_window()
        tries = 0
        while going():
            ini = PairingInitiator(me.identity, "X", drone, fleet.nodes[drone].public_bytes, stamp=time.time())
            refused = answered = 0
            for r in s.get(keyexprs.pair(drone, "X"), payload=ini.start(), timeout=3.0):
                answered += r.ok is not None
                refused += r.err is not None
            ask = KeyShareAsk(me.identity, "X", "B", fleet.nodes["B"].public_bytes, drone, 0.0)
            keys = [r for r in s.get(keyexprs.linkkey("B", drone), payload=ask.payload, timeout=2.0) if r.ok is not None]
            s.put(next_up(drone, "A"), land_frame(fleet.nodes["X"].sysid))  # denied by the router's ACL
            s.put(next_up(drone, "X"), land_frame(fleet.nodes["X"].sysid))  # nobody listens: X has no link
            tries += 1
            c.events.write_record(trec.UnauthorizedAttempt(pair_answered=answered, pair_refused=refused, linkkey_replies=len(keys)))
            c.stop.wait(1.0)
        c.events.write("attack_done", tries=tries)
    finally:
        s.close()
