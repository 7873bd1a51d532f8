"""A GS session is looked at only when it is due: after an input about its drone, or at the moment its
``deadline`` names. That is right only if every rule of ``tick`` that reads the time has its moment in
``deadline``: probed here on the reference flight (both autopilots, a companion restart in the overlap),
by ticking a copy of every session a moment before its deadline and finding that nothing happens: no
action, no count, no change of its view or its mission's stage."""

from __future__ import annotations

import copy
import math

import pytest

import zdrone.check.cores  # noqa: F401  (deep copies share the stateless AEAD contexts, as the checker's do)
from gs.context import DEADLINE_SLACK_S
from tests.coreflight import WALL0, CoreFlight
from zdrone.vehicle.personality import personality


@pytest.fixture(scope="module")
def fleet_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("fleet")


#: Counts of ticks that found a rule still waiting (each tick adds one): no deed of a rule.
PER_TICK = {"release_waits_position", "handover_waiting_key"}


def _probe(f: CoreFlight, fired: list[str]) -> int:
    """Tick a copy of every session of every GS just before its deadline; what it did goes to ``fired``."""
    probes = 0
    for name, st in f.gs.items():
        if st.down:
            continue
        for session in st.core.sessions.values():
            if math.isinf(session.due) or session.due <= f.now + 2 * DEADLINE_SLACK_S:
                continue  # nothing to wait for, or due at once (the next step ticks it)
            for t in (f.now + 0.5 * (session.due - f.now), session.due - 0.002):
                if t <= f.now:
                    continue
                twin = copy.deepcopy(session)
                counted = dict(twin.st.counters)
                out = twin.tick(t, WALL0 + t)
                probes += 1
                changed = {k: v for k, v in twin.st.counters.items() if counted.get(k) != v and k not in PER_TICK}
                if out or changed or twin.stale != session.stale or twin.mission.stage is not session.mission.stage:
                    fired.append(f"{name}@{f.now:.2f} tick({t:.3f}) < due {session.due:.3f}: {out[:3]} {changed}")
    return probes


@pytest.mark.parametrize("autopilot", ["px4", "ardupilot"])
def test_no_rule_of_a_session_acts_before_the_deadline_it_names(fleet_dir, autopilot):
    f = CoreFlight(fleet_dir, personality(autopilot))
    fired: list[str] = []
    probes, restarted = 0, False
    while f.now < 400 and not f.flown():
        f.run_until(lambda: False, 0.35)
        probes += _probe(f, fired)
        both = f.in_range("A") and f.in_range("B")
        if both and not restarted and f.drone.machine.owner == "A":
            f.restart_drone(2.0)  # silence, re-pairing and key sharing again: the session's timed rules
            restarted = True
    assert f.flown() and restarted, f"flown {f.flown()}, restarted {restarted}"
    assert probes > 500, probes
    assert not fired, fired[:5]


def test_the_same_word_again_after_a_silence_does_not_tell_the_operator_the_drone_became_ours(tmp_path):
    """"d1 is ours and holds in the air" is said when the drone's word makes it ours (a new owner, epoch
    or state), not again each time the same word comes back after a radio gap made our view stale."""
    from pymavlink.dialects.v20 import common as mav

    from gs.actions import ToOperator
    from tests.unit.test_station_core import paired_a
    from zdrone.core import wire
    from zdrone.core.authority import State as HaState
    from zdrone.fleet.files import init_fleet
    from zdrone.vehicle.modes import MODE_ROLES, mode_name

    init_fleet(tmp_path)
    a = paired_a(tmp_path)
    v = a.sessions["d1"]
    v.autopilot, v.armed, v.landed_state = "ardupilot", True, mav.MAV_LANDED_STATE_IN_AIR
    v.custom_mode = next(m for m in range(64) if mode_name("ardupilot", m) == MODE_ROLES["ardupilot"]["hold"])

    def said(out):
        return [x.text for x in out if isinstance(x, ToOperator) and "holds in the air" in x.text]

    v.link.tbm.observe(1.0)
    assert not said(v.on_control(wire.AuthorityStatus("B", 2, HaState.LINKED, None, ["A", "B"]), 1.0))  # B's
    assert said(v.on_control(wire.AuthorityStatus("A", 3, HaState.LINKED, None, ["A", "B"]), 1.1))  # made ours
    a.handle_timer(2.5)
    assert v.stale  # a radio gap: our view waits for the drone's word
    v.link.tbm.observe(2.6)
    assert not said(v.on_control(wire.AuthorityStatus("A", 3, HaState.LINKED, None, ["A", "B"]), 2.6))  # the same word
    assert not v.stale and a.holds_authority("d1")
