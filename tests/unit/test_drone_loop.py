"""The drone's timer (``DroneCore.get_timer``) wakes it when a link's TBM state next changes:
``TimeBetweenMessages.next_change`` after the core's ``poll``."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from zdrone.core.tbm import LinkState, TbmThresholds, TimeBetweenMessages

EPS = 1e-6


def test_a_link_changes_at_degraded_then_at_lost_then_never():
    tbm = TimeBetweenMessages(0.0, TbmThresholds(degraded=1.0, lost=3.0))
    tbm.poll(0.5)
    assert tbm.next_change() is None  # nothing seen yet: LOST, and stays so
    tbm.observe(10.0)
    tbm.poll(10.2)
    assert tbm.next_change() == 11.0
    tbm.poll(11.0)
    assert tbm.next_change() == 13.0
    tbm.poll(13.0)
    assert tbm.next_change() is None


@given(st.floats(0.01, 5.0), st.floats(0.0, 5.0), st.floats(0.0, 1e4), st.floats(0.0, 20.0))
def test_the_state_holds_until_the_next_change_and_differs_after_it(degraded, extra, seen, since):
    tbm = TimeBetweenMessages(0.0, TbmThresholds(degraded=degraded, lost=degraded + extra))
    tbm.observe(seen)
    now = seen + since
    tbm.poll(now)  # what the core does after a timer (after an input: only a better state)
    state, due = tbm.state(now), tbm.next_change()
    if due is None:
        assert state is LinkState.LOST
        return
    assert state is not LinkState.LOST
    if due - EPS > now:
        assert tbm.state(due - EPS) is state and tbm.state((now + due - EPS) / 2) is state
    assert tbm.state(due + EPS) is not state
