"""The authority record as the nodes keep it (``EventLog.start_audit``) and ``zdrone audit verify``:
decisions appended beside the event log, checkpoints on the log's clock, a witness's countersignature
in the GS's record, verification offline against the fleet's keys, tampering named."""

from __future__ import annotations

import base64
import json
from pathlib import Path
from typing import Any

import pytest

from zdrone.cli import main
from zdrone.core import records as rec
from zdrone.core.audit import AuditCheckpoint, countersign
from zdrone.fleet.files import init_fleet, load_fleet, load_secret
from zdrone.net.eventlog import EventLog, audit_path
from zdrone.nodes.drone_actions import Countersign


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
    b_kinds = [e["kind"] for e in b_entries if e["audit"] == "entry"]
    assert b_kinds == ["witness", "witness", "witness", "operator_request_granted"]  # countersignatures: B's entries
    consent = b_entries[[e.get("kind") for e in b_entries].index("operator_request_granted")]
    assert consent["fields"]["app"] == "qgc"
    assert main(["audit", "verify", str(tmp_path), "--fleet", str(fleet_dir)]) == 0
    out = capsys.readouterr().out
    assert "d1: verified 3 of 3 entries, witnessed through seq 2" in out and "B: verified 4 of 4" in out


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
    record = str(audit_path(run / "B.jsonl"))  # the file alone: a folder would want d1's record too
    assert main(["audit", "verify", record, "--fleet", str(fleet_dir)]) == 0
    assert "B: verified 3 of 3 entries" in capsys.readouterr().out
    # without the revisions (the base fleet alone: B's first key), the checkpoint under the new key fails
    base_only = tmp_path / "base"
    base_only.mkdir()
    (base_only / "fleet.json5").write_bytes((fleet_dir / "fleet.json5").read_bytes())
    assert main(["audit", "verify", record, "--fleet", str(base_only), "--json"]) == 1
    got = json.loads(capsys.readouterr().out)[0]
    assert (got["kind"], got["first_bad"]) == ("bad_signature", 2)
    # a tampered revision file is named, not trusted
    (fleet_dir / "revisions" / "0001.json").write_bytes(b"{}")
    assert main(["audit", "verify", record, "--fleet", str(fleet_dir)]) == 2


# ---------------------------------------------------------------- a run's records under every cut

def _run(run: Path, fleet_dir: Path, decisions: int = 3, witnessed: int | None = None,
         countersigned: bool = False) -> dict[str, EventLog]:
    """A run folder as ``zdrone demo`` leaves it: its fleet in ``fleet/``, the drone's log and record,
    A's and B's, each GS countersigning the drone's checkpoints (``Witnessing``, as ``zdrone gs`` does)
    of the first ``witnessed`` decisions (default all), then its operator's consent, which the drone
    countersigns (``countersigned``) in an entry of its own that both GSs countersign in turn."""
    import shutil

    from zdrone.core.audit import Witnessing

    if not (run / "fleet").exists():
        shutil.copytree(fleet_dir, run / "fleet")
    fleet = load_fleet(run / "fleet")
    clock = Clock()
    seen: list[AuditCheckpoint] = []
    drone = EventLog(run / "drone.jsonl", "d1", clock=clock)
    drone.start_audit(load_secret(run / "fleet", "d1", fleet).signing, on_checkpoint=seen.append)
    gss = {}
    for g in ("A", "B"):
        gss[g] = EventLog(run / f"{g}.jsonl", g, clock=clock)
        key = load_secret(run / "fleet", g, fleet).signing
        gss[g].start_audit(key)
        gss[g].witnessing = Witnessing(g, key, {"d1": fleet.signing_public("d1")})  # type: ignore[attr-defined]
    for i in range(decisions):
        drone.write_record(rec.Paired(gs="A"))
        clock.t += 2.0
        drone.write("link_state", gs="A", state="ok")  # a tick: the decision signed
        if witnessed is None or i < witnessed:
            for g, log in gss.items():
                w = log.witnessing.on_head("d1", *seen[-1].raw(), clock.t)  # type: ignore[attr-defined]
                assert w is not None
                log.write_witness(w)
    for g, log in gss.items():
        log.write_record(rec.OperatorRequestGranted(drone="d1", requester=g, to=g, why="consent", epoch=9, app="qgc"))
    if countersigned:  # the drone countersigns each GS's consent (its ``wire.AuditOffer``), as ``zdrone drone`` does
        clock.t += 2.0
        witnessing = Witnessing("d1", load_secret(run / "fleet", "d1", fleet).signing,
                                {g: fleet.signing_public(g) for g in gss})
        for g, log in gss.items():
            log.write("link_state", gs="d1", state="ok")  # a tick: the consent signed, offered to d1
            cp, named = log.audit.offer
            assert named == {"d1"} and cp.seq == log.audit.seq - 1
            w = witnessing.on_head(g, *cp.raw(), clock.t)
            assert w is not None
            drone.write_witness(w)
        clock.t += 2.0
        drone.write("link_state", gs="A", state="ok")  # a tick: the drone's checkpoint, which the GSs countersign
        for g, log in gss.items():
            log.write_witness(log.witnessing.on_head("d1", *seen[-1].raw(), clock.t))  # type: ignore[attr-defined]
    return {"d1": drone, **gss}


def _close(logs: dict[str, EventLog]) -> None:
    for log in logs.values():
        log.close()


def _verify_run(run: Path, capsys, *extra: str) -> tuple[int, dict[str, dict]]:
    code = main(["audit", "verify", str(run), "--json", *extra])
    return code, {r["node"]: r for r in json.loads(capsys.readouterr().out)}


def _lines(path: Path) -> list[str]:
    return path.read_text().splitlines()


def _write(path: Path, lines: list[str]) -> None:
    path.write_text("".join(x + "\n" for x in lines))


def test_an_untouched_run_verifies_witnessed_to_its_end(tmp_path, fleet_dir, capsys):
    _close(_run(tmp_path, fleet_dir, countersigned=True))
    code, got = _verify_run(tmp_path, capsys, "--require-witnessed")
    assert code == 0 and set(got) == {"d1", "A", "B"}
    assert (got["d1"]["witnessed_through"], got["d1"]["unwitnessed"]) == (4, 0)  # its countersignatures of A, B too
    assert (got["A"]["witnessed_through"], got["A"]["unwitnessed"]) == (3, 0)  # A's consent, countersigned by d1
    assert (got["B"]["witnessed_through"], got["B"]["unwitnessed"]) == (3, 0)


def test_cut_1_countersignatures_deleted_from_the_gs_records_break_them(tmp_path, fleet_dir, capsys):
    """The witnesses of the last checkpoint deleted from A's and B's records, the drone's record cut
    below it: A's and B's records miss an entry each."""
    _close(_run(tmp_path, fleet_dir))
    for g in ("A", "B"):
        path = audit_path(tmp_path / f"{g}.jsonl")
        _write(path, [x for x in _lines(path) if not ('"kind":"witness"' in x and '"seq":2,' in x)])
    path = audit_path(tmp_path / "drone.jsonl")
    lines = _lines(path)
    _write(path, lines[:[json.loads(x).get("seq") for x in lines].index(2)])  # entry 2 and what follows gone
    code, got = _verify_run(tmp_path, capsys)
    assert code == 1
    assert (got["A"]["kind"], got["A"]["first_bad"]) == ("missing", 2)
    assert (got["B"]["kind"], got["B"]["first_bad"]) == ("missing", 2)


def test_cut_2_a_deleted_drone_record_is_named_missing(tmp_path, fleet_dir, capsys):
    _close(_run(tmp_path, fleet_dir))
    audit_path(tmp_path / "drone.jsonl").unlink()
    code, got = _verify_run(tmp_path, capsys)
    assert code == 1 and got["d1"]["kind"] == "record_missing"
    assert "A, B countersigned its entries up to 2" in got["d1"]["problem"]
    # no GS countersigned it: the fleet still names the drone
    for g in ("A", "B"):
        audit_path(tmp_path / f"{g}.jsonl").write_text("")
    code, got = _verify_run(tmp_path, capsys)
    assert code == 1 and got["d1"]["problem"] == "record missing: the fleet names drone d1"
    # and a GS whose event log is in the run has its record too
    audit_path(tmp_path / "A.jsonl").unlink()
    code, got = _verify_run(tmp_path, capsys)
    assert code == 1 and got["A"]["problem"] == "record missing: its event log A.jsonl is in the run"


def _rotated_run(run: Path, node: str) -> tuple[dict[str, EventLog], Any]:
    """A run whose fleet rotates ``node`` (``zdrone fleet rotate``) after the run's three decisions,
    the node applying the revision in its record: its retired key, and the run's logs still open."""
    from zdrone.fleet.revise import rotate

    fleet_dir = run / "fleet"
    init_fleet(fleet_dir)
    logs = _run(run, fleet_dir)
    old = load_secret(fleet_dir, node, load_fleet(fleet_dir)).signing
    revised = rotate(fleet_dir, node)
    logs[node].write_record(rec.RevisionApplied(number=revised.revision.number, revoked=(), rotated=(node,)))
    return logs, old


def test_cut_3_entries_past_the_drone_s_rotation_signed_with_its_retired_key_are_refused(tmp_path, capsys):
    """The drone applied the revision that rotated it; entries appended after it with a checkpoint
    under its retired key (whoever kept that key) are refused, naming the revision."""
    logs, _ = _rotated_run(tmp_path, "d1")
    logs["d1"].write_record(rec.Failsafe(action="LAND", reason="forged", detect_to_command_ms=1.0, position=None))
    _close(logs)  # the record's last checkpoint: under the retired key
    code, got = _verify_run(tmp_path, capsys)
    assert code == 1 and (got["d1"]["kind"], got["d1"]["first_bad"]) == ("bad_signature", 3)
    assert "d1's key retired by revision 1" in got["d1"]["problem"]


def test_cut_4_a_countersignature_under_a_gs_s_retired_key_is_a_bad_witness(tmp_path, capsys):
    logs, old = _rotated_run(tmp_path, "A")
    a = logs["A"]
    logs["d1"].write_record(rec.Paired(gs="B"))
    a._clock.t += 2.0  # type: ignore[attr-defined]
    logs["d1"].write("link_state", gs="A", state="ok")  # a tick: the drone's checkpoint of entry 3
    cp = logs["d1"].audit.last
    assert old is not None and cp is not None and cp.seq == 3
    a.write_witness(countersign("A", old, "d1", load_fleet(tmp_path / "fleet").signing_public("d1"), *cp.raw(), 0.0))
    _close(logs)
    code, got = _verify_run(tmp_path, capsys)
    assert code == 1 and (got["A"]["kind"], got["A"]["first_bad"]) == ("bad_witness", 5)
    assert got["d1"]["ok"] and got["d1"]["witnessed_through"] == 2  # B's countersignatures stand, A's forged one not


def test_cut_5_a_gs_s_entries_past_its_rotation_under_its_retired_key_are_refused(tmp_path, capsys):
    logs, _ = _rotated_run(tmp_path, "A")
    logs["A"].write_record(rec.OperatorRequestGranted(drone="d1", requester="X", to="X", why="forged", epoch=10,
                                                      app="qgc"))
    _close(logs)
    code, got = _verify_run(tmp_path, capsys)
    assert code == 1 and got["A"]["kind"] == "bad_signature" and "A's key retired by revision 1" in got["A"]["problem"]


def test_require_witnessed_refuses_an_unwitnessed_tail(tmp_path, fleet_dir, capsys):
    _close(_run(tmp_path, fleet_dir, decisions=3, witnessed=2))
    code, got = _verify_run(tmp_path, capsys)
    assert code == 0 and got["d1"]["ok"] and (got["d1"]["witnessed_through"], got["d1"]["unwitnessed"]) == (1, 1)
    code, got = _verify_run(tmp_path, capsys, "--require-witnessed")
    assert code == 1
    assert main(["audit", "verify", str(tmp_path)]) == 0
    assert "1 decisions after the last witnessed entry" in capsys.readouterr().out


def test_a_gs_follows_the_revisions_in_its_record_and_its_countersignatures(tmp_path, capsys):
    """``audit_on_revision`` (what ``zdrone gs`` does on each revision it applies): the drones' keys
    refreshed (a rotated drone's retired key countersigned no more), its own record and
    countersignatures moved to its new key, or to none while it does not hold it."""
    from gs.station import audit_on_revision
    from zdrone.core.audit import AuditChain
    from zdrone.fleet.revise import rotate

    fleet_dir = tmp_path / "fleet"
    init_fleet(fleet_dir)
    logs = _run(tmp_path, fleet_dir, decisions=1)
    a, witnessing = logs["A"], logs["A"].witnessing  # type: ignore[attr-defined]
    a_old = load_secret(fleet_dir, "A", load_fleet(fleet_dir)).signing
    d1_old = load_secret(fleet_dir, "d1", load_fleet(fleet_dir)).signing
    assert a_old is not None and d1_old is not None
    r1 = rotate(fleet_dir, "d1")
    a.write_record(rec.RevisionApplied(number=1, revoked=(), rotated=("d1",)))  # as its RevisionChannel writes it
    assert audit_on_revision(a, witnessing, r1.fleet, "A", a_old.public, None) is False
    assert witnessing.node_keys["d1"] == r1.fleet.signing_public("d1") and a.audit.key.public == a_old.public
    forged = AuditChain("d1", d1_old, seq=5)  # past what A countersigned
    forged.append("paired", {"gs": "A"}, 0.0)
    assert witnessing.on_head("d1", *forged.checkpoint(0.0).raw(), 0.0) is None and witnessing.refused == 1
    r2 = rotate(fleet_dir, "A")
    a.write_record(rec.RevisionApplied(number=2, revoked=(), rotated=("A",)))
    assert audit_on_revision(a, witnessing, r2.fleet, "A", a_old.public, None) is True  # new key not here yet
    assert a.audit.key is None and witnessing.key is None
    a_new = load_secret(fleet_dir, "A", r2.fleet).signing
    assert audit_on_revision(a, witnessing, r2.fleet, "A", None, a_new) is True
    assert a.audit.key is a_new and witnessing.key is a_new
    a.write_record(rec.OperatorRequestGranted(drone="d1", requester="B", to="A", why="consent", epoch=11, app="qgc"))
    _close(logs)
    code, got = _verify_run(tmp_path, capsys)
    assert code == 0 and got["A"]["signed_through"] == got["A"]["entries"] - 1, got["A"]


def test_a_drone_moves_its_record_to_its_new_key_when_it_applies_its_rotation(tmp_path, capsys):
    """``DroneNode._rekey_audit``, before the core writes the revision's entry: the entries up to it
    signed under the old key, the revision's entry and the rest under the new; without the new key in
    its bundle, under none (counted)."""
    from collections import Counter
    from types import SimpleNamespace

    from zdrone.fleet.revise import rotate
    from zdrone.nodes.drone import DroneNode

    fleet_dir = tmp_path / "fleet"
    init_fleet(fleet_dir)
    logs = _run(tmp_path, fleet_dir, decisions=1)
    drone = logs["d1"]
    held = load_secret(fleet_dir, "d1")
    adopted: list[tuple] = []

    def adopt(identity, signing):  # DroneCore.adopt_own_keys: pairing and attestations under the new keys
        adopted.append((identity, signing))
        core.responder.me = identity or core.responder.me
        core.attester = None if signing is None else SimpleNamespace(key=signing)

    core = SimpleNamespace(counters=Counter(), responder=SimpleNamespace(me=held.identity),
                           attester=SimpleNamespace(key=held.signing), adopt_own_keys=adopt)
    node = SimpleNamespace(events=drone, name="d1", opts=SimpleNamespace(fleet=str(fleet_dir)), core=core,
                           witnessing=None)
    secret = fleet_dir / "secrets" / "d1.json"
    kept = secret.read_bytes()
    r1 = rotate(fleet_dir, "d1")
    new = secret.read_bytes()
    secret.write_bytes(kept)  # the bundle on the drone still holds the old key
    DroneNode._rekey_audit(node, r1.fleet)  # type: ignore[arg-type]
    assert drone.audit.key is None and node.core.counters["audit_rotation_pending"] == 1
    secret.write_bytes(new)
    DroneNode._rekey_audit(node, r1.fleet)  # type: ignore[arg-type]
    assert drone.audit.key is not None and drone.audit.key.public == r1.fleet.signing_public("d1")
    assert adopted[0] == (None, None)  # nothing signed while the new keys are not here, never the retired one
    assert adopted[1][0].public == r1.fleet.nodes["d1"].public_bytes and adopted[1][1].public == r1.fleet.signing_public("d1")
    DroneNode._rekey_audit(node, r1.fleet)  # type: ignore[arg-type]
    assert len(adopted) == 2  # the keys it holds are the fleet's: nothing more to do
    drone.write_record(rec.RevisionApplied(number=1, revoked=(), rotated=("d1",)))
    _close(logs)
    code, got = _verify_run(tmp_path, capsys)
    assert code == 0 and got["d1"]["signed_through"] == 1, got["d1"]


def test_a_gs_s_own_rotation_moves_its_signing_once_and_waits_for_a_key_it_does_not_hold(tmp_path, capsys):
    """``GroundStation._on_revision`` (on a stand-in for the station): its own rotation moves its
    record, its countersignatures and its revision stamps (``secret``) to the new key and re-pairs once;
    a later revision that leaves its keys alone changes nothing; a rotation whose secret is not here
    leaves it signing nothing until a revision finds the secret there."""
    from collections import Counter
    from types import SimpleNamespace

    from gs.station import GroundStation
    from zdrone.core.audit import Witnessing
    from zdrone.fleet import revisions
    from zdrone.fleet.revise import revise, rotate

    fleet_dir = tmp_path / "fleet"
    init_fleet(fleet_dir)
    logs = _run(tmp_path, fleet_dir, decisions=1)
    fleet = load_fleet(fleet_dir)
    secret = load_secret(fleet_dir, "A", fleet)
    a = logs["A"]
    adopted: list[Any] = []
    gs = SimpleNamespace(name="A", fleet=fleet, secret=secret, events=a, counters=Counter(), ops=None,
                         witnessing=Witnessing("A", secret.signing, {"d1": fleet.signing_public("d1")}),
                         audit_key=secret.signing.public, opts=SimpleNamespace(fleet=str(fleet_dir)),
                         core=SimpleNamespace(fleet=fleet, adopt_identity=lambda *args: adopted.append(args) or []),
                         _do=lambda actions: None)
    gs._adopt_own_key = lambda now: GroundStation._adopt_own_key(gs, now)  # type: ignore[arg-type]

    def apply(r: Any) -> None:
        def on_inbox(kind: str, data: Any) -> Any:  # as the station's RevisionChannel: its record first
            a.write_record(rec.RevisionApplied(number=r.revision.number, revoked=(), rotated=tuple(r.revision.changes.keys)))
            return revisions.RevisionAccepted(r.revision, r.fleet)
        gs.revision = SimpleNamespace(on_inbox=on_inbox, take_notice=lambda: None)
        GroundStation._on_revision(gs, "revision", b"", 0.0)  # type: ignore[arg-type]

    r1 = rotate(fleet_dir, "A")
    apply(r1)
    new = r1.fleet.signing_public("A")
    assert a.audit.key.public == new and gs.witnessing.key.public == new and gs.secret.signing.public == new
    assert len(adopted) == 1 and gs.counters["rotated"] == 1
    apply(revise(fleet_dir, pairing_pq=True))  # the revisions are cumulative: A's keys in it are the same
    assert len(adopted) == 1 and gs.counters["rotated"] == 1
    kept = (fleet_dir / "secrets" / "A.json").read_bytes()
    r3 = rotate(fleet_dir, "A")
    newer = (fleet_dir / "secrets" / "A.json").read_bytes()
    (fleet_dir / "secrets" / "A.json").write_bytes(kept)  # A's host does not have the new bundle yet
    apply(r3)
    assert gs.counters["rotation_pending"] == 1 and a.audit.key is None and gs.witnessing.key is None
    a.write_record(rec.OperatorRequestGranted(drone="d1", requester="B", to="A", why="consent", epoch=12, app="qgc"))
    (fleet_dir / "secrets" / "A.json").write_bytes(newer)
    r4 = revise(fleet_dir, pairing_pq=False)
    apply(r4)  # the next revision finds it
    assert a.audit.key.public == r4.fleet.signing_public("A") and len(adopted) == 2
    _close(logs)
    code, got = _verify_run(tmp_path, capsys)
    assert code == 0 and got["A"]["signed_through"] == got["A"]["entries"] - 1, got["A"]


# ------------------------------------------------ a GS's record countersigned by its drones; --fleet

def test_cut_6_a_gs_s_record_replaced_by_an_older_copy_of_itself_is_truncated_against_the_drone(tmp_path, fleet_dir,
                                                                                                  capsys):
    """A's record replaced by an older copy (its consent and everything after gone): the drone's
    record holds its countersignature of A's consent."""
    _close(_run(tmp_path, fleet_dir, countersigned=True))
    path = audit_path(tmp_path / "A.jsonl")
    lines = _lines(path)
    consent = next(i for i, x in enumerate(lines) if '"kind":"operator_request_granted"' in x)
    _write(path, lines[:consent])  # the copy as it was before the consent, its checkpoints included
    code, got = _verify_run(tmp_path, capsys, "--require-witnessed")
    assert code == 1 and (got["A"]["kind"], got["A"]["first_bad"]) == ("truncated", 3), got["A"]
    assert "d1 countersigned entry 3" in got["A"]["problem"]
    assert got["B"]["ok"] and got["d1"]["ok"]


def test_cut_7_the_drone_s_record_cut_before_its_countersignature_of_a_gs_is_truncated(tmp_path, fleet_dir, capsys):
    """The drone's record cut back to before its countersignatures of A's and B's consents (so that
    A's and B's records could be cut too): A and B countersigned the drone's checkpoint after them."""
    _close(_run(tmp_path, fleet_dir, countersigned=True))
    path = audit_path(tmp_path / "drone.jsonl")
    lines = _lines(path)
    _write(path, lines[:next(i for i, x in enumerate(lines) if '"kind":"witness"' in x)])
    code, got = _verify_run(tmp_path, capsys)
    assert code == 1 and (got["d1"]["kind"], got["d1"]["first_bad"]) == ("truncated", 3), got["d1"]


def test_the_cut_that_stays_undetectable_is_every_record_cut_back_together(tmp_path, fleet_dir, capsys):
    """What no offline check tells (README, "What the record promises"): A's consent cut, with the
    drone's countersignature of it and A's and B's countersignatures of the drone's checkpoint that
    covers it: every record that vouched for the consent cut back to a consistent earlier point."""
    _close(_run(tmp_path, fleet_dir, countersigned=True))
    a = audit_path(tmp_path / "A.jsonl")
    lines = _lines(a)
    _write(a, lines[:next(i for i, x in enumerate(lines) if '"kind":"operator_request_granted"' in x)])
    d1 = audit_path(tmp_path / "drone.jsonl")
    lines = _lines(d1)
    _write(d1, lines[:next(i for i, x in enumerate(lines) if '"kind":"witness"' in x)])
    code, _ = _verify_run(tmp_path, capsys)
    assert code == 1  # B still holds its countersignature of the drone's checkpoint of entry 4
    b = audit_path(tmp_path / "B.jsonl")
    _write(b, [x for x in _lines(b) if '"seq":4,' not in x])  # B's last countersignature, its last entry
    code, got = _verify_run(tmp_path, capsys)
    assert code == 0 and all(r["ok"] for r in got.values()), got  # B's consent: d1's countersignature cut too
    assert (got["B"]["unwitnessed"], got["A"]["unwitnessed"]) == (1, 0)  # ... which --require-witnessed shows
    assert _verify_run(tmp_path, capsys, "--require-witnessed")[0] == 1


def test_a_gs_decision_nobody_countersigned_fails_require_witnessed(tmp_path, fleet_dir, capsys):
    _close(_run(tmp_path, fleet_dir, countersigned=False))
    code, got = _verify_run(tmp_path, capsys)
    assert code == 0 and got["A"]["unwitnessed"] == 1 and got["d1"]["unwitnessed"] == 0
    assert _verify_run(tmp_path, capsys, "--require-witnessed")[0] == 1


@pytest.mark.parametrize("cut", ["drone", "A"])
def test_verify_with_fleet_reports_a_missing_record_as_with_the_run_s_own_fleet(tmp_path, fleet_dir, capsys, cut):
    """``zdrone audit verify DIR --fleet FLEET`` (docs/deploy.md) wants the same records as a run
    folder holding its own ``fleet/``: the drone's record deleted is ``record_missing`` either way."""
    import shutil

    own = tmp_path / "own"
    own.mkdir()
    _close(_run(own, fleet_dir, countersigned=True))
    audit_path(own / f"{cut}.jsonl").unlink()
    given = tmp_path / "given"
    shutil.copytree(own, given)
    shutil.rmtree(given / "fleet")
    code, by_own = _verify_run(own, capsys)
    assert code == 1 and by_own["d1" if cut == "drone" else cut]["kind"] == "record_missing"
    code, by_flag = _verify_run(given, capsys, "--fleet", str(fleet_dir))
    assert code == 1 and by_flag == by_own | {n: {**r, "file": r["file"].replace(str(own), str(given))}
                                             for n, r in by_own.items()}
    # files named one by one are checked as given
    files = [str(f) for f in sorted(given.glob("*.audit.jsonl"))]
    assert main(["audit", "verify", *files, "--fleet", str(fleet_dir)]) == 0


def test_a_gs_offers_its_checkpoint_to_the_drone_which_countersigns_it_in_its_own_record(tmp_path, fleet_dir):
    """The live path: ``StationCore.offer_checkpoint`` seals a ``wire.AuditOffer`` to the drone, now
    and at the next heartbeats; the drone's core asks its adapter to countersign it
    (``Countersign``), which ``DroneNode._countersign`` writes once in the drone's record."""
    from collections import Counter
    from types import SimpleNamespace

    from gs.station import GroundStation
    from tests.coreflight import CoreFlight
    from zdrone.core import wire
    from zdrone.core.audit import AuditChain, Witnessing
    from zdrone.nodes.drone import DroneNode

    f = CoreFlight(tmp_path / "fleet")
    assert f.run_until(lambda: f.gs["A"].core.drone_status("d1", f.now).linked, 30)
    a_key = load_secret(tmp_path / "fleet", "A", f.fleet).signing
    chain = AuditChain("A", a_key)
    chain.append("operator_request_granted", {"drone": "d1", "requester": "B"}, 0.0)
    chain.checkpoint(1.0)
    cp, named = chain.offer
    offered: list[Any] = []  # the station's loop hands each new offer to its core once
    station = SimpleNamespace(events=SimpleNamespace(audit=chain), _offered=None, _do=offered.extend,
                              core=SimpleNamespace(offer_checkpoint=lambda drones, head: [(drones, head)]))
    GroundStation._offer_checkpoint(station)  # type: ignore[arg-type]
    GroundStation._offer_checkpoint(station)  # type: ignore[arg-type]
    assert offered == [({"d1"}, wire.AuditHead(*cp.raw()))]
    f.station("A", f.gs["A"].core.offer_checkpoint(named, wire.AuditHead(*cp.raw())))
    assert [(c.gs, c.head.seq) for c in f.countersign] == [("A", 0)]
    f.run_until(lambda: len(f.countersign) >= 3, 5)
    f.run_until(lambda: False, 3)
    assert len(f.countersign) == 3  # now and at the next two heartbeats, then no more
    d1 = load_secret(tmp_path / "fleet", "d1", f.fleet).signing
    log = EventLog(tmp_path / "drone.jsonl", "d1", clock=Clock())
    log.start_audit(d1)
    node = SimpleNamespace(witnessing=Witnessing("d1", d1, {"A": f.fleet.signing_public("A")}), events=log,
                           core=SimpleNamespace(counters=Counter()))
    for c in f.countersign:
        DroneNode._countersign(node, c)  # type: ignore[arg-type]
    forged = AuditChain("A", load_secret(tmp_path / "fleet", "B", f.fleet).signing, seq=1, head=cp.head)
    forged.append("operator_request_granted", {"drone": "d1"}, 2.0)
    DroneNode._countersign(node, Countersign("A", wire.AuditHead(*forged.checkpoint(2.0).raw())))  # type: ignore[arg-type]
    log.close()
    entries = [json.loads(x) for x in _lines(audit_path(tmp_path / "drone.jsonl"))]
    witnesses = [e["fields"] for e in entries if e.get("kind") == "witness"]
    assert [(w["node"], w["seq"]) for w in witnesses] == [("A", 0)]  # once, and never the forged one
    assert node.core.counters["audit_bad_checkpoint"] == 1
