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
