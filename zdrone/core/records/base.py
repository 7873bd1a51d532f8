"""The base of every typed record, and the records every node writes (``zdrone.core.records``)."""

from __future__ import annotations

from typing import Any

import msgspec


#: a drone's position as logged: latitude, longitude (degrees), altitude above home (m)
Position = tuple[float, float, float]


class Record(msgspec.Struct, frozen=True, kw_only=True, tag_field="type", forbid_unknown_fields=True):
    """Base of every typed record: when and by whom it was written."""

    t: float = 0.0
    node: str = ""


class UntypedRecord(msgspec.Struct, frozen=True):
    """A line that no typed record fits (an unknown type, or fields that do not fit its record)."""

    t: float
    node: str
    type: str
    fields: dict[str, Any]


# ----------------------------------------------------------------------------- every node
class Closed(Record, frozen=True, tag="closed"):
    """The node closed its session (the last line of a clean exit); written by every node."""


class Suppressed(Record, frozen=True, tag="suppressed"):
    """Events of type ``of`` (and ``reason``) the event log left out, beyond its rate for them:
    ``count`` of them between ``first`` and ``last`` (written by the event log of every node)."""

    of: str
    reason: str | None
    count: int
    first: float
    last: float


class PathOpen(Record, frozen=True, tag="path_open"):
    """A session to router ``router`` opened (a node given a router per site has a path to each)."""

    router: str


class PathState(Record, frozen=True, tag="path_state"):
    """The path through ``router`` has its router now (``connected``) or lost it; the node publishes
    through every connected path."""

    router: str
    connected: bool
