"""Declarations off the loop (``zdrone.net.declarations``): in order, settled, failures counted."""

from __future__ import annotations

import threading

from zdrone.net.declarations import DeclarationThread


def test_calls_run_in_order_in_one_thread_and_settle_waits_for_them() -> None:
    d = DeclarationThread()
    seen: list[tuple[int, str]] = []
    gate = threading.Event()
    d.submit(lambda: gate.wait(5.0))  # the first call holds the thread: the rest wait behind it
    for i in range(5):
        d.submit(lambda i=i: seen.append((i, threading.current_thread().name)))
    assert seen == []
    gate.set()
    assert d.settle(5.0)
    assert [i for i, _ in seen] == [0, 1, 2, 3, 4]
    assert {name for _, name in seen} == {"zdrone-declarations"}


def test_a_call_that_raises_is_counted_and_the_next_still_runs() -> None:
    d = DeclarationThread()
    ran = []

    def boom() -> None:
        raise RuntimeError("session closed")

    d.submit(boom)
    d.submit(lambda: ran.append(1))
    assert d.settle(5.0)
    assert d.failed == 1 and ran == [1]


def test_settle_times_out_while_a_call_is_stuck() -> None:
    d = DeclarationThread()
    gate = threading.Event()
    d.submit(lambda: gate.wait(5.0))
    assert not d.settle(0.05)
    gate.set()
    assert d.settle(5.0)


def test_paced_calls_run_a_steady_interval_apart_and_settle_is_not_paced() -> None:
    import time

    d = DeclarationThread(max_per_s=100.0)
    at: list[float] = []
    started = time.monotonic()
    for _ in range(11):
        d.submit(lambda: at.append(time.monotonic()))
    assert d.settle(5.0)
    assert len(at) == 11 and at[-1] - started >= 0.095  # ten intervals of 10 ms at least
    t = time.monotonic()
    assert d.settle(5.0) and time.monotonic() - t < 1.0  # a settle alone waits for nothing
