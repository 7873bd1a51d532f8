"""Typed event-log records: one frozen msgspec struct per event a node writes, tagged by ``type``.

Theory of operation: every line of an event log (``zdrone.net.eventlog``) is one JSON object with
the wall time ``t``, the writing ``node``, the event ``type`` and the event's own fields. Each kind
of writer has its vocabulary: the drone node (``DRONE_RECORDS``) and the ground station
(``GS_RECORDS``) here; the testbed registers its own (``zdrone.sil.testbed_records``: the attacker, the
emulated radio) with ``register_vocabulary``. One tag may name different shapes
for different writers (a drone's ``status`` is not a GS's), so each vocabulary is its own tagged
union, and a line is the record of the first vocabulary with a record that fits it exactly: no
field missing, none unknown, every value of its type. A line no record fits, or of a type no
vocabulary has, is an ``UntypedRecord`` holding its fields as written: nothing is lost.

Field names are the logged names (``from`` is ``from_`` in Python). A field with a default is one
that a writer may leave out, or that logs of earlier versions lack. ``t`` and ``node`` default to
"unset": the log that writes a record stamps them. Pure: no I/O.
The records live by vocabulary: ``base`` (``Record``, and what every node writes), ``drone`` (the
drone node's), ``station`` (the ground station's); this module gathers them, makes each vocabulary
a tagged union and decodes log lines.
"""

from __future__ import annotations

from typing import Any, Iterable, TypeVar, Union

import msgspec

from zdrone.core.records.base import *  # noqa: F401,F403
from zdrone.core.records.base import Position, Record, UntypedRecord  # noqa: F401  (Position: the logged position type)
from zdrone.core.records.drone import *  # noqa: F401,F403
from zdrone.core.records.station import *  # noqa: F401,F403


# ----------------------------------------------------------------------------- vocabularies
#: the drone node's records
DRONE_RECORDS: tuple[type[Record], ...] = (
    Start, DroneStatus, DroneStop, Closed, Suppressed, PathOpen, PathState, Subscribe, Unsubscribe, LinkInstalled,
    LinkCandidate, LinkConfirmed, AuthorityChange, HandoverComplete, Failsafe, AuthorityForgotten, Restarted,
    Drop, Paired, PairAnswered, PairRefused, LinkStateChanged, RestoreRefused, Restored, FirstClaim, FirstClaimOver,
    HandoverStart,
    HandoverRequested, TakeoverSetting, HandoverTimeout, HandoverAborted, Reject, KeyInstalled, FailsafeRecovered, FailsafeEntered,
    AuthorityLinkLost, RegionEntered, RegionLeft, OwnerLinkLostOnGround,
    FailsafeConfirmed, FailsafeRetried, FailsafeUnconfirmed, VehicleFound, FcUnsigned,
    RevokedNote, LinkClosedNote, LinkKeptNote, RevisionApplied, RevisionRefused,
)
#: the ground station's records (its core's ``Log`` actions, its loop's, its GCS gateway's)
GS_RECORDS: tuple[type[Record], ...] = (
    GsStart, GsStatus, GsStop, Closed, Suppressed, PathOpen, PathState, ControlRequested, GsPairRefused, PairFailed,
    PairNotNeeded, GsPaired, GsLinkClosed, LinkkeyRefused, LinkkeyShared, LinkkeyError, LinkkeyBadReply, LinkkeyReceived,
    GsLinkConfirmed, AutopilotFound, VehicleText, AuthorityStatus, FcSigningHeard, KeyGranted, Rejected, FailsafeNoticed,
    HandoverFailed, VehicleRefused, MissionFailed, MissionRetry, VehicleParam, MissionUpload, MissionStarted, MissionStartFailed,
    VehicleWaiting, TakeoffConfirmed, TakeoffRestart, MissionProgress, HandoverRelease, HandoverHold, HandoverResume, GcsApp, GcsAppGone, OperatorControlRequested,
    *OPERATOR_CONTROL_RECORDS, RevisionApplied, RevisionRefused,
)
VOCABULARIES: dict[str, tuple[type[Record], ...]] = {"drone": DRONE_RECORDS, "gs": GS_RECORDS}
#: every typed record class, each once (``register_vocabulary`` adds to it)
ALL_RECORDS: tuple[type[Record], ...] = ()

AnyRecord = Union[Record, UntypedRecord]
R = TypeVar("R", bound=Record)


class _Head(msgspec.Struct, frozen=True):
    """What every event line has (other fields ignored)."""

    t: float
    node: str
    type: str


def record_type(rec: AnyRecord) -> str:
    """The event type of a record (its tag)."""
    if isinstance(rec, UntypedRecord):
        return rec.type
    tag = type(rec).__struct_config__.tag
    assert isinstance(tag, str), type(rec)
    return tag


def records_for(type_: str) -> tuple[type[Record], ...]:
    """The record classes of event type ``type_`` (one per vocabulary that has it)."""
    return _BY_TYPE.get(type_, ())


_BY_TYPE: dict[str, tuple[type[Record], ...]] = {}
_UNIONS: list[msgspec.json.Decoder[Any]] = []
_BY_CLASS: dict[type[Record], msgspec.json.Decoder[Any]] = {}


def register_vocabulary(name: str, records: tuple[type[Record], ...]) -> None:
    """Add (or replace) writer ``name``'s vocabulary: its records become decodable. The nodes'
    vocabularies are here; the testbed registers its own (``zdrone.sil.testbed_records``)."""
    global ALL_RECORDS
    VOCABULARIES[name] = records
    ALL_RECORDS = tuple(dict.fromkeys(c for v in VOCABULARIES.values() for c in v))
    _BY_TYPE.clear()
    for cls in ALL_RECORDS:
        tag = cls.__struct_config__.tag
        assert isinstance(tag, str), cls
        _BY_TYPE[tag] = (*_BY_TYPE.get(tag, ()), cls)
    _UNIONS[:] = [msgspec.json.Decoder(Union[v]) for v in VOCABULARIES.values()]  # type: ignore[valid-type]
    for cls in ALL_RECORDS:
        _BY_CLASS.setdefault(cls, msgspec.json.Decoder(cls))


register_vocabulary("drone", DRONE_RECORDS)
register_vocabulary("gs", GS_RECORDS)
_HEAD = msgspec.json.Decoder(_Head)
_ANY = msgspec.json.Decoder(dict[str, Any])
_ENCODER = msgspec.json.Encoder()


def decode_record(line: bytes | str) -> AnyRecord:
    """The record of one log line: typed when a record fits it, else untyped.
    ``msgspec.DecodeError`` if the line is no event (not JSON, or no ``t``/``node``/``type``)."""
    head = _HEAD.decode(line)  # a record's t and node have defaults (for writers): a line must have them
    for union in _UNIONS:
        try:
            return union.decode(line)  # type: ignore[no-any-return]
        except msgspec.ValidationError:
            continue
    fields = {k: v for k, v in _ANY.decode(line).items() if k not in ("t", "node", "type")}
    return UntypedRecord(head.t, head.node, head.type, fields)


def encode_record(rec: AnyRecord) -> bytes:
    """One log line (without its newline) for a record."""
    if isinstance(rec, UntypedRecord):
        return _ENCODER.encode({"t": rec.t, "node": rec.node, "type": rec.type, **rec.fields})
    return _ENCODER.encode(rec)


def misfit(line: bytes | str) -> str | None:
    """Why no record fits a line of a type that has records; None if one fits or none exists."""
    try:
        head = _HEAD.decode(line)
    except msgspec.DecodeError as exc:
        return f"not an event line: {exc}"
    classes = records_for(head.type)
    problems = []
    for cls in classes:
        try:
            _BY_CLASS[cls].decode(line)
            return None
        except msgspec.DecodeError as exc:
            problems.append(f"{cls.__name__}: {exc}")
    return f"{head.type!r}: no record fits ({'; '.join(problems)})" if problems else None


def fields_of(rec: AnyRecord) -> dict[str, Any]:
    """The event's own fields as logged (names, JSON values), without ``t``, ``node`` and ``type``."""
    if isinstance(rec, UntypedRecord):
        return dict(rec.fields)
    return {k: v for k, v in _ANY.decode(_ENCODER.encode(rec)).items() if k not in ("t", "node", "type")}


def logged(rec: AnyRecord) -> dict[str, Any]:
    """The event as its log line holds it: ``t``, ``node``, ``type``, then its fields (JSON values; a
    field the line left out has its default)."""
    return {"t": rec.t, "node": rec.node, "type": record_type(rec), **fields_of(rec)}


def only(records: Iterable[AnyRecord], cls: type[R]) -> list[R]:
    """The records of one class (and its subclasses), in order."""
    return [r for r in records if isinstance(r, cls)]
