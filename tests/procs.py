"""Starting and always cleaning up real processes in integration tests."""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any, Callable, Iterator

from zdrone.sil.ports import free_port  # noqa: F401  (the testbed's: outside the ephemeral range)

ZDRONE = str(Path(sys.executable).parent / "zdrone")


class Proc:
    """A child process whose stdout lines are collected on a thread, so tests can wait on them."""

    def __init__(self, args: list[str], env: dict[str, str] | None = None) -> None:
        self.args = args
        self.p = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1,
                                  env={**os.environ, **(env or {})}, start_new_session=True)
        self.lines: list[str] = []
        self._q: queue.Queue[str] = queue.Queue()
        self._t = threading.Thread(target=self._pump, daemon=True)
        self._t.start()

    def _pump(self) -> None:
        assert self.p.stdout is not None
        for line in self.p.stdout:
            self.lines.append(line)
            self._q.put(line)

    def wait_line(self, needle: str, timeout: float) -> str:
        deadline = time.monotonic() + timeout
        for line in list(self.lines):
            if needle in line:
                return line
        while time.monotonic() < deadline:
            try:
                line = self._q.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                break
            if needle in line:
                return line
        raise TimeoutError(f"{needle!r} not seen from {self.args[:3]} in {timeout}s; output:\n{''.join(self.lines[-30:])}")

    def stop(self, timeout: float = 10.0) -> int:
        if self.p.poll() is None:
            self.p.send_signal(signal.SIGTERM)
            try:
                self.p.wait(timeout)
            except subprocess.TimeoutExpired:
                self.p.kill()
                self.p.wait(5)
        self._t.join(2)
        return self.p.returncode


def wait_until(done: Callable[[], Any], timeout: float, step: float = 0.05) -> Any:
    """Poll ``done()`` until it is truthy or ``timeout`` s pass; its last value (falsy on timeout).
    The one place tests wait for a condition they cannot be woken for."""
    deadline = time.monotonic() + timeout
    stop = threading.Event()
    while True:
        value = done()
        if value or time.monotonic() >= deadline:
            return value
        stop.wait(min(step, max(0.0, deadline - time.monotonic())))


@contextlib.contextmanager
def spawn(*args: str, env: dict[str, str] | None = None) -> Iterator[Proc]:
    proc = Proc(list(args), env)
    try:
        yield proc
    finally:
        proc.stop()


def once_per_run(tmp_path_factory: Any, name: str, produce: Callable[[Path], dict]) -> tuple[dict, Path]:
    """``produce(folder)`` once per test run, for every test that shares its outcome (one flight checked
    by several tests), even when they land in different pytest-xdist workers: the first to ask runs it
    under a file lock in the run's common temporary folder, the others wait and read its JSON result.
    A failure is kept too: the others fail with it rather than run it again."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # the folder all workers of this run share
    folder = root / f"shared-{name}"
    with open(root / f"shared-{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        result, failed = folder / "result.json", folder / "failed.txt"
        if result.exists():
            return json.loads(result.read_text()), folder
        if failed.exists():
            raise AssertionError(f"shared run {name} failed (in another test): {failed.read_text()}")
        folder.mkdir(exist_ok=True)
        try:
            value = produce(folder)
        except BaseException as exc:
            failed.write_text(f"{type(exc).__name__}: {exc}"[-4000:])
            raise
        result.write_text(json.dumps(value))
        return value, folder
