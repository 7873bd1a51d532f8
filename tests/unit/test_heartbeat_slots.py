"""The GS's heartbeat, spread over its period (``gs.core.HEARTBEAT_SLOTS``): every drone still gets one
heartbeat a period, but a pass sends at most a slot's share of them, not the whole fleet's at once."""

import math

import pytest

from gs.core import HEARTBEAT_SLOTS, CoreOptions, StationCore
from zdrone.fleet.files import init_fleet, load_fleet, load_secret, scale_nodes

K = 25


@pytest.fixture(scope="module")
def fleet_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("fleet")
    init_fleet(d, nodes_spec=scale_nodes(K, 3))
    return d


def _station(fleet_dir) -> tuple[StationCore, list[tuple[float, str]]]:
    fleet = load_fleet(fleet_dir)
    drones = tuple(d for d in fleet.drones() if fleet.is_authorized(d, "A"))
    a = StationCore("A", fleet, load_secret(fleet_dir, "A", fleet).identity, drones, CoreOptions())
    sent: list[tuple[float, str]] = []
    for name, session in a.sessions.items():
        session.heartbeat = lambda name=name: sent.append((a.clock, name)) or []  # type: ignore[method-assign]
    return a, sent


def test_each_drone_gets_one_heartbeat_a_period_and_a_pass_sends_a_slots_share(fleet_dir):
    a, sent = _station(fleet_dir)
    assert len(a.sessions) == K
    period = 1.0 / a.opts.heartbeat_hz
    now = 0.0
    while now < 10 * period:
        a.clock = now
        before = len(sent)
        a.handle_timer(now)
        assert len(sent) - before <= math.ceil(K / HEARTBEAT_SLOTS)  # never the whole fleet in one pass
        now = max(a.get_timer(), now + 0.001)
    times: dict[str, list[float]] = {}
    for t, d in sent:
        times.setdefault(d, []).append(t)
    assert set(times) == set(a.sessions)
    for d, ts in times.items():  # each drone at its own slot, a period apart
        assert all(y - x == pytest.approx(period) for x, y in zip(ts, ts[1:])), d
        assert len(ts) in (10, 11)
    firsts = sorted(ts[0] for ts in times.values())
    assert firsts[-1] - firsts[0] == pytest.approx(period * (HEARTBEAT_SLOTS - 1) / HEARTBEAT_SLOTS)


def test_a_late_pass_sends_each_drone_one_heartbeat_and_no_more(fleet_dir):
    """A loop stalled for three periods sends every drone one heartbeat when it wakes (the slots it
    missed, each once), then goes on a slot's time from then."""
    a, sent = _station(fleet_dir)
    a.clock = 0.0
    a.handle_timer(0.0)
    first = len(sent)
    period = 1.0 / a.opts.heartbeat_hz
    a.clock = late = 3 * period + 0.01
    a.handle_timer(late)
    woke = [d for t, d in sent[first:]]
    assert len(woke) == len(set(woke)) == K  # each drone once
    assert a.get_timer() == pytest.approx(late + period / HEARTBEAT_SLOTS)


def test_the_timer_is_the_earliest_of_the_sessions_deadlines_and_the_next_slot(fleet_dir):
    """One walk over the sessions runs the due ones and finds the earliest deadline: the timer the
    station asks for is the same as a second walk after every session and heartbeat would give."""
    fleet = load_fleet(fleet_dir)
    drones = tuple(d for d in fleet.drones() if fleet.is_authorized(d, "A"))
    a = StationCore("A", fleet, load_secret(fleet_dir, "A", fleet).identity, drones, CoreOptions())
    now = 0.0
    for _ in range(200):
        a.handle_timer(now, 1_800_000_000.0 + now)
        earliest = min(s.due for s in a.sessions.values())
        assert a._due == earliest and a.get_timer() == min(a._hb_due, earliest)
        now = max(now + 0.001, min(a.get_timer(), now + 0.3))
