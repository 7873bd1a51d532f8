"""A process of the testbed that crashes leaves its stacks, and the signal is reported.

``zdrone bench sweep --quick`` once died of SIGSEGV with nothing printed: no process had faulthandler
on. Each test here crashes a process (``ctypes.string_at(0)``: a read of address 0) started the way
the testbed starts it, from an environment without ``PYTHONFAULTHANDLER``, and checks that its
Python stacks are in its output and that whoever started it names the signal.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from zdrone import crashes
from zdrone.sil import procs
from zdrone.sil.launcher import Demo, DemoOptions

#: a child that crashes two calls deep (in a function whose name must appear in its stacks)
CRASHER = """
import ctypes, time
def deep_in_the_testbed():
    ctypes.string_at(0)
def flying():
    time.sleep(0.1)
    deep_in_the_testbed()
flying()
"""


def _env_without_faulthandler() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if k != crashes.ENV}


def _wait(proc: subprocess.Popen, timeout: float = 30.0) -> int:
    code = proc.wait(timeout)
    procs.forget(proc)
    return code


def test_a_child_spawned_like_the_testbeds_leaves_its_stacks_and_the_signal_is_named(tmp_path: Path):
    log = tmp_path / "child.log"
    with open(log, "w") as fh:
        proc = procs.spawn([sys.executable, "-c", CRASHER], stdout=fh, stderr=subprocess.STDOUT,
                           stdin=subprocess.DEVNULL, env=_env_without_faulthandler())
    assert _wait(proc) == -signal.SIGSEGV
    out = log.read_text()
    assert "Segmentation fault" in out and "deep_in_the_testbed" in out and "flying" in out, out
    report = crashes.crash_report("child", proc.returncode, out)
    assert report is not None and report.startswith("child crashed: SIGSEGV (-11)")
    assert "deep_in_the_testbed" in report


def test_the_launcher_notes_a_crashed_child_with_its_signal_and_stacks(tmp_path: Path):
    """A ground station that crashes mid-flight: at the end its exit code says SIGSEGV and the run's
    notes carry the end of its log (its stacks)."""
    demo = Demo(DemoOptions(out=tmp_path), tmp_path)
    child = demo.start("gsA", ["-c", CRASHER])  # as the launcher starts every node: PY + args, log in the run
    deadline = time.monotonic() + 30
    while child.proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    codes = demo.shutdown(timeout=5)
    assert codes == {"gsA": -signal.SIGSEGV}
    [note] = [n for n in demo.notes if n.startswith("gsA crashed: SIGSEGV (-11)")]
    assert "Segmentation fault" in note and "deep_in_the_testbed" in note


def test_the_zdrone_command_and_what_it_starts_leave_their_stacks(tmp_path: Path):
    """The ``zdrone`` entry point turns faulthandler on for itself (a crash in a worker thread, as in a
    bench's flights) and for every Python process it starts, by whatever means."""
    code = """
import subprocess, sys, threading, ctypes
import zdrone.cli as cli
def crash_in_a_worker(args):
    subprocess.run([sys.executable, "-c", "import ctypes\\ndef grandchild_crash():\\n    ctypes.string_at(0)\\ngrandchild_crash()"])
    t = threading.Thread(target=lambda: ctypes.string_at(0), name="sweep-worker")
    t.start()
    t.join()
    return 0
cli.run_parsed = crash_in_a_worker
sys.exit(cli.main(["fleet", "show", "--dir", "nowhere"]))
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                         env=_env_without_faulthandler(), cwd=tmp_path)
    assert out.returncode == -signal.SIGSEGV, (out.returncode, out.stderr)
    assert out.stderr.count("Segmentation fault") == 2, out.stderr  # the grandchild's, then its own
    assert "grandchild_crash" in out.stderr and "crash_in_a_worker" in out.stderr, out.stderr


def test_exit_codes_in_words():
    assert crashes.exit_text(0) == "0" and crashes.exit_text(3) == "3" and crashes.exit_text(None) == "still running"
    assert crashes.exit_text(-11) == "SIGSEGV (-11)" and crashes.exit_text(-9) == "SIGKILL (-9)"
    assert crashes.crashed(-6) and crashes.crashed(-11) and not crashes.crashed(-9) and not crashes.crashed(-15)
    assert crashes.crash_report("router", -15, "stopped") is None  # a signal we send is no crash
    assert crashes.crash_report("router", 1, "error") is None
    assert crashes.crash_report("sim", -11, "") == "sim crashed: SIGSEGV (-11); its output ends:\n(nothing)"
