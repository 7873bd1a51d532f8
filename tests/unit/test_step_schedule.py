"""The bench hosts' step schedule: each drone at its own deadline, brought forward by an input."""

from __future__ import annotations

import math

import pytest

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


def test_a_step_that_begins_after_its_deadline_is_noted_late_by_that_much():
    s = StepSchedule(2, now=0.0)
    s.set(0, 1.0)
    s.set(1, 1.5)
    assert s.take(2.0) == [0, 1]
    s.started(0, 2.0)  # 1.0 s after its deadline
    s.started(1, 2.004)  # stepped after drone 0: 0.504 s
    s.set(0, 3.0)
    s.bring_forward(0, 2.5)  # an input at 2.5
    assert s.take(2.5) == [0]
    s.started(0, 2.5)  # at once: not late
    r = s.lateness.report()
    assert r["n"] == 3 and r["p50_ms"] == pytest.approx(504.0) and r["max_ms"] == pytest.approx(1000.0)


def test_the_lateness_sample_stays_bounded_and_uniform():
    from zdrone.bench.stepping import LATENESS_SAMPLES, StepLateness

    import random

    draw, late = random.Random(7), StepLateness()
    for _ in range(3 * LATENESS_SAMPLES):
        late.add(0.099 * draw.random())  # 0..99 ms, evenly
    r = late.report()
    assert len(late.samples) < LATENESS_SAMPLES and r["n"] == 3 * LATENESS_SAMPLES
    assert 45 <= r["p50_ms"] <= 55 and 97 <= r["p99_ms"] <= 99 and 98.9 <= r["max_ms"] <= 99.0
    assert StepLateness().report()["p99_ms"] is None


def test_the_latest_host_is_reported():
    from zdrone.bench.stepping import worst_lateness

    a, b = {"n": 1, "p50_ms": 1.0, "p99_ms": 9.0, "max_ms": 9.0}, {"n": 1, "p50_ms": 2.0, "p99_ms": 3.0, "max_ms": 3.0}
    assert worst_lateness([a, None, b]) is a and worst_lateness([None]) is None
