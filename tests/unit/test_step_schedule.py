"""The bench hosts' step schedule: each drone at its own deadline, brought forward by an input."""

from __future__ import annotations

import math

from hypothesis import given
from hypothesis import strategies as st

from zdrone.bench.stepping import StepSchedule


def test_every_drone_is_due_at_the_start_then_at_its_own_deadline() -> None:
    s = StepSchedule(3, now=0.0)
    assert s.take(0.0) == [0, 1, 2]
    assert s.take(1.0) == [] and s.next_due() == math.inf  # not due again until set
    s.set(0, 0.25)
    s.set(1, 0.10)
    s.set(2, 1.00)
    assert s.next_due() == 0.10
    assert s.take(0.2) == [1] and s.take(0.3) == [0] and s.steps == 5


def test_an_input_brings_a_deadline_forward_never_back() -> None:
    s = StepSchedule(2, now=0.0)
    s.take(0.0)
    s.set(0, 1.0)
    s.set(1, 1.0)
    s.bring_forward(0, 0.1)
    s.bring_forward(1, 2.0)  # later than its deadline: no change
    assert s.take(0.1) == [0] and s.take(0.5) == [] and s.take(1.0) == [1]
    assert s.take(5.0) == []  # the stale entry of 0 at 1.0 is not taken twice


@given(st.lists(st.tuples(st.integers(0, 4), st.floats(0, 10), st.booleans()), max_size=60), st.floats(0, 12))
def test_a_drone_is_taken_once_at_most_and_only_when_due(moves: list[tuple[int, float, bool]], now: float) -> None:
    s = StepSchedule(5, now=0.0)
    s.take(0.0)
    for i, t, forward in moves:
        (s.bring_forward if forward else s.set)(i, t)
    want = sorted(i for i in range(5) if s.due[i] <= now)
    got = s.take(now)
    assert sorted(got) == want and len(set(got)) == len(got)
    assert all(s.due[i] > now for i in range(5))
