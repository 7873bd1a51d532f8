"""The copies other paths deliver (``zdrone.net.paths.RecentPayloads``): refused within the window,
remembered no longer than it (and never more than ``size``), so a node's memory of them stays small."""

from zdrone.net.paths import RecentPayloads


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_a_copy_within_the_window_is_refused_and_one_after_it_is_let_through():
    clock = Clock()
    r = RecentPayloads(size=100, window=5.0, clock=clock)
    assert r.first("down", "A", b"frame")
    clock.now = 4.9
    assert not r.first("down", "A", b"frame")  # another path's copy
    assert r.first("down", "B", b"frame") and r.first("pair", "A", b"frame")  # another sender, another kind
    clock.now = 5.1
    assert r.first("down", "A", b"frame")  # past the window: the envelope's replay window is the guard then


def test_what_is_remembered_is_bounded_by_the_window_and_the_size():
    clock = Clock()
    r = RecentPayloads(size=1000, window=5.0, clock=clock)
    for k in range(10_000):  # 20 payloads a second for 500 s
        clock.now = k / 20
        assert r.first("down", "A", k.to_bytes(4, "big"))
        assert len(r) <= 5.0 * 20 + 1
    small = RecentPayloads(size=10, window=60.0, clock=clock)
    for k in range(100):
        small.first("down", "A", k.to_bytes(4, "big"))
    assert len(small) == 10 and not small.first("down", "A", (99).to_bytes(4, "big"))
