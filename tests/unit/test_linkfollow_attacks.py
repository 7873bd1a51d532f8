"""Attacks on links that follow the drone (review): each test fails while the break stands."""

from __future__ import annotations

from pathlib import Path

from pymavlink.dialects.v20 import common as mav

from tests.coreflight import WALL0
from tests.unit.test_corridor_core import _flight
from zdrone.core import wire
from zdrone.core.envelope import SecureLink
from zdrone.core.keys import LinkKey
from zdrone.core.mavlink import FrameCodec
from zdrone.core.pairing import PairAccepted, PairingInitiator
from zdrone.fleet.files import load_secret


def test_pairing_candidates_proven_later_never_pass_links_max(tmp_path: Path) -> None:
    """Two authorized GSs far off the route each send message 1 while the drone holds 2 links (accepted:
    room), then both prove their keys: the drone must not end up with 4 live links (links_max 3)."""
    f, _ = _flight(tmp_path, 8.0)
    m = f.drone.machine
    assert f.run_until(lambda: f.sim.armed and m.owner == "A" and len(f.drone.links) == 2, 300.0)
    links = {}
    for g in ("G", "H"):  # outside coverage: the drone is LINKED, pairing needs no coverage
        ini = PairingInitiator(load_secret(tmp_path, g, f.fleet).identity, g, "d1", f.fleet.nodes["d1"].public_bytes,
                               stamp=WALL0 + f.now)
        ans, outs = f.drone.on_pair_query(g, ini.start(), f.now, bytes(32), WALL0 + f.now)
        f.handle(outs)
        assert isinstance(ans, PairAccepted)
        links[g] = SecureLink(key=ini.finish(ans.reply), role="gs", tx_keyexpr=f"zdrone/d1/up/{g}",
                              rx_keyexpr=f"zdrone/d1/down/{g}", peer_sysid=f.fleet.nodes["d1"].sysid, now=f.now)
    for g, link in links.items():
        hb = FrameCodec(f.fleet.nodes[g].sysid, 190).encode(mav.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))
        f.handle(f.drone.on_envelope(g, link.seal(hb), f.now))
    assert len(f.drone.links) <= f.fleet.links_max, sorted(f.drone.links)


def test_the_ex_owner_cannot_wipe_the_new_owners_link_with_a_linkclosed_under_the_key_it_granted(tmp_path: Path) -> None:
    """A granted B its key (key sharing: A carries the secret), handed over to B. A LinkClosed sealed by A
    under that key is 'authentic' to B, yet the drone never closes its owner's link: B must keep it (else
    B wipes its end, the drone loses its owner's link and lands)."""
    f, _ = _flight(tmp_path, 8.0)
    m = f.drone.machine
    secrets: dict[str, bytes] = {}
    a = f.gs["A"].core.sessions["d1"]
    send = a.send_control

    def spy(msg, *args, **kw):  # what A knows: the secret of every grant it made
        if isinstance(msg, wire.KeyGrant):
            secrets[msg.gs] = msg.secret
        return send(msg, *args, **kw)

    a.send_control = spy  # type: ignore[method-assign]
    assert f.run_until(lambda: m.owner == "B" and m.state.value == "linked", 600.0)
    b = f.gs["B"].core.sessions["d1"]
    forged = SecureLink(key=LinkKey.from_secret("d1", "B", secrets["B"]), role="drone", tx_keyexpr="zdrone/d1/down/B",
                        rx_keyexpr="zdrone/d1/up/B", peer_sysid=f.fleet.nodes["B"].sysid, now=f.now)
    forged._tx_counter = f.drone.links["B"]._tx_counter + 1  # the drone's next counter (its headers are in the clear)
    f.station("B", f.gs["B"].core.on_envelope("d1", forged.seal(wire.encode_control(wire.LinkClosed("forged"))), f.now))
    assert b.link is not None
    f.run_until(lambda: m.state.value == "failsafe", 20.0)
    assert m.state.value != "failsafe" and not f.commands
