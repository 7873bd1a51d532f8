"""The owner's lease (``zdrone.core.lease.OwnerLease``), pure, with explicit ``now``: whose stamps renew
it. In the reference fleet d1's authorized GSs are A and B; X is a GS of the fleet authorized for no
drone; V (viewer) and d1 are nodes that are no GS. A owns d1 from now = 0; the lease is 15 s."""

from __future__ import annotations

import msgspec
import pytest

from zdrone.core.lease import NotNewer, OwnerLease, Renewed, StampRefused
from zdrone.core.revision import (Changes, RevisionStamp, apply_revision, make_push, make_revision, split_push,
                                  with_authorized)
from zdrone.fleet.files import init_fleet, load_fleet, load_fleet_signing_key, load_secret

WALL0 = 1_800_000_000.0  # the drone's time of day at now = 0 (its wall offset)
LEASE = 15.0


@pytest.fixture(scope="module")
def fleet_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("fleet")
    init_fleet(d)
    return d


@pytest.fixture(scope="module")
def fleet(fleet_dir):
    return load_fleet(fleet_dir)


def stamp(fleet_dir, fleet, gs: str, t: float, drones=("d1",), number: int | None = None) -> bytes:
    """``gs``'s stamp (its own signing key) of revision ``number`` (default: ``fleet``'s), dated ``t`` on
    the drone's clock, naming ``drones``."""
    key = load_secret(fleet_dir, gs, fleet).signing
    got, _ = split_push(make_push(gs, fleet.revision if number is None else number, WALL0 + t, key, None, drones))
    assert got is not None
    return got


def owned_by_a() -> OwnerLease:
    lease = OwnerLease()
    lease.owner_is("A", 0.0)
    return lease


def judge(lease: OwnerLease, fleet, data: bytes, carrier: str, now: float):
    return lease.stamp(data, fleet, "d1", carrier, now, WALL0, LEASE)


def test_the_report_a_gs_authorized_for_no_drone_stamping_every_5_s_renews_nothing(fleet_dir, fleet):
    """The attack report: X, authorized for nothing, put a stamp every 5 s naming the drone's revision
    and the owner kept the drone 45.7 s. Now each of X's stamps is refused and A lapses at 15 s."""
    lease = owned_by_a()
    for t in (0.0, 5.0, 10.0, 14.999):
        assert judge(lease, fleet, stamp(fleet_dir, fleet, "X", t), "X", t) == StampRefused("unauthorized")
    assert lease.synced is None and lease.due(LEASE) == 15.0
    assert lease.lapse_due(14.999, LEASE) is None and lease.lapse_due(15.0, LEASE) == "A"
    # nor does X end the lapse: another GS authorized for the drone does
    assert judge(lease, fleet, stamp(fleet_dir, fleet, "X", 20.0), "X", 20.0) == StampRefused("unauthorized")
    assert lease.lapsed == {"A"}
    assert judge(lease, fleet, stamp(fleet_dir, fleet, "B", 20.0), "B", 20.0) == Renewed("B", frozenset({"A"}))


def test_the_control_the_same_stamps_from_b_authorized_for_the_drone_renew_it(fleet_dir, fleet):
    lease = owned_by_a()
    for t in (5.0, 10.0, 15.0, 20.0):
        assert judge(lease, fleet, stamp(fleet_dir, fleet, "B", t), "B", t) == Renewed("B", frozenset())
    assert lease.lapse_due(34.999, LEASE) is None and lease.lapse_due(35.0, LEASE) == "A"  # 15 s after B's last


def test_authorized_means_in_the_revision_in_force(fleet_dir, fleet):
    fkey = load_fleet_signing_key(fleet_dir, fleet)
    only_a = apply_revision(fleet, make_revision(fleet, 1, with_authorized(Changes(), "d1", ["A"]), fkey))
    with_x = apply_revision(fleet, make_revision(fleet, 1, with_authorized(Changes(), "d1", ["A", "X"]), fkey))
    b = stamp(fleet_dir, fleet, "B", 1.0, number=1)
    assert judge(owned_by_a(), only_a, b, "B", 1.0) == StampRefused("unauthorized")  # not revoked, no longer authorized
    assert judge(owned_by_a(), fleet, b, "B", 1.0) == StampRefused("newer_revision")  # the drone still at 0
    x = stamp(fleet_dir, fleet, "X", 1.0, number=1)
    assert judge(owned_by_a(), with_x, x, "X", 1.0) == Renewed("X", frozenset())  # authorized by the revision


@pytest.mark.parametrize("drones", [(), ("d2",), ("d10",)])
def test_a_stamp_that_does_not_name_the_drone_renews_nothing(fleet_dir, fleet, drones):
    assert judge(owned_by_a(), fleet, stamp(fleet_dir, fleet, "B", 1.0, drones), "B", 1.0) == StampRefused("unnamed")


def test_a_stamp_naming_a_set_renews_each_drone_of_it(fleet_dir, fleet):
    got = judge(owned_by_a(), fleet, stamp(fleet_dir, fleet, "B", 1.0, ("d2", "d1")), "B", 1.0)
    assert got == Renewed("B", frozenset())


def test_the_named_drones_are_signed(fleet_dir, fleet):
    genuine = msgspec.msgpack.decode(stamp(fleet_dir, fleet, "B", 1.0, ("d2",)), type=RevisionStamp)
    moved = msgspec.msgpack.encode(msgspec.structs.replace(genuine, drones=("d1",)))
    assert judge(owned_by_a(), fleet, moved, "B", 1.0) == StampRefused("signature")


def test_the_owner_renews_nothing_of_its_own(fleet_dir, fleet):
    assert judge(owned_by_a(), fleet, stamp(fleet_dir, fleet, "A", 1.0), "A", 1.0) == StampRefused("owner")


@pytest.mark.parametrize("name", ["V", "d1"])
def test_a_name_that_is_no_gs_of_the_fleet_signs_no_stamp(fleet_dir, fleet, name):
    assert judge(owned_by_a(), fleet, stamp(fleet_dir, fleet, name, 1.0), name, 1.0) == StampRefused("signature")


@pytest.mark.parametrize("carrier", ["A", "X", "fleet"])
def test_a_stamp_counts_only_on_its_own_gss_key(fleet_dir, fleet, carrier):
    assert judge(owned_by_a(), fleet, stamp(fleet_dir, fleet, "B", 1.0), carrier, 1.0) == StampRefused("relayed")


def test_a_renewal_runs_from_the_issuers_signed_time_never_later(fleet_dir, fleet):
    lease = owned_by_a()
    old = stamp(fleet_dir, fleet, "B", 3.0)
    assert isinstance(judge(lease, fleet, old, "B", 10.0), Renewed) and lease.due(LEASE) == 18.0  # heard late: 3 + 15
    assert judge(lease, fleet, old, "B", 17.0) == NotNewer() and lease.due(LEASE) == 18.0  # replayed: nothing more
    assert lease.lapse_due(18.0, LEASE) == "A"
    lease = owned_by_a()
    assert isinstance(judge(lease, fleet, stamp(fleet_dir, fleet, "B", 14.0), "B", 10.0), Renewed)
    assert lease.due(LEASE) == 25.0  # dated 4 s ahead of the drone: counted from now, not from its date
    assert judge(lease, fleet, stamp(fleet_dir, fleet, "B", 20.1), "B", 15.0) == StampRefused("ahead")
