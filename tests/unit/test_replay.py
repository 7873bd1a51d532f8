from hypothesis import given
from hypothesis import strategies as st

from zdrone.core.replay import ReplayWindow


@given(st.lists(st.integers(0, 300)), st.integers(1, 128))
def test_window_matches_a_model(counters, size):
    w = ReplayWindow(size)
    seen: set[int] = set()
    highest = -1
    for c in counters:
        expected = c not in seen and c > highest - size
        assert w.is_fresh(c) == expected
        if expected:
            w.mark(c)
            seen.add(c)
            highest = max(highest, c)
