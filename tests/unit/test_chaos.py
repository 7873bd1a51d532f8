"""The chaos bench's schedules are reproducible, and its invariants catch what they claim to."""

from __future__ import annotations

from zdrone.bench.chaos import invariants, schedule
from zdrone.sil.launcher import Outcome


def test_a_seed_always_gives_the_same_schedule():
    assert schedule(11) == schedule(11)
    assert {schedule(s)[2][0] for s in range(40)} != {schedule(0)[2][0]}  # seeds differ
    for s in range(40):
        faults, radio, text = schedule(s)
        assert 1 <= len(text) <= 3 and (faults or radio)


def _outcome(drone: list[dict]) -> Outcome:
    return Outcome({"exit_codes": {}, "timed_out": False}, drone, {}, [])


def _ev(t: float, type_: str, **kw) -> dict:
    return {"t": t, "type": type_, **kw}


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
