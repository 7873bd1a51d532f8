"""A GS's frames on one uplink key go out at most once per gap, in order; bounded; counted."""

from __future__ import annotations

from collections import Counter

from zdrone.net.pacing import Pacer


def test_a_burst_on_one_key_goes_out_one_per_gap_in_order_and_other_keys_are_not_held():
    refused: Counter[str] = Counter()
    p = Pacer(0.01, lambda r: refused.update([r]))
    assert p.offer("up/A", b"1", 0.0)  # the first goes at once
    assert not p.offer("up/A", b"2", 0.001) and not p.offer("up/A", b"3", 0.002)
    assert p.offer("d2/up/A", b"x", 0.002)  # another key has its own turn
    assert p.next_due() == 0.01 and p.due(0.009) == []
    assert p.due(0.01) == [("up/A", b"2")]
    assert not p.offer("up/A", b"4", 0.05)  # something still waits: the new one queues behind it
    assert p.due(0.05) == [("up/A", b"3")] and p.due(0.055) == [] and p.due(0.061) == [("up/A", b"4")]
    assert p.next_due() is None and p.waiting() == 0
    assert p.offer("up/A", b"5", 0.2) and not refused


def test_the_queue_per_key_is_bounded_and_refusals_are_counted():
    refused: Counter[str] = Counter()
    p = Pacer(1.0, lambda r: refused.update([r]), limit=3)
    for i in range(10):
        p.offer("k", bytes([i]), 0.0)
    assert p.waiting() == 3 and refused == {"put:pace_full": 6}
    assert [p.due(float(t)) for t in (1, 2, 3)] == [[("k", b"\x01")], [("k", b"\x02")], [("k", b"\x03")]]


def test_with_a_burst_of_lanes_a_frame_per_lane_goes_at_once_and_each_lane_keeps_its_gap():
    """burst = the uplink's lanes, gap = how far apart one lane's frames must be: the frames go on the
    lanes in turn (as ``NodeRuntime.put_link`` does), so the n-th frame's lane last carried frame n-burst."""
    lanes, gap = 4, 0.16
    p = Pacer(gap, lambda r: None, burst=lanes)
    sent: list[tuple[int, float]] = []  # (lane, when)

    def out(now: float, went: bool) -> None:
        if went:
            sent.append((len(sent) % lanes, now))

    for i in range(6):  # a heartbeat, a command and control messages in one tick
        out(0.0, p.offer("up/A", bytes([i]), 0.0))
    assert len(sent) == lanes and p.waiting() == 2  # a frame per lane at once; the rest waits
    assert p.next_due() == gap and p.due(gap - 0.001) == []
    for _key, _payload in p.due(gap):
        out(gap, True)
    assert len(sent) == 6 and p.waiting() == 0
    assert p.offer("up/A", b"late", 0.2)  # lane 2 last went at 0.0
    out(0.2, True)
    last: dict[int, float] = {}
    for lane, t in sent:  # the rule the router enforces: one lane's frames at least the gap apart
        assert lane not in last or t - last[lane] >= gap - 1e-9, (lane, t, last)
        last[lane] = t
    assert p.offer("up/A", b"lane 3", 0.25)  # lane 3 last went at 0.0
    assert not p.offer("up/A", b"held", 0.26)  # lane 0 went at 0.16: its turn at 0.32
    assert p.next_due() == gap * 2


def test_sustained_the_rate_is_a_burst_per_gap():
    p = Pacer(0.16, lambda r: None, burst=8)
    went = sum(p.offer("k", b"x", i * 0.001) for i in range(1000))  # 1 000 offers in a second
    t, now = went, 0.0
    while now < 1.0:
        now += 0.001
        t += len(p.due(now))
    assert t <= 8 * (1 + int(1.0 / 0.16)) + 8 and t >= 8 * int(1.0 / 0.16)


def test_the_send_table_is_swept_at_most_once_a_gap_and_stays_bounded():
    """A GS of hundreds of drones calls ``due`` every pass: the sweep of old send times is not O(drones)
    each time (the sweep every pass: 3 990 sweeps in 4 000 passes here), and the rule is unchanged."""
    p = Pacer(0.02, lambda r: None)
    largest, sweeps, table = 0, 0, p._sent
    for step in range(2000):  # 300 uplinks, each used every 25 ms; two passes every millisecond, for 2 s
        t = step * 0.001
        for i in range(12):
            assert p.offer(f"d{(step % 25) * 12 + i}/up/A", b"x", t)
        for now in (t, t + 0.0005):
            p.due(now)
            sweeps += p._sent is not table
            table = p._sent
        largest = max(largest, len(p._sent))
    assert 0 < sweeps <= 2.0 / 0.02 + 1  # 4 000 passes
    assert largest <= 300 + 64 and p.waiting() == 0
