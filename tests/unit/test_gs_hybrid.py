"""The GSs pair and share keys with the hybrid (ML-KEM-768) handshake while the fleet says
``pairing_pq``, in memory (``zdrone.bench.fleetnet``: the drone's and the GSs' pure cores, real
crypto): both exchanges complete end to end, a classical one is refused as a downgrade, and a revision
turning it on in flight applies to the next exchange."""

from __future__ import annotations

import os

import pytest

from gs.actions import Ask, AskKind
from zdrone.bench.fleetnet import WALL0, FleetNet, make_fleet
from zdrone.core.authority import State
from zdrone.core.keys import Identity
from zdrone.core.keyshare import KeyShareAsk, ShareRefusal, decode_query
from zdrone.core.kk import is_hybrid
from zdrone.core.pairing import PairingInitiator, PairRefusal, PairRefused
from zdrone.core.revision import Changes, apply_revision, make_revision
from zdrone.fleet.files import load_base_fleet, load_fleet_signing_key, load_secret


@pytest.fixture(scope="module")
def fleet_dir(tmp_path_factory):
    return make_fleet(tmp_path_factory.mktemp("fleet"))


def pq_fleet(fleet_dir):
    base = load_base_fleet(fleet_dir)
    rev = make_revision(base, 1, Changes(pairing_pq=True), load_fleet_signing_key(fleet_dir, base))
    return apply_revision(base, rev)


def revise(net: FleetNet, fleet) -> None:
    net.drone_outs(net.drone.on_revision(fleet, net.now))
    for core in net.gss.values():
        core.fleet = fleet


def asks(net: FleetNet, kind: AskKind) -> list[tuple[str, Ask]]:
    """Every query of ``kind`` the GSs send from now on, as sent (the net still delivers them)."""
    seen: list[tuple[str, Ask]] = []
    deliver = net._ask

    def spy(gs: str, a: Ask) -> None:
        if a.kind is kind:
            seen.append((gs, a))
        deliver(gs, a)

    net._ask = spy  # type: ignore[method-assign]
    return seen


def identity(fleet_dir, net: FleetNet, name: str) -> Identity:
    return load_secret(fleet_dir, name, net.fleet).identity


def test_with_pairing_pq_pairing_and_key_sharing_complete_hybrid_end_to_end(fleet_dir):
    net = FleetNet(fleet_dir)
    a_core = net.add_gs("A", pair=True)
    b_core = net.add_gs("B")
    revise(net, pq_fleet(fleet_dir))
    pairs, shares = asks(net, AskKind.PAIR), asks(net, AskKind.LINKKEY)
    net.run(4.0)
    assert net.drone.machine.owner == "A" and net.drone.machine.state is State.LINKED
    assert set(net.drone.links) == {"A", "B"} and b_core.counters["linkkey_shared"] == 1
    assert pairs and all(is_hybrid(a.payload) for _, a in pairs)
    assert shares and all(is_hybrid(decode_query(a.payload).m1) for _, a in shares)
    assert not net.drone.counters["pair_refused:downgrade"] and not b_core.counters["linkkey_refused:downgrade"]
    assert a_core.sessions["d1"].link.key == net.drone.links["A"].key


def test_with_pairing_pq_a_classical_pairing_or_key_sharing_query_is_refused_as_a_downgrade(fleet_dir):
    net = FleetNet(fleet_dir)
    net.add_gs("A", pair=True)
    b_core = net.add_gs("B")
    revise(net, pq_fleet(fleet_dir))
    net.run(4.0)
    drone_public = net.fleet.nodes["d1"].public_bytes
    classical = PairingInitiator(identity(fleet_dir, net, "B"), "B", "d1", drone_public, stamp=WALL0 + net.now)
    ans, _ = net.drone.on_pair_query("B", classical.start(), net.now, os.urandom(32), WALL0 + net.now)
    assert isinstance(ans, PairRefused) and ans.reason is PairRefusal.DOWNGRADE
    # A asks B classically for its key of d1 (B's link cut off first: only then does B answer at all)
    net.cut.add("B")
    net.run(4.0)
    ask = KeyShareAsk(identity(fleet_dir, net, "A"), "A", "B", net.fleet.nodes["B"].public_bytes, "d1", net.now,
                      wall=WALL0 + net.now)
    answer, _ = b_core.on_linkkey_query("d1", ask.payload, net.now, os.urandom(32), WALL0 + net.now)
    assert answer.reply is None and answer.error == ShareRefusal.DOWNGRADE.value.encode()
    assert b_core.counters["linkkey_refused:downgrade"] == 1 and b_core.counters["linkkey_shared"] == 1


def test_a_revision_turning_pairing_pq_on_in_flight_applies_to_the_next_exchange(fleet_dir):
    net = FleetNet(fleet_dir)
    a_core = net.add_gs("A", pair=True)
    b_core = net.add_gs("B")
    shares = asks(net, AskKind.LINKKEY)
    net.run(4.0)
    assert shares and not any(is_hybrid(decode_query(a.payload).m1) for _, a in shares)  # classical so far
    net.on_ground = False
    revise(net, pq_fleet(fleet_dir))
    assert b_core.key_owner.responder.require_hybrid
    # the drone restarts: A re-pairs it and shares B's key again, both under the fleet now in force
    pairs = asks(net, AskKind.PAIR)
    shares.clear()
    net.restart_drone()
    net.drone_outs(net.drone.on_revision(a_core.fleet, net.now))
    net.cut.add("B")  # B hears the drone's silence: its link LOST, it answers the new query
    net.run(6.0)
    net.cut.discard("B")
    net.run(2.0)
    assert pairs and all(is_hybrid(a.payload) for _, a in pairs)
    assert shares and all(is_hybrid(decode_query(a.payload).m1) for _, a in shares)
    assert net.drone.machine.owner == "A" and set(net.drone.links) == {"A", "B"}
    assert not b_core.counters["linkkey_refused:downgrade"]


def test_with_pairing_pq_a_key_grant_over_a_classical_link_is_refused_and_the_owner_pairs_again_hybrid(fleet_dir):
    """Paired classically, then the fleet requires the hybrid pairing: a key shared for B that A
    would deliver under its classical link key is refused (it is only as strong as that key); A pairs
    again, hybrid, make-before-break (no failsafe, authority kept), and B's key then reaches the
    drone under the hybrid link."""
    from zdrone.core import wire

    net = FleetNet(fleet_dir)
    a_core = net.add_gs("A", pair=True)
    b_core = net.add_gs("B")
    net.cut.add("B")  # B out of reach: no key shared for it yet
    net.run(4.0)
    assert net.drone.machine.owner == "A" and not net.drone.links["A"].hybrid
    # the drone alone applies the revision first: A (still classical) hands it a grant for B
    fleet = pq_fleet(fleet_dir)
    net.drone_outs(net.drone.on_revision(fleet, net.now))
    from zdrone.core.keys import LinkKey

    secret = os.urandom(32)
    grant = wire.KeyGrant(gs="B", sysid=net.fleet.nodes["B"].sysid, secret=secret, grant_id=1)
    sealed = a_core.sessions["d1"].link.seal_control(grant)  # as A sends it: under its live (classical) link key
    net.drone_outs(net.drone.on_envelope("A", sealed, net.now))
    assert net.drone.counters["grant_refused:downgrade"] == 1
    slot = net.drone.slots.get("B")
    held = [] if slot is None else [slot.live] * (slot.live is not None) + [c.link for c in slot.candidates]
    assert not any(link.key.same_as(LinkKey.from_secret("d1", "B", secret)) for link in held)
    # A applies it too: it pairs again, hybrid, while its classical link goes on
    epoch = net.drone.machine.epoch
    for core in net.gss.values():
        core.fleet = fleet
    assert a_core.counters["repair_hybrid"] == 1
    pairs = asks(net, AskKind.PAIR)
    net.run(4.0)
    assert pairs and all(is_hybrid(a.payload) for _, a in pairs)
    assert net.drone.links["A"].hybrid and a_core.sessions["d1"].link.hybrid
    assert a_core.sessions["d1"].link.key == net.drone.links["A"].key
    assert (net.drone.machine.owner, net.drone.machine.epoch) == ("A", epoch) and not net.commands
    # the same grant under A's hybrid link key is taken (a candidate of B's until B proves it)
    sealed = a_core.sessions["d1"].link.seal_control(grant)
    net.drone_outs(net.drone.on_envelope("A", sealed, net.now))
    assert net.drone.counters["grant_refused:downgrade"] == 1
    taken = [c.link for c in net.drone.slots["B"].candidates if c.link.key.same_as(LinkKey.from_secret("d1", "B", secret))]
    assert taken and taken[0].hybrid
