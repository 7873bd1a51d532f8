"""A process of the testbed that crashes leaves its stacks, and the signal is reported; and the
crash that ``zdrone bench sweep --quick`` once died of (SIGSEGV, nothing printed) is gone.

The first tests crash a process (``ctypes.string_at(0)``: a read of address 0) started the way the
testbed starts it, from an environment without ``PYTHONFAULTHANDLER``, and check that its Python
stacks are in its output and that whoever started it names the signal.

The sweep's crash, once its stacks were there: its two flights, each in a thread, parsed their
fleets at the same moment, and msgspec builds a Struct type's validation info on the type's first
use, which two threads at once can crash (about one process in five with four threads switching
often). The types are now built at import; the last tests check that parsing builds none, and
parse from many threads at once in fresh processes.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

from zdrone import crashes
from zdrone.fleet.files import init_fleet
from zdrone.sil import procs
from zdrone.sil.launcher import Demo, DemoOptions

#: a child that crashes two calls deep (in a function whose name must appear in its stacks)
CRASHER = """
import ctypes, time
def deep_in_the_testbed():
    ctypes.string_at(0)
def flying():
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
    child.proc.wait(30)  # it crashes by itself
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


#: a fresh process: the testbed's modules imported, then a fleet, a secret and an event log read while a
#: profiler watches msgspec build type info (``get_class_annotations``); a probe type shows it would see it
NO_TYPE_INFO_BUILT = """
import sys, msgspec
from zdrone.fleet.files import load_fleet, load_secret
from zdrone.net.eventlog import EventLog, read_records
from zdrone.core.records import Closed
import zdrone.sil.launcher, zdrone.bench.sweep
class Probe(msgspec.Struct):
    x: int
built = []
def watch(frame, event, arg):
    if event == "call" and frame.f_code.co_name == "get_class_annotations":
        built.append(getattr(frame.f_locals.get("obj"), "__name__", "?"))
fleet, log = sys.argv[1], sys.argv[2]
sys.setprofile(watch)
load_fleet(fleet)
load_secret(fleet, "A")
events = EventLog(log, "A")
events.write_record(Closed())
events.close()
read_records(log)
msgspec.convert({"x": 1}, Probe)
sys.setprofile(None)
print(" ".join(built))
"""


def test_reading_a_fleet_a_secret_or_an_event_log_builds_no_type_info(tmp_path: Path):
    """What a bench's flights parse, each in its own thread, was built at import, in one thread."""
    init_fleet(tmp_path / "fleet")
    out = subprocess.run([sys.executable, "-c", NO_TYPE_INFO_BUILT, str(tmp_path / "fleet"), str(tmp_path / "A.jsonl")],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["Probe"]  # only the probe's, built on its first use


PARSE_FROM_THREADS = """
import sys, threading
sys.setswitchinterval(1e-6)  # threads switch as often as they can: a race shows
from zdrone.core.fleet import parse_fleet
from zdrone.fleet.files import fleet_path, load_secret
fleet = sys.argv[1]
text = fleet_path(fleet).read_text()
barrier = threading.Barrier(8)
def flight():
    barrier.wait()
    parse_fleet(text)
    load_secret(fleet, "A")
threads = [threading.Thread(target=flight) for _ in range(8)]
for t in threads:
    t.start()
for t in threads:
    t.join()
"""


def test_threads_parsing_fleets_at_once_never_crash(tmp_path: Path):
    """The crash itself: before the fix, one process in four to ten died of SIGSEGV here (of eight, at
    least one in most runs; the test above is the one that always tells)."""
    init_fleet(tmp_path / "fleet")
    runs = [subprocess.Popen([sys.executable, "-c", PARSE_FROM_THREADS, str(tmp_path / "fleet")], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True, env=crashes.child_env()) for _ in range(8)]
    for p in runs:
        _, err = p.communicate(timeout=120)
        assert p.returncode == 0, f"{crashes.exit_text(p.returncode)}:\n{err[-3000:]}"
