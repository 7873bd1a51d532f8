"""TESTBED: the processes that ``zdrone demo`` and the benches start die with them, however they end.

Two mechanisms, one for each way a launcher can end:

* **It ends by itself or by a catchable signal** (a normal end, a child that fails to start, an
  exception, SIGINT, SIGTERM, SIGHUP): ``on_signals`` turns SIGTERM and SIGHUP into ``Terminated``
  (SIGINT already is ``KeyboardInterrupt``), so the ``finally`` blocks run: the launcher stops its
  children in order (nodes first, then the simulator and the router), and ``stop_all`` ends
  whatever any code path left, by PID.
* **It is killed outright** (SIGKILL, an OOM kill, a crash of the interpreter): no code of the
  launcher runs, so every child asks the kernel, between fork and exec, to be sent SIGKILL when the
  thread that started it dies (Linux ``prctl(PR_SET_PDEATHSIG)``; it survives exec). SIGKILL rather
  than SIGTERM because a child may be stopped (SIGSTOP, a hung-GS scenario), and a stopped process
  holds SIGTERM pending forever. A launcher that dies between the fork and the ``prctl`` is caught by
  comparing the parent's PID afterwards. Children are started by the thread that owns the run and
  stops them (a bench's worker thread included), so that thread's end is also the run's end.

Children run in a session of their own (a terminal's Ctrl-C reaches the launcher only, which then
stops them in order). Elsewhere than Linux only the first mechanism exists.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import logging
import os
import select
import signal
import subprocess
import sys
import threading
import time
from types import FrameType
from typing import Any, Callable, Iterator, Sequence

from zdrone.crashes import child_env

log = logging.getLogger(__name__)

_PR_SET_PDEATHSIG = 1
_prctl: Callable[..., int] | None = None
if sys.platform.startswith("linux"):
    try:  # resolved once, here: the child must not look anything up between fork and exec
        _prctl = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True).prctl
    except (OSError, AttributeError):
        _prctl = None

#: every child started through ``spawn`` and not yet seen to end (by PID)
_live: dict[int, subprocess.Popen] = {}
_lock = threading.Lock()


class Terminated(BaseException):
    """SIGTERM or SIGHUP reached the launcher: unwinds like KeyboardInterrupt, so clean-ups run."""

    def __init__(self, signum: int) -> None:
        super().__init__(f"terminated by {signal.Signals(signum).name}")
        self.signum = signum


def _die_with_parent(parent: int) -> Callable[[], None]:
    def arm() -> None:  # runs in the child between fork and exec: no imports, no locks
        if _prctl is not None:
            _prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
            if os.getppid() != parent:  # the launcher died before the prctl took effect
                os.kill(os.getpid(), signal.SIGKILL)

    return arm


def spawn(args: Sequence[str], **popen: Any) -> subprocess.Popen:
    """``subprocess.Popen`` of a child that dies with this process (see the module's text), in a
    session of its own, registered for ``stop_all``; with faulthandler on (``PYTHONFAULTHANDLER``):
    if it crashes, its stacks are in its output (``zdrone.crashes``)."""
    popen.setdefault("start_new_session", True)
    popen["env"] = child_env(popen.get("env"))
    proc = subprocess.Popen(list(args), preexec_fn=_die_with_parent(os.getpid()), **popen)
    with _lock:
        _live[proc.pid] = proc
    return proc


def forget(proc: subprocess.Popen) -> None:
    """``proc`` has ended and been reaped by its owner."""
    with _lock:
        _live.pop(proc.pid, None)


def live() -> list[subprocess.Popen]:
    """The children started through ``spawn`` that are still running."""
    with _lock:
        for pid in [p for p, proc in _live.items() if proc.poll() is not None]:
            del _live[pid]
        return list(_live.values())


def stop_all(timeout: float = 5.0) -> int:
    """End every child still running: SIGCONT + SIGTERM, then SIGKILL after ``timeout``; returns how
    many had to be stopped. The owners' ordered shutdown runs first; this ends what it missed."""
    procs = live()
    for p in procs:
        with contextlib.suppress(ProcessLookupError):
            os.kill(p.pid, signal.SIGCONT)  # a stopped process cannot act on SIGTERM
            p.terminate()
    deadline = time.monotonic() + timeout
    for p in procs:
        try:
            p.wait(max(0.05, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(5)
        forget(p)
    if procs:
        log.warning("stopped %d child process(es) left running: %s", len(procs), ", ".join(str(p.pid) for p in procs))
    return len(procs)


#: the signals a launcher turns into an orderly end
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


@contextlib.contextmanager
def on_signals(signals: Sequence[int] = STOP_SIGNALS) -> Iterator[None]:
    """While inside: SIGINT raises ``KeyboardInterrupt``, SIGTERM and SIGHUP ``Terminated``, in the
    main thread, the first one only (a second signal must not cut the clean-up short: SIGKILL is
    the way to hurry it, and the children die with the launcher then too); on the way out (any way)
    every child still running is stopped. Outside the main thread it only does the latter."""
    previous: dict[int, Any] = {}

    def handler(signum: int, frame: FrameType | None) -> None:
        for s in previous:
            signal.signal(s, signal.SIG_IGN)
        if signum == signal.SIGINT:
            raise KeyboardInterrupt
        raise Terminated(signum)

    if threading.current_thread() is threading.main_thread():
        for s in signals:
            previous[s] = signal.signal(s, handler)
    try:
        yield
    finally:
        try:
            stop_all()
        finally:
            for s, h in previous.items():
                signal.signal(s, h)


def stop_in_order(procs: "dict[str, subprocess.Popen]", order: Sequence[str], grace: float = 20.0) -> None:
    """End the named children in ``order`` (those not running are skipped): SIGTERM, then SIGKILL
    after ``grace`` seconds; each is reaped and forgotten. The benches' ordered shutdown: the nodes
    before their routers, so that they close their sessions while the router is still there."""
    for name in order:
        p = procs.get(name)
        if p is None:
            continue
        if p.poll() is None:
            p.terminate()
            try:
                p.wait(grace)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(5)
        forget(p)


def wait_line(proc: subprocess.Popen, needle: str, timeout: float) -> str:
    """The first line of ``proc``'s output holding ``needle`` (``RuntimeError`` if none in time)."""
    assert proc.stdout is not None
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        ready, _, _ = select.select([proc.stdout], [], [], max(0.0, deadline - time.monotonic()))
        if not ready:
            break
        line = proc.stdout.readline()
        if not line:
            break
        if needle in line:
            return line
    raise RuntimeError(f"no {needle!r} from {proc.args[:4]} within {timeout:.0f} s")
