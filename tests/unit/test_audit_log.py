"""The authority record as the nodes keep it (``EventLog.start_audit``) and ``zdrone audit verify``:
decisions appended beside the event log, checkpoints on the log's clock, a witness's countersignature
in the GS's record, verification offline against the fleet's keys, tampering named."""

from __future__ import annotations

import base64
import json
from pathlib import Path

import pytest

from zdrone.cli import main
from zdrone.core import records as rec
from zdrone.core.audit import AuditCheckpoint, countersign
from zdrone.fleet.files import init_fleet, load_fleet, load_secret
from zdrone.net.eventlog import EventLog, audit_path


class Clock:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


@pytest.fixture(scope="module")
def fleet_dir(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("fleet") / "fleet"
    init_fleet(d)
    return d


def _fly(run: Path, fleet_dir: Path) -> list[AuditCheckpoint]:
    """A drone's log with three decisions and statuses between them; GS B witnesses its checkpoints."""
    fleet = load_fleet(fleet_dir)
    d1, b = load_secret(fleet_dir, "d1", fleet).signing, load_secret(fleet_dir, "B", fleet).signing
    assert d1 is not None and b is not None
    clock = Clock()
    seen: list[AuditCheckpoint] = []
    drone = EventLog(run / "drone.jsonl", "d1", clock=clock)
    drone.start_audit(d1, on_checkpoint=seen.append)
    gs = EventLog(run / "B.jsonl", "B", clock=clock)
    gs.start_audit(b)
    decisions = [rec.AuthorityChange(from_=None, to="A", epoch=1, kind="paired", time=1000.0, position=None),
                 rec.HandoverComplete(from_="A", to="B", epoch=2, kind="handover", time=1010.0, position=(47.0, 8.0, 30.0)),
                 rec.Failsafe(action="LAND", reason="authority link lost", detect_to_command_ms=12.0, position=None)]
    for d in decisions:
        drone.write_record(d)
        drone.write("link_state", gs="A", state="ok")  # not a decision: only a tick of the record's clock
        clock.t += 2.0
        drone.write("link_state", gs="A", state="ok")
        cp = seen[-1]
        w = countersign("B", b, "d1", fleet.signing_public("d1"), cp.seq, bytes.fromhex(cp.head),
                        base64.b64decode(cp.sig), clock.t)
        assert w is not None
        gs.write_witness(w)
    gs.write_record(rec.OperatorRequestGranted(drone="d1", requester="A", to="B", why="consent", epoch=2, app="qgc"))
    drone.close()
    gs.close()
    return seen


def test_decisions_are_recorded_signed_and_witnessed(tmp_path, fleet_dir, capsys):
    seen = _fly(tmp_path, fleet_dir)
    assert [cp.seq for cp in seen] == [0, 1, 2]  # each decision signed within a second, on the log's clock
    lines = audit_path(tmp_path / "drone.jsonl").read_text().splitlines()
    kinds = [json.loads(x).get("kind") for x in lines if json.loads(x)["audit"] == "entry"]
    assert kinds == ["authority", "handover_complete", "failsafe"]
    b_entries = [json.loads(x) for x in audit_path(tmp_path / "B.jsonl").read_text().splitlines()]
    consent = [e for e in b_entries if e["audit"] == "entry"]
    assert consent[0]["kind"] == "operator_request_granted" and consent[0]["fields"]["app"] == "qgc"
    assert main(["audit", "verify", str(tmp_path), "--fleet", str(fleet_dir)]) == 0
    out = capsys.readouterr().out
    assert "d1: verified 3 of 3 entries, witnessed through seq 2" in out and "B: verified 1 of 1" in out


@pytest.mark.parametrize("tamper, kind, first_bad", [
    ("modify", "modified", 1), ("delete", "missing", 1), ("reorder", "missing", 0), ("truncate", "truncated", 2)])
def test_verify_names_the_first_bad_entry(tmp_path, fleet_dir, capsys, tamper, kind, first_bad):
    _fly(tmp_path, fleet_dir)
    path = audit_path(tmp_path / "drone.jsonl")
    lines = path.read_text().splitlines()
    entries = [i for i, x in enumerate(lines) if json.loads(x)["audit"] == "entry"]
    if tamper == "modify":
        obj = json.loads(lines[entries[1]])
        obj["fields"]["to"] = "X"
        lines[entries[1]] = json.dumps(obj)
    elif tamper == "delete":
        del lines[entries[1]]
    elif tamper == "reorder":
        lines[entries[0]], lines[entries[1]] = lines[entries[1]], lines[entries[0]]
    else:
        lines = lines[:entries[2]]  # the last decision and its checkpoint gone: B's copy says otherwise
    path.write_text("\n".join(lines) + "\n")
    assert main(["audit", "verify", str(path), str(audit_path(tmp_path / "B.jsonl")), "--fleet", str(fleet_dir),
                 "--json"]) == 1
    got = {r["node"]: r for r in json.loads(capsys.readouterr().out)}
    assert (got["d1"]["kind"], got["d1"]["first_bad"]) == (kind, first_bad)
    assert got["B"]["ok"]


def test_a_restarted_node_continues_its_chain(tmp_path, fleet_dir, capsys):
    _fly(tmp_path, fleet_dir)
    fleet = load_fleet(fleet_dir)
    again = EventLog(tmp_path / "drone.jsonl", "d1", clock=Clock())
    again.start_audit(load_secret(fleet_dir, "d1", fleet).signing)
    again.write_record(rec.Paired(gs="A"))
    again.close()
    assert main(["audit", "verify", str(tmp_path), "--fleet", str(fleet_dir)]) == 0
    assert "d1: verified 4 of 4 entries" in capsys.readouterr().out


def test_verify_without_a_fleet_or_a_record_is_one_line_and_exit_2(tmp_path, capsys):
    assert main(["audit", "verify", str(tmp_path)]) == 2
    assert main(["audit", "verify", str(tmp_path / "nope")]) == 2


def test_the_flight_report_shows_each_record(tmp_path, fleet_dir):
    import shutil

    from zdrone.report import _audit_section

    _fly(tmp_path, fleet_dir)
    shutil.copytree(fleet_dir, tmp_path / "fleet")
    page = _audit_section(tmp_path)
    assert "d1: verified 3 of 3 entries" in page and "BAD" not in page
    path = audit_path(tmp_path / "drone.jsonl")
    path.write_text("\n".join(path.read_text().splitlines()[1:]) + "\n")  # the first entry deleted
    assert "BAD" in _audit_section(tmp_path) and "d1: BAD at entry 0" in _audit_section(tmp_path)


def test_after_a_key_rotation_earlier_checkpoints_verify_against_the_key_in_force_then(tmp_path, capsys):
    """GS B's record: a consent signed under its first key, B rotated by a fleet revision
    (``zdrone fleet rotate``), its record going on under the new key (``EventLog.rekey_audit``):
    ``zdrone audit verify`` checks each checkpoint against the key the revisions say was B's then."""
    from zdrone.fleet.revise import rotate

    fleet_dir = tmp_path / "fleet"
    init_fleet(fleet_dir)
    run = tmp_path / "run"
    run.mkdir()
    old = load_secret(fleet_dir, "B", load_fleet(fleet_dir)).signing
    clock = Clock()
    gs = EventLog(run / "B.jsonl", "B", clock=clock)
    gs.start_audit(old)
    gs.write_record(rec.OperatorRequestGranted(drone="d1", requester="A", to="B", why="consent", epoch=2, app="qgc"))
    clock.t += 2.0
    gs.write("link_state", gs="A", state="ok")  # a tick: the consent is signed under the first key
    rotate(fleet_dir, "B")
    new = load_secret(fleet_dir, "B", load_fleet(fleet_dir)).signing
    assert new is not None and new.public != old.public
    gs.write_record(rec.OperatorRequestGranted(drone="d1", requester="B", to="A", why="consent", epoch=3, app="qgc"))
    gs.rekey_audit(new)  # the second consent still unsigned: signed under the old key before the switch
    gs.write_record(rec.OperatorRequestGranted(drone="d1", requester="A", to="B", why="consent", epoch=4, app="qgc"))
    gs.close()
    assert main(["audit", "verify", str(run), "--fleet", str(fleet_dir)]) == 0
    assert "B: verified 3 of 3 entries" in capsys.readouterr().out
    # without the revisions (the base fleet alone: B's first key), the checkpoint under the new key fails
    base_only = tmp_path / "base"
    base_only.mkdir()
    (base_only / "fleet.json5").write_bytes((fleet_dir / "fleet.json5").read_bytes())
    assert main(["audit", "verify", str(run), "--fleet", str(base_only), "--json"]) == 1
    got = json.loads(capsys.readouterr().out)[0]
    assert (got["kind"], got["first_bad"]) == ("bad_signature", 2)
    # a tampered revision file is named, not trusted
    (fleet_dir / "revisions" / "0001.json").write_bytes(b"{}")
    assert main(["audit", "verify", str(run), "--fleet", str(fleet_dir)]) == 2
