"""The scale bench's stall watch: where a slow step waits, where a slow pass's time went, collections."""

from __future__ import annotations

import gc
import threading
import time

from zdrone.bench.stallwatch import CpuSampler, FrameGaps, GcClock, LoopTimer, PassClock, StallWatch


def _waits_in_here(seen: threading.Event) -> None:
    assert seen.wait(10.0), "the watch never saw the slow step"


def test_a_slow_step_is_seen_once_with_the_call_it_waits_in():
    watch = StallWatch(threshold=0.05, period=0.01)
    try:
        seen = threading.Event()
        threading.Thread(target=lambda: (_until(lambda: watch.count > 0), seen.set()), daemon=True).start()
        watch.begin("d7")
        _waits_in_here(seen)
        watch.end()
        watch.begin("d8")  # a fast step: nothing
        watch.end()
        report = watch.report()
        assert report["stalls_seen"] == 1
        (stall,) = report["stalls"]
        assert stall["node"] == "d7" and stall["seen_after_s"] >= 0.05
        assert any("_waits_in_here" in f for f in stall["frames"])  # the loop's innermost frames
    finally:
        watch.close()


def _until(cond, timeout: float = 10.0) -> None:
    end = time.monotonic() + timeout
    while not cond() and time.monotonic() < end:
        time.sleep(0.005)


def test_a_slow_pass_says_how_long_the_loop_slept_and_a_fast_one_is_not_kept():
    clock = PassClock(threshold=0.05)
    clock.begin()
    clock.end(1.0)
    assert clock.slow == []
    clock.begin()
    time.sleep(0.1)  # asleep: neither on a CPU nor queued for one
    clock.end(2.0)
    (p,) = clock.slow
    assert p["after_takeoff_s"] == 2.0 and p["wall_s"] >= 0.1
    assert p["loop_on_cpu_s"] < p["wall_s"] and p["process_cpu_s"] < p["wall_s"]


def test_the_collections_are_timed_per_generation():
    clock = GcClock()
    try:
        keep = [[i] for i in range(50_000)]
        gc.collect()
        report = clock.report()
        assert report["gc_worst_s"][2] > 0.0 and report["gc_total_s"] >= report["gc_worst_s"][2] - 0.005
        del keep
    finally:
        clock.close()
    assert clock._on_gc not in gc.callbacks


class _Station:
    """What the loop timer wraps: a ground station's loop methods."""

    name = "A"

    def __init__(self) -> None:
        self.slow_step = 0.0

    def drain(self, timeout: float) -> None:
        time.sleep(timeout)

    def step(self, now: float) -> None:
        time.sleep(self.slow_step)

    def print_view(self, now: float) -> None:
        pass

    def status(self) -> dict:
        return {}

    def run_pass(self) -> None:
        self.drain(0.0)
        self.step(0.0)
        self.status()


def test_a_slow_station_pass_is_kept_with_what_it_spent_its_time_in_and_fast_ones_are_not():
    loops, st = LoopTimer(threshold=0.05), _Station()
    loops.watch(st)
    loops.mark()
    for _ in range(3):
        st.run_pass()
    st.slow_step = 0.08
    st.run_pass()
    st.slow_step = 0.0
    st.run_pass()  # its drain closes the slow pass
    report = loops.report()
    (p,) = report["slow_passes"]
    assert p["gs"] == "A" and p["work_s"] >= 0.08 and p["step"] >= 0.08 and report["slow_passes_seen"] == 1
    assert report["worst"]["A.step"]["s"] >= 0.08 and report["worst"]["A.step"]["after_takeoff_s"] >= 0.0


def test_the_cpu_sampler_finds_the_busy_half_second_of_a_process():
    import os

    sampler = CpuSampler({"me": os.getpid()}, period=0.02, window=0.2)
    t0 = time.monotonic()
    time.sleep(0.3)  # idle
    end = time.monotonic() + 0.4
    while time.monotonic() < end:  # busy: one core
        pass
    time.sleep(0.1)
    sampler.close()
    report = sampler.report(t0)["me"]
    best = report["busiest"][0]  # (the suite's load may give the busy loop less than a core: no share asserted)
    assert best["core_share"] > 0.1 and 0.1 <= best["after_takeoff_s"] <= 0.7, report
    assert report["over_90_percent_s"] >= 0.0 and len(report["busiest"]) >= 1


def test_the_cpu_sampler_sees_a_process_wait_for_a_cpu_it_shares():
    """Two busy processes on one CPU: each runs about half the time and waits the other half."""
    import os
    import subprocess
    import sys

    cpu = min(os.sched_getaffinity(0))
    spin = "import os, time\nos.sched_setaffinity(0, {%d})\nend = time.monotonic() + 1.2\nwhile time.monotonic() < end: pass\n" % cpu
    procs = [subprocess.Popen([sys.executable, "-c", spin]) for _ in range(2)]
    try:
        sampler = CpuSampler({"one": procs[0].pid, "two": procs[1].pid}, period=0.05, window=0.3)
        t0 = time.monotonic()
        for p in procs:
            p.wait(10)
        sampler.close()
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
    report = sampler.report(t0)
    waited = [report[n]["waited_most"][0]["waited"] for n in ("one", "two")]
    assert max(waited) >= 0.2, report  # one core for two: someone waited
    during = sampler.around(t0, 0.8, before=0.6)
    assert set(during) <= {"one", "two"} and all(v["core_share"] <= 1.05 for v in during.values()), during


def test_frame_gaps_keep_each_senders_long_gaps_to_each_receiver_with_their_end():
    gaps = FrameGaps(threshold=0.7, cap=2)
    for sender, receiver, t in [("B", "d1", 10.0), ("B", "d1", 10.5), ("B", "d2", 10.6), ("B", "d1", 11.3),
                                ("A", "d1", 11.4), ("B", "d2", 12.0), ("B", "d1", 13.0)]:
        gaps.note(sender, receiver, t)
    report = gaps.report()
    # B -> d1: 0.5 (short), 0.8 (kept, ended at 11.3); B -> d2: 1.4 (kept); B -> d1 1.7: over the cap, counted
    assert report["gaps"] == [("B", "d1", 0.8, 11.3), ("B", "d2", 1.4, 12.0)] and report["over_cap"] == 1
