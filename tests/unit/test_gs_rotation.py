"""A GS whose static key is rotated in flight re-pairs under the new key as a fresh pairing, in memory
(``zdrone.bench.fleetnet``: the drone's pure core and the GSs' pure cores, real crypto, explicit
time): make-before-break (the old live link serves until the new key is proven), no failsafe, no gap
in command, and the keys it shared before stay as they are: the hand-over that follows goes through."""

from __future__ import annotations

import os

import pytest

from gs.actions import Ask, AskKind
from zdrone.bench.fleetnet import WALL0, FleetNet, make_fleet
from zdrone.core.pairing import query_answer
from zdrone.core.authority import State
from zdrone.core.keys import Identity, SigningKey
from zdrone.core.revision import Changes, apply_revision, make_revision, with_keys
from zdrone.fleet.files import load_base_fleet, load_fleet_signing_key


@pytest.fixture(scope="module")
def fleet_dir(tmp_path_factory):
    return make_fleet(tmp_path_factory.mktemp("fleet"))


def rotate(net: FleetNet, fleet_dir, gs: str) -> Identity:
    """Revision 1 rotates ``gs``'s static key: applied by the drone and every GS, and ``gs`` adopts it."""
    new = revised(fleet_dir, net, gs)
    net.gs_outs(gs, net.gss[gs].adopt_identity(new, net.now, WALL0 + net.now))
    return new


def revised(fleet_dir, net: FleetNet, gs: str) -> Identity:
    """Revision 1 rotates ``gs``'s static key, applied by the drone and every GS (not yet adopted)."""
    base = load_base_fleet(fleet_dir)
    new = Identity.generate()
    rev = make_revision(base, 1, with_keys(Changes(), gs, new.public, SigningKey.generate().public),
                        load_fleet_signing_key(fleet_dir, base))
    fleet = apply_revision(base, rev)
    net.drone_outs(net.drone.on_revision(fleet, net.now))
    for core in net.gss.values():
        core.fleet = fleet
    return new


def test_rotating_the_owner_in_flight_keeps_the_shared_keys_and_the_hand_over_goes_through(fleet_dir):
    net = FleetNet(fleet_dir)
    a_core = net.add_gs("A", pair=True, command_rate=2.0)
    b_core = net.add_gs("B")
    net.cut.add("B")  # B out of reach until the overlap: the key A got it is a candidate of B's until then
    net.run(4.0)
    assert net.drone.machine.owner == "A" and set(net.drone.links) == {"A", "B"}
    net.on_ground = False
    a, b = net.centre("A"), net.centre("B")
    net.fly(a, net.between(a, b, 0.1), 3.0)
    m, epoch = net.drone.machine, net.drone.machine.epoch
    shared, b_key = b_core.counters["linkkey_shared"], net.drone.links["B"]
    new = revised(fleet_dir, net, "A")
    (ask,) = a_core.adopt_identity(new, net.now, WALL0 + net.now)
    assert isinstance(ask, Ask) and ask.kind is AskKind.PAIR
    ans, outs = net.drone.on_pair_query("A", ask.payload, net.now, os.urandom(32), WALL0 + net.now)
    net.drone_outs(outs)
    answer = query_answer(ans)
    assert answer is not None and answer[0] is not None
    replied = a_core.on_pair_reply("d1", *answer, net.now)
    # A's timer runs before the drone's next word reaches it (a real network's order): a fresh pairing
    # under the new key is no restart of the drone, so no key is asked for again
    early = a_core.handle_timer(net.now, WALL0 + net.now)
    assert not [x for x in early if isinstance(x, Ask)], early
    net.gs_outs("A", replied + early)
    net.run(3.0)
    assert m.owner == "A" and m.epoch == epoch and m.state is State.LINKED and not net.commands
    assert "A" not in net.drone.rekey and net.drone.links["A"].key == a_core.sessions["d1"].link.key
    assert b_core.counters["linkkey_shared"] == shared and net.drone.links["B"] is b_key
    net.cut.discard("B")
    net.fly(net.position, b, 30.0)
    assert m.owner == "B" and m.state is State.LINKED and not net.commands, (m.owner, m.state, net.commands)


def test_a_rotation_the_drone_has_not_applied_yet_is_paired_again_until_it_has(fleet_dir):
    """The GS adopted its new key first: the drone, still on the old fleet, cannot answer; the fresh
    pairing is tried again until the drone applies the revision, and the old link serves meanwhile."""
    net = FleetNet(fleet_dir)
    a_core = net.add_gs("A", pair=True, command_rate=2.0)
    net.run(4.0)
    net.on_ground = False
    net.run(1.0)
    base = load_base_fleet(fleet_dir)
    new = Identity.generate()
    rev = make_revision(base, 1, with_keys(Changes(), "A", new.public, SigningKey.generate().public),
                        load_fleet_signing_key(fleet_dir, base))
    fleet = apply_revision(base, rev)
    a_core.fleet = fleet
    old = a_core.sessions["d1"].link
    net.gs_outs("A", a_core.adopt_identity(new, net.now, WALL0 + net.now))
    forwarded = len(net.to_vehicle)
    net.run(5.0)
    assert a_core.sessions["d1"].link is old and a_core.holds_authority("d1")  # the old link serves
    assert len(net.to_vehicle) > forwarded
    net.drone_outs(net.drone.on_revision(fleet, net.now))
    net.run(3.0)
    assert a_core.sessions["d1"].link is not old and net.drone.links["A"].key == a_core.sessions["d1"].link.key
    assert net.drone.machine.owner == "A" and not net.commands


def test_the_old_link_serves_until_the_drone_speaks_under_the_new_key(fleet_dir):
    net = FleetNet(fleet_dir)
    a_core = net.add_gs("A", pair=True, command_rate=2.0)
    net.run(4.0)
    net.on_ground = False
    net.run(1.0)
    forwarded = len(net.to_vehicle)
    old = a_core.sessions["d1"].link
    rotate(net, fleet_dir, "A")
    for _ in range(40):
        net.step(0.05)
        assert a_core.drone_status("d1", net.now).holds_authority  # no moment without command
    assert a_core.sessions["d1"].link is not old and net.drone.links["A"].key == a_core.sessions["d1"].link.key
    assert len(net.to_vehicle) > forwarded and not net.commands
