"""The operations picture, pure: sealing for the viewer (who said it, replays, old starts), parts under
the size limit, the merged fleet picture with explicit ``now`` and ``wall``: the owner and liveness the
drone itself signed, recently, under its key in force; a GS's word only on the drones it is authorized
for, aged out when it goes quiet, bounded in rate; names outside the fleet dropped."""

from __future__ import annotations

import os

from zdrone.core.attestation import Attester
from zdrone.core.keys import Identity, SigningKey
from zdrone.core.opspicture import (ATTEST_LIVE_S, CLAIM_KEEP_S, EXPIRE_EVERY_S, MAX_SKEW_S, OFFSET_BEHIND_S,
                                    OPS_MAX_BYTES,
                                    REPORT_TTL_S, STALE_S, DroneOps, FleetPicture, OpsDrop, OpsEvent, OpsOpener,
                                    OpsReport, OpsRequest, OpsSealer, _natural, report_parts)
from zdrone.core.wire import AuthorityState, AuthorityStatus
from zdrone.fleet.routerconfig import access_control
from tests.unit.test_routerconfig import default_fleet

A, B, V = Identity.generate(), Identity.generate(), Identity.generate()
WALL = 1_800_000_000.0


def _ops(owner: str = "A", epoch: int = 1, since: float = 0.1, drone: str = "d1", **kw) -> DroneOps:
    return DroneOps(drone, True, owner, epoch, "linked", None, "ok", since, **kw)


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


#: d1 and d2 as the fleet has them: A, B and H (hostile, but authorized) may speak for them; X is a GS
#: of the fleet authorized for neither.
AUTH = {"d1": frozenset({"A", "B", "H"}), "d2": frozenset({"A", "B", "H"})}
STATIONS = ("A", "B", "H", "X")


def _report(gs: str, *drones: DroneOps, events: list[OpsEvent] | None = None) -> OpsReport:
    return OpsReport(gs, WALL, 0, 1, list(drones), events or [])


def _on(pic: FleetPicture, gs: str, now: float, *drones: DroneOps, events: list[OpsEvent] | None = None) -> None:
    """``gs``'s part at the viewer's ``now`` (its time of day ``WALL + now``)."""
    pic.on_report(_report(gs, *drones, events=events), now, WALL + now)


def _row(pic: FleetPicture, now: float, name: str = "d1") -> dict:
    return pic.drone(name, now, WALL + now)


def test_the_picture_takes_the_highest_epoch_shows_disputes_and_goes_stale():
    pic = FleetPicture(AUTH)  # drones without signing keys: only their GSs' word, never verified
    _on(pic, "A", 10.0, _ops("A", 1))
    _on(pic, "B", 10.0, _ops("B", 2, since=0.2))
    row = _row(pic, 10.0)
    assert (row["owner"], row["epoch"], row["stale"], row["disputed"], row["verified"]) == ("B", 2, False, [], False)
    _on(pic, "A", 10.1, _ops("A", 2))  # a hostile A claims epoch 2 too
    assert _row(pic, 10.1)["disputed"] == ["A", "B"]
    assert _row(pic, 10.1 + STALE_S)["stale"]  # nobody heard since: stale, never live
    assert _row(pic, 10.5)["links"]["A"]["link"] == "ok"


def test_the_viewer_may_only_read_the_pictures_and_the_revisions():
    acl = access_control(default_fleet())
    rules = {r["id"]: r for r in acl["rules"]}
    mine = [r for r in acl["rules"] if r["id"].startswith("V-")]
    assert {r["id"] for r in mine} == {"V-ops-sub", "V-ops-recv", "V-revision", "V-revision-recv"}
    assert rules["V-ops-sub"]["messages"] == ["declare_subscriber"] and rules["V-ops-sub"]["flows"] == ["ingress"]
    assert rules["V-ops-recv"]["messages"] == ["put"] and rules["V-ops-recv"]["flows"] == ["egress"]
    # it hears and asks for the fleet's revisions (revocations, rotations, live) and never publishes
    assert rules["V-revision"]["messages"] == ["declare_subscriber", "query"] and rules["V-revision"]["flows"] == ["ingress"]
    assert rules["V-revision-recv"]["flows"] == ["egress"] and rules["V-revision"]["key_exprs"] == ["zdrone-fleet/revision/*"]
    assert not any(m in r["messages"] for r in mine if "ingress" in r["flows"]
                   for m in ("put", "declare_queryable", "reply"))
    assert rules["A-ops-own"]["key_exprs"] == [f"zdrone-ops/A/{i}" for i in range(8)]  # its lanes, nothing else
    assert rules["A-ops-own"]["flows"] == ["ingress"] and rules["V-ops-sub"]["key_exprs"] == ["zdrone-ops/*/*"]
    # every (GS, lane) has a budget at the viewer's egress: one credential's parts a second are bounded
    from zdrone.fleet.routerconfig import OPS_LANE_HZ

    from zdrone.fleet.routerconfig import router_config

    (ops,) = [d for d in router_config(default_fleet(), "c.txt")["downsampling"] if d["id"] == "ops-rate"]
    assert ops["flows"] == ["egress"] and {r["key_expr"] for r in ops["rules"]} == {
        f"zdrone-ops/{g}/{i}" for g in ("A", "B", "X") for i in range(8)}
    assert {r["freq"] for r in ops["rules"]} == {OPS_LANE_HZ}


# ------------------------------------------------- the drone's signed word on who commands it
D1, D1_OLD, D2, HOSTILE = SigningKey.generate(), SigningKey.generate(), SigningKey.generate(), SigningKey.generate()


def _signed(owner: str | None, epoch: int, at: float, key: SigningKey = D1, drone: str = "d1", seq: int = 1,
            state: AuthorityState = AuthorityState.LINKED, **kw):
    """``drone``'s attestation of (owner, epoch) at its time of day ``at``, its ``seq``-th signature."""
    att = Attester(drone, key)
    att.signed = seq - 1
    return att.attest(AuthorityStatus(owner, epoch, state, None, **kw), at, renew=True)


def _attested(owner: str, epoch: int, at: float, key: SigningKey = D1, drone: str = "d1", gs_says: tuple | None = None,
              seq: int = 1, since: float = 0.1, **kw) -> DroneOps:
    """A GS's word on d1, carrying ``drone``'s attestation of (owner, epoch) signed with ``key``."""
    says_owner, says_epoch = gs_says or (owner, epoch)
    return _ops(says_owner, says_epoch, since=since, attest=_signed(owner, epoch, at, key, drone, seq), **kw)


def _picture() -> FleetPicture:
    return FleetPicture(AUTH, {"d1": (D1_OLD.public, D1.public), "d2": (D2.public,)}, STATIONS)


def test_a_hostile_gs_higher_epoch_claim_without_the_drones_word_is_shown_apart_never_as_owner():
    pic = _picture()
    _on(pic, "A", 10.0, _attested("A", 3, WALL + 10.0))
    for i, forged in enumerate([
            _ops("H", 99),  # no attestation at all
            _attested("H", 99, WALL + 10.1, key=HOSTILE),  # signed, but not by the drone
            _ops("H", 99, attest=_signed("H", 99, WALL + 10.1, D2, "d2")),  # d2's, replayed for d1
            _attested("A", 3, WALL + 10.0, gs_says=("H", 99))]):  # the drone's own word, under a claim it does not back
        _on(pic, "H", 10.1 + 0.1 * i, forged)
        row = _row(pic, 10.1 + 0.1 * i)
        assert (row["owner"], row["epoch"], row["verified"], row["stale"]) == ("A", 3, True, False), i
        assert row["unverified"] == [{"gs": "H", "owner": "H", "epoch": 99}], i
    assert pic.check.counts["bad_signature"] == 2  # the hostile key's and d2's for d1


def test_an_honest_lagging_gs_with_an_older_verified_claim_does_not_override_a_newer_one():
    pic = _picture()
    _on(pic, "B", 10.0, _attested("B", 2, WALL + 10.0, seq=7))
    _on(pic, "A", 10.5, _attested("A", 1, WALL + 9.0, seq=3))  # heard later, an older word
    row = _row(pic, 10.5)
    assert (row["owner"], row["epoch"], row["verified"], row["unverified"], row["disputed"]) == ("B", 2, True, [], [])


def test_a_replayed_genuine_old_word_never_shows_as_the_owner_nor_keeps_a_drone_live():
    """Found: epoch 2's genuine attestation replayed after epoch 3 happened showed "B verified epoch 2,
    live" (the drone signed only on change, so an old word was as good as a new one)."""
    pic = _picture()
    old = _attested("B", 2, WALL + 1.0, seq=5)  # recorded by a hostile authorized GS
    for t in (10.0, 10.5, 11.0):  # the drone signs at every beacon: A carries its newest word
        _on(pic, "A", t, _attested("A", 3, WALL + t - 0.05, seq=10 + int(t * 2)))
    _on(pic, "H", 11.2, old)
    row = _row(pic, 11.2)
    assert (row["owner"], row["epoch"], row["verified"]) == ("A", 3, True)
    assert pic.older == 1
    # the drone stops (nobody carries a newer word); H goes on replaying the old one and says its link is ok
    for i in range(40):
        _on(pic, "H", 11.5 + 0.25 * i, _attested("B", 2, WALL + 1.0, seq=5, since=0.0))
    row = _row(pic, 21.25)
    assert (row["owner"], row["epoch"], row["verified"], row["stale"]) == ("A", 3, False, True)
    assert row["age"] >= 21.25 - 11.0 - 0.1 and row["attested_age"] >= ATTEST_LIVE_S
    # a viewer that starts now hears only the replay: an old word, stale on arrival
    for t in (50.0, 10.0):  # 49 s after it was signed, or 9 s
        fresh = _picture()
        _on(fresh, "H", t, old)
        row = _row(fresh, t)
        assert (row["owner"], row["verified"], row["stale"]) == ("B", False, True) and row["attested_age"] > ATTEST_LIVE_S


def test_a_word_held_back_and_let_go_later_is_old_on_arrival():
    pic = _picture()
    for t in (10.0, 11.0, 12.0):  # the drone's words arrive 0.1 s after it signed them (its clock 2 s behind)
        _on(pic, "A", t, _attested("A", 1, WALL + t - 0.1 - 2.0, seq=int(t)))
    assert not _row(pic, 12.0)["stale"]
    # A goes silent; H had held the drone's next word back, and lets it go 6 s after it was signed
    _on(pic, "H", 19.0, _attested("A", 1, WALL + 13.0 - 2.0, seq=13, since=0.0))
    row = _row(pic, 19.0)
    # 8 s late by the drone's clock, of which OFFSET_BEHIND_S is credited (its clock behind, or the way)
    assert row["stale"] and not row["verified"] and row["attested_age"] == 8.0 - OFFSET_BEHIND_S


def test_a_sole_carrier_holding_every_word_back_buys_no_freshness_from_the_clock_offset():
    """Found: the owner's GS stopped, B (the only GS the view hears) let every word of d1 go 4.8 s
    late: the learnt offset took the delay for the drone's clock, and a stopped drone showed live and
    verified for 7.0 s (2.4 s when carried at once)."""
    for delay in (0.05, 1.0, 2.0, 4.8, 10.0):
        pic = _picture()
        t = 10.0
        while t < 40.0:  # the drone signs every beacon, its clock the viewer's; B lets each go ``delay`` late
            _on(pic, "B", t + delay, _attested("A", 1, WALL + t, seq=int(t), since=0.0))
            t += 1.0
        stop = t - 1.0  # its last word was signed at ``stop``; B goes on saying "link ok"
        if delay <= OFFSET_BEHIND_S:  # carried at once: live while the drone speaks
            assert not _row(pic, stop + delay)["stale"]
        for k in range(1, 41):
            now = stop + delay + 0.1 * k
            _on(pic, "B", now, _ops("A", 1, since=0.0))
            if now - stop > ATTEST_LIVE_S + OFFSET_BEHIND_S:
                row = _row(pic, now)
                assert row["stale"] and not row["verified"], (delay, now - stop)


def test_a_drone_whose_clock_runs_ahead_is_aged_and_one_a_little_behind_stays_live():
    for skew in (-3.0, 1.5):  # the drone's clock 3 s ahead of the viewer's, 1.5 s behind
        pic = _picture()
        for i in range(20):
            t = 10.0 + i
            _on(pic, "A", t + 0.05, _attested("A", 1, WALL + t - skew, seq=i))
            assert not _row(pic, t + 0.05)["stale"] and not _row(pic, t + 0.95)["stale"], (skew, t)
        assert _row(pic, 29.0 + ATTEST_LIVE_S + 0.01)["stale"]  # stopped: stale on time by the viewer's clock


def test_a_word_dated_far_ahead_is_refused():
    pic = _picture()
    _on(pic, "A", 10.0, _attested("A", 1, WALL + 10.0, seq=1))
    _on(pic, "A", 10.5, _attested("A", 1, WALL + 10.0 + MAX_SKEW_S + 5, seq=2))  # would shadow every true word
    _on(pic, "A", 11.0, _attested("A", 1, WALL + 11.0, seq=3))
    assert pic.drops["attest_future"] == 1 and pic.attested["d1"].att.seq == 3


def test_a_key_the_revision_held_retired_is_refused_whether_or_not_the_new_one_was_heard():
    """Found: after a rotation, an attestation signed with the retired drone key showed verified; then,
    a view started after ``fleet rotate d1`` while the GSs were silent showed a word forged under the
    retired key as the verified, live owner (B, epoch 99): it retired a key only once it heard the new one."""
    pic = _picture()  # the revisions held give d1 (D1_OLD, D1): D1 in force
    _on(pic, "B", 10.0, _attested("B", 99, WALL + 10.0, key=D1_OLD, seq=99))  # nothing heard under D1 yet
    row = _row(pic, 10.0)
    assert (row["verified"], row["stale"]) == (False, True) and "d1" not in pic.attested
    assert pic.check.counts["retired_key"] == 1
    _on(pic, "A", 10.5, _attested("A", 1, WALL + 10.5, key=D1, seq=1))  # the drone speaks under its new key
    # the old key's thief, with a newer time and counter, even dated ahead: refused
    _on(pic, "H", 11.0, _attested("H", 9, WALL + 11.0 + 5, key=D1_OLD, seq=100))
    row = _row(pic, 11.0)
    assert (row["owner"], row["epoch"], row["verified"]) == ("A", 1, True)
    assert pic.check.counts["retired_key"] == 2 and pic.check.in_force["d1"] == 1
    # a word under a retired key that came first, dated ahead, does not shadow the new key's words
    pic = _picture()
    _on(pic, "H", 10.0, _attested("H", 9, WALL + 10.0 + 20, key=D1_OLD, seq=99))
    _on(pic, "A", 10.5, _attested("A", 1, WALL + 10.5, key=D1, seq=1))
    assert (_row(pic, 10.5)["owner"], _row(pic, 10.5)["verified"]) == ("A", True)


def test_a_key_rotated_live_is_taken_and_retires_the_old_one_at_once():
    pic = FleetPicture(AUTH, {"d1": (D1_OLD.public,)}, STATIONS)
    _on(pic, "A", 10.0, _attested("A", 1, WALL + 10.0, key=D1, seq=1))
    assert not _row(pic, 10.0)["verified"]  # not a key of d1's yet
    _on(pic, "A", 10.2, _attested("A", 1, WALL + 10.2, key=D1_OLD, seq=2))
    assert _row(pic, 10.2)["verified"]  # under the key in force
    pic.add_key("d1", D1.public)  # a revision rotated it (``Follower.apply_fleet``): D1_OLD retired now
    assert "d1" not in pic.attested and not _row(pic, 10.3)["verified"]  # the word held under D1_OLD goes
    _on(pic, "B", 10.4, _attested("B", 99, WALL + 10.4, key=D1_OLD, seq=3))  # the thief of the old key
    assert not _row(pic, 10.4)["verified"] and pic.check.counts["retired_key"] == 1
    _on(pic, "A", 10.5, _attested("A", 1, WALL + 10.5, key=D1, seq=4))
    assert _row(pic, 10.5)["verified"]


def test_each_word_is_checked_once_and_a_repeated_forgery_costs_one_check():
    pic = _picture()
    word = _attested("A", 1, WALL + 10.0)
    for t in (10.0, 10.5, 11.0):  # the same word repeated by every report, from two GSs
        _on(pic, "A", t, word)
        _on(pic, "B", t, word)
    forged = _attested("H", 9, WALL + 12.0, key=HOSTILE)
    for t in (12.0, 12.1, 12.2):  # the same forgery repeated costs one check
        _on(pic, "H", t, forged)
    assert pic.check.checked == 2
    assert _row(pic, 12.2)["owner"] == "A"


def test_a_gs_sending_a_new_forgery_in_every_report_gets_bounded_checks_and_others_are_still_believed():
    pic = _picture()
    for i in range(300):  # 300 forgeries at once, each new
        _on(pic, "H", 10.0, _attested("H", 99, WALL + 10.0 + i * 0.01, key=HOSTILE, seq=i))
    assert pic.check.checked < 100  # the rest: counted, not checked (or not even taken: the GS's rate)
    assert pic.check.counts["check_rate_limited"] + pic.drops["rate_limited"] > 200
    _on(pic, "A", 10.0, _attested("A", 3, WALL + 10.0))  # another GS's budget
    assert (_row(pic, 10.0)["owner"], _row(pic, 10.0)["verified"]) == ("A", True)


# ------------------------------------------------- what a GS says on its own
def test_an_unauthorized_gs_says_nothing_of_a_drone_and_an_authorized_ones_word_ages_out():
    """Found: one part from unauthorized GS X, then silence, showed d1 FAILSAFE, takeover allowed, a
    pending request and X among its links for 25 s."""
    pic = _picture()
    loud = dict(failsafe=True, takeover=True, request=OpsRequest("X", "X", 1, 0.0, 30.0),
                position=(47.0, 8.0, 10.0))
    _on(pic, "X", 10.0, _ops("X", 1, since=0.0, **loud), events=[OpsEvent(WALL, "d1", "failsafe_notice", "forged")])
    assert "d1" not in pic.claims and pic.drops["not_authorized"] == 1 and pic.drops["event_not_authorized"] == 1
    assert pic.snapshot(10.0, WALL + 10.0)["drones"] == [] and not pic.feed
    # an authorized GS says the same once, then goes quiet: its word counts only while it is fresh
    _on(pic, "A", 20.0, _attested("A", 1, WALL + 20.0, request=OpsRequest("B", "B", 1, 0.0, 30.0),
                                  failsafe=True, takeover=True, position=(47.0, 8.0, 10.0)))
    row = _row(pic, 20.0)
    assert row["reports_failsafe"] == ["A"] and not row["failsafe"]  # the alarm is the drone's word; A's is listed
    assert row["requests"] and row["position_from"] == "A" and not row["takeover"]  # takeover: the drone's word
    later = _row(pic, 20.0 + REPORT_TTL_S + 0.1)
    assert (later["reports_failsafe"], later["requests"], later["position"], later["stale"]) == ([], [], None, True)
    assert later["links"]["A"]["silent"]
    _on(pic, "B", 20.0 + CLAIM_KEEP_S + EXPIRE_EVERY_S, _ops("B", 1, drone="d2"))  # A's word forgotten
    assert "A" not in _row(pic, 20.0 + CLAIM_KEEP_S + EXPIRE_EVERY_S)["links"]


def test_an_event_naming_no_drone_is_nobodys_word_in_the_feed():
    """Found (view-truth, a real flight): GS X, authorized for no drone, put lines in the page's
    authority feed ("d1: owner X, epoch 99, failsafe") by naming no drone in its events."""
    pic = _picture()
    for gs in ("X", "H", "A"):  # an unauthorized GS, a hostile authorized one, an honest one: the same rule
        _on(pic, gs, 10.0, events=[OpsEvent(WALL, "", "authority_status", "d1: owner X, epoch 99, failsafe"),
                                   OpsEvent(WALL, "d9", "failsafe_notice", "outside the fleet")])
    assert not pic.feed and pic.drops["event_not_authorized"] == 6
    _on(pic, "A", 11.0, events=[OpsEvent(WALL, "d1", "authority_status", "owner A, epoch 1")])
    assert [e["gs"] for e in pic.feed] == ["A"]


def test_a_gs_saying_link_ok_does_not_keep_a_stopped_drone_live_at_its_position():
    """Found: X saying "since_last 0, link ok" every 0.25 s kept a stopped drone live at X's position."""
    pic = _picture()
    _on(pic, "A", 10.0, _attested("A", 1, WALL + 10.0, position=(47.0, 8.0, 10.0)))
    assert not _row(pic, 10.0)["stale"]
    for i in range(100):  # the drone stops; X (unauthorized) and H (authorized, hostile) say it is fine
        t = 10.25 + 0.25 * i
        _on(pic, "X", t, _ops("X", 1, since=0.0, position=(46.0, 7.0, 10.0)))
        _on(pic, "H", t, _ops("A", 1, since=0.0, position=(46.5, 7.5, 10.0)))
    row = _row(pic, 35.0)
    assert row["stale"] and not row["verified"] and row["age"] >= 35.0 - 10.0 - 0.1
    assert "X" not in row["links"] and row["position_from"] == "H"  # who said where it is, never live


def test_names_outside_the_fleet_are_dropped_and_each_gs_is_bounded_in_rate():
    """Found: new names from X at 40/s grew the viewer's memory without end."""
    pic = _picture()
    for i in range(400):
        _on(pic, "H", 10.0 + i / 40, _ops("H", 1, drone=f"new{i}"))
    assert set(pic.claims) == set() and pic.drops["unknown_drone"] == 400 and not pic.tracks
    for i in range(2000):  # an authorized GS at 2000 records a second (an honest one: at most 10 pictures a second)
        _on(pic, "H", 20.0 + i / 2000, _ops("H", 1), _ops("H", 1, drone="d2"))
    assert pic.drops["rate_limited"] > 1000
    _on(pic, "A", 21.0, _attested("A", 1, WALL + 21.0))  # another GS's budget
    assert _row(pic, 21.0)["owner"] == "A"
    # a request naming a GS outside the fleet is no request
    _on(pic, "A", 21.1, _attested("A", 1, WALL + 21.0, request=OpsRequest("Q", "A", 1, 0.0, 30.0)))
    assert _row(pic, 21.1)["requests"] == [] and pic.drops["request_unknown_gs"] == 1


def test_a_revoked_gs_drops_out():
    pic = _picture()
    _on(pic, "H", 10.0, _attested("A", 1, WALL + 10.0))
    pic.set_fleet({d: g - {"H"} for d, g in AUTH.items()}, ("A", "B"))  # a revision revoked H
    assert "H" not in _row(pic, 10.0)["links"] and "H" not in pic.heard
    _on(pic, "H", 10.5, _ops("H", 5))
    assert pic.drops["unknown_gs"] == 1 and "H" not in _row(pic, 10.5)["links"]


def test_names_sort_naturally_without_converting_digits():
    """Found: a drone named with 4400 digits broke the sort (Python's int digit limit)."""
    long = "d" + "1" * 4400
    names = ["d10", long, "d2", "x", "d02", "d"]
    assert sorted(names, key=_natural) == ["d", "d02", "d2", "d10", long, "x"]
    pic = FleetPicture({**AUTH, long: frozenset({"A"})})
    _on(pic, "A", 10.0, _ops("A", 1, drone=long), _ops("A", 1, drone="d2"))
    assert [d["drone"] for d in pic.snapshot(10.0, WALL + 10.0)["drones"]] == ["d2", long]


# ------------------------------------------------- revisions taken live
def test_a_rotated_gs_key_is_taken_live_and_a_revoked_gs_no_longer_opens():
    o = _opener()
    old = OpsSealer(A, "A", "V", V.public, "zdrone-ops/A", os.urandom(16))
    assert isinstance(o.open("A", "zdrone-ops/A", _sealed(old, sent=WALL), 0.0, WALL), OpsReport)
    a2 = Identity.generate()
    o.set_senders({"A": a2.public, "B": B.public})  # a revision rotated A's key
    assert o.open("A", "zdrone-ops/A", _sealed(old, sent=WALL + 1), 1.0, WALL + 1) is OpsDrop.AUTH_FAILED
    new = OpsSealer(a2, "A", "V", V.public, "zdrone-ops/A", os.urandom(16))
    assert isinstance(o.open("A", "zdrone-ops/A", _sealed(new, sent=WALL + 2), 2.0, WALL + 2), OpsReport)
    o.set_senders({"B": B.public})  # a revision revoked A
    assert o.open("A", "zdrone-ops/A", _sealed(new, sent=WALL + 3), 3.0, WALL + 3) is OpsDrop.UNKNOWN_SENDER


def test_the_view_applies_a_revision_revoked_gss_drop_out_rotated_drone_keys_are_taken():
    import msgspec
    from types import SimpleNamespace

    from zdrone.core.keys import b64
    from zdrone.core.opspicture import fleet_authorized, fleet_senders
    from zdrone.view.server import Follower

    base = default_fleet()
    pic = FleetPicture(fleet_authorized(base), {"d1": (D1_OLD.public,)}, fleet_senders(base))
    view = SimpleNamespace(rt=SimpleNamespace(fleet=base), fleet=base, picture=pic,
                           opener=OpsOpener(V, "V", fleet_senders(base)), revisions=SimpleNamespace(keeper=SimpleNamespace(number=1)))
    _on(pic, "B", 10.0, _attested("B", 1, WALL + 10.0, key=D1_OLD))
    assert _row(pic, 10.0)["links"].keys() == {"B"}
    d1 = msgspec.structs.replace(base.nodes["d1"], signing_key=b64(D1.public))
    revised = msgspec.structs.replace(base, nodes={**base.nodes, "d1": d1}, revoked=frozenset({"B"}), revision=1)
    Follower.apply_fleet(view, revised)
    assert "B" not in view.opener.senders and "B" not in _row(pic, 10.0)["links"]
    _on(pic, "B", 10.5, _attested("B", 2, WALL + 10.5, key=D1))
    assert pic.drops["unknown_gs"] == 1
    _on(pic, "A", 11.0, _attested("A", 2, WALL + 11.0, key=D1))  # the drone's rotated key: taken
    row = _row(pic, 11.0)
    assert (row["owner"], row["epoch"], row["verified"]) == ("A", 2, True)
