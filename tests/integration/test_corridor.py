"""The corridor end to end: eight GSs along 16 km and one drone, as processes (``zdrone demo --scenario
corridor-gs-down``: two site routers, the drones host, the stations host). What only the processes show:
links following the drone over a real Zenoh mesh (prepared, proven, closed), an in-flight GS death in a
shared host. The whole out-and-back (14 hand-overs) flies in memory at speed-ups 4 and 8
(tests/unit/test_corridor_core.py); as processes it takes 220 s of wall time at speed-up 8, more than
this suite's budget allows (``zdrone demo --scenario corridor``, docs/results.md)."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import pytest

from tests.procs import ZDRONE
from zdrone.core import records as rec
from zdrone.net.eventlog import read_records

SPEEDUP = "8"
#: minutes of wall time, little CPU: started first (tests/conftest.py)
pytestmark = [pytest.mark.slow, pytest.mark.longest]


def _fly(tmp_path: Path, scenario: str) -> tuple[subprocess.CompletedProcess, dict, Path]:
    out = tmp_path / scenario
    proc = subprocess.run([ZDRONE, "demo", "--scenario", scenario, "--speedup", SPEEDUP, "--out", str(out)],
                          capture_output=True, text=True, timeout=420)
    assert "Traceback" not in proc.stderr, proc.stderr[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    return proc, summary, Path(summary["run"])


@pytest.mark.skipif(os.environ.get("ZDRONE_CORRIDOR_FULL") != "1",
                    reason="the full out-and-back: 220 s of wall time (ZDRONE_CORRIDOR_FULL=1 flies it)")
def test_the_corridor_hands_over_14_times_with_at_most_three_links(tmp_path: Path) -> None:
    proc, s, run = _fly(tmp_path, "corridor")
    assert proc.returncode == 0 and s["ok"], (s, proc.stdout[-2000:])
    assert s["handovers"] == 14 and s["owners"] == list("ABCDEFGHGFEDCBA")
    assert s["links_max"] <= 3 and s["links_closed"] >= 6 and s["landed"]
    stations = json.loads((run / "stations.json").read_text())["counters"]
    # the other end: a GS the drone let go wipes its key (by the drone's notice, or once silent 105 s:
    # at speed-up 8 the flight is over before most are; tests/unit/test_corridor_core.py waits for all)
    assert sum(c.get("link_wiped", 0) for c in stations.values()) >= 1, stations
    closed = [r for r in read_records(run / "d1.jsonl").records if isinstance(r, rec.LinkClosedNote)]
    assert len(closed) == s["links_closed"]


def test_a_gs_dying_in_the_middle_hands_the_drone_to_a_covering_heir_or_lands_it(tmp_path: Path) -> None:
    proc, s, run = _fly(tmp_path, "corridor-gs-down")
    assert proc.returncode == 0 and s["ok"], (s, proc.stdout[-2000:])
    killed = json.loads((run / "killed.json").read_text())
    assert killed["gs"] == "D" and killed["owned"] == ["d1"]
    owners = s["owners"]
    assert owners[:4] == list("ABCD") and "D" not in owners[4:]  # D never again
    assert s["links_max"] <= 3 and s["landed"]
    # links followed the drone on the way: A's closed for room once B, C and D were wanted
    assert s["links_closed"] >= 1
