"""The hold of a vehicle while a hand-over waits for a key (gs.keyhold): the whole table."""

from collections import Counter

from hypothesis import given, settings
from hypothesis import strategies as st

from gs.keyhold import (HOLD_FOR_KEY_S, HOLD_RESEND_S, TABLE, HoldPhase, HoldStep, KeyHold, KeyMissing, KeyThere,
                        ModeAck)

PARAMS = {"HOLD": (1.0, 4.0, 3.0), "MISSION": (1.0, 4.0, 4.0)}
MODES = st.sampled_from(["HOLD", "MISSION", "POSCTL"])
NOW = st.floats(10.0, 40.0)
EVENTS = st.one_of(st.builds(KeyMissing, NOW, MODES, st.booleans()), st.builds(KeyThere, NOW, MODES, st.just("B")),
                   st.builds(ModeAck, NOW, st.booleans()))


def _hold(phase: HoldPhase = HoldPhase.HOLDING) -> KeyHold:
    hold, _ = KeyHold.start("d1", 3, "B", 10.0, "HOLD", "MISSION", PARAMS, Counter())
    hold.phase = phase
    return hold


@settings(max_examples=500, deadline=None)
@given(st.sampled_from(list(HoldPhase)), EVENTS)
def test_every_phase_and_event_follows_the_table(phase, ev):
    hold = _hold(phase)
    row = TABLE.get((phase, type(ev)))
    step = hold.handle(ev)
    if row is None:
        assert step is None and hold.phase is phase
        return
    assert hold.phase is phase or hold.phase in row[1]
    if step is not None:
        assert isinstance(step, HoldStep)
        assert step.send in (None, *PARAMS.values())
        assert step.over is None or hold.phase is HoldPhase.OVER  # ending without the hand-over ends the hold
        assert not step.rtl or step.over is not None  # an RTL only when the hold ends without the hand-over


@settings(max_examples=200, deadline=None)
@given(st.lists(EVENTS, max_size=25))
def test_a_hold_ends_once_and_never_outlives_its_time(events):
    hold, overs = _hold(), 0
    for ev in sorted(events, key=lambda e: e.now):
        step = hold.handle(ev)
        overs += step is not None and step.over is not None
        if isinstance(ev, KeyMissing) and ev.now - hold.since >= HOLD_FOR_KEY_S:
            assert hold.phase is not HoldPhase.HOLDING  # expired, or resumed before
    assert overs <= 1


def test_the_hold_mode_is_sent_again_until_confirmed_then_the_mission_resumes():
    hold, first = KeyHold.start("d1", 3, "B", 10.0, "HOLD", "MISSION", PARAMS, Counter())
    assert first.send == PARAMS["HOLD"] and first.log is not None
    assert hold.handle(KeyMissing(10.2, "MISSION", False)).send is None  # not yet
    assert hold.handle(KeyMissing(10.0 + HOLD_RESEND_S, "MISSION", False)).send == PARAMS["HOLD"]  # again
    assert hold.handle(KeyMissing(11.0, "HOLD", False)) == HoldStep()  # the vehicle holds: wait
    step = hold.handle(KeyThere(12.0, "HOLD", "B"))
    assert hold.phase is HoldPhase.RESUMING and step.send == PARAMS["MISSION"] and step.log is not None
    assert hold.handle(ModeAck(12.1, True)) == HoldStep()
    assert hold.handle(KeyThere(12.2, "MISSION", "B")) is None and hold.phase is HoldPhase.OVER  # release now
