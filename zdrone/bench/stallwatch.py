"""Where a host's loop waits: a watch on the drones host's steps (testbed).

A thread looks at the loop every ``period`` seconds; when one drone's step has run longer than
``threshold``, it takes the loop thread's Python stack once for that step (the innermost frames: the
call that waits), and, with ``native``, a ``py-spy dump --native`` of the process (the threads' native
stacks: what the Zenoh call waits on). A watch that is itself late by much more than its period says
the waiting call held the GIL. Reported in ``zdrone bench scale``'s ``drones_host_slow.stalls``.
"""

from __future__ import annotations

import gc
import os
import shutil
import subprocess
import sys
import threading
import time
import traceback
from pathlib import Path
from typing import Any

MAX_STALLS = 8  # stalls kept (the first ones; every later one is counted)


class StallWatch:
    """Watches ``begin``/``end`` of the loop's steps from a thread of its own."""

    def __init__(self, threshold: float = 0.2, period: float = 0.02, native_dir: str | None = None) -> None:
        self.threshold, self.period = threshold, period
        self.pyspy = shutil.which("py-spy") or shutil.which("py-spy", path=str(Path(sys.executable).parent))
        self.native_dir = native_dir if native_dir and self.pyspy else None
        self._loop_ident = threading.get_ident()
        self._step: tuple[str, float, int] | None = None  # (node, started, serial)
        self._serial = 0
        self._taken = -1  # the serial of the step last taken
        self.stalls: list[dict[str, Any]] = []
        self.count = 0
        self.worst_watch_late_s = 0.0  # the watch's own worst lateness (long: the GIL was held)
        self.gc = GcClock()
        self._running = True
        self._thread = threading.Thread(target=self._run, name="zdrone-stallwatch", daemon=True)
        self._thread.start()

    def begin(self, node: str) -> None:
        self._serial += 1
        self._step = (node, time.monotonic(), self._serial)

    def end(self) -> None:
        self._step = None

    def close(self) -> None:
        self._running = False
        self.gc.close()

    def _run(self) -> None:
        last = time.monotonic()
        while self._running:
            time.sleep(self.period)
            now = time.monotonic()
            self.worst_watch_late_s = max(self.worst_watch_late_s, now - last - self.period)
            last = now
            step = self._step
            if step is None or step[2] == self._taken or now - step[1] < self.threshold:
                continue
            self._taken = step[2]
            if len(self.stalls) < MAX_STALLS:
                self.stalls.append(self._take(step, now))
            self.count += 1  # after the stall is kept: whoever sees the count sees the stall

    def _take(self, step: tuple[str, float, int], now: float) -> dict[str, Any]:
        """The loop thread's innermost frames now (and, with ``native_dir``, py-spy's dump)."""
        frame = sys._current_frames().get(self._loop_ident)
        frames = [f"{Path(f.filename).name}:{f.lineno} {f.name}" for f in traceback.extract_stack(frame)[-8:]] if frame else []
        stall: dict[str, Any] = {"node": step[0], "seen_after_s": round(now - step[1], 3), "frames": frames}
        if self.native_dir is not None:
            out = Path(self.native_dir, f"stall-{self.count + 1}.txt")
            with open(out, "w") as f:
                subprocess.run([str(self.pyspy), "dump", "--native", "--pid", str(os.getpid())], stdout=f,
                               stderr=subprocess.STDOUT, timeout=20, check=False)
            stall["native"] = str(out)
        return stall

    def report(self) -> dict[str, Any]:
        return {"stalls": self.stalls, "stalls_seen": self.count, "watch_late_worst_s": round(self.worst_watch_late_s, 3),
                **self.gc.report()}


class GcClock:
    """The process's garbage collections: the longest of each generation and their total (a
    collection holds the GIL: every thread of the process waits for it)."""

    def __init__(self) -> None:
        self.worst_s = [0.0, 0.0, 0.0]
        self.total_s = 0.0
        self._start = 0.0
        gc.callbacks.append(self._on_gc)

    def close(self) -> None:
        if self._on_gc in gc.callbacks:
            gc.callbacks.remove(self._on_gc)

    def _on_gc(self, phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            self._start = time.monotonic()
            return
        took = time.monotonic() - self._start
        self.total_s += took
        g = info.get("generation", 0)
        self.worst_s[g] = max(self.worst_s[g], took)

    def report(self) -> dict[str, Any]:
        return {"gc_worst_s": [round(x, 3) for x in self.worst_s], "gc_total_s": round(self.total_s, 2)}


def _schedstat() -> tuple[float, float]:
    """The calling thread's time on a CPU and waiting on a run queue, in seconds (0, 0 if unknown)."""
    try:
        on_cpu, runq, _ = open("/proc/thread-self/schedstat").read().split()
        return int(on_cpu) / 1e9, int(runq) / 1e9
    except (OSError, ValueError):
        return 0.0, 0.0


def _steal() -> float:
    """The machine's stolen time so far (a virtual CPU the hypervisor did not run), in CPU-seconds."""
    try:
        fields = open("/proc/stat").readline().split()
        return int(fields[8]) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return 0.0


class PassClock:
    """Where a slow pass's wall time went: the loop thread on a CPU, waiting for one (run queue), the
    machine's stolen time, the whole process's CPU. Neither on a CPU nor queued: the thread slept
    (a lock, a futex). Kept for the ``MAX_STALLS`` slowest passes over ``threshold``."""

    def __init__(self, threshold: float = 0.5, on: bool = True) -> None:
        self.threshold = threshold
        self.on = on  # off: begin and end do nothing
        self.slow: list[dict[str, float]] = []
        self._start = (0.0, 0.0, 0.0, 0.0, 0.0)

    def begin(self) -> None:
        if self.on:
            self._start = (time.monotonic(), *_schedstat(), _steal(), time.process_time())

    def end(self, after_takeoff_s: float) -> None:
        if not self.on:
            return
        wall = time.monotonic() - self._start[0]
        if wall < self.threshold:
            return
        cpu, runq = _schedstat()
        self.slow.append({"after_takeoff_s": round(after_takeoff_s, 2), "wall_s": round(wall, 3),
                          "loop_on_cpu_s": round(cpu - self._start[1], 3), "loop_run_queue_s": round(runq - self._start[2], 3),
                          "steal_s": round(_steal() - self._start[3], 2),
                          "process_cpu_s": round(time.process_time() - self._start[4], 3)})
        self.slow = sorted(self.slow, key=lambda x: -x["wall_s"])[:MAX_STALLS]


class LoopTimer:
    """Where a ground station's loop spends a slow pass (testbed: the stations host runs three GSs in
    threads of one process). ``watch(station)`` wraps the station's own methods on the instance: the
    time between one wait for input (``drain``) and the next is the pass's work; ``step`` (timers:
    heartbeats, commands), ``print_view`` and ``status`` are timed on their own. Keeps, per method, the
    longest call and when (seconds after ``mark``), and the ``MAX_STALLS`` slowest passes over
    ``threshold`` with what they spent their time in."""

    TIMED = ("step", "print_view", "status", "drain")

    def __init__(self, threshold: float = 0.2) -> None:
        self.threshold = threshold
        self.t0: float | None = None
        self.worst: dict[str, dict[str, Any]] = {}
        self.slow: list[dict[str, Any]] = []
        self.passes_over = 0
        self._lock = threading.Lock()

    def mark(self) -> None:
        """Take-off: times are given after it (before it: negative)."""
        self.t0 = time.monotonic()

    def _after(self, t: float) -> float:
        return round(t - (self.t0 if self.t0 is not None else t), 2)

    def watch(self, station: Any) -> None:
        name = station.name
        parts: dict[str, float] = {}
        last_drain_end = [0.0]

        def timed(method: str, fn: Any) -> Any:
            def call(*args: Any, **kw: Any) -> Any:
                start = time.monotonic()
                if method == "drain" and last_drain_end[0]:
                    self._pass(name, start - last_drain_end[0], parts)
                    parts.clear()
                try:
                    return fn(*args, **kw)
                finally:
                    end = time.monotonic()
                    took = end - start
                    if method == "drain":
                        last_drain_end[0] = end
                    else:
                        parts[method] = parts.get(method, 0.0) + took
                    key = f"{name}.{method}"
                    with self._lock:
                        if took > self.worst.get(key, {}).get("s", 0.0):
                            self.worst[key] = {"s": round(took, 3), "after_takeoff_s": self._after(start)}
            return call

        for method in self.TIMED:
            setattr(station, method, timed(method, getattr(station, method)))

    def _pass(self, name: str, work: float, parts: dict[str, float]) -> None:
        if work < self.threshold:
            return
        with self._lock:
            self.passes_over += 1
            entry = {"gs": name, "after_takeoff_s": self._after(time.monotonic()), "work_s": round(work, 3),
                     **{k: round(v, 3) for k, v in parts.items()}}
            self.slow.append(entry)
            self.slow.sort(key=lambda e: -e["work_s"])
            del self.slow[MAX_STALLS:]

    def report(self) -> dict[str, Any]:
        with self._lock:
            return {"worst": dict(sorted(self.worst.items())), "threshold_s": self.threshold, "slow_passes_seen": self.passes_over,
                    "slow_passes": list(self.slow)}


def cpu_seconds(pid: int) -> float | None:
    """User + system CPU time of a live process (all its threads), from ``/proc/<pid>/stat``."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime, stime
    except (OSError, IndexError, ValueError):
        return None


def run_queue_seconds(pid: int) -> float | None:
    """How long a live process's threads have waited, all together, for a CPU while runnable (the
    second field of each ``/proc/<pid>/task/<tid>/schedstat``): a process starved by others shows here,
    one idle or blocked on a lock does not."""
    try:
        tasks = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return None
    total = 0
    for tid in tasks:
        try:
            total += int(Path(f"/proc/{pid}/task/{tid}/schedstat").read_text().split()[1])
        except (OSError, IndexError, ValueError):
            continue  # a thread that ended meanwhile
    return total / 1e9


class CpuSampler:
    """The processes' CPU over time (testbed): every ``period`` s, from ``/proc/<pid>/stat`` and each
    thread's ``schedstat``, until ``close``. Reported per process: its busiest ``window``-second
    stretches (the share of one core, and when, in seconds after ``t0``), how long it ran above 90 % of a
    core, and its stretches of the longest wait for a CPU (``waited``: thread-seconds waited per second,
    the run queue's share): a router that pauses its forwarding for lack of a CPU waits there, one that
    pauses while idle (a lock, its own work) does not."""

    def __init__(self, pids: dict[str, int], period: float = 0.1, window: float = 0.5) -> None:
        self.pids, self.period, self.window = dict(pids), period, window
        # (monotonic, cpu seconds, run-queue seconds)
        self.samples: dict[str, list[tuple[float, float, float]]] = {n: [] for n in pids}
        self._running = True
        self._thread = threading.Thread(target=self._run, name="zdrone-cpusampler", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while self._running:
            now = time.monotonic()
            for name, pid in self.pids.items():
                if (cpu := cpu_seconds(pid)) is not None:
                    self.samples[name].append((now, cpu, run_queue_seconds(pid) or 0.0))
            time.sleep(self.period)

    def close(self) -> None:
        self._running = False
        self._thread.join(2.0)

    def _top(self, windows: list[tuple[float, float]], top: int) -> list[tuple[float, float]]:
        picked: list[tuple[float, float]] = []
        for share, at in sorted(windows, reverse=True):  # the largest, not overlapping each other
            if all(abs(at - p) >= self.window for _, p in picked):
                picked.append((share, at))
            if len(picked) == top:
                break
        return picked

    @staticmethod
    def _monotone(xs: list[tuple[float, float, float]]) -> list[tuple[float, float, float]]:
        """The samples with the run-queue time made cumulative over the process's life: a thread that
        ended takes its wait out of the sum of the live ones (a drop is counted as no wait)."""
        out: list[tuple[float, float, float]] = []
        for t, cpu, wait in xs:
            if not out:
                out.append((t, cpu, 0.0))
            else:
                out.append((t, cpu, out[-1][2] + max(0.0, wait - prev)))
            prev = wait
        return out

    def report(self, t0: float, top: int = 5) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for name, raw in self.samples.items():
            xs = self._monotone(raw)
            cpu_w: list[tuple[float, float]] = []  # (share of a core, start after t0)
            wait_w: list[tuple[float, float]] = []  # (thread-seconds waited per second, start after t0)
            busy_s = 0.0
            j = 0
            for i in range(len(xs)):
                while j < len(xs) and xs[j][0] - xs[i][0] < self.window:
                    j += 1
                if j >= len(xs):
                    break
                span = xs[j][0] - xs[i][0]
                cpu_w.append(((xs[j][1] - xs[i][1]) / span, xs[i][0] - t0))
                wait_w.append(((xs[j][2] - xs[i][2]) / span, xs[i][0] - t0))
            for (ta, ca, _), (tb, cb, _) in zip(xs, xs[1:]):
                if tb > ta and (cb - ca) / (tb - ta) > 0.9:
                    busy_s += tb - ta
            waited = (xs[-1][2] - xs[0][2]) / (xs[-1][0] - xs[0][0]) if len(xs) > 1 and xs[-1][0] > xs[0][0] else 0.0
            out[name] = {"busiest": [{"core_share": round(s, 2), "after_takeoff_s": round(a, 2)} for s, a in self._top(cpu_w, top)],
                         "over_90_percent_s": round(busy_s, 1),
                         "waited_mean": round(waited, 2),
                         "waited_most": [{"waited": round(s, 2), "after_takeoff_s": round(a, 2)} for s, a in self._top(wait_w, top)]}
        return out

    def around(self, t0: float, at: float, before: float = 2.0) -> dict[str, Any]:
        """Each process's CPU share and wait for a CPU over the ``before`` seconds up to ``at`` (seconds
        after ``t0``): what the machine did during a silence that ended then."""
        out: dict[str, Any] = {}
        for name, raw in self.samples.items():
            inside = self._monotone([x for x in raw if t0 + at - before <= x[0] <= t0 + at])
            if len(inside) < 2 or inside[-1][0] <= inside[0][0]:
                continue
            span = inside[-1][0] - inside[0][0]
            out[name] = {"core_share": round((inside[-1][1] - inside[0][1]) / span, 2),
                         "waited": round((inside[-1][2] - inside[0][2]) / span, 2)}
        return out


class FrameGaps:
    """Where a silence begins (testbed): the gaps of ``threshold`` s or more between one sender's
    consecutive frames to one receiver, noted at one point of their way (a GS's put, a drone's
    Zenoh callback), with the moment each gap ended (``time.monotonic``, the same clock in every
    process of the machine). A silence a drone's loop sees but its callback did not began after Zenoh
    delivered; one the callback saw and the GS's puts did not, between the two processes (the GSs
    host's Zenoh, the routers, the drones host's Zenoh); one at the puts, in the GS."""

    def __init__(self, threshold: float = 0.7, cap: int = 20_000) -> None:
        self.threshold, self.cap = threshold, cap
        self._last: dict[tuple[str, str], float] = {}
        self._lock = threading.Lock()
        self.gaps: list[tuple[str, str, float, float]] = []  # (sender, receiver, gap s, ended at)
        self.over_cap = 0

    def note(self, sender: str, receiver: str, now: float) -> None:
        key = (sender, receiver)
        with self._lock:
            last = self._last.get(key)
            self._last[key] = now
            if last is not None and now - last >= self.threshold:
                if len(self.gaps) < self.cap:
                    self.gaps.append((sender, receiver, round(now - last, 3), round(now, 3)))
                else:
                    self.over_cap += 1

    def report(self) -> dict[str, Any]:
        with self._lock:
            return {"threshold_s": self.threshold, "gaps": list(self.gaps), "over_cap": self.over_cap}
