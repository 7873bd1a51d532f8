"""TESTBED ONLY: the attackers of the demo scenarios, the tests and ``zdrone bench attack``, one module
per class of attacker (what it holds decides what it may try):

- ``outsider``: stolen router passwords, captured bytes, a certificate of its own; no key of any GS
  (``no-key``, ``key-injection``, ``linkkey-knockout``, ``pair-replay``, ``uplink-unsealed``,
  ``no-cert``, ``stale-pairing``);
- ``unauthorized``: a fleet GS not authorized for the drone (``unauthorized``);
- ``lease_stamper``: the same GS vouching for the drone to keep its owner's lease alive (``lease-stamper``);
- ``insider``: an authorized GS gone bad, with B's own key (``uplink-sealed``, ``insider-heir``,
  ``key-escrow``);
- ``gs_host``: a local process on GS A's host (``gateway-flood``, ``local-app``);
- ``companion_host``: on the vehicle: a process on the companion host, a radio on the autopilot's
  second port (``fake-autopilot``, ``fc-radio``);
- ``flood``: floods and junk (``pair-flood``, ``big-flood``, ``junk-flood``);
- ``ops``: GSs that tell the fleet's viewer what only the drone may say (``ops-unauthorized``: X's
  own key; ``ops-insider``: B's own key, replaying the drone's old signed word);
- ``common``: what they share (``Ctx``, frames, uplink lanes, a reply counter).

Each runs as its own process: ``python -m zdrone.sil.rogue --mode MODE`` (``zdrone.sil.rogue``).
"""

from __future__ import annotations

from typing import Callable

from zdrone.sil.attackers.common import Ctx
from zdrone.sil.attackers.companion_host import fake_autopilot, fc_radio
from zdrone.sil.attackers.flood import big_flood, junk_flood, pair_flood
from zdrone.sil.attackers.gs_host import gateway_flood, local_app
from zdrone.sil.attackers.insider import insider_heir, key_escrow, uplink_sealed
from zdrone.sil.attackers.lease_stamper import lease_stamper
from zdrone.sil.attackers.ops import ops_insider, ops_unauthorized
from zdrone.sil.attackers.outsider import key_injection, linkkey_knockout, no_cert, no_key, pair_replay, stale_pairing, uplink_unsealed
from zdrone.sil.attackers.unauthorized import unauthorized

MODES = ("no-key", "unauthorized", "key-injection", "linkkey-knockout", "pair-replay", "pair-flood",
         "uplink-sealed", "uplink-unsealed", "gateway-flood", "big-flood", "junk-flood", "no-cert", "insider-heir",
         "key-escrow", "stale-pairing", "fc-radio", "fake-autopilot", "local-app", "ops-unauthorized", "ops-insider",
         "lease-stamper")
ATTACKS: dict[str, Callable[[Ctx], None]] = {
    "no-key": no_key, "unauthorized": unauthorized, "key-injection": key_injection,
    "linkkey-knockout": linkkey_knockout, "pair-replay": pair_replay, "pair-flood": pair_flood,
    "uplink-sealed": uplink_sealed, "uplink-unsealed": uplink_unsealed, "gateway-flood": gateway_flood,
    "big-flood": big_flood, "junk-flood": junk_flood, "no-cert": no_cert, "insider-heir": insider_heir,
    "key-escrow": key_escrow, "stale-pairing": stale_pairing, "fc-radio": fc_radio, "fake-autopilot": fake_autopilot,
    "local-app": local_app, "ops-unauthorized": ops_unauthorized, "ops-insider": ops_insider,
    "lease-stamper": lease_stamper,
}
assert set(ATTACKS) == set(MODES)
