"""Signals are taken on a thread of their own (``route_signals``): a process whose main thread waits
on an event, in short waits, is sent that event's signal many times and then SIGTERM, and ends every
time. (A Python handler calling ``Event.set`` there can catch the main thread inside the same event's
lock and hang the process for good: an attacker of the testbed did, once in a few hundred runs.)"""

from __future__ import annotations

import os
import signal
import subprocess
import sys

WAITER = r"""
import signal, sys, threading
from zdrone.net.shutdown import route_signals
go, stop = threading.Event(), threading.Event()
seen = [0]
def on_go():
    seen[0] += 1
    go.set()
route_signals({signal.SIGUSR2: on_go, signal.SIGTERM: stop.set})
print("ready", flush=True)
while not stop.is_set():
    go.wait(0.0005)   # the main thread is in go's lock most of the time
    go.clear()
print("stopped", seen[0] > 0, flush=True)
"""


def test_an_event_set_by_a_signal_never_hangs_the_thread_waiting_on_it():
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    p = subprocess.Popen([sys.executable, "-c", WAITER], stdout=subprocess.PIPE, text=True, env=env)
    try:
        assert p.stdout is not None and p.stdout.readline().strip() == "ready"
        for _ in range(3000):
            os.kill(p.pid, signal.SIGUSR2)
        os.kill(p.pid, signal.SIGTERM)
        out, _ = p.communicate(timeout=20)
        assert p.returncode == 0 and out.strip() == "stopped True", out
    finally:
        if p.poll() is None:
            p.kill()
            p.wait(5)
