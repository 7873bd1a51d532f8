"""The chaos bench's schedules are reproducible, and its invariants catch what they claim to."""

from __future__ import annotations

import json
import signal
from typing import Any

from zdrone.bench.chaos import invariants, schedule
from zdrone.core.records import AnyRecord, UntypedRecord, decode_record
from zdrone.sil.launcher import Outcome


def test_a_seed_always_gives_the_same_schedule():
    assert schedule(11) == schedule(11)
    assert {schedule(s)[2][0] for s in range(40)} != {schedule(0)[2][0]}  # seeds differ
    for s in range(40):
        faults, radio, text = schedule(s)
        assert 1 <= len(text) <= 3 and (faults or radio)


def _outcome(drone: list[AnyRecord]) -> Outcome:
    return Outcome({"exit_codes": {}, "timed_out": False}, drone, {}, [])


#: neutral values of the fields a test leaves out, per drone event type
_NEUTRAL: dict[str, dict[str, Any]] = {
    "start": {"vehicle": "udpout:127.0.0.1:14540"},
    "authority": {"from": None, "kind": "paired", "time": 0.0, "position": None},
    "handover_complete": {"from": None, "kind": "handover", "time": 0.0, "position": None},
    "failsafe": {"action": "LAND", "reason": "authority link lost", "detect_to_command_ms": 0.0, "position": None},
    "link_state": {},
    "status": {"owner": None, "epoch": 0, "state": "linked", "pending_to": None, "position": None, "armed": True,
               "mode": "MISSION", "landed_state": 2, "in_region": False, "subscribed": [], "links": {}, "keys": {},
               "ha_drops": {}, "rejects": {}, "counters": {}, "forwarded_commands": {}, "out_of_coverage": {}},
}


def _ev(t: float, type_: str, **kw: Any) -> AnyRecord:
    """The drone's record of one event: the fields given, neutral values for the rest."""
    rec = decode_record(json.dumps({"t": t, "node": "d1", "type": type_, **_NEUTRAL[type_], **kw}))
    assert not isinstance(rec, UntypedRecord), rec
    return rec


def test_two_commanders_in_one_epoch_or_a_non_authority_commander_is_a_violation():
    base = [_ev(0, "start"), _ev(1, "authority", to="A", epoch=1), _ev(5, "handover_complete", to="B", epoch=2, kind="handover")]
    ok = base + [_ev(9, "status", forwarded_epochs={"1:A": 10, "2:B": 4})]
    assert invariants(_outcome(ok)) == []
    two = base + [_ev(9, "status", forwarded_epochs={"1:A": 10, "1:B": 1})]
    assert any("forwarded from ['A', 'B']" in w for w in invariants(_outcome(two)))
    wrong = base + [_ev(9, "status", forwarded_epochs={"2:A": 1})]
    assert any("authority was B" in w for w in invariants(_outcome(wrong)))


def test_a_lost_authority_link_must_be_followed_by_a_hand_over_or_the_failsafe():
    base = [_ev(0, "start"), _ev(1, "authority", to="A", epoch=1), _ev(5.0, "link_state", gs="A", state="lost")]
    assert invariants(_outcome(base + [_ev(5.01, "failsafe", detect_to_command_ms=2.0)])) == []
    assert invariants(_outcome(base + [_ev(7.0, "failsafe", detect_to_command_ms=2.0)]))
    late = base + [_ev(5.01, "failsafe", detect_to_command_ms=250.0)]
    assert any("250 ms" in w for w in invariants(_outcome(late)))


def test_a_link_lost_again_while_already_in_the_failsafe_asks_for_nothing():
    """Found by the 50-schedule run (seed 1021): A's link came back and went again during the landing."""
    ev = [_ev(0, "start"), _ev(1, "authority", to="A", epoch=1), _ev(5.0, "link_state", gs="A", state="lost"),
          _ev(5.001, "failsafe", detect_to_command_ms=1.0), _ev(6.0, "link_state", gs="A", state="ok"),
          _ev(10.0, "link_state", gs="A", state="lost")]
    assert invariants(_outcome(ev)) == []


def test_a_sites_schedule_draws_site_faults_at_every_moment_and_ends_each_it_starts():
    from zdrone.bench.chaos import SITE_MOMENTS, schedule_sites
    from zdrone.sil.launcher import LINK_DOWN, LINK_UP, RESTART

    assert schedule_sites(11) == schedule_sites(11)
    kinds: set[str] = set()
    moments: set[str] = set()
    for s in range(200):
        faults, radio, text = schedule_sites(s)
        assert 1 <= len({t.split(" ")[0] for t in text}) and (faults or radio)
        moments |= {f.trigger for f in faults}
        for f in faults:
            if f.target in ("router", "router2"):
                kinds.add("site router killed" if f.sig == RESTART else "site router hung")
            elif f.target == "backhaul":
                kinds.add("backhaul cut")
            elif f.target.startswith("site-"):
                kinds.add("radio flap")
        for target in {f.target for f in faults if f.sig in (LINK_DOWN, signal.SIGSTOP)}:  # each one ends
            downs = [f for f in faults if f.target == target and f.sig in (LINK_DOWN, signal.SIGSTOP)]
            ups = [f for f in faults if f.target == target and f.sig in (LINK_UP, signal.SIGCONT)]
            assert len(downs) == len(ups) and all(u.after > d.after for d, u in zip(downs, ups))
    assert kinds == {"site router killed", "site router hung", "backhaul cut", "radio flap"}
    assert moments == set(SITE_MOMENTS)


def test_over_sites_the_flight_must_complete_when_no_fault_is_active_as_the_drone_returns():
    from zdrone.bench.chaos import site_invariants

    def outcome(ends: float | None, **summary: Any) -> Outcome:
        base = {"exit_codes": {}, "timed_out": False, "failsafe": None, "delivered": True, "final_owner": "A",
                "distance_from_home_m": 0.3, "moments": {"returning": 50.0}, "ended_at": 80.0,
                "faults": [{"t": 20.0, "target": "router2", "text": "site-2's router killed", "ends": ends}]}
        return Outcome(base | summary, [], {"A": [], "B": []}, [])

    assert site_invariants(outcome(26.0)) == []
    assert site_invariants(outcome(26.0, final_owner="B")) == ["faults over, yet final authority B, expected A (home's GS)"]
    assert site_invariants(outcome(26.0, delivered=False)) == ["faults over, yet not delivered"]
    assert site_invariants(outcome(60.0, delivered=False)) == []  # still down as the drone came back
    assert site_invariants(outcome(None, delivered=False)) == []
    assert site_invariants(outcome(26.0, delivered=False), whole_flight=True) == []  # e.g. loss bursts all flight
