"""The GS's hand-over sub-machine (``gs.handover``): its table, over every phase and event."""

from __future__ import annotations

import copy

from hypothesis import given, settings
from hypothesis import strategies as st

from gs.handover import TABLE, Confirmed, Failed, Handover, HandoverPhase, ReleaseSent

times = st.floats(0, 1000, allow_nan=False)
EVENTS = st.one_of(
    st.builds(ReleaseSent, times, st.sampled_from(["B", "C"]), st.floats(0, 500, allow_nan=False)),
    st.builds(Confirmed, times),
    st.builds(Failed, times, st.just("test")),
)
#: A way into each phase from a fresh epoch.
INTO = {
    HandoverPhase.IDLE: [],
    HandoverPhase.RELEASED: [ReleaseSent(1.0, "B", 100.0)],
    HandoverPhase.CONFIRMED: [ReleaseSent(1.0, "B", 100.0), Confirmed(1.5)],
    HandoverPhase.FAILED: [Failed(1.0, "no link")],
}


def _state(h: Handover) -> dict:
    return dict(vars(h)) if hasattr(h, "__dict__") else {}


@settings(max_examples=300, deadline=None)
@given(st.sampled_from(list(HandoverPhase)), EVENTS)
def test_every_phase_and_event_goes_where_the_table_says_or_changes_nothing(phase, ev):
    h = Handover("d1").for_epoch(3)
    for e in INTO[phase]:
        assert h.handle(e)
    assert h.phase is phase
    before = copy.deepcopy(_state(h))
    row = TABLE.get((phase, type(ev)))
    assert h.handle(ev) is (row is not None)
    if row is None:
        assert _state(h) == before  # not in the table: nothing changes
    else:
        assert h.phase is row[1]


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(st.integers(1, 3), EVENTS), max_size=40))
def test_over_any_sequence_the_machine_keeps_its_epoch_and_its_facts(steps):
    """Released means sent and not failed since; failures, the first release's distance and the
    RTL flag belong to one epoch; a new epoch starts afresh."""
    h = Handover("d1")
    epoch, failures, first = None, 0, None
    for e, ev in steps:
        if e != epoch:
            epoch, failures, first = e, 0, None
            h.for_epoch(e)
            assert h.phase is HandoverPhase.IDLE and h.failures == 0 and h.first_distance is None and not h.rtl_done
        was = h.phase
        h.handle(ev)
        if isinstance(ev, Failed):
            failures += 1
            assert h.phase is HandoverPhase.FAILED and h.failed_at == ev.now and not h.released_in(e)
        elif isinstance(ev, ReleaseSent) and was is not HandoverPhase.CONFIRMED:
            first = ev.distance if first is None else first
            assert h.phase is HandoverPhase.RELEASED and h.sent == ev.now and h.released_in(e) and h.to == ev.to
        elif isinstance(ev, Confirmed) and was in (HandoverPhase.RELEASED, HandoverPhase.CONFIRMED):
            assert h.phase is HandoverPhase.CONFIRMED
        else:
            assert h.phase is was
        assert (h.failures, h.first_distance, h.epoch) == (failures, first, e)
        assert h.released == (h.phase in (HandoverPhase.RELEASED, HandoverPhase.CONFIRMED))
        assert not h.released_in(e + 1)


def test_the_waits_follow_the_phase():
    h = Handover("d1").for_epoch(1)
    h.handle(ReleaseSent(10.0, "B", 50.0))
    assert h.resend_waits(10.1, 0.25) and not h.resend_waits(10.3, 0.25)  # never confirmed: sent again
    h.handle(Confirmed(10.2))
    assert h.resend_waits(99.0, 0.25)  # confirmed: the drone decides
    h.handle(Failed(11.0, "release timed out"))
    assert h.retry_waits(12.0, 2.0) and not h.retry_waits(13.0, 2.0) and not h.resend_waits(12.0, 0.25)
    h.for_epoch(2)
    assert h.phase is HandoverPhase.IDLE and not h.retry_waits(12.0, 2.0)
