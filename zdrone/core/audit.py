"""The authority record: a node's authority decisions as a signed hash chain, countersigned by witnesses.

Theory of operation
-------------------
Every authority decision a node takes (a drone: pairing, hand-over, release, emergency hand-over,
failsafe, a fleet revision applied; a ground station: its operator's consent with the application
named) becomes one ``AuditEntry``: its sequence number, the node's time, the decision's kind and
fields, and ``prev``, the hash of the entry before it (the first entry chains to a hash of the node's
name). An entry's hash is SHA-256 over a deterministic encoding of all of these and the node's name,
so changing, removing or moving any entry breaks the chain at the next entry.

A hash chain alone proves nothing: whoever edits the file can compute the hashes again. So the node
signs the chain's head with its Ed25519 key (``Node.signing_key`` in the fleet) in an
``AuditCheckpoint`` (node, seq, head hash): every ``every`` entries, and ``interval`` seconds after
an entry at the latest (``AuditChain.tick``). A checkpoint covers every entry up to its ``seq``: one
signature check per checkpoint plus one hash per entry is what verifying costs (``zdrone bench
crypto``: 100 000 entries well under a second), where a signature per entry would cost 60 µs each.
Entries after the last checkpoint are reported as unsigned, never as verified.

Deleting the end of the file (and its checkpoints) leaves a shorter chain that verifies: only a copy
held elsewhere can tell. The drone sends its newest checkpoint in its authority status to every GS it
is linked to (``wire.AuditHead``); a GS checks the drone's signature and countersigns it
(``AuditWitness``, in the GS's own record). Against a witness, a record that ends before the
witnessed ``seq``, or whose hash at that ``seq`` differs, is truncated or rewritten.

``verify_chain`` checks one node's lines offline against the fleet's public keys and stops at the
first problem, naming the first bad entry: ``modified`` (an entry's hash is not the one the next
entry or a checkpoint names), ``missing`` (a sequence number skipped: deleted or reordered),
``out_of_order``, ``bad_signature``, ``truncated`` (against a witness), ``undecodable``.

Keys over time: a node whose signing key was rotated (a fleet revision) signed its earlier
checkpoints with its earlier key. ``verify_chain`` takes a node's keys in the order the fleet gave
them (the base fleet's, then each revision's that changed it: ``zdrone.fleet.revisions.
signing_key_history``); each checkpoint must verify under the key in force at the checkpoint before
it or a later one, never an earlier one: once a checkpoint is signed with a newer key, a checkpoint
signed with a retired key after it is ``bad_signature`` (a stolen retired key writes nothing after
the rotation).

Pure: no clock (``now`` comes in), no files (lines in, lines out; ``zdrone.net.eventlog`` writes
them).
"""

from __future__ import annotations

import base64
import hashlib
import struct
from dataclasses import dataclass
from typing import Any, Iterable, Sequence

import msgspec

from .keys import SigningKey, verify_signature

#: Checkpoint at least every this many entries, and this many seconds after an unsigned entry.
CHECKPOINT_EVERY = 64
CHECKPOINT_INTERVAL = 1.0
#: The record types (``zdrone.core.records``) that are authority decisions: appended to the chain.
AUDITED = frozenset({
    # a drone's
    "authority", "handover_complete", "handover_start", "handover_timeout", "handover_aborted", "paired",
    "failsafe", "failsafe_entered", "failsafe_recovered", "key_installed", "restarted", "restored",
    "restore_refused", "authority_forgotten", "first_claim", "first_claim_over", "revision_applied", "revoked",
    # a ground station's: consent (with the application named) and what it released
    "operator_request_granted", "operator_request_declined", "operator_consent_refused",
    "takeover_window_opened", "handover_release",
})

_HASH_DOMAIN = b"zdrone audit entry v2\0"  # v2: over the line's bytes
_CHECKPOINT_DOMAIN = b"zdrone audit checkpoint v1\0"
_WITNESS_DOMAIN = b"zdrone audit witness v1\0"


class AuditEntry(msgspec.Struct, frozen=True, tag="entry", tag_field="audit", forbid_unknown_fields=True):
    """One decision: ``kind`` (its record type) and ``fields``; ``prev``: the previous entry's hash (hex)."""

    node: str
    seq: int
    t: float
    kind: str
    fields: dict[str, Any]
    prev: str


class AuditCheckpoint(msgspec.Struct, frozen=True, tag="checkpoint", tag_field="audit", forbid_unknown_fields=True):
    """The node's signature (base64) of its chain's head: entry ``seq`` has hash ``head`` (hex)."""

    node: str
    seq: int
    head: str
    t: float
    sig: str

    def raw(self) -> tuple[int, bytes, bytes]:
        """(seq, head, signature) as bytes: what the drone sends its ground stations (``wire.AuditHead``)."""
        return self.seq, bytes.fromhex(self.head), _unb64(self.sig)


class AuditWitness(msgspec.Struct, frozen=True, tag="witness", tag_field="audit", forbid_unknown_fields=True):
    """A witness's countersignature (``wsig``) of ``node``'s checkpoint (seq, head, the node's ``sig``)."""

    node: str
    seq: int
    head: str
    sig: str
    witness: str
    t: float
    wsig: str


AuditLine = AuditEntry | AuditCheckpoint | AuditWitness

_line_decoder = msgspec.json.Decoder(AuditLine)
_line_encoder = msgspec.json.Encoder()


def genesis(node: str) -> str:
    """The ``prev`` of a node's first entry."""
    return hashlib.sha256(b"zdrone audit genesis v1\0" + node.encode()).hexdigest()


def entry_hash(e: AuditEntry) -> str:
    """The hash of the entry's line as ``encode_line`` writes it."""
    return line_hash(encode_line(e))


def line_hash(raw: bytes) -> str:
    """The hash of an entry from the bytes of its line (without the newline)."""
    return hashlib.sha256(_HASH_DOMAIN + raw).hexdigest()


def checkpoint_message(node: str, seq: int, head: str) -> bytes:
    return _CHECKPOINT_DOMAIN + node.encode() + b"\0" + struct.pack(">Q", seq) + bytes.fromhex(head)


def witness_message(witness: str, node: str, seq: int, head: str) -> bytes:
    return _WITNESS_DOMAIN + witness.encode() + b"\0" + checkpoint_message(node, seq, head)


def encode_line(line: AuditLine) -> bytes:
    return _line_encoder.encode(line)


def decode_line(data: bytes | str) -> AuditLine:
    """One line of a record; raises ``msgspec.DecodeError`` / ``msgspec.ValidationError``."""
    return _line_decoder.decode(data)


def _b64(raw: bytes) -> str:
    return base64.b64encode(raw).decode("ascii")


def _unb64(text: str) -> bytes:
    try:
        return base64.b64decode(text.encode("ascii"), validate=True)
    except (ValueError, UnicodeEncodeError):
        return b""


class AuditChain:
    """A node's chain being written: ``append`` each decision, ``tick`` on the node's clock."""

    def __init__(self, node: str, key: SigningKey, every: int = CHECKPOINT_EVERY,
                 interval: float = CHECKPOINT_INTERVAL, seq: int = 0, head: str | None = None) -> None:
        """``seq``/``head``: where an existing record ends (``resume``): the next entry's number and
        the hash it chains to."""
        self.node, self.key, self.every, self.interval = node, key, every, interval
        self.seq = seq
        self.head = head if head is not None else genesis(node)
        self.last: AuditCheckpoint | None = None  # the newest checkpoint (what the node shows witnesses)
        self._pending = 0  # entries since the last checkpoint
        self._first_pending_at = 0.0

    @classmethod
    def resume(cls, node: str, key: SigningKey, lines: Iterable[bytes | str], **kw: Any) -> "AuditChain":
        """Continue the record whose lines are given (a restarted node): after its last entry."""
        last: tuple[AuditEntry, bytes] | None = None
        for raw in lines:
            raw = raw.encode() if isinstance(raw, str) else raw
            try:
                line = decode_line(raw)
            except (msgspec.DecodeError, msgspec.ValidationError):
                continue
            if isinstance(line, AuditEntry) and line.node == node:
                last = line, raw
        if last is None:
            return cls(node, key, **kw)
        return cls(node, key, seq=last[0].seq + 1, head=line_hash(last[1].strip()), **kw)

    def append(self, kind: str, fields: dict[str, Any], now: float) -> list[AuditLine]:
        """The entry of one decision (and a checkpoint when ``every`` entries are unsigned)."""
        entry = AuditEntry(self.node, self.seq, round(now, 4), kind, msgspec.to_builtins(fields, enc_hook=str), self.head)
        self.head, self.seq = entry_hash(entry), self.seq + 1
        if not self._pending:
            self._first_pending_at = now
        self._pending += 1
        out: list[AuditLine] = [entry]
        if self._pending >= self.every:
            out.append(self.checkpoint(now))
        return out

    @property
    def pending(self) -> int:
        """Entries appended since the last checkpoint."""
        return self._pending

    def tick(self, now: float) -> list[AuditLine]:
        """A checkpoint when an entry has waited ``interval`` seconds unsigned."""
        if self._pending and now - self._first_pending_at >= self.interval:
            return [self.checkpoint(now)]
        return []

    def rekey(self, key: SigningKey, now: float) -> list[AuditLine]:
        """The node's signing key rotated (a fleet revision): the entries still unsigned are signed
        under the old key first (a checkpoint), then the chain goes on under ``key``."""
        out: list[AuditLine] = [self.checkpoint(now)] if self._pending else []
        self.key = key
        return out

    def checkpoint(self, now: float) -> AuditCheckpoint:
        """Sign the head now (the entries so far)."""
        if self.seq == 0:
            raise RuntimeError("no entry to sign")
        seq = self.seq - 1
        cp = AuditCheckpoint(self.node, seq, self.head, round(now, 4),
                             _b64(self.key.sign(checkpoint_message(self.node, seq, self.head))))
        self.last, self._pending = cp, 0
        return cp


def countersign(witness: str, key: SigningKey, node: str, node_public: bytes | None, seq: int, head: bytes,
                sig: bytes, now: float) -> AuditWitness | None:
    """A witness's countersignature of ``node``'s checkpoint, None if the node's signature does not
    verify against its fleet key (the witness never vouches for what it could not check)."""
    if node_public is None or len(head) != 32 or seq < 0:
        return None
    if not verify_signature(node_public, checkpoint_message(node, seq, head.hex()), sig):
        return None
    return AuditWitness(node, seq, head.hex(), _b64(sig), witness, round(now, 4),
                        _b64(key.sign(witness_message(witness, node, seq, head.hex()))))


class Witnessing:
    """A witness's side: countersign each node's checkpoint once, when its ``seq`` grows (the node
    repeats its newest in every status); a checkpoint whose signature fails is counted, never signed."""

    def __init__(self, witness: str, key: SigningKey, node_keys: dict[str, bytes | None]) -> None:
        self.witness, self.key, self.node_keys = witness, key, node_keys
        self.last: dict[str, int] = {}  # per node: the seq countersigned last (bounded by the fleet's nodes)
        self.refused = 0

    def on_head(self, node: str, seq: int, head: bytes, sig: bytes, now: float) -> AuditWitness | None:
        if node not in self.node_keys or seq <= self.last.get(node, -1):
            return None
        w = countersign(self.witness, self.key, node, self.node_keys[node], seq, head, sig, now)
        if w is None:
            self.refused += 1
            return None
        self.last[node] = seq
        return w


#: One node's public signing key, or its keys in the order the fleet's revisions gave them.
PublicKeys = bytes | Sequence[bytes] | None


def key_list(keys: PublicKeys) -> tuple[bytes, ...]:
    """A node's keys in force over time (oldest first), from one key, a sequence or None."""
    if keys is None:
        return ()
    return (keys,) if isinstance(keys, bytes) else tuple(keys)


def witness_valid(w: AuditWitness, node_public: PublicKeys, witness_public: PublicKeys) -> bool:
    """Both signatures of a witness line check (the node's and the witness's), each under one of its
    keys over time (a witness line carries no order of its own)."""
    node_keys, witness_keys = key_list(node_public), key_list(witness_public)
    if not node_keys or not witness_keys:
        return False
    try:
        bytes.fromhex(w.head)
    except ValueError:
        return False
    cp, ws = checkpoint_message(w.node, w.seq, w.head), witness_message(w.witness, w.node, w.seq, w.head)
    sig, wsig = _unb64(w.sig), _unb64(w.wsig)
    return (any(verify_signature(k, cp, sig) for k in node_keys)
            and any(verify_signature(k, ws, wsig) for k in witness_keys))


@dataclass(frozen=True, slots=True)
class ChainReport:
    """What ``verify_chain`` found for one node's record."""

    node: str
    entries: int  # entries read before the first problem (all of them if none)
    checkpoints: int  # valid checkpoints
    signed_through: int  # the last seq a valid checkpoint covers (-1: none)
    witnessed_through: int  # the highest seq a valid witness countersigned (-1: none)
    witnesses: int  # valid witness lines for this node
    problem: str | None = None  # the first problem, in one line (None: the record verifies)
    kind: str | None = None  # modified, missing, out_of_order, bad_signature, truncated, undecodable, ...
    first_bad: int | None = None  # the first bad entry's seq

    @property
    def ok(self) -> bool:
        return self.problem is None

    @property
    def unsigned(self) -> int:
        """Entries after the last checkpoint: not (yet) signed, so not verified."""
        return self.entries - (self.signed_through + 1)

    def summary(self) -> str:
        if self.problem is not None:
            return f"{self.node}: BAD at entry {self.first_bad}: {self.problem}"
        tail = f", {self.unsigned} unsigned after the last checkpoint" if self.unsigned else ""
        wit = (f", witnessed through seq {self.witnessed_through} ({self.witnesses} countersignatures)"
               if self.witnesses else ", no witness")
        return f"{self.node}: verified {self.signed_through + 1} of {self.entries} entries{tail}{wit}"


def verify_chain(node: str, lines: Iterable[bytes | str | AuditLine], node_public: PublicKeys,
                 witnesses: Iterable[AuditWitness] = (), witness_keys: dict[str, Any] | None = None
                 ) -> ChainReport:
    """Check ``node``'s record (its entry and checkpoint lines, in file order) against its fleet
    signing key (or its keys over time, oldest first: each checkpoint under the one in force then),
    then against the witnesses' countersigned checkpoints; stop at the first problem."""
    node_keys = key_list(node_public)
    in_force = 0  # index in node_keys of the key the last valid checkpoint verified under
    hashes: list[str] = []
    prev = genesis(node)
    checkpoints = 0
    signed = -1

    def bad(kind: str, first: int, problem: str) -> ChainReport:
        return ChainReport(node, len(hashes), checkpoints, signed, -1, 0, problem, kind, first)

    for i, item in enumerate(lines):
        if isinstance(item, (bytes, str)):
            raw = (item.encode() if isinstance(item, str) else item).strip()
            try:
                line = decode_line(raw)
            except (msgspec.DecodeError, msgspec.ValidationError) as exc:
                return bad("undecodable", len(hashes), f"line {i + 1} is no audit line ({str(exc)[:60]})")
        else:  # a line made in memory: its bytes are encode_line's
            line, raw = item, None
        if isinstance(line, AuditWitness):
            continue  # a witness line in a node's own file vouches for another node's record
        if line.node != node:
            return bad("foreign", len(hashes), f"line {i + 1} is {line.node}'s, in {node}'s record")
        if isinstance(line, AuditEntry):
            expect = len(hashes)
            if line.seq < expect:
                return bad("out_of_order", line.seq, f"entry {line.seq} comes again after entry {expect - 1}")
            if line.seq > expect:
                return bad("missing", expect, f"entry {expect} is missing (entry {line.seq} follows entry "
                                              f"{expect - 1}): deleted or reordered")
            if line.prev != prev:
                return bad("modified", expect - 1, f"entry {expect - 1} is not the one entry {expect} chains to")
            prev = line_hash(raw) if raw is not None else entry_hash(line)
            hashes.append(prev)
        else:
            if line.seq >= len(hashes) or line.seq < 0:
                return bad("missing", len(hashes), f"entry {len(hashes)} is missing (a checkpoint signs entry "
                                                   f"{line.seq} here): deleted or reordered")
            if hashes[line.seq] != line.head:
                return bad("modified", line.seq, f"entry {line.seq} is not the one its checkpoint signed")
            message, sig = checkpoint_message(node, line.seq, line.head), _unb64(line.sig)
            under = next((i for i in range(in_force, len(node_keys)) if verify_signature(node_keys[i], message, sig)),
                         None)
            if under is None:
                retired = any(verify_signature(k, message, sig) for k in node_keys[:in_force])
                return bad("bad_signature", signed + 1,
                           f"the checkpoint of entry {line.seq} is signed by a key of {node}'s retired before it"
                           if retired else f"the checkpoint of entry {line.seq} is not signed by {node}'s fleet key")
            in_force = under
            checkpoints += 1
            signed = max(signed, line.seq)
    witnessed, count = -1, 0
    keys = witness_keys or {}
    for w in witnesses:
        if w.node != node or not witness_valid(w, node_public, keys.get(w.witness)):
            continue
        count += 1
        if w.seq >= len(hashes):
            return ChainReport(node, len(hashes), checkpoints, signed, witnessed, count,
                               f"the record ends at entry {len(hashes) - 1} but {w.witness} countersigned entry "
                               f"{w.seq}: truncated", "truncated", len(hashes))
        if hashes[w.seq] != w.head:
            return ChainReport(node, len(hashes), checkpoints, signed, witnessed, count,
                               f"entries up to {w.seq} differ from what {w.witness} countersigned: rewritten",
                               "modified", min(w.seq, signed + 1))  # entries a valid checkpoint covers are the node's
        witnessed = max(witnessed, w.seq)
    return ChainReport(node, len(hashes), checkpoints, signed, witnessed, count)
