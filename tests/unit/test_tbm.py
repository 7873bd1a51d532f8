import pytest
from hypothesis import given
from hypothesis import strategies as st

from zdrone.core.tbm import LinkState, TbmThresholds, TimeBetweenMessages


def test_states_follow_silence():
    t = TimeBetweenMessages(0.0)
    assert t.state(0.0) is LinkState.LOST  # nothing heard yet
    t.observe(1.0)
    assert t.state(1.5) is LinkState.OK
    assert t.state(2.0) is LinkState.DEGRADED
    assert t.state(3.99) is LinkState.DEGRADED
    assert t.state(4.0) is LinkState.LOST
    assert t.deadline() == 4.0


def test_poll_reports_changes_once():
    t = TimeBetweenMessages(0.0, TbmThresholds(0.5, 1.0))
    t.observe(0.0)
    assert t.poll(0.1) is LinkState.OK
    assert t.poll(0.2) is None
    assert t.poll(0.6) is LinkState.DEGRADED
    assert t.poll(1.2) is LinkState.LOST
    assert t.poll(1.3) is None


def test_bad_thresholds():
    with pytest.raises(ValueError):
        TbmThresholds(3.0, 1.0)


@given(st.lists(st.floats(0.0, 10.0), min_size=2, max_size=50))
def test_statistics(gaps):
    t = TimeBetweenMessages(0.0)
    now = 0.0
    t.observe(now)
    for g in gaps:
        now += g
        t.observe(now)
    snap = t.snapshot(now)
    assert snap.frames == len(gaps) + 1
    assert snap.mean_gap == pytest.approx(sum(gaps) / len(gaps))
    assert snap.max_gap == pytest.approx(max(gaps))


def test_after_an_input_only_a_better_state_is_reported_a_silence_waits_for_the_timer():
    m = TimeBetweenMessages(0.0)
    m.observe(0.0)
    assert m.poll(0.0) is LinkState.OK
    assert m.poll(3.5, worsen=False) is None  # another input: this link's frame may still be queued
    m.observe(3.5)
    assert m.poll(3.5, worsen=False) is None  # it was: nothing changed
    assert m.poll(4.6, worsen=False) is None
    assert m.poll(4.6) is LinkState.DEGRADED  # the timer judges the silence
    assert m.poll(7.0) is LinkState.LOST
    m.observe(7.1)
    assert m.poll(7.1, worsen=False) is LinkState.OK  # better: reported after any input
    assert m.next_change() == 8.1
