"""TESTBED ONLY: a fleet GS not authorized for the drone that vouches for it, to keep its owner's
lease alive (``zdrone.core.lease``).

``lease-stamper``: GS X's own signing key, router password and (TLS, sites) certificate; X is in the
fleet, authorized for no drone. It opens its session on the router ``--router`` names (the launcher
gives it the site the drone still reaches when the network splits: ``RogueSpec.beside``) and takes
the revision in force as it sets up (the fleet directory as it is then: the operator's later
revision is made on A's side of the cut and never reaches the drone). Told to attack, it puts every
``1 / --rate`` s, on its own revision key (``keyexprs.revision("X")``, which the router lets it put
on), a genuine stamp signed with its own key naming that revision, now, and the drone
(``make_push("X", N, time.time(), key, None, (drone,))``): only the check that a renewing GS is
authorized for the drone refuses it (``stamp_refused:unauthorized``). One ``stamp_put`` record per
put.
"""

from __future__ import annotations

import time

from zdrone.core.fleet import ConfigError
from zdrone.core.revision import make_push
from zdrone.fleet import keyexprs
from zdrone.fleet.files import load_secret
from zdrone.sil import testbed_records as trec
from zdrone.sil.attackers.common import Ctx, session_as


def lease_stamper(c: Ctx) -> None:
    fleet, drone = c.fleet, c.drone  # the revision in force now, before any revision made in flight
    me = load_secret(c.fleet_dir, "X", fleet)
    if me.signing is None:
        raise ConfigError("X's secret holds no signing key: it cannot sign a stamp")
    number = fleet.revision
    s = session_as(c, "X", own_site=False)  # at the router it was given: the drone's side of the split
    stamps = failed = 0
    try:
        c.ready()
        if not c.wait_for_go():
            return
        going = c.attack_window()
        while going():
            wall = time.time()
            try:
                s.put(keyexprs.revision("X"), make_push("X", number, wall, me.signing, None, (drone,)))
            except Exception:  # a session closing at the end of the run: counted (attack_done), never fatal
                failed += 1
            else:
                stamps += 1
                c.events.write_record(trec.StampPut(gs="X", number=number, wall=round(wall, 3), drones=(drone,)))
            c.stop.wait(1.0 / c.rate)
        c.events.write("attack_done", stamps=stamps, failed=failed, number=number, period_s=round(1.0 / c.rate, 3))
    finally:
        s.close()
