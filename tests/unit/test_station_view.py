"""A GS's telemetry view never shows a stale drone as live: each line says how old the drone's last
report is and whether this GS holds its authority; past the DEGRADED threshold the line is STALE,
and what it shows is as of then."""

from __future__ import annotations

from dataclasses import dataclass, field

from gs.core import DroneView
from gs.station import view_line
from zdrone.core.authority import State as HaState
from zdrone.core.tbm import TimeBetweenMessages


@dataclass
class _Link:  # what the view reads of a link
    tbm: TimeBetweenMessages
    opened: int = 120
    sent: int = 80
    drops: dict = field(default_factory=dict)


def _view(owner: str, heard_at: float | None) -> DroneView:
    tbm = TimeBetweenMessages(0.0)
    if heard_at is not None:
        tbm.observe(heard_at)
    v = DroneView("d1", 1, link=_Link(tbm), owner=owner, epoch=3, ha_state=HaState.LINKED, armed=True,
                  custom_mode=(4 << 16) | (4 << 24), mission_seq=5, autopilot="px4")  # type: ignore[arg-type]
    return v


def test_a_live_report_says_its_age_and_whose_authority_it_is():
    line = view_line("B", "d1", _view("A", heard_at=100.0), now=100.3)
    assert "report 0.3 s old" in line and "authority A (epoch 3, linked), not this GS" in line
    assert "STALE" not in line and "ARMED" in line
    assert "authority B (epoch 3, linked), this GS" in view_line("B", "d1", _view("B", 100.0), now=100.2)


def test_a_drone_not_heard_is_shown_stale_with_the_age_of_what_is_shown():
    """B after the hand-back: the drone flew home out of its coverage and landed at A."""
    line = view_line("B", "d1", _view("A", heard_at=100.0), now=142.0)
    assert line.startswith("gs B | d1: STALE, last report 42.0 s ago (link lost): as of then authority A")
    assert "not this GS" in line and "was ARMED" in line and "last position" in line
    assert "report 42.0 s old" not in line  # never the live form
    degraded = view_line("B", "d1", _view("B", heard_at=100.0), now=101.5)
    assert "STALE, last report 1.5 s ago (link degraded)" in degraded and "this GS (it may have moved since)" in degraded


def test_a_link_never_heard_says_so():
    assert "nothing heard yet" in view_line("A", "d1", _view("A", heard_at=None), now=5.0)
