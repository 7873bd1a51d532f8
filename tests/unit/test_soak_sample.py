"""The soak bench's per-process sample: a process that is exiting is gone, not a process of 0 MB."""

from __future__ import annotations

import os
import subprocess
import sys
import time

from zdrone.bench.soak import sample


def test_a_live_process_is_sampled_and_an_exited_one_is_not():
    me = sample(os.getpid())
    assert me is not None and me["rss_mb"] > 1 and me["fds"] > 0 and me["threads"] >= 1
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    try:
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:  # exited, not yet reaped: a zombie that /proc still lists
            state = open(f"/proc/{child.pid}/stat").read().rsplit(")", 1)[1].split()[0]
            if state == "Z":
                break
            time.sleep(0.01)
        assert state == "Z"
        assert sample(child.pid) is None
    finally:
        child.wait()
