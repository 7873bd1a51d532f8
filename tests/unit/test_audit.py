"""The authority record (``zdrone.core.audit``): a chain that verifies, and each kind of tampering
detected with the first bad entry named: modify, delete, reorder, truncate (against a witness), a
forged checkpoint, a rewritten tail."""

from __future__ import annotations

import base64
import json

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from zdrone.core.audit import (AuditChain, AuditCheckpoint, AuditEntry, AuditWitness, countersign, decode_line,
                               encode_line, verify_chain)
from zdrone.core.keys import SigningKey

DRONE_KEY = SigningKey(bytes([7]) * 32)
GS_KEY = SigningKey(bytes([8]) * 32)
OTHER_KEY = SigningKey(bytes([9]) * 32)
KEYS = {"B": GS_KEY.public}


def _record(n: int = 20, every: int = 4) -> tuple[list[bytes], AuditChain]:
    chain = AuditChain("d1", DRONE_KEY, every=every)
    lines: list[bytes] = []
    for i in range(n):
        for line in chain.append("authority", {"from": "A", "to": "B", "epoch": i, "kind": "handover",
                                               "position": (47.4, 8.5, 30.0)}, 100.0 + i):
            lines.append(encode_line(line))
    lines += [encode_line(x) for x in chain.tick(100.0 + n + 5)]
    return lines, chain


def _witness(chain: AuditChain, now: float = 200.0) -> AuditWitness:
    cp = chain.last
    assert cp is not None
    w = countersign("B", GS_KEY, "d1", DRONE_KEY.public, cp.seq, bytes.fromhex(cp.head), base64.b64decode(cp.sig), now)
    assert w is not None
    return w


def _verify(lines, witnesses=()):
    return verify_chain("d1", lines, DRONE_KEY.public, witnesses, KEYS)


def _entries(lines):
    return [i for i, raw in enumerate(lines) if isinstance(decode_line(raw), AuditEntry)]


def _edit(raw: bytes, **changes) -> bytes:
    obj = json.loads(raw)
    for k, v in changes.items():
        if k in obj:
            obj[k] = v
        else:
            obj["fields"][k] = v
    return json.dumps(obj).encode()


def test_an_untouched_record_verifies_and_is_witnessed():
    lines, chain = _record()
    r = _verify(lines, [_witness(chain)])
    assert r.ok and r.entries == 20 and r.signed_through == 19 and r.unsigned == 0
    assert r.witnessed_through == 19 and r.witnesses == 1
    assert "verified 20 of 20" in r.summary()


def test_entries_after_the_last_checkpoint_are_reported_unsigned():
    chain = AuditChain("d1", DRONE_KEY, every=4, interval=1.0)
    lines = [encode_line(x) for i in range(6) for x in chain.append("failsafe", {"action": "LAND"}, float(i) * 0.1)]
    r = _verify(lines)
    assert r.ok and r.signed_through == 3 and r.unsigned == 2
    assert chain.tick(0.55) == []  # not yet an interval after the first unsigned entry (0.4)
    cp = chain.tick(1.5)
    assert len(cp) == 1 and isinstance(cp[0], AuditCheckpoint) and cp[0].seq == 5
    assert _verify(lines + [encode_line(cp[0])]).unsigned == 0


def test_a_modified_entry_is_named():
    lines, _ = _record()
    i = _entries(lines)[7]
    lines[i] = _edit(lines[i], to="X")
    r = _verify(lines)
    assert not r.ok and r.kind == "modified" and r.first_bad == 7


def test_the_last_modified_entry_before_a_checkpoint_is_named():
    lines, _ = _record()
    i = _entries(lines)[11]  # entry 11 is followed by the checkpoint of seq 11 (every 4)
    lines[i] = _edit(lines[i], epoch=99)
    r = _verify(lines)
    assert r.kind == "modified" and r.first_bad == 11


def test_a_modified_entry_with_the_chain_recomputed_fails_the_checkpoint_signature():
    # the first entry changed and every hash after it made again: only the node's key can sign the head
    chain = AuditChain("d1", OTHER_KEY, every=8)
    forged = [encode_line(x) for i in range(8) for x in chain.append(
        "authority", {"from": "A", "to": "X" if i == 0 else "B", "epoch": i, "kind": "handover",
                      "position": (47.4, 8.5, 30.0)}, 100.0 + i)]
    r = _verify(forged)
    assert r.kind == "bad_signature" and r.first_bad == 0


def test_a_deleted_entry_is_named():
    lines, _ = _record()
    del lines[_entries(lines)[5]]
    r = _verify(lines)
    assert r.kind == "missing" and r.first_bad == 5


def test_reordered_entries_are_named():
    lines, _ = _record()
    a, b = _entries(lines)[9], _entries(lines)[10]
    lines[a], lines[b] = lines[b], lines[a]
    r = _verify(lines)
    assert r.kind == "missing" and r.first_bad == 9  # entry 10 came where 9 belongs


def test_a_repeated_entry_is_out_of_order():
    lines, _ = _record()
    i = _entries(lines)[3]
    lines.insert(i + 1, lines[i])
    r = _verify(lines)
    assert r.kind == "out_of_order" and r.first_bad == 3


def test_truncation_is_detected_against_a_witness_only():
    lines, chain = _record()
    witness = _witness(chain)
    cut = lines[:_entries(lines)[12]]  # entries 12.. and their checkpoints gone
    assert _verify(cut).ok  # alone, a shorter record verifies: only a copy held elsewhere tells
    r = _verify(cut, [witness])
    assert r.kind == "truncated" and r.first_bad == 12 and "B countersigned entry 19" in r.problem


def test_a_rewritten_unsigned_tail_is_detected_against_a_witness():
    lines, chain = _record()
    witness = _witness(chain)
    keep = lines[:_entries(lines)[16]]  # up to the checkpoint of seq 15
    tail = AuditChain("d1", DRONE_KEY, seq=16, head=json.loads(lines[_entries(lines)[16]])["prev"], every=100)
    rewritten = keep + [encode_line(x) for i in range(16, 20) for x in tail.append("authority", {"to": "X"}, 1.0 * i)]
    assert _verify(rewritten).ok  # a chain again, but its tail is unsigned
    r = _verify(rewritten, [witness])
    assert r.kind == "modified" and r.first_bad == 16


def test_a_forged_checkpoint_signature_is_named():
    lines, _ = _record()
    i = next(i for i, raw in enumerate(lines) if isinstance(decode_line(raw), AuditCheckpoint))
    lines[i] = _edit(lines[i], sig=base64.b64encode(OTHER_KEY.sign(b"x")).decode())
    r = _verify(lines)
    assert r.kind == "bad_signature" and r.first_bad == 0


def test_a_witness_with_a_bad_countersignature_counts_for_nothing():
    lines, chain = _record()
    w = _witness(chain)
    fake = AuditWitness(w.node, w.seq + 5, w.head, w.sig, "B", w.t, w.wsig)  # claims more than B signed
    r = _verify(lines, [fake])
    assert r.ok and r.witnesses == 0
    assert countersign("B", GS_KEY, "d1", OTHER_KEY.public, 1, bytes(32), bytes(64), 0.0) is None


def test_an_undecodable_line_is_named():
    lines, _ = _record()
    lines[_entries(lines)[2]] = b'{"audit":"entry",'
    r = _verify(lines)
    assert r.kind == "undecodable" and r.first_bad == 2


def test_resume_continues_the_chain():
    lines, _ = _record(10)
    chain = AuditChain.resume("d1", DRONE_KEY, lines + [b"half a li"], every=4)
    assert chain.seq == 10
    more = [encode_line(x) for x in chain.append("failsafe", {"action": "LAND"}, 300.0)]
    more.append(encode_line(chain.checkpoint(301.0)))
    r = _verify(lines + more)
    assert r.ok and r.entries == 11 and r.unsigned == 0


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 19), st.sampled_from(["from", "to", "epoch", "t", "kind"]), st.integers(1, 1000))
def test_any_change_of_a_signed_entry_is_detected_at_that_entry(index, field, value):
    lines, _ = _record()
    i = _entries(lines)[index]
    old = json.loads(lines[i])
    new_value = {"epoch": value + 1000, "t": 1e6 + value}.get(field, f"changed-{value}")
    lines[i] = _edit(lines[i], **{field: new_value})
    assert json.loads(lines[i]) != old
    r = _verify(lines)
    assert not r.ok and r.first_bad == index


@pytest.mark.parametrize("n", [1, 64, 65])
def test_checkpoints_every_n_entries(n):
    chain = AuditChain("d1", DRONE_KEY, every=64)
    out = [x for i in range(n) for x in chain.append("paired", {"gs": "A"}, float(i))]
    assert sum(isinstance(x, AuditCheckpoint) for x in out) == n // 64


def test_a_witness_countersigns_each_checkpoint_once_and_never_a_forged_one():
    from zdrone.core.audit import Witnessing

    lines, chain = _record()
    w = Witnessing("B", GS_KEY, {"d1": DRONE_KEY.public})
    seq, head, sig = chain.last.raw()
    first = w.on_head("d1", seq, head, sig, 1.0)
    assert first is not None and _verify(lines, [first]).witnessed_through == seq
    assert w.on_head("d1", seq, head, sig, 2.0) is None  # repeated in every status: countersigned once
    assert w.on_head("d1", seq + 1, head, sig, 3.0) is None and w.refused == 1  # the signature is for seq
    assert w.on_head("X", seq, head, sig, 3.0) is None  # not a node it witnesses


def _rotated_record() -> list[bytes]:
    """d1 signs its first checkpoints with DRONE_KEY, is rotated to OTHER_KEY, signs on with it."""
    chain = AuditChain("d1", DRONE_KEY, every=4)
    lines: list[bytes] = []
    for i in range(10):
        lines += [encode_line(x) for x in chain.append("authority", {"epoch": i}, 100.0 + i)]
        if i == 5:  # two entries unsigned: signed under the old key before the chain goes on under the new
            rotated = chain.rekey(OTHER_KEY, 105.5)
            assert [type(x) for x in rotated] == [AuditCheckpoint]
            lines += [encode_line(x) for x in rotated]
    lines += [encode_line(x) for x in chain.tick(200.0)]
    return lines


def test_a_rotated_node_s_earlier_checkpoints_verify_against_the_key_in_force_when_signed():
    lines = _rotated_record()
    r = verify_chain("d1", lines, (DRONE_KEY.public, OTHER_KEY.public))
    assert r.ok and r.checkpoints == 3 and r.signed_through == 9, r.summary()
    # the new key alone: the first checkpoint (signed before the rotation) fails
    r = verify_chain("d1", lines, OTHER_KEY.public)
    assert (r.kind, r.first_bad) == ("bad_signature", 0)
    # the old key alone: the first checkpoint after the rotation fails
    r = verify_chain("d1", lines, DRONE_KEY.public)
    assert (r.kind, r.first_bad) == ("bad_signature", 6) and r.signed_through == 5


def test_a_checkpoint_under_a_retired_key_after_the_rotation_is_refused():
    """Whoever stole the retired key signs nothing after the rotation: keys only move forward."""
    lines = _rotated_record()
    chain = AuditChain.resume("d1", DRONE_KEY, lines, every=1)  # the old key appends after the new one signed
    lines += [encode_line(x) for x in chain.append("failsafe", {"action": "LAND"}, 300.0)]
    r = verify_chain("d1", lines, (DRONE_KEY.public, OTHER_KEY.public))
    assert (r.kind, r.first_bad) == ("bad_signature", 10) and "retired" in (r.problem or "")


def test_a_witness_of_an_earlier_checkpoint_holds_after_the_rotation():
    lines = _rotated_record()
    first = decode_line(next(raw for raw in lines if isinstance(decode_line(raw), AuditCheckpoint)))
    w = countersign("B", GS_KEY, "d1", DRONE_KEY.public, first.seq, bytes.fromhex(first.head),
                    base64.b64decode(first.sig), 150.0)
    assert w is not None
    r = verify_chain("d1", lines, (DRONE_KEY.public, OTHER_KEY.public), [w], KEYS)
    assert r.ok and r.witnesses == 1 and r.witnessed_through == first.seq


# ---------------------------------------------------------------- countersignatures chained, keys in force

GS_NEW_KEY = SigningKey(bytes([10]) * 32)


def _gs_record(*entries: tuple[str, dict], key: SigningKey = GS_KEY) -> list[bytes]:
    """GS B's record: the entries given (kind, fields), then a checkpoint."""
    gs = AuditChain("B", key, every=100)
    lines = [encode_line(x) for i, (kind, fields) in enumerate(entries) for x in gs.append(kind, fields, 200.0 + i)]
    return lines + [encode_line(gs.checkpoint(300.0))]


def _revision(number: int, rotated: tuple[str, ...]) -> tuple[str, dict]:
    return "revision_applied", {"number": number, "revoked": [], "rotated": list(rotated), "pairing_pq": False}


def test_a_countersignature_is_an_entry_of_the_witness_s_chain_and_deleting_it_breaks_that_chain():
    from zdrone.core.audit import WITNESS_KIND, check_chain, witness_fields

    lines, chain = _record()
    b = _gs_record((WITNESS_KIND, witness_fields(_witness(chain))), ("operator_request_granted", {"drone": "d1"}))
    witness = check_chain("B", b, GS_KEY.public, {"d1": DRONE_KEY.public})
    assert witness.problem is None and [(w.witness, w.seq) for w in witness.countersigned] == [("B", 19)]
    cut = lines[:_entries(lines)[12]]
    r = check_chain("d1", cut, DRONE_KEY.public).report(witness.countersigned, witnessed=True)
    assert (r.kind, r.first_bad) == ("truncated", 12)
    r = check_chain("d1", lines, DRONE_KEY.public).report(witness.countersigned, witnessed=True)
    assert r.ok and r.witnessed_through == 19 and r.unwitnessed == 0
    # the countersignature deleted from B's record: B's record is missing that entry
    gone = check_chain("B", b[1:], GS_KEY.public, {"d1": DRONE_KEY.public})
    assert (gone.kind, gone.first_bad) == ("missing", 0) and gone.countersigned == []
    # a witness line outside any chain (the format before) vouches for nothing
    free = check_chain("B", [encode_line(_witness(chain))], GS_KEY.public, {"d1": DRONE_KEY.public})
    assert free.countersigned == [] and free.unchained == 1
    r = check_chain("d1", cut, DRONE_KEY.public).report(free.countersigned, witnessed=True)
    assert r.ok and r.witnesses == 0 and r.unwitnessed == 12 and "no witness of its 12 decisions" in r.summary()


def test_a_checkpoint_under_the_key_a_revision_the_node_applied_retired_is_refused():
    """d1 applied revision 3, which rotated it: whoever holds its old key signs nothing after that entry."""
    keys = ((0, DRONE_KEY.public), (3, OTHER_KEY.public))

    def up_to_the_revision() -> tuple[AuditChain, list[bytes]]:
        chain = AuditChain("d1", DRONE_KEY, every=100)
        lines = [encode_line(x) for i in range(3) for x in chain.append("paired", {"gs": "A"}, float(i))]
        return chain, lines + [encode_line(x) for x in chain.append(*_revision(3, ("d1",)), 3.0)]

    chain, lines = up_to_the_revision()
    lines += [encode_line(x) for x in chain.append("failsafe", {"action": "LAND"}, 4.0)]
    lines.append(encode_line(chain.checkpoint(5.0)))  # the retired key signs past the revision
    r = verify_chain("d1", lines, keys)
    assert (r.kind, r.first_bad) == ("bad_signature", 0) and "d1's key retired by revision 3" in (r.problem or "")
    # the node itself: the entries up to the revision under the old key, the rest under the new
    chain, honest = up_to_the_revision()
    honest += [encode_line(x) for x in chain.rekey(OTHER_KEY, 3.5)]
    honest += [encode_line(x) for x in chain.append("failsafe", {"action": "LAND"}, 4.0)]
    honest.append(encode_line(chain.checkpoint(5.0)))
    r = verify_chain("d1", honest, keys)
    assert r.ok and r.signed_through == 4 and r.checkpoints == 2, r.summary()


def test_a_countersignature_under_keys_retired_by_a_revision_the_witness_applied_is_a_bad_witness():
    from zdrone.core.audit import WITNESS_KIND, check_chain, witness_fields

    _, chain = _record()
    b_keys = ((0, GS_KEY.public), (2, GS_NEW_KEY.public))
    old = (WITNESS_KIND, witness_fields(_witness(chain)))  # countersigned with B's first key
    keys = {"d1": DRONE_KEY.public}
    assert check_chain("B", _gs_record(old), b_keys, keys).problem is None  # before B's rotation: its key then
    c = check_chain("B", _gs_record(_revision(2, ("B",)), old), b_keys, keys)
    assert (c.kind, c.first_bad) == ("bad_witness", 1) and "revision 2" in (c.problem or "")
    cp = chain.last
    assert cp is not None
    new = countersign("B", GS_NEW_KEY, "d1", DRONE_KEY.public, cp.seq, bytes.fromhex(cp.head),
                      base64.b64decode(cp.sig), 200.0)
    assert new is not None
    renewed = _gs_record(_revision(2, ("B",)), (WITNESS_KIND, witness_fields(new)), key=GS_NEW_KEY)
    assert check_chain("B", renewed, b_keys, keys).problem is None
    # the drone's checkpoint under the drone's key that revision retired: B vouches for no retired key
    c = check_chain("B", renewed, b_keys, {"d1": ((0, DRONE_KEY.public), (2, OTHER_KEY.public))})
    assert (c.kind, c.first_bad) == ("bad_witness", 1)


def test_a_witness_follows_the_fleet_s_keys():
    from zdrone.core.audit import Witnessing

    _, chain = _record()
    seq, head, sig = chain.last.raw()
    w = Witnessing("B", GS_KEY, {"d1": DRONE_KEY.public})
    w.set_node_keys({"d1": OTHER_KEY.public})  # d1 rotated: its old key's checkpoint is refused
    assert w.on_head("d1", seq, head, sig, 1.0) is None and w.refused == 1
    w.set_node_keys({"d1": DRONE_KEY.public})
    w.rekey(None)  # B rotated, its new key not here yet: it countersigns nothing
    assert w.on_head("d1", seq, head, sig, 2.0) is None and w.refused == 1
    w.rekey(GS_NEW_KEY)
    got = w.on_head("d1", seq, head, sig, 3.0)
    assert got is not None and verify_chain("d1", _record()[0], DRONE_KEY.public, [got],
                                            {"B": GS_NEW_KEY.public}).witnessed_through == seq


def test_a_checkpoint_is_offered_only_when_it_covers_a_decision_with_the_drones_it_names():
    """``AuditChain.offer``: what a GS asks its drones to countersign. A checkpoint that covers only
    countersignatures is not offered (else countersigning each other's would never end)."""
    from zdrone.core.audit import WITNESS_KIND, witness_fields

    gs = AuditChain("B", GS_KEY, every=64)
    gs.append("operator_request_granted", {"drone": "d1", "requester": "A"}, 0.0)
    gs.append("handover_release", {"drone": "d2", "to": "A"}, 0.1)
    first = gs.checkpoint(1.0)
    assert gs.offer == (first, frozenset({"d1", "d2"}))
    _, chain = _record()
    gs.append(WITNESS_KIND, witness_fields(_witness(chain)), 2.0)
    gs.checkpoint(3.0)
    assert gs.offer == (first, frozenset({"d1", "d2"}))  # the countersignature alone: the same offer
    gs.append("takeover_window_opened", {"drone": "d1", "to": "A"}, 4.0)
    assert gs.offer[0] is first
    assert gs.tick(5.5)[0] == gs.offer[0] and gs.offer[1] == {"d1"}


def test_a_gs_s_decisions_after_its_last_countersigned_entry_are_unwitnessed_its_countersignatures_not():
    from zdrone.core.audit import WITNESS_KIND, check_chain, witness_fields

    _, chain = _record()
    gs = AuditChain("B", GS_KEY, every=64)
    b = [encode_line(x) for x in gs.append("operator_request_granted", {"drone": "d1"}, 0.0)]
    b += [encode_line(gs.checkpoint(1.0))]
    b += [encode_line(x) for x in gs.append(WITNESS_KIND, witness_fields(_witness(chain)), 2.0)]
    b += [encode_line(gs.checkpoint(3.0))]
    checked = check_chain("B", b, GS_KEY.public, {"d1": DRONE_KEY.public})
    assert checked.decisions == [0]
    r = checked.report([], witnessed=True)
    assert r.ok and r.unwitnessed == 1 and "no witness of its 1 decisions" in r.summary()
    # the drone countersigns B's consent (its checkpoint of entry 0): B's trailing countersignature is no decision
    cp = AuditCheckpoint("B", 0, checked.hashes[0], 1.0, "")
    w = countersign("d1", DRONE_KEY, "B", GS_KEY.public, 0, bytes.fromhex(cp.head),
                    base64.b64decode(json.loads(b[1])["sig"]), 4.0)
    assert w is not None
    r = checked.report([w], witnessed=True)
    assert r.ok and (r.witnessed_through, r.unwitnessed) == (0, 0)
    # B's record cut back before its consent: the drone's countersignature says otherwise
    r = check_chain("B", [], GS_KEY.public).report([w], witnessed=True)
    assert (r.kind, r.first_bad) == ("truncated", 0)


def test_a_witness_given_a_period_countersigns_a_node_at_most_once_in_it():
    from zdrone.core.audit import Witnessing

    gs = AuditChain("B", GS_KEY, every=1)
    w = Witnessing("d1", DRONE_KEY, {"B": GS_KEY.public}, every=0.4)
    heads = [gs.append("handover_release", {"drone": "d1"}, float(i))[1].raw() for i in range(3)]
    assert w.on_head("B", *heads[0], 10.0) is not None
    assert w.on_head("B", *heads[1], 10.1) is None and w.refused == 0  # too soon: not even checked
    assert w.on_head("B", *heads[1], 10.5).seq == 1 and w.on_head("B", *heads[2], 10.6) is None
