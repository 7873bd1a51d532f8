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
held elsewhere can tell. So every node's checkpoints are countersigned by another node: the drone
sends its newest checkpoint in its authority status to every GS it is linked to (``wire.AuditHead``),
and a GS sends each checkpoint that covers one of its own decisions (``AuditChain.offer``) to the
drones those decisions name (``wire.AuditOffer``). The countersigner checks the signature and
countersigns it: the countersignature (``AuditWitness``) is an **entry of the countersigner's own
chain** (kind ``witness``, ``witness_fields``), hashed, chained and signed like its decisions, so
deleting it breaks that record at that entry. Against a countersignature, a record that ends before
the countersigned ``seq``, or whose hash at that ``seq`` differs, is truncated or rewritten; a node's
decisions (entries other than countersignatures) after its last countersigned one
(``ChainReport.unwitnessed``) are its word alone. A GS's checkpoint that covers only
countersignatures is not offered: countersigning each other's countersignatures would never end.

``check_chain`` checks one node's lines offline against the fleet's public keys and stops at the
first problem, naming the first bad entry: ``modified`` (an entry's hash is not the one the next
entry or a checkpoint names), ``missing`` (a sequence number skipped: deleted or reordered),
``out_of_order``, ``bad_signature``, ``bad_witness`` (a countersignature in the chain that does not
verify under the keys in force then), ``undecodable``; it collects the chain's countersignatures.
``CheckedChain.report`` then checks the record against every witness's (``truncated``, ``modified``).
``verify_chain`` is both for one record. A witness line outside any chain (the format before witnesses
were entries) vouches for nothing: counted as ``unchained``.

Keys over time: a node whose signing key was rotated (a fleet revision) signed its earlier
checkpoints with its earlier key. The keys come in the order the fleet gave them, with the revision
that gave each (``zdrone.fleet.revisions.signing_key_epochs``: the base fleet's at 0); each
checkpoint must verify under the key in force at the checkpoint before it or a later one, never an
earlier one (once its successor signed, a retired key signs nothing more), and every checkpoint
that covers an entry after the node's own ``revision_applied`` entry of revision N must verify under
the key in force at N or a later one: a node moves its signing to its new key when it applies the
revision that rotated it (``key_floor``). A countersignature is checked likewise: the witness's
signature under the witness's key in force at the revision the witness had applied before it, the
node's signature under the node's key in force at that revision.

What verifying cannot tell: records cut back together to a consistent earlier point. One node's
record cut back alone is caught wherever another record holds a countersignature of a checkpoint it
cut (``truncated``). What no record holds a countersignature of is the **tail of each record after
its last countersigned checkpoint** (the decisions in it are reported as ``unwitnessed``;
``zdrone audit verify --require-witnessed`` refuses them), and the countersignatures at the very end
of a record (they are not offered). So these cuts verify: any record cut to its last countersigned
checkpoint; and several cut together so that each countersignature deleted goes with everything it
vouched for, e.g. A's consent and the drone's countersignature of it and every GS's countersignature
of the drone's checkpoint after it. Only a copy held elsewhere tells (records collected off the
nodes). A node's key stolen before its rotation can still write a record that ends before the node
applied the rotation.

Pure: no clock (``now`` comes in), no files (lines in, lines out; ``zdrone.net.eventlog`` writes
them).
"""

from __future__ import annotations

import base64
import bisect
import hashlib
import struct
from dataclasses import dataclass, field
from typing import Any, Iterable, Mapping, Sequence

import msgspec

from zdrone.core.keys import SigningKey, verify_signature

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

#: The entry kind of a witness's countersignature (in the witness's own chain) and of a revision applied.
WITNESS_KIND = "witness"
REVISION_KIND = "revision_applied"

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
    """A witness's countersignature (``wsig``) of ``node``'s checkpoint (seq, head, the node's ``sig``):
    what ``countersign`` makes and the witness appends to its own chain (``witness_fields``); as a
    line of its own (the format before) it vouches for nothing."""

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

    def __init__(self, node: str, key: SigningKey | None, every: int = CHECKPOINT_EVERY,
                 interval: float = CHECKPOINT_INTERVAL, seq: int = 0, head: str | None = None) -> None:
        """``seq``/``head``: where an existing record ends (``resume``): the next entry's number and
        the hash it chains to. ``key`` None: no key in force (a rotation whose new key the node does
        not hold yet): entries are chained, never signed."""
        self.node, self.key, self.every, self.interval = node, key, every, interval
        self.seq = seq
        self.head = head if head is not None else genesis(node)
        self.last: AuditCheckpoint | None = None  # the newest checkpoint (what the node shows witnesses)
        #: the newest checkpoint that covers a decision (not only countersignatures), with the drones
        #: those decisions name: what a GS asks them to countersign (``wire.AuditOffer``)
        self.offer: tuple[AuditCheckpoint, frozenset[str]] | None = None
        self._pending = 0  # entries since the last checkpoint
        self._first_pending_at = 0.0
        self._decided = False  # a decision among them
        self._named: set[str] = set()  # the drones their decisions name

    @classmethod
    def resume(cls, node: str, key: SigningKey | None, lines: Iterable[bytes | str], **kw: Any) -> "AuditChain":
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
        if kind != WITNESS_KIND:
            self._decided = True
            if isinstance(drone := entry.fields.get("drone"), str):
                self._named.add(drone)
        out: list[AuditLine] = [entry]
        if self._pending >= self.every and self.key is not None:
            out.append(self.checkpoint(now))
        return out

    @property
    def pending(self) -> int:
        """Entries appended since the last checkpoint."""
        return self._pending

    def tick(self, now: float) -> list[AuditLine]:
        """A checkpoint when an entry has waited ``interval`` seconds unsigned."""
        if self._pending and self.key is not None and now - self._first_pending_at >= self.interval:
            return [self.checkpoint(now)]
        return []

    def rekey(self, key: SigningKey | None, now: float) -> list[AuditLine]:
        """The node's signing key rotated (a fleet revision): the entries still unsigned are signed
        under the old key first (a checkpoint), then the chain goes on under ``key`` (None: unsigned
        until a key comes)."""
        out: list[AuditLine] = [self.checkpoint(now)] if self._pending and self.key is not None else []
        self.key = key
        return out

    def checkpoint(self, now: float) -> AuditCheckpoint:
        """Sign the head now (the entries so far)."""
        if self.seq == 0:
            raise RuntimeError("no entry to sign")
        if self.key is None:
            raise RuntimeError("no signing key in force")
        seq = self.seq - 1
        cp = AuditCheckpoint(self.node, seq, self.head, round(now, 4),
                             _b64(self.key.sign(checkpoint_message(self.node, seq, self.head))))
        self.last, self._pending = cp, 0
        if self._decided:
            self.offer = cp, frozenset(self._named)
            self._decided, self._named = False, set()
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


def witness_fields(w: AuditWitness) -> dict[str, Any]:
    """The fields of the witness's chain entry (kind ``WITNESS_KIND``) that holds ``w``."""
    return {"node": w.node, "seq": w.seq, "head": w.head, "sig": w.sig, "wsig": w.wsig}


def witness_from_entry(e: AuditEntry) -> AuditWitness | None:
    """The countersignature a witness entry holds (the witness: the entry's node), None if malformed."""
    f = e.fields
    node, seq, head, sig, wsig = f.get("node"), f.get("seq"), f.get("head"), f.get("sig"), f.get("wsig")
    if (not isinstance(node, str) or not isinstance(seq, int) or isinstance(seq, bool) or seq < 0
            or not isinstance(head, str) or not isinstance(sig, str) or not isinstance(wsig, str) or len(f) != 5):
        return None
    return AuditWitness(node, seq, head, sig, e.node, e.t, wsig)


class Witnessing:
    """A witness's side: countersign each node's checkpoint once, when its ``seq`` grows (the node
    repeats its newest in every status); a checkpoint whose signature fails is counted, never signed.
    The node keys follow the fleet's revisions (``set_node_keys``) and so does the witness's own
    (``rekey``: None while it holds no key in force, then it countersigns nothing). ``every``: at most
    one countersignature of a node per this many seconds, before any signature is checked (a drone
    countersigning its GSs: a hostile GS's offers cost it at most that many entries; a later offer
    covers what an earlier one did)."""

    def __init__(self, witness: str, key: SigningKey | None, node_keys: dict[str, bytes | None],
                 every: float = 0.0) -> None:
        self.witness, self.key, self.node_keys, self.every = witness, key, dict(node_keys), every
        self.last: dict[str, int] = {}  # per node: the seq countersigned last (bounded by the fleet's nodes)
        self._at: dict[str, float] = {}  # per node: when it was countersigned last
        self.refused = 0

    def set_node_keys(self, node_keys: dict[str, bytes | None]) -> None:
        """The nodes' keys in force now (a fleet revision applied): a retired key's checkpoint is refused."""
        self.node_keys = dict(node_keys)

    def rekey(self, key: SigningKey | None) -> None:
        """The witness's own key in force now (its rotation applied)."""
        self.key = key

    def on_head(self, node: str, seq: int, head: bytes, sig: bytes, now: float) -> AuditWitness | None:
        if self.key is None or node not in self.node_keys or seq <= self.last.get(node, -1):
            return None
        if node in self._at and 0.0 <= now - self._at[node] < self.every:
            return None
        w = countersign(self.witness, self.key, node, self.node_keys[node], seq, head, sig, now)
        if w is None:
            self.refused += 1
            return None
        self.last[node], self._at[node] = seq, now
        return w


#: One node's public signing key, its keys in the order the fleet's revisions gave them, or those
#: keys with the revision that gave each (``(revision, key)``, the base fleet's at 0).
PublicKeys = bytes | Sequence[bytes] | Sequence[tuple[int, bytes]] | None
#: A node's keys over time, oldest first, each with the revision that gave it (None: not known).
KeyEpochs = tuple[tuple[int | None, bytes], ...]


def key_epochs(keys: PublicKeys) -> KeyEpochs:
    """A node's keys over time with their revisions, from any ``PublicKeys`` (a plain sequence: the
    first at revision 0, the revisions of the others unknown)."""
    if keys is None:
        return ()
    if isinstance(keys, bytes):
        return ((0, keys),)
    out: list[tuple[int | None, bytes]] = []
    for i, k in enumerate(keys):
        out.append((k[0], k[1]) if isinstance(k, tuple) else (0 if i == 0 else None, k))
    return tuple(out)


def key_list(keys: PublicKeys) -> tuple[bytes, ...]:
    """A node's keys in force over time (oldest first), from one key, a sequence or None."""
    return tuple(k for _, k in key_epochs(keys))


def key_floor(keys: KeyEpochs, revision: int) -> int:
    """The index in ``keys`` of the key in force at ``revision``: the last one given by it or an
    earlier one (0 if none is known to be)."""
    floor = 0
    for i, (rev, _) in enumerate(keys):
        if rev is not None and rev <= revision:
            floor = i
    return floor


def _retired_by(keys: KeyEpochs, index: int) -> int | None:
    """The revision that retired key ``index`` (gave the next one), if known."""
    return keys[index + 1][0] if index + 1 < len(keys) else None


#: Signatures already found valid, ``(public key, message, signature)``: what the records of one run
#: share (a drone's checkpoint checked in its record is not checked again in its witness's).
Verified = set[tuple[bytes, bytes, bytes]]


def _valid(public: bytes, message: bytes, sig: bytes, seen: Verified | None) -> bool:
    if seen is None:
        return verify_signature(public, message, sig)
    if (public, message, sig) in seen:
        return True
    if verify_signature(public, message, sig):
        seen.add((public, message, sig))
        return True
    return False


def witness_valid(w: AuditWitness, node_public: PublicKeys, witness_public: PublicKeys, revision: int | None = None,
                  seen: Verified | None = None) -> bool:
    """Both signatures of a countersignature check (the node's and the witness's), each under one of
    its keys over time; with ``revision`` (the one the witness had applied when it countersigned),
    under the key in force at that revision or a later one only."""
    node_keys, witness_keys = key_epochs(node_public), key_epochs(witness_public)
    if not node_keys or not witness_keys:
        return False
    try:
        bytes.fromhex(w.head)
    except ValueError:
        return False
    nf = key_floor(node_keys, revision) if revision is not None else 0
    wf = key_floor(witness_keys, revision) if revision is not None else 0
    cp, ws = checkpoint_message(w.node, w.seq, w.head), witness_message(w.witness, w.node, w.seq, w.head)
    sig, wsig = _unb64(w.sig), _unb64(w.wsig)
    return (any(_valid(k, cp, sig, seen) for _, k in node_keys[nf:])
            and any(verify_signature(k, ws, wsig) for _, k in witness_keys[wf:]))


@dataclass(frozen=True, slots=True)
class ChainReport:
    """What ``verify_chain`` found for one node's record."""

    node: str
    entries: int  # entries read before the first problem (all of them if none)
    checkpoints: int  # valid checkpoints
    signed_through: int  # the last seq a valid checkpoint covers (-1: none)
    witnessed_through: int  # the highest seq a valid witness countersigned (-1: none)
    witnesses: int  # valid countersignatures of this record
    problem: str | None = None  # the first problem, in one line (None: the record verifies)
    kind: str | None = None  # modified, missing, out_of_order, bad_signature, bad_witness, truncated, ...
    first_bad: int | None = None  # the first bad entry's seq
    unwitnessed: int | None = None  # decisions after the last witnessed entry (None: a record nobody witnesses)
    unchained: int = 0  # witness lines outside any chain (an older format): they vouch for nothing

    @property
    def ok(self) -> bool:
        return self.problem is None

    @property
    def unsigned(self) -> int:
        """Entries after the last checkpoint: not (yet) signed, so not verified."""
        return self.entries - (self.signed_through + 1)

    def summary(self) -> str:
        if self.kind == "record_missing":
            return f"{self.node}: {self.problem}"
        if self.problem is not None:
            return f"{self.node}: BAD at entry {self.first_bad}: {self.problem}"
        tail = f", {self.unsigned} unsigned after the last checkpoint" if self.unsigned else ""
        wit = (f", witnessed through seq {self.witnessed_through} ({self.witnesses} countersignatures)"
               if self.witnesses else ", no witness")
        if self.unwitnessed:
            wit += (f", {self.unwitnessed} decisions after the last witnessed entry" if self.witnesses
                    else f" of its {self.unwitnessed} decisions")
        if self.unchained:
            wit += f", {self.unchained} witness lines outside any chain (ignored)"
        return f"{self.node}: verified {self.signed_through + 1} of {self.entries} entries{tail}{wit}"


@dataclass(slots=True)
class CheckedChain:
    """One node's own chain checked (``check_chain``): its entries' hashes, its valid checkpoints,
    the countersignatures it holds, or its first problem. ``report`` checks it against witnesses."""

    node: str
    hashes: list[str]
    checkpoints: int
    signed: int
    countersigned: list[AuditWitness]  # this node's valid countersignatures of other nodes' checkpoints
    unchained: int = 0
    problem: str | None = None
    kind: str | None = None
    first_bad: int | None = None
    decisions: list[int] = field(default_factory=list)  # the seqs of its entries that are no countersignature

    def report(self, witnesses: Iterable[AuditWitness] = (), witnessed: bool = False) -> ChainReport:
        """The record against the (valid) countersignatures of it in ``witnesses``; ``witnessed``: a
        record that others countersign (a fleet node's): its decisions after the last witnessed entry
        are counted."""
        hashes, n = self.hashes, len(self.hashes)
        if self.problem is not None:
            return ChainReport(self.node, n, self.checkpoints, self.signed, -1, 0, self.problem, self.kind,
                               self.first_bad, unchained=self.unchained)
        top, count = -1, 0
        for w in witnesses:
            if w.node != self.node:
                continue
            count += 1
            if w.seq >= n:
                return ChainReport(self.node, n, self.checkpoints, self.signed, top, count,
                                   f"the record ends at entry {n - 1} but {w.witness} countersigned entry "
                                   f"{w.seq}: truncated", "truncated", n, unchained=self.unchained)
            if hashes[w.seq] != w.head:  # entries a valid checkpoint covers are the node's
                return ChainReport(self.node, n, self.checkpoints, self.signed, top, count,
                                   f"entries up to {w.seq} differ from what {w.witness} countersigned: rewritten",
                                   "modified", min(w.seq, self.signed + 1), unchained=self.unchained)
            top = max(top, w.seq)
        return ChainReport(self.node, n, self.checkpoints, self.signed, top, count,
                           unwitnessed=len(self.decisions) - bisect.bisect_right(self.decisions, top) if witnessed
                           else None, unchained=self.unchained)


def check_chain(node: str, lines: Iterable[bytes | str | AuditLine], node_public: PublicKeys,
                keys: Mapping[str, PublicKeys] | None = None, seen: Verified | None = None) -> CheckedChain:
    """Check ``node``'s own record (its lines, in file order) against its signing keys over time
    (``PublicKeys``; see the module's text for which key each checkpoint must verify under); its
    countersignatures (witness entries) against its keys and those in ``keys`` of the nodes it
    countersigned, each under the key in force at the revision it had applied then. Stops at the
    first problem. ``seen``: signatures found valid so far (shared by the records of a run)."""
    node_keys = key_epochs(node_public)
    others = keys or {}
    in_force = 0  # index in node_keys of the key the last valid checkpoint verified under
    floors: list[tuple[int, int]] = []  # (first seq, key index): from a revision applied on, its key or later
    revision: int | None = None  # the last revision this node applied, by its record
    hashes: list[str] = []
    countersigned: list[AuditWitness] = []
    decisions: list[int] = []
    prev = genesis(node)
    checkpoints, signed, unchained = 0, -1, 0

    def bad(kind: str, first: int, problem: str) -> CheckedChain:
        return CheckedChain(node, hashes, checkpoints, signed, countersigned, unchained, problem, kind, first, decisions)

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
            unchained += 1  # a free witness line (the format before witnesses were chained): vouches for nothing
            continue
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
            if line.kind == WITNESS_KIND:
                w = witness_from_entry(line)
                if w is None:
                    return bad("bad_witness", expect, f"entry {expect} is no countersignature")
                if not witness_valid(w, others.get(w.node), node_keys, revision, seen):
                    at = f" in force at revision {revision}" if revision is not None else ""
                    return bad("bad_witness", expect, f"entry {expect}: {node}'s countersignature of {w.node}'s "
                                                      f"entry {w.seq} does not verify under their keys{at}")
                countersigned.append(w)
            else:
                decisions.append(expect)
            if line.kind == REVISION_KIND:
                number = line.fields.get("number")
                if isinstance(number, int) and not isinstance(number, bool) and (revision is None or number > revision):
                    revision = number
                    floor = key_floor(node_keys, number)
                    if floor > (floors[-1][1] if floors else 0):
                        floors.append((expect + 1, floor))
        else:
            if line.seq >= len(hashes) or line.seq < 0:
                return bad("missing", len(hashes), f"entry {len(hashes)} is missing (a checkpoint signs entry "
                                                   f"{line.seq} here): deleted or reordered")
            if hashes[line.seq] != line.head:
                return bad("modified", line.seq, f"entry {line.seq} is not the one its checkpoint signed")
            message, sig = checkpoint_message(node, line.seq, line.head), _unb64(line.sig)
            least = max([in_force, *(f for first, f in floors if first <= line.seq)])
            under = next((i for i in range(least, len(node_keys)) if _valid(node_keys[i][1], message, sig, seen)),
                         None)
            if under is None:
                retired = next((i for i in range(least) if verify_signature(node_keys[i][1], message, sig)), None)
                by = _retired_by(node_keys, retired) if retired is not None else None
                return bad("bad_signature", signed + 1,
                           f"the checkpoint of entry {line.seq} is not signed by {node}'s fleet key" if retired is None
                           else f"the checkpoint of entry {line.seq} is signed by {node}'s key retired by revision {by}"
                           if by is not None else
                           f"the checkpoint of entry {line.seq} is signed by a key of {node}'s retired before it")
            in_force = under
            checkpoints += 1
            signed = max(signed, line.seq)
    return CheckedChain(node, hashes, checkpoints, signed, countersigned, unchained, decisions=decisions)


def verify_chain(node: str, lines: Iterable[bytes | str | AuditLine], node_public: PublicKeys,
                 witnesses: Iterable[AuditWitness] = (), witness_keys: Mapping[str, Any] | None = None
                 ) -> ChainReport:
    """Check ``node``'s record (``check_chain``; ``witness_keys``: every other node's keys) and then
    against ``witnesses``: countersignatures held elsewhere, each counted only if both its signatures
    verify (the node's under ``node_public``, the witness's under its keys in ``witness_keys``)."""
    keys = witness_keys or {}
    checked = check_chain(node, lines, node_public, keys)
    valid = [w for w in witnesses if w.node == node and witness_valid(w, node_public, keys.get(w.witness))]
    return checked.report(valid)
