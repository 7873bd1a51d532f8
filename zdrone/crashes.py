"""A process of zdrone that crashes leaves every thread's Python stack behind, and whoever started it
says which signal ended it.

``stacks_on_crash()`` is the first thing every entry point does (the ``zdrone`` command, the testbed's
attackers and operators, the bench harness): a fatal signal (SIGSEGV, SIGFPE, SIGABRT, SIGBUS,
SIGILL) writes every thread's stack to stderr before the process dies, and ``PYTHONFAULTHANDLER``
goes into the environment so that every Python process it starts (the testbed's children, a
bench's ``multiprocessing`` workers) does the same from its first line. The testbed's launcher
(``zdrone.sil.procs.spawn``) also sets it in each child's own environment.

``exit_text`` and ``crash_report`` turn an exit code into words: a child that died of a signal
nobody sent it on purpose is reported with the end of its output, where its stacks are.
"""

from __future__ import annotations

import faulthandler
import io
import os
import signal

#: the environment variable that turns faulthandler on in a Python process from its start
ENV = "PYTHONFAULTHANDLER"
#: the signals a process dies of when it crashes (faulthandler writes its stacks on each of them)
CRASH_SIGNALS = frozenset({signal.SIGSEGV, signal.SIGFPE, signal.SIGABRT, signal.SIGBUS, signal.SIGILL})


def stacks_on_crash() -> None:
    """Stacks on a crash for this process (unless something, a test runner, already set them up)
    and for every Python process it starts. Never fails: a stderr without a file descriptor (a
    test capturing it) only means no stacks here."""
    if not faulthandler.is_enabled():
        try:
            faulthandler.enable(all_threads=True)
        except (ValueError, OSError, AttributeError, io.UnsupportedOperation):
            pass
    os.environ.setdefault(ENV, "1")


def child_env(env: dict[str, str] | None = None) -> dict[str, str]:
    """The environment for a child process (``env``, or this process's): with faulthandler on."""
    out = dict(os.environ if env is None else env)
    out.setdefault(ENV, "1")
    return out


def exit_text(code: int | None) -> str:
    """``0``, ``3``, ``SIGSEGV (-11)``, ``still running``."""
    if code is None:
        return "still running"
    if code < 0:
        try:
            return f"{signal.Signals(-code).name} ({code})"
        except ValueError:
            return f"signal {-code} ({code})"
    return str(code)


def crashed(code: int | None) -> bool:
    """The process died of a crash signal (not of a SIGTERM or SIGKILL someone sent it)."""
    return code is not None and code < 0 and -code in {int(s) for s in CRASH_SIGNALS}


def crash_report(name: str, code: int | None, output: str, lines: int = 40) -> str | None:
    """For a process that crashed: which signal, and the last ``lines`` of its output (its stacks,
    when faulthandler was on); None for any other end."""
    if not crashed(code):
        return None
    tail = "\n".join(output.rstrip().splitlines()[-lines:])
    return f"{name} crashed: {exit_text(code)}; its output ends:\n{tail or '(nothing)'}"
