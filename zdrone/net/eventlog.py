"""JSONL event logs: one object per line with wall time ``t``; flushed at once so others can tail.

Every line of a type that has a typed record (``zdrone.core.records``) is checked against it as it
is written. A line that fits no record is a writer's mistake (a misspelled, missing or mistyped
field). In production it is counted (``EventLog.misfits``), logged once per type and written as it
is: a drone in the air must not stop over a log line, and the line (read back as an
``UntypedRecord``) keeps every field. Tests make it an ``EventShapeError``: ``strict=True``, or the
environment variable ``ZDRONE_STRICT_EVENTS=1`` (inherited by the node processes a test starts).
"""

from __future__ import annotations

import json
import logging
import os
import time
from collections import Counter
from pathlib import Path
from typing import Any, NamedTuple, TextIO, TypeVar

import msgspec

from ..core.records import AnyRecord, UntypedRecord, decode_record, encode_record, misfit, record_type, records_for

log = logging.getLogger(__name__)

RecordT = TypeVar("RecordT", bound=AnyRecord)

#: set to 1 to make a line that fits no record an error (tests)
STRICT_ENV = "ZDRONE_STRICT_EVENTS"


class EventShapeError(ValueError):
    """An event's fields fit none of its type's records (a programming error)."""


class EventLog:
    """Appends events to a JSONL file (or nowhere)."""

    def __init__(self, path: str | Path | None, node: str, strict: bool | None = None) -> None:
        self.node = node
        self.strict = os.environ.get(STRICT_ENV, "") not in ("", "0") if strict is None else strict
        self.misfits: Counter[str] = Counter()  # lines written though no record fits them, per type
        self._fh: TextIO | None = None
        if path:
            Path(path).parent.mkdir(parents=True, exist_ok=True)
            self._fh = open(path, "a", buffering=1, encoding="utf-8")

    def write(self, type_: str, **fields: Any) -> dict[str, Any]:
        """Write one event; checked against its type's record when it has one."""
        ev = {"t": round(time.time(), 4), "node": self.node, "type": type_, **fields}
        line = json.dumps(ev, default=str)
        if records_for(type_):
            problem = misfit(line)
            if problem is not None:
                self._misfit(type_, problem)
        self._append(line)
        return ev

    def write_record(self, rec: RecordT) -> RecordT:
        """Write a record; an unset ``t`` or ``node`` is stamped with this log's clock and name."""
        if not rec.t or not rec.node:
            rec = msgspec.structs.replace(rec, t=rec.t or round(time.time(), 4), node=rec.node or self.node)
        line = encode_record(rec).decode()
        if records_for(record_type(rec)):  # a struct's values are not checked when it is made
            problem = misfit(line)
            if problem is not None:
                self._misfit(record_type(rec), problem)
        self._append(line)
        return rec

    def _misfit(self, type_: str, problem: str) -> None:
        if self.strict:
            raise EventShapeError(f"event of node {self.node}: {problem}")
        self.misfits[type_] += 1
        if self.misfits[type_] == 1:  # once per type: the counter has the rest
            log.error("event of node %s written though it fits no record: %s", self.node, problem)

    def _append(self, line: str) -> None:
        if self._fh is not None:
            self._fh.write(line + "\n")

    def close(self) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None


def read_events(path: str | Path) -> list[dict[str, Any]]:
    """All complete events of a JSONL log (a half-written last line is skipped)."""
    out = []
    for line in Path(path).read_text(encoding="utf-8", errors="replace").splitlines():
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
    """Every event of a JSONL log as its typed record (``UntypedRecord`` when none fits). A last line
    that does not decode is being written (skipped); any other line that does not is counted."""
    lines = Path(path).read_bytes().split(b"\n")
    records: list[AnyRecord] = []
    undecodable = 0
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

