"""A fleet in CI: 25 drones x 3 GSs over three site routers (``zdrone bench scale --quick --sites 3
--drones 25``: mutual TLS, the mesh over QUIC, the budgets per credential), every drone correct. A
3-drone bench never caught issue 30 (a GS's session dropping the tail of the burst it sends its
drones every tick: 13 and 3 of 25 correct on the landed code, 1-2 commands lost each). Correctness
only, never speed: every hand-over, no command lost, no failsafe, the authority link never LOST, keys
shared before the hold ran out, the drones spread over the sites and their samples crossing the mesh.
About 2 minutes of wall clock."""

from __future__ import annotations

import json
import subprocess

import pytest

from tests.procs import ZDRONE
from zdrone.crashes import exit_text

K = 25


@pytest.mark.slow
def test_25_drones_x_3_gss_over_three_sites_every_hand_over_and_no_command_lost():
    # --hosts-nice 0: in the suite every test's processes share the machine; hosts that gave way to all
    # of them (not only to their routers) would wait behind the other tests
    out = subprocess.run([ZDRONE, "bench", "scale", "--quick", "--sites", "3", "--drones", str(K), "--hosts-nice", "0",
                          "--json"], capture_output=True, text=True, timeout=480)
    assert out.returncode == 0, f"exit {exit_text(out.returncode)}; stderr ends:\n{out.stderr[-4000:]}"
    (row,) = json.loads(out.stdout)["rows"]
    assert "error" not in row, row
    assert row["k"] == K and row["g"] == 3 and row["hosts_given_way"] == {"drones": "no", "stations": "no"}
    assert row["released"] == "keys", f"keys not all shared in the hold ({row['ground_s']} s)"
    assert row["failures"] == {} and row["correct"] == K and row["all_correct"], row["failures"]
    assert row["handovers"] == {"expected_each": 4, "min": 4, "max": 4, "total": 4 * K}  # A->B->C->B->A, each drone
    assert row["layout"] == "3 sites" and row["drones_per_site"] == {"site-1": 9, "site-2": 8, "site-3": 8}
    assert set(row["cpu_percent"]) == {"router site-1", "router site-2", "router site-3", "drones host", "stations host"}
    assert all(v is not None and v > 0 for v in row["cpu_percent"].values()), row["cpu_percent"]
    assert 0 < row["mesh"]["samples_per_s"] < row["samples_per_s"]  # GS i's samples from drones on site i stay off the mesh


@pytest.mark.slow
def test_a_gs_that_crashes_in_flight_and_starts_again_with_no_key_gets_every_drone_back_and_the_flight_is_correct():
    """``--restart-gs B``: each GS in a process of its own; B's is killed (SIGKILL) 3 s after the take-off,
    the drones near home and out of B's radio, and a new B starts with no key. Every drone takes B's new
    key through its owner A (B's signed keys-lost notice), and every hand-over to and from B follows."""
    k = 6
    out = subprocess.run([ZDRONE, "bench", "scale", "--quick", "--sites", "3", "--drones", str(k), "--hosts-nice", "0",
                          "--restart-gs", "B", "--json"], capture_output=True, text=True, timeout=480)
    assert out.returncode == 0, f"exit {exit_text(out.returncode)}; stderr ends:\n{out.stderr[-4000:]}"
    (row,) = json.loads(out.stdout)["rows"]
    assert "error" not in row, row
    rs = row["restart"]
    assert rs["gs"] == "B" and "error" not in rs and rs["drones_relinked"] == k and rs["relinked_s"] is not None, rs
    assert row["failures"] == {} and row["correct"] == k and row["all_correct"], row["failures"]
    assert row["handovers"] == {"expected_each": 4, "min": 4, "max": 4, "total": 4 * k}
    assert row["gs_processes"] == 3 and row["hosts_given_way"] == {"drones": "no", "stations-A": "no", "stations-B": "no",
                                                                   "stations-C": "no"}
