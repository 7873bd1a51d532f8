"""``audit-cuts``: the authority records of a real flight (``rotate-in-flight``: A's keys rotated in
flight, so its record and countersignatures move to the new key) cut as an attacker who holds the
files would cut them; ``zdrone audit verify`` exits 1 and names each cut, next to the untouched run
that verifies (exit 0): a GS's record cut back alone among them (the drone countersigned its
checkpoints), and a record missing with the fleet given apart (``--fleet``). The cuts with retired
keys are built in ``tests/unit/test_audit_log.py`` (they need the retired private key, which the
flight does not leave behind)."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest

from tests.integration.test_flight_e2e import run_demo
from tests.procs import ZDRONE


def _verify(run: Path, *extra: str) -> tuple[int, list[dict]]:
    proc = subprocess.run([ZDRONE, "audit", "verify", str(run), "--json", *extra], capture_output=True, text=True,
                          timeout=60)
    assert "Traceback" not in proc.stderr, proc.stderr
    return proc.returncode, json.loads(proc.stdout)


def _lines(path: Path) -> list[dict]:
    return [json.loads(x) for x in path.read_text().splitlines() if x.strip()]


def _write(path: Path, lines: list[dict]) -> None:
    path.write_text("".join(json.dumps(x, separators=(",", ":")) + "\n" for x in lines))


def _problems(reports: list[dict]) -> str:
    return json.dumps(reports)


@pytest.mark.slow
def test_the_records_of_a_real_flight_fail_verify_under_each_cut(tmp_path):
    s, out = run_demo(tmp_path, "rotate-in-flight")
    assert s["ok"], s["why_not_ok"]
    rc, reports = _verify(out)
    assert rc == 0, _problems(reports)  # the control: the untouched run verifies

    # 1. the drone's record deleted: A and B hold countersignatures of it
    cut = tmp_path / "no-drone-record"
    shutil.copytree(out, cut)
    (cut / "drone.audit.jsonl").unlink()
    rc, reports = _verify(cut)
    assert rc == 1 and "record missing" in _problems(reports), _problems(reports)

    # 2. the witnesses' countersignatures of the drone's last checkpoint deleted from A's and B's
    #    records, and the drone's record cut below it
    cut = tmp_path / "witnesses-cut"
    shutil.copytree(out, cut)
    drone = _lines(cut / "drone.audit.jsonl")
    last = max(x["seq"] for x in drone if x["audit"] == "checkpoint")
    for gs in ("A", "B"):
        path = cut / f"{gs}.audit.jsonl"
        _write(path, [x for x in _lines(path) if not (x.get("kind") == "witness" and x["fields"]["seq"] == last)])
    _write(cut / "drone.audit.jsonl", [x for x in drone if x["seq"] < last])
    rc, reports = _verify(cut)
    assert rc == 1, _problems(reports)
    assert any(not r["ok"] and r["node"] in ("A", "B") for r in reports), _problems(reports)

    # 3. the drone's last decision left without a countersignature: the GSs' records cut before their first
    #    countersignature that covers it (its countersignatures of the GSs' own checkpoints are no decisions)
    cut = tmp_path / "unwitnessed"
    shutil.copytree(out, cut)
    decided = max(x["seq"] for x in drone if x["audit"] == "entry" and x.get("kind") != "witness")
    for gs in ("A", "B"):
        path = cut / f"{gs}.audit.jsonl"
        lines = _lines(path)
        first = next((i for i, x in enumerate(lines) if x.get("kind") == "witness" and x["fields"]["node"] == "d1"
                      and x["fields"]["seq"] >= decided), None)
        if first is not None:
            _write(path, lines[:first])
    rc, reports = _verify(cut, "--require-witnessed")
    assert rc == 1, _problems(reports)
    d1 = next(r for r in reports if r["node"] == "d1")
    assert d1.get("unwitnessed"), d1

    # 4. A's record replaced by an older copy of itself, from its last decision the drone countersigned on
    cut = tmp_path / "gs-cut-back"
    shutil.copytree(out, cut)
    a = _lines(cut / "A.audit.jsonl")
    top = max(x["fields"]["seq"] for x in drone if x.get("kind") == "witness" and x["fields"]["node"] == "A")
    last = max(i for i, x in enumerate(a) if x["audit"] == "entry" and x["kind"] != "witness" and x["seq"] <= top)
    _write(cut / "A.audit.jsonl", a[:last])
    rc, reports = _verify(cut, "--require-witnessed")
    assert rc == 1 and next(r for r in reports if r["node"] == "A")["kind"] == "truncated", _problems(reports)

    # 5. cut 1 with the fleet given apart (``--fleet``, as docs/deploy.md shows it): the same record missing
    cut = tmp_path / "no-drone-record-fleet-apart"
    shutil.copytree(tmp_path / "no-drone-record", cut)
    shutil.move(cut / "fleet", tmp_path / "fleet-apart")
    rc, reports = _verify(cut, "--fleet", str(tmp_path / "fleet-apart"))
    assert rc == 1 and "record missing" in _problems(reports), _problems(reports)
