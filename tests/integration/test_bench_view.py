"""``zdrone bench view --quick --json``: the page in headless chromium over a short flight and the
scale fleet; every figure's structure and that every sample was taken (not the speed)."""

from __future__ import annotations

import json
import os
import subprocess

import pytest

from tests.procs import ZDRONE
from zdrone.crashes import exit_text

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("view")]


def test_bench_view_quick_takes_every_sample(tmp_path):
    pytest.importorskip("playwright.sync_api")
    if not os.path.exists("/usr/bin/chromium"):
        pytest.skip("Debian's chromium is not installed (make venv installs it)")
    out = subprocess.run([ZDRONE, "bench", "view", "--quick", "--json", "--out", str(tmp_path)], capture_output=True,
                         text=True, timeout=240)
    assert out.returncode == 0, f"exit {exit_text(out.returncode)}; stderr ends:\n{out.stderr[-4000:]}"
    r = json.loads(out.stdout)
    assert r["outside_requests"] == []

    lat = r["latency"]
    assert lat["flight_ok"], lat["why_not_ok"]
    assert lat["changes"] >= lat["crossings"] >= 2  # a hand-over per crossing, each after the page opened
    assert lat["missed"] == [] and lat["shown"] == lat["changes"] == len(lat["rows"])
    owners = [row["to"] for row in lat["rows"]]
    assert set(owners) <= {"A", "B"} and all(x != y for x, y in zip(owners, owners[1:]))  # back and forth
    assert all(isinstance(row["page_ms"], float) for row in lat["rows"])
    assert set(lat["ms"]) == {"p50", "p95", "max"} and lat["ms"]["p50"] <= lat["ms"]["p95"] <= lat["ms"]["max"]

    mem = r["memory"]
    assert mem["samples"] == mem["ticks"] >= mem["span_s"] / mem["interval_s"] >= 5  # one per interval, none lost
    assert 0 < mem["rss_start_mb"] <= mem["rss_max_mb"] and mem["rss_end_mb"] <= mem["rss_max_mb"]

    fleet = r["fleet"]
    assert "error" not in fleet, fleet
    assert fleet["k"] == 25 and fleet["samples"] == fleet["expected_samples"] == 10
    assert fleet["rows_shown"] == {"min": 25, "max": 25}  # every drone in every sample
    assert fleet["pictures"] > 0 and fleet["lag_s"]["p50"] is not None and fleet["age_s"]["p50"] is not None
    assert fleet["server_rss_mb"]["start"] > 0 and fleet["send_q_bytes"] is not None
    assert isinstance(fleet["kept_up"], bool)
