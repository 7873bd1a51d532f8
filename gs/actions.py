"""What the ground station's pure core asks its adapter to do: the GS's output vocabulary.

``Put`` and ``Emit`` are the outputs the drone's core has too (``zdrone.core.outputs``); the GS adds
``Ask`` (a query whose replies come back through ``StationCore.on_pair_reply`` /
``on_linkkey_reply``), ``FrameUp`` (an authentic vehicle frame for the GCS gateway) and ``ToOperator`` (a
line for the operator) and ``Checkpoint`` (a drone's authority-record checkpoint to countersign). An incoming key-sharing query is answered with a ``QueryAnswer`` value.
The sub-machines of the GS core (``gs.mission``, ``gs.linking``, ``gs.handover``) return these values
and import them from here, never from ``gs.core``.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from zdrone.core import wire
from zdrone.core.outputs import Emit, Put

__all__ = ["Action", "Ask", "AskKind", "Checkpoint", "Emit", "FrameUp", "Put", "QueryAnswer", "ToOperator"]


class AskKind(enum.Enum):
    PAIR = "pair"
    LINKKEY = "linkkey"


@dataclass(frozen=True, slots=True)
class Ask:
    """Send a query; hand every reply back with ``on_pair_reply`` / ``on_linkkey_reply``."""

    kind: AskKind
    drone: str
    gs: str
    keyexpr: str
    payload: bytes
    timeout: float


@dataclass(frozen=True, slots=True)
class FrameUp:
    """An authentic MAVLink frame from ``drone`` for the GCS gateway."""

    drone: str
    frame: bytes


@dataclass(frozen=True, slots=True)
class ToOperator:
    """A line for the operator (stdout)."""

    text: str


@dataclass(frozen=True, slots=True)
class Checkpoint:
    """The drone's newest authority-record checkpoint, from its authentic status: for this GS to
    countersign (``zdrone.core.audit``), if it keeps an authority record."""

    drone: str
    head: wire.AuditHead


Action = Put | Ask | Emit | FrameUp | ToOperator | Checkpoint


@dataclass(frozen=True, slots=True)
class QueryAnswer:
    """How to answer one key-sharing query: a reply payload, or an error (None: no answer at all)."""

    reply: bytes | None = None
    error: bytes | None = None
    crypto: bool = False  # a handshake was computed (the adapter bounds these per loop turn)
