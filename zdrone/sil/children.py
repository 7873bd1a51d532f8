"""TESTBED: the child processes of a run (``Demo``'s part in them): each started in the run's folder
with its output in ``<name>.log`` (inside a network namespace with ``--netns``), dying with the launcher
however it ends (``zdrone.sil.procs``); waiting for a line in its log, restarting it (a fault), and
stopping them all in order at the end, the nodes before the simulator and the routers.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from zdrone.sil import procs
from zdrone.sil.netns import NetnsTopology

#: The interpreter every child runs in (this one).
PY = sys.executable


@dataclass
class Child:
    name: str
    proc: subprocess.Popen
    log: Path
    stopped: bool = False
    args: list[str] = field(default_factory=list)
    ns: str | None = None  # the network namespace it runs in (``--netns``)


class ChildProcesses:
    """``Demo``'s child processes, by name in ``children``. A mixin: the run's ``Demo`` holds the state
    (its dataclass fields named here) and ``close_links``, which the shutdown calls last."""

    out: Path
    children: dict[str, Child]
    notes: list[str]
    restarting: dict[str, tuple[str, int]]  # restarted child -> (ready line, count before)
    netns: NetnsTopology | None

    def start(self, name: str, args: list[str], append: bool = False, ns: str | None = None) -> Child:
        log = self.out / f"{name}.log"
        fh = open(log, "a" if append else "w")
        prefix = self.netns.exec_prefix(ns) if (ns and self.netns) else []  # ``ip netns exec`` execs: same PID
        try:  # dies with the launcher, however it ends (zdrone.sil.procs)
            proc = procs.spawn([*prefix, PY, *args], stdout=fh, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                               cwd=self.out)
        finally:
            fh.close()
        child = Child(name, proc, log, args=list(args), ns=ns)
        self.children[name] = child
        return child

    def restart(self, name: str, down: float) -> None:
        """Kill ``name`` (SIGKILL), wait ``down`` seconds, start it again with the same arguments."""
        child = self.children[name]
        if child.proc.poll() is None:
            os.kill(child.proc.pid, signal.SIGKILL)
        child.proc.wait(5.0)
        time.sleep(down)
        needle = _ready_line(name)
        if needle:
            self.restarting[name] = (needle, child.log.read_text(errors="replace").count(needle))
        self.start(name, child.args, append=True, ns=child.ns)

    def _wait_restarted(self, timeout: float) -> None:
        """Before the end: every restarted child has finished starting (its ready line is there again),
        so that SIGTERM finds its handler in place (a router stopped mid-start dies of the signal)."""
        deadline = time.monotonic() + timeout
        for name, (needle, before) in self.restarting.items():
            child = self.children[name]
            while time.monotonic() < deadline and child.proc.poll() is None:
                if child.log.read_text(errors="replace").count(needle) > before:
                    break
                time.sleep(0.05)
        self.restarting.clear()

    def wait_line(self, child: Child, needle: str, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if needle in child.log.read_text(errors="replace"):
                return
            if child.proc.poll() is not None:
                raise RuntimeError(f"{child.name} exited ({child.proc.returncode}): {child.log.read_text()[-600:]}")
            time.sleep(0.05)
        raise RuntimeError(f"{child.name}: {needle!r} not seen within {timeout:.0f} s")

    def _wait_more(self, child: Child, needle: str, before: int, timeout: float) -> None:
        """Wait until ``child``'s log holds ``needle`` more than ``before`` times (a log that an
        earlier process of the same name began)."""
        deadline = time.monotonic() + timeout
        while child.log.read_text(errors="replace").count(needle) <= before:
            if child.proc.poll() is not None:
                raise RuntimeError(f"{child.name} exited ({child.proc.returncode}): {child.log.read_text()[-600:]}")
            if time.monotonic() > deadline:
                raise RuntimeError(f"{child.name}: {needle!r} not seen again within {timeout:.0f} s")
            time.sleep(0.02)

    def signal(self, name: str, sig: int) -> None:
        child = self.children.get(name)
        if child is not None and child.proc.poll() is None:
            os.kill(child.proc.pid, sig)

    def shutdown(self, timeout: float = 10.0) -> dict[str, int | None]:
        """SIGTERM the nodes first (so they close their sessions while the router is still up), then
        the simulator and the router; SIGKILL only what does not exit in time, and a node the scenario
        left stopped (hung to the end: woken, it would act on a view the run left long ago); return
        exit codes."""
        codes: dict[str, int | None] = {}
        self._wait_restarted(timeout)
        nodes = [c for n, c in self.children.items() if n != "sim" and not n.startswith("router")]
        infra = [c for n, c in self.children.items() if n == "sim" or n.startswith("router")]
        for group in (nodes, infra):
            for child in reversed(group):
                if child.proc.poll() is None:
                    try:
                        if child.stopped:  # hung on purpose to the end: woken, it would act on a view the
                            child.proc.kill()  # run left long ago (a stopped owner re-pairing a landed drone)
                        else:
                            os.kill(child.proc.pid, signal.SIGCONT)  # a stopped process cannot handle SIGTERM
                            child.proc.terminate()
                    except ProcessLookupError:
                        pass
            deadline = time.monotonic() + timeout
            for child in group:
                try:
                    child.proc.wait(max(0.1, deadline - time.monotonic()))
                except subprocess.TimeoutExpired:
                    try:
                        os.kill(child.proc.pid, signal.SIGUSR1)  # its stacks go to its log, for diagnosis
                        time.sleep(0.25)
                    except ProcessLookupError:
                        pass
                    child.proc.kill()
                    child.proc.wait(5)
                    self.notes.append(f"{child.name} had to be killed (stacks in {child.log.name})")
                procs.forget(child.proc)
                codes[child.name] = child.proc.returncode
        self._report_crashes(codes)
        self.close_links()
        return {n: codes.get(n) for n in self.children}

    def _report_crashes(self, codes: dict[str, int | None]) -> None:
        """A child that died of a crash signal (SIGSEGV, SIGABRT, ...): a note with the signal and the
        end of its log, where faulthandler left its stacks (``zdrone.crashes``)."""
        from zdrone.crashes import crash_report

        for name, code in codes.items():
            report = crash_report(name, code, self.children[name].log.read_text(errors="replace"))
            if report is not None:
                self.notes.append(report)


def _ready_line(name: str) -> str | None:
    """What a child's log says once it has started (None: nothing known to wait for)."""
    if name.startswith("router"):
        return "listening"
    if name == "drone":
        return "ready"
    if name.startswith("gs"):
        return f"zdrone gs {name[2:]}"
    return None

def _exit_text(code: int | None) -> str:
    """An exit code in words: ``1``, ``SIGSEGV (-11)``."""
    from zdrone.crashes import exit_text

    return exit_text(code)
