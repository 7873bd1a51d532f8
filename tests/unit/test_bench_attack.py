"""``zdrone bench attack``'s junk-flood row: A's link out of OK, read from the drone's log."""

from __future__ import annotations

from zdrone.bench.attack import _not_ok_periods
from zdrone.core.records import LinkStateChanged
from zdrone.core.tbm import LinkState


def _ch(t: float, gs: str, state: LinkState) -> LinkStateChanged:
    return LinkStateChanged(t=t, node="d1", gs=gs, state=state)


def test_the_longest_stretch_out_of_ok_and_the_worst_state_inside_the_window():
    events = [_ch(5.0, "A", LinkState.DEGRADED), _ch(5.5, "A", LinkState.OK),  # before the window
              _ch(11.0, "A", LinkState.DEGRADED), _ch(11.4, "A", LinkState.OK),
              _ch(12.0, "B", LinkState.LOST),  # another GS's link
              _ch(13.0, "A", LinkState.DEGRADED), _ch(14.5, "A", LinkState.OK)]
    assert _not_ok_periods(events, "A", 10.0, 20.0) == ("degraded", 1.5)
    assert _not_ok_periods(events, "A", 0.0, 4.0) == ("ok", 0.0)


def test_a_stretch_open_at_either_end_counts_from_or_until_the_window_edge_and_lost_is_worst():
    events = [_ch(9.0, "A", LinkState.DEGRADED), _ch(10.5, "A", LinkState.OK),
              _ch(18.0, "A", LinkState.DEGRADED), _ch(19.0, "A", LinkState.LOST)]
    assert _not_ok_periods(events, "A", 10.0, 20.0) == ("lost", 2.0)
    assert _not_ok_periods(events[:2], "A", 10.0, 20.0) == ("degraded", 0.5)
