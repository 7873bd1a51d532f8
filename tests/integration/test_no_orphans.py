"""No process of a run is left, however ``zdrone demo`` or a bench ends: a child that fails to start,
an exception, SIGINT, SIGTERM, SIGHUP, and SIGKILL of the launcher itself (its children die with
it). A normal end is checked by the reference flight (``test_nominal_reference_flight``). After
each, every process of the run is gone within 5 s of the end."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.procs import ZDRONE, spawn, wait_until
from zdrone.sil import procs
from zdrone.sil.launcher import Demo, DemoOptions, Scenario, flight_unaffected

GONE_WITHIN_S = 5.0


def processes_of(run: Path) -> list[str]:
    """The processes working in the run's folder (every child of the launcher runs there), with
    their command lines."""
    found = []
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            if os.readlink(f"/proc/{pid}/cwd") == str(run):
                cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
                found.append(f"{pid} {cmd[:120]}")
        except OSError:
            pass
    return found


def left_after(run: Path, since: float) -> list[str]:
    """The run's processes still there ``GONE_WITHIN_S`` after ``since`` ([] as soon as none is)."""
    wait_until(lambda: not processes_of(run), max(0.0, since + GONE_WITHIN_S - time.monotonic()), 0.1)
    return processes_of(run)


@pytest.fixture
def run_dir(tmp_path: Path):
    run = (tmp_path / "run").resolve()
    yield run
    procs.stop_all()  # an in-process Demo that failed this test must not leave its children either
    for line in processes_of(run):  # nor a subprocess one: by PID, only this run's
        try:
            os.kill(int(line.split()[0]), signal.SIGKILL)
        except ProcessLookupError:
            pass


EXIT_CODE = {signal.SIGINT: 130, signal.SIGTERM: 128 + signal.SIGTERM, signal.SIGHUP: 128 + signal.SIGHUP,
             signal.SIGKILL: -signal.SIGKILL}


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGKILL],
                         ids=lambda s: signal.Signals(s).name)
def test_a_signal_to_the_demo_in_flight_leaves_no_process(run_dir, sig):
    """Router, simulator, drone, GS B and GS A are up and the flight is going (A holds authority);
    the signal reaches the launcher only (as from timeout(1), systemd, a CI cancellation, a closed
    terminal, or the OOM killer)."""
    with spawn(ZDRONE, "demo", "--out", str(run_dir), "--no-live", "--no-report", "--speedup", "4") as demo:
        demo.wait_line("authority None -> A", 120)
        running = processes_of(run_dir)
        assert len(running) == 5, running
        for node in ("drone --id d1 --fleet bundles/d1", "gs --id A --fleet bundles/A", "gs --id B --fleet bundles/B",
                     "router -c bundles/router/router/router.json5"):  # each from its own bundle alone
            assert any(node in cmd for cmd in running), (node, running)
        sent = time.monotonic()
        demo.p.send_signal(sig)
        rc = demo.p.wait(30)
    assert rc == EXIT_CODE[sig], "".join(demo.lines[-20:])
    assert left_after(run_dir, sent) == []


@pytest.mark.slow
def test_a_child_that_fails_to_start_leaves_no_process(run_dir):
    """The drone node refuses its options after the router and the simulator are up."""
    proc = subprocess.run([ZDRONE, "demo", "--out", str(run_dir), "--no-live", "--no-report", "--radio=--sil-loss=2"],
                          capture_output=True, text=True, timeout=120)
    ended = time.monotonic()
    assert proc.returncode == 1 and "drone exited (2)" in proc.stderr, proc.stderr
    assert left_after(run_dir, ended) == []


@pytest.mark.slow
def test_a_ground_station_refusing_its_options_leaves_no_process(run_dir):
    """``Demo.run`` as the benches call it: GS A refuses its options when router, simulator, drone
    and GS B are up; the exception goes on, and nothing is left running."""
    spec = Scenario("bad-gs-a", "GS A refuses its options", "-", flight_unaffected, gs_a_extra=("--no-such-option",))
    demo = Demo(DemoOptions(out=run_dir, spec=spec, speedup=4.0, quiet=True, live=False, report=False), run_dir)
    run_dir.mkdir(parents=True)
    with pytest.raises(RuntimeError, match="gsA exited"):
        demo.run()
    assert left_after(run_dir, time.monotonic()) == []
    assert procs.live() == []


@pytest.mark.slow
def test_an_exception_in_flight_leaves_no_process(run_dir, monkeypatch):
    """A bug in the watch loop (any exception) in the middle of the flight."""
    def broken(self, ev, state, live):
        raise ValueError("a bug in the watch loop")

    monkeypatch.setattr(Demo, "_on_event", broken)
    demo = Demo(DemoOptions(out=run_dir, speedup=4.0, quiet=True, live=False, report=False), run_dir)
    run_dir.mkdir(parents=True)
    with pytest.raises(ValueError, match="a bug"):
        demo.run()
    assert left_after(run_dir, time.monotonic()) == []
    assert procs.live() == []


def descendants(pid: int) -> dict[int, str]:
    """Every process below ``pid`` (by parent PID), with its start time (a PID is only reused by a
    process with another start time)."""
    parent: dict[int, int] = {}
    start: dict[int, str] = {}
    for p in os.listdir("/proc"):
        if p.isdigit():
            try:
                fields = Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            parent[int(p)], start[int(p)] = int(fields[1]), fields[19]
    found: dict[int, str] = {}
    todo = [pid]
    while todo:
        here = todo.pop()
        for child, ppid in parent.items():
            if ppid == here and child not in found:
                found[child] = start[child]
                todo.append(child)
    return found


def still_running(procs_: dict[int, str]) -> list[int]:
    alive = []
    for pid, started in procs_.items():
        try:
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if fields[19] == started and fields[0] != "Z":
            alive.append(pid)
    return alive


@pytest.mark.slow
def test_sigterm_to_a_bench_in_flight_leaves_no_process():
    """``zdrone bench handover``: its flight's five processes are up when SIGTERM comes."""
    with spawn(ZDRONE, "bench", "handover", "--quick", "--json") as bench:
        up = wait_until(lambda: bench.p.poll() is not None or len(descendants(bench.p.pid)) >= 5, 120, 0.2)
        children = descendants(bench.p.pid)
        assert up and bench.p.poll() is None and len(children) >= 5, "".join(bench.lines[-20:])
        sent = time.monotonic()
        bench.p.send_signal(signal.SIGTERM)
        rc = bench.p.wait(30)
    assert rc == 128 + signal.SIGTERM, "".join(bench.lines[-20:])
    wait_until(lambda: not still_running(children), max(0.0, sent + GONE_WITHIN_S - time.monotonic()), 0.1)
    assert still_running(children) == []


def test_a_child_dies_with_its_launcher_killed_outright(tmp_path):
    """The kernel's part alone: a launcher killed with SIGKILL runs no code, and what it started
    through ``procs.spawn`` dies with it (Linux: the parent-death signal)."""
    if not sys.platform.startswith("linux"):
        pytest.skip("the parent-death signal is Linux only")
    script = ("import signal, subprocess, sys\n"
              "from zdrone.sil import procs\n"
              "p = procs.spawn([sys.executable, '-c', 'import signal; signal.pause()'], cwd=sys.argv[1])\n"
              "print(p.pid, flush=True)\n"
              "signal.pause()\n")
    run = tmp_path.resolve()
    with spawn(sys.executable, "-c", script, str(run)) as launcher:
        child = int(launcher.wait_line("\n", 30))
        assert processes_of(run), "the child did not start"
        sent = time.monotonic()
        launcher.p.kill()
        launcher.p.wait(10)
    assert left_after(run, sent) == [], f"child {child} outlived its launcher"
