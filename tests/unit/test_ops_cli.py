"""Operator-facing options: a refused value says why, in one line, exit 2."""

from __future__ import annotations

import subprocess

import pytest

from tests.procs import ZDRONE


@pytest.mark.parametrize("argv, says", [
    (["gs", "--id", "A", "--mission", "shuttle:0"], "shuttle:0: 0 crossings: must be 1..65000 (the loop is one DO_JUMP"),
    (["gs", "--id", "A", "--mission", "shuttle:70000"], "must be 1..65000"),
    (["gs", "--id", "A", "--mission", "shuttle:many"], "expected shuttle:N with N crossings"),
    (["gs", "--id", "A", "--events-max-mb", "0"], "--events-max-mb 0: must be 0.01..100000"),
    (["drone", "--events-max-mb", "-1"], "--events-max-mb -1: must be 0.01..100000"),
    (["demo", "--scenario", "key-escrow", "--tls"], "--tls: scenario key-escrow's attacker holds router passwords only"),
    (["demo", "--scenario", "stale-pairing", "--sites"], "--sites: scenario stale-pairing's attacker holds router"),
])
def test_a_refused_value_says_why(argv, says):
    """In a process of its own: the node commands block SIGTERM and SIGINT in the thread that runs them."""
    p = subprocess.run([ZDRONE, *argv], capture_output=True, text=True, timeout=60)
    assert p.returncode == 2 and says in p.stderr and p.stderr.count("\n") == 1, p.stderr
