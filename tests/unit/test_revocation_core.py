"""Fleet revisions applied in flight, in memory (``zdrone.bench.fleetnet``: the drone's pure core
with the GSs' pure cores, real crypto, explicit time): a revoked GS loses its link, its keys and its
authority (to an heir whose coverage holds the drone, else the failsafe); a revoked GS that did not
hold authority costs nothing; the revision lease; the authority machine's table with revisions."""

from __future__ import annotations

import pytest
from hypothesis import given, settings, strategies as st

from zdrone.bench.fleetnet import WALL0, FleetNet, make_fleet
from zdrone.core import authority as ha
from zdrone.core import records as rec
from zdrone.core.authority import State
from zdrone.core.revision import Changes, apply_revision, make_revision, with_revoked
from zdrone.fleet.files import DEFAULT_REVISION_LEASE_S, load_base_fleet, load_fleet_signing_key


@pytest.fixture(scope="module")
def fleet_dir(tmp_path_factory):
    return make_fleet(tmp_path_factory.mktemp("fleet"))


def revoked(fleet_dir, *nodes: str, number: int = 1):
    base = load_base_fleet(fleet_dir)
    changes = Changes()
    for n in nodes:
        changes = with_revoked(changes, n)
    return apply_revision(base, make_revision(base, number, changes, load_fleet_signing_key(fleet_dir, base)))


def linked(fleet_dir) -> FleetNet:
    net = FleetNet(fleet_dir)
    net.add_gs("A", pair=True)
    net.add_gs("B")
    net.run(4.0)
    assert net.drone.machine.owner == "A" and set(net.drone.links) == {"A", "B"}
    return net


def in_region_owned_by_b(fleet_dir) -> FleetNet:
    """B holds authority (handed over by A), the drone inside both coverages, both links proven."""
    net = linked(fleet_dir)
    net.on_ground = False
    a, b = net.centre("A"), net.centre("B")
    net.fly(a, b, 30.0)  # handed over to B on the way
    net.fly(b, net.between(a, b, 0.55), 8.0)  # back into the region: B keeps authority
    m = net.drone.machine
    assert m.owner == "B" and {"A", "B"} <= m.inside, (m.owner, m.inside)
    return net


def apply(net: FleetNet, fleet) -> None:
    net.drone_outs(net.drone.on_revision(fleet, net.now))


def test_revoking_the_owner_in_the_region_hands_over_to_the_heir_without_a_failsafe(fleet_dir):
    net = in_region_owned_by_b(fleet_dir)
    net.run(1.0)
    epoch = net.drone.machine.epoch
    apply(net, revoked(fleet_dir, "B"))
    m = net.drone.machine
    assert m.owner == "A" and m.epoch == epoch + 1 and m.state is State.LINKED
    assert "B" not in net.drone.links and "B" not in net.drone.slots and "B" not in m.links
    assert not net.commands
    before = net.drone.counters["no_link"]
    net.run(2.0)  # B goes on sending: every frame is refused before any key is tried
    assert net.drone.counters["no_link"] > before or "B" not in net.drone._listening
    assert [r.number for r in net.records if isinstance(r, rec.RevisionApplied)] == [1]


def test_revoking_the_owner_where_no_other_gs_covers_the_drone_lands_it(fleet_dir):
    net = in_region_owned_by_b(fleet_dir)
    b = net.centre("B")
    net.fly(net.position, b, 15.0)  # deep in B's coverage, out of A's
    assert net.drone.machine.owner == "B" and "A" not in net.drone.machine.inside
    apply(net, revoked(fleet_dir, "B"))
    assert net.drone.machine.state is State.FAILSAFE
    assert [c.command for c in net.commands] == ["LAND"]


def test_revoking_a_gs_that_holds_no_authority_costs_the_owner_nothing(fleet_dir):
    net = linked(fleet_dir)
    net.on_ground = False
    apply(net, revoked(fleet_dir, "B"))
    net.run(3.0)
    m = net.drone.machine
    assert m.owner == "A" and m.state is State.LINKED and not net.commands
    assert "B" not in net.drone.links
    # B may no longer pair: the responder refuses it (unauthorized) before any crypto
    assert not net.drone.responder.authorized & {"B"}


def _lease(net: FleetNet) -> float:
    assert net.drone.lease_s == net.drone.fleet.revision_lease == DEFAULT_REVISION_LEASE_S  # in the fleet
    return net.drone.lease_s


def test_the_lease_is_armed_from_the_first_pairing_without_any_revision_and_others_stamps_renew_it(fleet_dir):
    net = linked(fleet_dir)  # A and B push stamps: B's renew A's lease
    lease = _lease(net)
    assert net.drone.fleet.revision == 0 and net.drone.lease_due() is not None
    net.run(2 * lease)
    assert net.drone.machine.owner == "A" and net.drone.machine.state is State.LINKED and not net.commands
    assert net.drone.counters["stamp_renewed"] >= 50 and net.drone.counters["stamp_refused:owner"] >= 50


@pytest.mark.parametrize("on_ground", [False, True])
def test_an_owner_that_alone_reaches_the_drone_does_not_renew_its_own_lease(fleet_dir, on_ground):
    """Only the owner's stamps are heard (the rest of the fleet is behind a partition): the lease
    lapses, in the air and on the ground, and the owner's authority goes (B, an authorized heir, is
    cut off too: the failsafe)."""
    net = linked(fleet_dir)
    net.on_ground = on_ground
    lease = _lease(net)
    net.cut.add("B")  # B's radio and its stamps are gone; A's stamps still come, every push period
    t0 = net.drone.revision_synced
    net.run(lease + 1.0)
    assert net.drone.counters["revision_lease_lapsed"] == 1
    assert net.drone.revision_synced == t0  # A's own stamps renewed nothing
    assert net.drone.machine.state is State.FAILSAFE
    assert "lease_lapsed" in [r.reason for r in net.records if isinstance(r, rec.Drop)]
    if not on_ground:
        assert [c.command for c in net.commands] == ["LAND"]
    # another GS's stamp renews the lease; the lapsed owner's own stamps still buy nothing
    net.cut.discard("B")
    net.run(11.0)
    assert net.drone.lease_due() is not None and net.drone.counters["revision_lease_lapsed"] == 1


def test_a_replayed_old_stamp_of_another_gs_buys_nothing_past_its_own_time(fleet_dir):
    net = linked(fleet_dir)
    lease = _lease(net)
    old = net.stamp("B")  # B's genuine stamp, captured now
    net.cut.add("B")
    for _ in range(int(lease) + 5):  # replayed every second by whoever holds it
        net.run(1.0)
        net.drone_outs(net.drone.on_revision_stamp(old, net.now, carrier="B"))
    assert net.drone.counters["revision_lease_lapsed"] == 1 and net.drone.machine.state is State.FAILSAFE


def test_stamps_that_are_forged_revoked_from_the_future_or_of_an_older_revision_renew_nothing(fleet_dir):
    net = linked(fleet_dir)
    net.stamps = False
    d = net.drone
    b = net.stamp("B")
    forged = b[:-1] + bytes([b[-1] ^ 1])
    assert d.on_revision_stamp(forged, net.now, carrier="B") == [] and d.counters["stamp_refused:signature"] == 1
    assert d.on_revision_stamp(net.stamp("B", wall=net.now + 60), net.now, carrier="B") == []
    assert d.counters["stamp_refused:ahead"] == 1
    apply(net, revoked(fleet_dir, "X"))
    old_revision = b  # B's stamp names revision 0, the fleet is at 1 now
    net.run(1.0)
    assert d.on_revision_stamp(old_revision, net.now, carrier="B") == []
    assert d.counters["stamp_refused:stale_revision"] == 1
    apply(net, revoked(fleet_dir, "X", "B", number=2))
    assert d.on_revision_stamp(net.stamp("B"), net.now, carrier="B") == []
    assert d.counters["stamp_refused:signature"] == 2


def test_the_lease_length_is_part_of_the_signed_revision(fleet_dir):
    from zdrone.core.revision import with_lease

    base = load_base_fleet(fleet_dir)
    rev = make_revision(base, 1, with_lease(Changes(), 15.0), load_fleet_signing_key(fleet_dir, base))
    fleet = apply_revision(base, rev)
    assert fleet.revision_lease == 15.0
    net = linked(fleet_dir)
    apply(net, fleet)
    net.cut.add("B")
    net.run(20.0)
    assert net.drone.counters["revision_lease_lapsed"] == 1
    # a revision that leaves the lease alone signs as revisions did before the lease existed
    plain = make_revision(base, 1, Changes(), load_fleet_signing_key(fleet_dir, base))
    assert b"revision_lease" not in plain.signed_bytes() and apply_revision(base, plain).revision_lease == DEFAULT_REVISION_LEASE_S


# ----------------------------------------------------------- the machine's table with revisions
AUTH = frozenset({"A", "B"})
GS = st.sampled_from(["A", "B", "X"])
times = st.floats(0, 1000, allow_nan=False)
EVENTS = st.one_of(
    st.builds(ha.PairingDone, times, GS, st.booleans()),
    st.builds(ha.GrantHeard, times, GS, GS),
    st.builds(ha.Frame, times, GS, st.sampled_from(list(ha.UplinkClass))),
    st.builds(ha.LinkChanged, times, GS, st.sampled_from(list(ha.LinkState))),
    st.builds(ha.RegionChanged, times, st.frozensets(GS)),
    st.builds(ha.Release, times, GS, GS, st.integers(0, 4)),
    st.builds(ha.GroundChanged, times, st.booleans()),
    st.builds(ha.Revised, times, st.frozensets(st.sampled_from(["A", "B"]))),
)


def test_the_table_has_a_revision_row_in_every_state():
    for state in State:
        assert (state, ha.Revised) in ha.TRANSITIONS


@settings(max_examples=300, deadline=None)
@given(st.lists(EVENTS, max_size=40))
def test_after_any_revision_no_gs_off_the_list_holds_a_link_or_authority(events):
    m = ha.AuthorityMachine(ha.Config(AUTH))
    for ev in events:
        m.grant(ev) if isinstance(ev, ha.GrantHeard) else m.handle(ev)
        auth = m.config.authorized
        assert set(m.links) <= auth
        assert m.pending_to is None or m.pending_to in auth
        if m.state in (State.LINKED, State.HANDOVER_PENDING):
            assert m.owner in auth and m.owner in m.subscribed
        assert (m.pending_to is not None) == (m.state is State.HANDOVER_PENDING)


def test_rotating_the_owner_in_flight_repairs_it_under_the_new_key_without_a_gap(fleet_dir):
    from zdrone.core.keys import Identity, SigningKey
    from zdrone.core.revision import with_keys

    net = linked(fleet_dir)
    net.on_ground = False
    net.fly(net.centre("A"), net.between(net.centre("A"), net.centre("B"), 0.1), 3.0)
    m, old_link = net.drone.machine, net.drone.links["A"]
    epoch, forwarded = m.epoch, len(net.to_vehicle)
    base = load_base_fleet(fleet_dir)
    new = Identity.generate()
    rev = make_revision(base, 1, with_keys(Changes(), "A", new.public, SigningKey.generate().public),
                        load_fleet_signing_key(fleet_dir, base))
    fleet = apply_revision(base, rev)
    apply(net, fleet)
    for core in net.gss.values():
        core.fleet = fleet
    net.gs_outs("A", net.gss["A"].adopt_identity(new, net.now, WALL0 + net.now))
    net.run(3.0)
    assert m.owner == "A" and m.epoch == epoch and m.state is State.LINKED and not net.commands
    assert net.drone.links["A"] is not old_link and "A" not in net.drone.rekey  # the new key is live
    assert len(net.to_vehicle) > forwarded  # A's frames went on reaching the vehicle
    assert net.drone.responder.ground_stations["A"] == new.public


def test_a_stamp_of_a_newer_revision_or_relayed_on_another_gs_key_renews_nothing(fleet_dir):
    """Found by review: B, revoked behind a split, relayed the other side's genuine stamps (naming the
    revision revoking B, which the drone never got) on B's own key; a stamp naming a newer revision
    renewed the lease. Now a stamp renews only the revision in force, and only on its own GS's key."""
    from zdrone.core.revision import make_push, split_push
    from zdrone.fleet.files import load_secret

    net = linked(fleet_dir)  # A owns: B's stamps are the ones that renew
    net.stamps = False
    d = net.drone
    apply(net, revoked(fleet_dir, "X"))  # revision 1 in force
    key = load_secret(fleet_dir, "B", d.fleet).signing

    def stamp(number: int) -> bytes:
        got, _ = split_push(make_push("B", number, net.now, key, None, ("d1",)))
        assert got is not None
        return got

    net.run(1.0)
    synced = d.revision_synced
    assert d.on_revision_stamp(stamp(2), net.now, carrier="B") == []  # a revision the drone does not hold
    assert d.counters["stamp_refused:newer_revision"] == 1 and d.revision_synced == synced
    assert d.on_revision_stamp(stamp(1), net.now, carrier="A") == []  # B's stamp on A's key: a relay
    assert d.counters["stamp_refused:relayed"] == 1 and d.revision_synced == synced
    d.on_revision_stamp(stamp(1), net.now, carrier="B")  # on its own key, the revision in force: renews
    assert d.revision_synced == net.now


def test_a_new_owner_after_a_lapse_holds_a_lease_of_its_own(fleet_dir):
    """Found by review: after the owner's lease lapsed, the GS that took authority held it with no
    lease at all. Now each owner's lease runs from when it took authority, and a lapsed GS's stamps
    renew nothing: B (owner) hears only its own stamps and lapses; A, the covered heir, takes over and,
    hearing only the lapsed B's stamps, lapses in its turn: the failsafe."""
    net = in_region_owned_by_b(fleet_dir)  # B owns, the drone inside both coverages, both links proven
    lease = _lease(net)
    net.stamps = False  # A's radio stays up (an heir), but only B's stamps reach the drone
    moved_at = None
    for _ in range(int(2.5 * lease / 5.0)):
        net.drone_outs(net.drone.on_revision_stamp(net.stamp("B"), net.now, carrier="B"))
        net.run(5.0)
        if moved_at is None and net.drone.machine.owner == "A":
            moved_at = net.now
    assert moved_at is not None, "B's lease never lapsed"
    assert net.drone.lapsed == {"A", "B"} and net.drone.counters["revision_lease_lapsed"] == 2
    assert net.drone.machine.state is State.FAILSAFE


def test_a_gs_authorized_for_no_drone_renews_nothing(fleet_dir):
    """Found by an outside attack: lease 15 s, B behind a partition; X, a GS of the fleet authorized for
    no drone, put a stamp every 5 s naming the drone's revision: A kept the drone 45.7 s with no lapse.
    Now A lapses at its lease, whatever X says, and X's stamps do not end the lapse."""
    from zdrone.core.revision import with_lease

    base = load_base_fleet(fleet_dir)
    net = linked(fleet_dir)  # A owns
    apply(net, apply_revision(base, make_revision(base, 1, with_lease(Changes(), 15.0),
                                                  load_fleet_signing_key(fleet_dir, base))))
    net.stamps = False
    net.cut.add("B")  # the partition: B's stamps are gone
    due, lapsed_at = net.drone.lease_due(), None
    assert due is not None
    for i in range(500):  # 50 s; X stamps every 5 s
        if i % 50 == 0:
            net.drone_outs(net.drone.on_revision_stamp(net.stamp("X"), net.now, carrier="X"))
        net.step(0.1)
        if lapsed_at is None and net.drone.counters["revision_lease_lapsed"]:
            lapsed_at = net.now
    assert lapsed_at is not None and due <= lapsed_at <= due + 0.1 + 1e-6, (due, lapsed_at)
    assert net.drone.counters["stamp_renewed"] == 0 or net.drone.revision_synced <= due - 15.0
    assert net.drone.lapsed == {"A"} and net.drone.machine.state is State.FAILSAFE
