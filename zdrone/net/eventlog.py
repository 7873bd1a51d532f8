"""JSONL event logs: one object per line with wall time ``t``; flushed at once so others can tail.

Every line of a type that has a typed record (``zdrone.core.records``) is checked against it as it
is written. A line that fits no record is a writer's mistake (a misspelled, missing or mistyped
field). In production it is counted (``EventLog.misfits``), logged once per type and written as it
is: a drone in the air must not stop over a log line, and the line (read back as an
``UntypedRecord``) keeps every field. Tests make it an ``EventShapeError``: ``strict=True``, or the
environment variable ``ZDRONE_STRICT_EVENTS=1`` (inherited by the node processes a test starts).

**Bounded.** A log cannot grow without end, whatever its peers send:

* *Rate.* Every event type but the node's own clockwork (``start``, ``status``, ``stop``,
  ``closed``) may be triggered by a peer, so each (type, reason) has a token bucket
  (``EventRate``: a burst, then a steady rate). What it refuses is counted exactly
  (``EventLog.suppressed``) and written as a ``suppressed`` record ("N similar left out") at most
  every ``summary_every`` seconds per (type, reason), and at close. A type's distinct reasons are
  capped (the rest share one bucket), so no peer can make new buckets without end. The check comes
  before any encoding: a refused event costs a dict look-up.
* *Size.* With ``max_bytes`` the file rotates (``drone.jsonl`` -> ``drone.jsonl.1`` ... up to
  ``keep`` old files, the oldest dropped); ``read_records`` and ``LogTail`` read across them.

The node commands set both for every log of the process (``configure``) so node code needs no
option of its own.

**The authority record.** ``start_audit(signing_key)`` gives the log a signed hash chain
(``zdrone.core.audit``) in a file of its own beside it (``drone.jsonl`` -> ``drone.audit.jsonl``,
never rotated: decisions are few). Every event of an ``audit.AUDITED`` type is appended to it as
well, whatever the rate limit left out of the log, and every write is a tick of its clock
(a checkpoint a second after an unsigned entry at the latest; ``on_checkpoint`` hears each one: the
drone shows its newest to its ground stations). A ground station appends the checkpoints it
countersigned to its own chain (``write_witness``). A restarted node continues its chain; a rotated
one goes on under its new key (``rekey_audit``).
"""

from __future__ import annotations

import json
import logging
import os
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, NamedTuple, TextIO, TypeVar

import msgspec

from zdrone.core.ratelimit import TokenBucket
from zdrone.core import audit
from zdrone.core.keys import SigningKey
from zdrone.core.records import (AnyRecord, Suppressed, UntypedRecord, decode_record, encode_record, misfit, record_type,
                            records_for)

log = logging.getLogger(__name__)

RecordT = TypeVar("RecordT", bound=AnyRecord)

#: set to 1 to make a line that fits no record an error (tests)
STRICT_ENV = "ZDRONE_STRICT_EVENTS"


class EventShapeError(ValueError):
    """An event's fields fit none of its type's records (a programming error)."""


#: event types written on the node's own clock, never by a peer's doing: not rate-limited
OWN_CLOCK_TYPES = frozenset({"start", "status", "stop", "closed", "suppressed"})
#: distinct reasons kept apart per event type; further ones share one bucket
MAX_REASONS_PER_TYPE = 16
OTHER_REASON = "(other)"


@dataclass(frozen=True)
class EventRate:
    """How many events of one (type, reason) a log writes: ``burst`` at once, then ``per_s`` a
    second; a ``suppressed`` line at most every ``summary_every`` seconds for the rest."""

    burst: float = 50.0
    per_s: float = 5.0
    summary_every: float = 10.0


@dataclass
class _Bucket:
    tokens: TokenBucket
    left_out: int = 0  # since the last summary
    first: float = 0.0
    last: float = 0.0
    summary_at: float = 0.0


@dataclass
class LogLimits:
    """A process's event-log bounds (``configure``): rotation size (None: none), old files kept,
    and the rate of peer-triggered events (None: unlimited)."""

    max_bytes: int | None = 64 * 1024 * 1024
    keep: int = 3
    rate: EventRate | None = field(default_factory=EventRate)


_limits = LogLimits()


def configure(max_bytes: int | None = None, keep: int | None = None, rate: EventRate | None = None) -> LogLimits:
    """Set the bounds of every event log this process opens from now on (the node commands'
    ``--events-max-mb``); returns the previous ones."""
    global _limits
    previous = _limits
    _limits = LogLimits(max_bytes if max_bytes is not None else previous.max_bytes,
                        keep if keep is not None else previous.keep, rate if rate is not None else previous.rate)
    return previous


class EventLog:
    """Appends events to a JSONL file (or nowhere: then it only counts), rate-limited and rotated
    (see the module's text)."""

    def __init__(self, path: str | Path | None, node: str, strict: bool | None = None,
                 limits: LogLimits | None = None, clock: Callable[[], float] = time.time) -> None:
        self.node = node
        self.strict = os.environ.get(STRICT_ENV, "") not in ("", "0") if strict is None else strict
        self.misfits: Counter[str] = Counter()  # lines written though no record fits them, per type
        self.suppressed: Counter[tuple[str, str | None]] = Counter()  # events left out, per (type, reason): exact
        self.bytes_written = 0  # by this log, over every file (also counted when it writes nowhere)
        self.rotations = 0
        self.limits = limits or _limits
        self._clock = clock
        self._buckets: dict[tuple[str, str | None], _Bucket] = {}
        self._reasons: dict[str, set[str | None]] = {}
        self._next_summary = float("inf")  # earliest time a summary may be due
        self._lock = threading.Lock()  # a node may write from more than one thread
        self._path = Path(path) if path else None
        self._fh: TextIO | None = None
        self._size = 0
        self.audit: audit.AuditChain | None = None
        self._audit_fh: TextIO | None = None
        self._on_checkpoint: Callable[[audit.AuditCheckpoint], None] | None = None
        if self._path is not None:
            self._path.parent.mkdir(parents=True, exist_ok=True)
            self._open()

    def _open(self) -> None:
        assert self._path is not None
        self._fh = open(self._path, "a", buffering=1, encoding="utf-8")
        self._size = self._fh.tell()

    def write(self, type_: str, **fields: Any) -> dict[str, Any]:
        """Write one event (unless its rate is spent); checked against its type's record when it has one."""
        now = self._clock()
        ev = {"t": round(now, 4), "node": self.node, "type": type_, **fields}
        reason = fields.get("reason")
        if self.audit is not None:
            self._audit(type_, fields, now)
        with self._lock:
            if not self._admit(type_, reason if isinstance(reason, str) or reason is None else str(reason), now):
                return ev
        line = json.dumps(ev, default=str)
        if records_for(type_):
            problem = misfit(line)
            if problem is not None:
                self._misfit(type_, problem)
        with self._lock:
            self._append(line)
        return ev

    def write_record(self, rec: RecordT) -> RecordT:
        """Write a record (unless its rate is spent); an unset ``t`` or ``node`` is stamped with this
        log's clock and name."""
        now = self._clock()
        if not rec.t or not rec.node:
            rec = msgspec.structs.replace(rec, t=rec.t or round(now, 4), node=rec.node or self.node)
        reason = getattr(rec, "reason", None)
        if self.audit is not None:
            self._audit(record_type(rec), rec, now)
        with self._lock:
            if not self._admit(record_type(rec), reason if isinstance(reason, str) or reason is None else str(reason), now):
                return rec
        line = encode_record(rec).decode()
        if records_for(record_type(rec)):  # a struct's values are not checked when it is made
            problem = misfit(line)
            if problem is not None:
                self._misfit(record_type(rec), problem)
        with self._lock:
            self._append(line)
        return rec

    def write_as(self, cls: type[RecordT], fields: dict[str, Any]) -> RecordT | dict[str, Any]:
        """Write a record of class ``cls`` made from ``fields`` (a status a node assembles): converted
        and checked before it is written. Fields that do not make a ``cls`` are a programming error:
        raised in a strict log (the tests'), else written as they are and counted (nothing is lost)."""
        try:
            record = msgspec.convert(fields, cls)
        except msgspec.ValidationError as exc:
            tag = cls.__struct_config__.tag
            self._misfit(str(tag), f"{cls.__name__}: {exc}")
            return self.write(str(tag), **fields)
        return self.write_record(record)

    # ---------------------------------------------------------------- authority record
    def start_audit(self, key: SigningKey,
                    on_checkpoint: Callable[[audit.AuditCheckpoint], None] | None = None) -> None:
        """Keep this node's authority record (see the module's text); a log without a file keeps none."""
        if self._path is None:
            return
        path = audit_path(self._path)
        lines = path.read_bytes().splitlines() if path.exists() else []
        self.audit = audit.AuditChain.resume(self.node, key, lines)
        self._audit_fh = open(path, "a", buffering=1, encoding="utf-8")
        self._on_checkpoint = on_checkpoint

    def rekey_audit(self, key: SigningKey | None) -> None:
        """This node's signing key was rotated (a fleet revision): the record goes on under ``key``,
        its unsigned entries signed under the old one first (``AuditChain.rekey``); None: the node
        does not hold its new key yet, so it signs nothing more (an unsigned tail, never a retired key's
        signature)."""
        if self.audit is None:
            return
        with self._lock:
            self._audit_lines(self.audit.rekey(key, self._clock()))

    def countersign(self, witnessing: audit.Witnessing, node: str, head: Any, wall: float) -> bool:
        """Another node's checkpoint (``head``: its seq, head and signature) countersigned by
        ``witnessing`` and written as an entry of this node's chain (once per seq); False when its
        signature failed (counted by the caller)."""
        refused = witnessing.refused
        w = witnessing.on_head(node, head.seq, head.head, head.sig, wall)
        if w is not None:
            self.write_witness(w)
        return witnessing.refused == refused

    def write_witness(self, witness: audit.AuditWitness) -> None:
        """A checkpoint of another node this node countersigned: an entry of its own chain."""
        if self.audit is None:
            return
        now = self._clock()
        with self._lock:
            lines = self.audit.append(audit.WITNESS_KIND, audit.witness_fields(witness), now)
            self._audit_lines(lines + self.audit.tick(now))

    def _audit(self, type_: str, what: Any, now: float) -> None:
        """Append a decision to the chain (``what``: a record or its fields), then tick the chain."""
        assert self.audit is not None
        with self._lock:
            lines: list[audit.AuditLine] = []
            if type_ in audit.AUDITED:
                fields = msgspec.to_builtins(what) if not isinstance(what, dict) else what
                fields = {k: v for k, v in fields.items() if k not in ("t", "node", "type")}
                lines += self.audit.append(type_, fields, now)
            lines += self.audit.tick(now)
            self._audit_lines(lines)

    def _audit_lines(self, lines: list[audit.AuditLine]) -> None:
        if self._audit_fh is None:
            return
        for line in lines:
            self._audit_fh.write(audit.encode_line(line).decode() + "\n")
            if isinstance(line, audit.AuditCheckpoint) and self._on_checkpoint is not None:
                self._on_checkpoint(line)

    # ---------------------------------------------------------------- rate
    def _admit(self, type_: str, reason: str | None, now: float) -> bool:
        """Whether an event of (type, reason) is written now; counts it if not. Also writes the
        summaries that are due."""
        rate = self.limits.rate
        if now >= self._next_summary:
            self._summaries(now, due_only=True)
        if rate is None or type_ in OWN_CLOCK_TYPES:
            return True
        key = (type_, reason)
        b = self._buckets.get(key)
        if b is None:
            seen = self._reasons.setdefault(type_, set())
            if reason not in seen and len(seen) >= MAX_REASONS_PER_TYPE:
                key = (type_, OTHER_REASON)
                b = self._buckets.get(key)
            else:
                seen.add(reason)
            if b is None:
                b = self._buckets[key] = _Bucket(TokenBucket.full(rate.per_s, rate.burst, now), summary_at=now)
        if b.tokens.take(now):
            return True
        if not b.left_out:
            b.first = now
            self._next_summary = min(self._next_summary, b.summary_at + rate.summary_every)
        b.left_out += 1
        b.last = now
        self.suppressed[key] += 1
        return False

    def _summaries(self, now: float, due_only: bool) -> None:
        """A ``suppressed`` record for each (type, reason) with events left out (only those whose
        last summary is ``summary_every`` old when ``due_only``)."""
        every = self.limits.rate.summary_every if self.limits.rate else 0.0
        pending = float("inf")
        for (type_, reason), b in self._buckets.items():
            if not b.left_out:
                continue
            if due_only and now < b.summary_at + every:
                pending = min(pending, b.summary_at + every)
                continue
            rec = Suppressed(t=round(now, 4), node=self.node, of=type_, reason=reason, count=b.left_out,
                             first=round(b.first, 4), last=round(b.last, 4))
            self._append(encode_record(rec).decode())
            b.left_out, b.summary_at = 0, now
        self._next_summary = pending

    def _misfit(self, type_: str, problem: str) -> None:
        if self.strict:
            raise EventShapeError(f"event of node {self.node}: {problem}")
        self.misfits[type_] += 1
        if self.misfits[type_] == 1:  # once per type: the counter has the rest
            log.error("event of node %s written though it fits no record: %s", self.node, problem)

    # ---------------------------------------------------------------- size
    def _append(self, line: str) -> None:
        n = len(line.encode()) + 1
        self.bytes_written += n
        if self._fh is None:
            return
        max_bytes = self.limits.max_bytes
        if max_bytes is not None and self._size > 0 and self._size + n > max_bytes:
            self._rotate()
        self._fh.write(line + "\n")
        self._size += n

    def _rotate(self) -> None:
        """``path`` -> ``path.1`` -> ... -> ``path.keep`` (the oldest dropped), then a new ``path``."""
        assert self._fh is not None and self._path is not None
        self._fh.close()
        keep = max(1, self.limits.keep)
        for i in range(keep - 1, 0, -1):
            older = rotated(self._path, i)
            if older.exists():
                os.replace(older, rotated(self._path, i + 1))
        os.replace(self._path, rotated(self._path, 1))
        self.rotations += 1
        self._open()

    def close(self) -> None:
        with self._lock:
            if self.audit is not None and self.audit.pending and self.audit.key is not None:
                self._audit_lines([self.audit.checkpoint(self._clock())])  # nothing left unsigned
            if self._audit_fh is not None:
                self._audit_fh.close()
                self._audit_fh = None
            if self._buckets:
                self._summaries(self._clock(), due_only=False)  # every count left out, exactly
            if self._fh is not None:
                self._fh.close()
                self._fh = None


def audit_path(path: str | Path) -> Path:
    """The authority record beside an event log: ``drone.jsonl`` -> ``drone.audit.jsonl``."""
    p = Path(path)
    return p.with_name(f"{p.stem}.audit{p.suffix or '.jsonl'}")


def rotated(path: str | Path, i: int) -> Path:
    """The ``i``-th older file of a rotated log (``drone.jsonl.1`` is the newest of them)."""
    return Path(f"{path}.{i}")


def log_files(path: str | Path) -> list[Path]:
    """A log's files, oldest first: its rotated files that exist, then the log itself."""
    older = []
    i = 1
    while rotated(path, i).exists():
        older.append(rotated(path, i))
        i += 1
    return [*reversed(older), Path(path)]


def read_events(path: str | Path) -> list[dict[str, Any]]:
    """All complete events of a JSONL log and its rotated files, oldest first (a half-written last
    line is skipped)."""
    out = []
    for part in log_files(path):
        if not part.exists():
            continue
        for line in part.read_text(encoding="utf-8", errors="replace").splitlines():
            try:
                out.append(json.loads(line))
            except ValueError:
                continue
    return out


class LogRecords(NamedTuple):
    """The records of an event log, and how many of its complete lines were no event at all."""

    records: list[AnyRecord]
    undecodable: int

    @property
    def untyped(self) -> list[UntypedRecord]:
        """The records no typed record fits (an unknown type, or a writer's misfit)."""
        return [r for r in self.records if isinstance(r, UntypedRecord)]


def read_records(path: str | Path) -> LogRecords:
    """Every event of a JSONL log and its rotated files (oldest first) as its typed record
    (``UntypedRecord`` when none fits). A last line that does not decode is being written (skipped);
    any other line that does not is counted."""
    records: list[AnyRecord] = []
    undecodable = 0
    for part in log_files(path):
        if not part.exists():
            continue
        lines = part.read_bytes().split(b"\n")
        for i, line in enumerate(lines):
            if not line.strip():
                continue
            try:
                records.append(decode_record(line))
            except msgspec.DecodeError:
                if i < len(lines) - 1:
                    undecodable += 1
    if undecodable:
        log.warning("%s: %d line(s) that are no event", path, undecodable)
    return LogRecords(records, undecodable)



class LogTail:
    """The records appended to a log since the last ``read`` (rotation followed): a watcher's cost
    grows with what is new, not with the log's length."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.undecodable = 0
        self._fh: Any = None
        self._inode: int | None = None
        self._rest = b""  # a line not finished yet

    def read(self) -> list[AnyRecord]:
        if self._fh is None:
            try:
                self._fh = open(self.path, "rb")
            except FileNotFoundError:
                return []
            self._inode = os.fstat(self._fh.fileno()).st_ino
        out = self._drain()
        try:
            moved = os.stat(self.path).st_ino != self._inode
        except FileNotFoundError:
            moved = False
        if moved:  # rotated: what the writer put in the old file before it moved it, then the new file
            out += self._drain()
            if self._rest.strip():
                self.undecodable += 1
            self._fh.close()
            self._fh, self._rest = None, b""
            out += self.read()
        return out

    def _drain(self) -> list[AnyRecord]:
        data = self._fh.read()
        if not data:
            return []
        lines = (self._rest + data).split(b"\n")
        self._rest = lines.pop()
        out: list[AnyRecord] = []
        for line in lines:
            if line.strip():
                try:
                    out.append(decode_record(line))
                except msgspec.DecodeError:
                    self.undecodable += 1
        return out

    def close(self) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None
