"""Signed fleet revisions over real processes: ``zdrone bench revoke --quick`` (3 drones x 3 GSs
through a real router, GS B revoked in flight by a revision published as A): every drone applies
it, B never holds authority after it, B's drones go to A (an heir) or their failsafe, no failsafe is
commanded where an authorized GS covered the drone, and a drone out of reach for 30 s applies it
once back. Correctness only, never speed (the
latency figures are the bench's)."""

from __future__ import annotations

import json
import subprocess

import pytest

from tests.procs import ZDRONE
from zdrone.crashes import exit_text


@pytest.mark.slow
def test_bench_revoke_quick_every_drone_applies_the_revision_and_b_is_out():
    out = subprocess.run([ZDRONE, "bench", "revoke", "--quick", "--only", "revoke", "--json"], capture_output=True,
                         text=True, timeout=420)
    assert out.returncode == 0, f"exit {exit_text(out.returncode)}; stderr ends:\n{out.stderr[-4000:]}\n{out.stdout[-2000:]}"
    (row,) = json.loads(out.stdout)["rows"]
    assert "error" not in row, row
    assert row["applied"] == "2/2" and row["held_by_b"] >= 1  # the third drone is out of reach meanwhile
    oor = row["out_of_reach"]  # cut off before the revision, it applies it once back in reach, not before
    assert oor["back_to_applied_ms"] is not None and not oor["applied_before_back"], oor
    assert row["b_authority_after"] == 0
    assert all(v != "-" for v in row["held_went_to"].values()), row["held_went_to"]
    assert row["failsafes_where_a_gs_covered"] == 0, row
