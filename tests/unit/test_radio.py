"""The testbed's lossy radio against the TBM defaults: 20 % loss never LOST, 60 % shows DEGRADED,
a 4 s burst is LOST (explicit time, seeded randomness, no sockets)."""

from __future__ import annotations

import pytest

from zdrone.core.tbm import LinkState, TbmThresholds, TimeBetweenMessages
from zdrone.sil.radio import RadioChannel, RadioModel, parse_models

#: what a GS sends up in flight: 2 Hz heartbeats; the authority also a 5 Hz command stream
SEND_PERIODS = (0.5, 0.2)


def _states(channel: RadioChannel, seconds: float, step: float = 0.01) -> set[LinkState]:
    """Run one uplink through the radio for ``seconds``; the TBM states the drone would report."""
    tbm = TimeBetweenMessages(0.0, TbmThresholds())
    tbm.observe(0.0)
    due = {p: 0.0 for p in SEND_PERIODS}
    arrivals: list[float] = []
    seen = {LinkState.OK}
    t = 0.0
    while t < seconds:
        for p in SEND_PERIODS:
            if t >= due[p]:
                due[p] += p
                at = channel.admit("A", "up", t)
                if at is not None:
                    arrivals.append(at)
        for a in [a for a in arrivals if a <= t]:
            arrivals.remove(a)
            tbm.observe(t)
        seen.add(tbm.state(t))
        t += step
    return seen


def test_twenty_percent_independent_loss_is_never_lost():
    for seed in range(5):
        seen = _states(RadioChannel(RadioModel(loss=0.2, delay_s=0.05, jitter_s=0.02), seed=seed), 600.0)
        assert LinkState.LOST not in seen, seed


def test_sixty_percent_loss_shows_degraded():
    seen = _states(RadioChannel(RadioModel(loss=0.6), seed=1), 300.0)
    assert LinkState.DEGRADED in seen


def test_a_four_second_burst_is_lost():
    channel = RadioChannel(RadioModel(good_s=20.0, bad_s=4.0), seed=3)
    # force one burst of exactly 4 s: good until 10 s, bad until 14 s
    path = channel._path("A", "up")
    path.switch_at, path.bad = 10.0, False
    path.rng.expovariate = lambda rate: 4.0 if rate == 0.25 else 1000.0  # type: ignore[method-assign]
    seen = _states(channel, 20.0)
    assert LinkState.LOST in seen
    assert channel.lost["up:A:burst"] >= 4 / 0.2


def test_loss_is_counted_and_delay_never_goes_back_in_time():
    ch = RadioChannel(RadioModel(loss=0.5, delay_s=0.01, jitter_s=0.05), seed=7)
    outs = [ch.admit("B", "down", float(i)) for i in range(1000)]
    assert all(o is None or o >= i for i, o in enumerate(outs))
    assert ch.lost["down:B:loss"] == sum(o is None for o in outs) and 400 < ch.lost["down:B:loss"] < 600


def test_perfect_radio_passes_everything_at_once():
    ch = RadioChannel()
    assert ch.admit("A", "up", 5.0) == 5.0 and not ch.lost


def test_command_line_models():
    default, per = parse_models(["0.2", "B=0.6"], ["A=10:4"], 50.0, 20.0)
    assert default == RadioModel(loss=0.2, delay_s=0.05, jitter_s=0.02)
    assert per["B"].loss == 0.6 and per["A"].good_s == 10.0 and per["A"].bad_s == 4.0 and per["A"].loss == 0.2  # the rest inherited
    with pytest.raises(ValueError):
        parse_models(["1.5"], [], 0.0, 0.0)
    with pytest.raises(ValueError):
        parse_models([], ["3"], 0.0, 0.0)


def test_a_jammed_site_radio_stays_down_wherever_the_vehicle_is_and_the_position_decides_again_after():
    from zdrone.core.geometry import Circle, offset
    from zdrone.core.reference import HOME
    from zdrone.sil.radiolink import SiteCoverage

    class Link:
        def __init__(self) -> None:
            self.up = False

        def set_up(self, up: bool) -> bool:
            changed, self.up = self.up != up, up
            return changed

        def close(self) -> None:
            pass

    links = {"site-1": Link(), "site-2": Link()}
    changes: list[tuple[str, bool]] = []
    cov = SiteCoverage({"site-1": [Circle(HOME, 350.0)], "site-2": [Circle(offset(HOME, 0, 500), 350.0)]}, links,
                       lambda site, up, _p: changes.append((site, up)))
    cov.update(offset(HOME, 0, 300))  # the overlap
    assert links["site-1"].up and links["site-2"].up
    cov.jam("site-1", True)
    cov.update(offset(HOME, 0, 310))
    assert not links["site-1"].up and links["site-2"].up
    cov.jam("site-1", False)
    assert links["site-1"].up
    assert changes == [("site-1", True), ("site-2", True), ("site-1", False), ("site-1", True)]
