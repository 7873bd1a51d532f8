"""The operations picture, pure: sealing for the viewer (who said it, replays, old starts), parts under
the size limit, the merged fleet picture (highest epoch, disputes, staleness; the owner the drone itself
signed, a GS's claim it does not back shown apart) with explicit ``now``."""

from __future__ import annotations

import os

from zdrone.core.attestation import Attester
from zdrone.core.keys import Identity, SigningKey
from zdrone.core.opspicture import (MAX_SKEW_S, OPS_MAX_BYTES, STALE_S, DroneOps, FleetPicture, OpsDrop, OpsOpener,
                                    OpsReport, OpsSealer, report_parts)
from zdrone.core.wire import AuthorityState
from zdrone.fleet.routerconfig import access_control
from tests.unit.test_routerconfig import default_fleet

A, B, V = Identity.generate(), Identity.generate(), Identity.generate()
WALL = 1_800_000_000.0


def _ops(owner: str = "A", epoch: int = 1, since: float = 0.1, **kw) -> DroneOps:
    return DroneOps("d1", True, owner, epoch, "linked", None, "ok", since, **kw)


def _sealed(sealer: OpsSealer, gs: str = "A", sent: float = WALL, drones: list[DroneOps] | None = None) -> bytes:
    return sealer.seal(report_parts(gs, sent, drones or [_ops()], [])[0])


def _opener() -> OpsOpener:
    return OpsOpener(V, "V", {"A": A.public, "B": B.public})


def test_a_part_opens_only_for_the_viewer_from_the_gs_that_sealed_it_once():
    s = OpsSealer(A, "A", "V", V.public, "zdrone-ops/A", os.urandom(16))
    o = _opener()
    part = _sealed(s)
    assert isinstance(o.open("A", "zdrone-ops/A", part, 0.0, WALL), OpsReport)
    assert o.open("A", "zdrone-ops/A", part, 0.1, WALL) is OpsDrop.REPLAY
    assert o.open("B", "zdrone-ops/B", _sealed(s), 0.2, WALL) is OpsDrop.AUTH_FAILED  # A's part said to be B's
    assert o.open("X", "zdrone-ops/X", part, 0.3, WALL) is OpsDrop.UNKNOWN_SENDER
    other = OpsOpener(Identity.generate(), "V", {"A": A.public})
    assert other.open("A", "zdrone-ops/A", _sealed(s), 0.0, WALL) is OpsDrop.AUTH_FAILED  # not sealed for it
    forged = OpsSealer(B, "A", "V", V.public, "zdrone-ops/A", os.urandom(16))  # B's key, A's name
    assert o.open("A", "zdrone-ops/A", _sealed(forged), 5.0, WALL) is OpsDrop.AUTH_FAILED
    assert o.drops["replay"] == 1 and o.drops["auth_failed"] == 2


def test_an_old_start_replayed_later_is_refused_a_new_one_taken():
    o = _opener()
    old = OpsSealer(A, "A", "V", V.public, "zdrone-ops/A", os.urandom(16))
    recorded = _sealed(old, sent=WALL)
    new = OpsSealer(A, "A", "V", V.public, "zdrone-ops/A", os.urandom(16))
    assert isinstance(o.open("A", "zdrone-ops/A", _sealed(new, sent=WALL + 10), 0.0, WALL + 10), OpsReport)
    assert o.open("A", "zdrone-ops/A", recorded, 5.0, WALL + 11) is OpsDrop.OLD_START
    fresh = OpsOpener(V, "V", {"A": A.public})  # a viewer that knows nothing yet: the clock decides
    assert fresh.open("A", "zdrone-ops/A", recorded, 0.0, WALL + MAX_SKEW_S + 1) is OpsDrop.OLD_START


def test_parts_stay_under_the_limit_and_carry_every_drone():
    drones = [DroneOps(f"d{i}", True, "A", 1, "linked", None, "ok", 0.1, "MISSION", True, (47.1, 8.5, 30.0), 3)
              for i in range(300)]
    parts = report_parts("A", WALL, drones, [])
    assert len(parts) > 1 and all(len(p) <= OPS_MAX_BYTES - 40 for p in parts)
    s = OpsSealer(A, "A", "V", V.public, "zdrone-ops/A", os.urandom(16))
    o = _opener()
    got = [o.open("A", "zdrone-ops/A", s.seal(p), 0.0, WALL) for p in parts]
    assert sum(len(r.drones) for r in got if isinstance(r, OpsReport)) == 300


def test_the_picture_takes_the_highest_epoch_shows_disputes_and_goes_stale():
    pic = FleetPicture()
    pic.on_report(OpsReport("A", WALL, 0, 1, [_ops("A", 1)], []), 10.0)
    pic.on_report(OpsReport("B", WALL, 0, 1, [_ops("B", 2, since=0.2)], []), 10.0)
    row = pic.drone("d1", 10.0)
    assert (row["owner"], row["epoch"], row["stale"], row["disputed"]) == ("B", 2, False, [])
    pic.on_report(OpsReport("A", WALL, 0, 1, [_ops("A", 2)], []), 10.1)  # a hostile A claims epoch 2 too
    assert pic.drone("d1", 10.1)["disputed"] == ["A", "B"]
    assert pic.drone("d1", 10.1 + STALE_S)["stale"]  # nobody heard since: stale, never live
    assert pic.drone("d1", 10.5)["links"]["A"]["link"] == "ok"


def test_the_viewer_may_only_read_the_pictures():
    acl = access_control(default_fleet())
    rules = {r["id"]: r for r in acl["rules"]}
    mine = [r for r in acl["rules"] if r["id"].startswith("V-")]
    assert {r["id"] for r in mine} == {"V-ops-sub", "V-ops-recv"}
    assert rules["V-ops-sub"]["messages"] == ["declare_subscriber"] and rules["V-ops-sub"]["flows"] == ["ingress"]
    assert rules["V-ops-recv"]["messages"] == ["put"] and rules["V-ops-recv"]["flows"] == ["egress"]
    assert rules["A-ops-own"]["key_exprs"] == ["zdrone-ops/A"] and rules["A-ops-own"]["flows"] == ["ingress"]


def test_the_view_serves_loopback_unless_an_address_and_a_token_are_given():
    import pytest

    from zdrone.core.errors import UsageError
    from zdrone.view.server import check_exposure

    assert check_exposure(None, None) == "127.0.0.1"
    with pytest.raises(UsageError, match="needs --token"):
        check_exposure("0.0.0.0", None)
    with pytest.raises(UsageError, match="at least 16"):
        check_exposure("10.0.0.1", "short")
    assert check_exposure("10.0.0.1", "x" * 32) == "10.0.0.1"


# ------------------------------------------------- the drone's signed word on who commands it
D1, D1_OLD, D2, HOSTILE = SigningKey.generate(), SigningKey.generate(), SigningKey.generate(), SigningKey.generate()


def _attested(owner: str, epoch: int, at: float, key: SigningKey = D1, drone: str = "d1", gs_says: tuple | None = None
              ) -> DroneOps:
    """A GS's word on d1, carrying ``drone``'s attestation of (owner, epoch) signed with ``key``."""
    att = Attester(drone, key).attest(owner, epoch, AuthorityState.LINKED, None, at)
    says_owner, says_epoch = gs_says or (owner, epoch)
    return _ops(says_owner, says_epoch, attest=att)


def _picture() -> FleetPicture:
    return FleetPicture({"d1": (D1_OLD.public, D1.public), "d2": (D2.public,)})


def test_a_hostile_gs_higher_epoch_claim_without_the_drones_word_is_shown_apart_never_as_owner():
    pic = _picture()
    pic.on_report(OpsReport("A", WALL, 0, 1, [_attested("A", 3, WALL)], []), 10.0)
    for i, forged in enumerate([
            _ops("H", 99),  # no attestation at all
            _attested("H", 99, WALL + 1, key=HOSTILE),  # signed, but not by the drone
            _ops("H", 99, attest=Attester("d2", D2).attest("H", 99, AuthorityState.LINKED, None, WALL)),  # d2's, replayed for d1
            _attested("A", 3, WALL, gs_says=("H", 99))]):  # the drone's own word, under a claim it does not back
        pic.on_report(OpsReport("H", WALL, 0, 1, [forged], []), 10.1 + i)
        row = pic.drone("d1", 10.1 + i)
        assert (row["owner"], row["epoch"], row["verified"]) == ("A", 3, True), i
        assert row["unverified"] == [{"gs": "H", "owner": "H", "epoch": 99}], i
    assert pic.check.counts["bad_signature"] == 2  # the hostile key's and d2's for d1


def test_an_honest_lagging_gs_with_an_older_verified_claim_does_not_override_a_newer_one():
    pic = _picture()
    pic.on_report(OpsReport("B", WALL, 0, 1, [_attested("B", 2, WALL + 5)], []), 10.0)
    pic.on_report(OpsReport("A", WALL, 0, 1, [_attested("A", 1, WALL)], []), 10.5)  # heard later, an older epoch
    row = pic.drone("d1", 10.5)
    assert (row["owner"], row["epoch"], row["verified"], row["unverified"], row["disputed"]) == ("B", 2, True, [], [])


def test_a_rotated_drone_key_still_verifies_and_each_word_is_checked_once():
    pic = _picture()
    pic.on_report(OpsReport("A", WALL, 0, 1, [_attested("A", 1, WALL, key=D1_OLD)], []), 10.0)
    assert pic.drone("d1", 10.0)["verified"]  # signed before the rotation, under the drone's earlier key
    for t in (10.5, 11.0, 11.5):  # the same word repeated by every report, from two GSs
        pic.on_report(OpsReport("A", WALL, 0, 1, [_attested("A", 1, WALL, key=D1_OLD)], []), t)
        pic.on_report(OpsReport("B", WALL, 0, 1, [_attested("A", 1, WALL, key=D1_OLD)], []), t)
    forged = _attested("H", 9, WALL, key=HOSTILE)
    for t in (12.0, 12.5, 13.0):  # the same forgery repeated costs one check
        pic.on_report(OpsReport("H", WALL, 0, 1, [forged], []), t)
    assert pic.check.checked == 2
    assert pic.drone("d1", 13.0)["owner"] == "A"


def test_without_any_valid_attestation_the_highest_claim_shows_marked_unverified():
    pic = FleetPicture()  # a fleet whose drones have no signing keys
    pic.on_report(OpsReport("A", WALL, 0, 1, [_attested("A", 1, WALL)], []), 10.0)
    row = pic.drone("d1", 10.0)
    assert (row["owner"], row["verified"], row["unverified"]) == ("A", False, [])


def test_a_gs_sending_a_new_forgery_in_every_report_gets_bounded_checks_and_others_are_still_believed():
    pic = _picture()
    for i in range(300):  # 300 forgeries at once, each new
        pic.on_report(OpsReport("H", WALL, 0, 1, [_attested("H", 99, WALL + i, key=HOSTILE)], []), 10.0)
    assert pic.check.checked < 100 and pic.check.counts["rate_limited"] > 200
    pic.on_report(OpsReport("A", WALL, 0, 1, [_attested("A", 3, WALL)], []), 10.0)  # another GS's budget
    assert (pic.drone("d1", 10.0)["owner"], pic.drone("d1", 10.0)["verified"]) == ("A", True)
