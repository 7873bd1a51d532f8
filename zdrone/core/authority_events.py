"""The handover authority's vocabulary: the events it is fed, the actions it returns, why it drops a
frame, and what becomes of a key grant. ``zdrone.core.authority`` is the machine that speaks it, and
re-exports every name here: import them from there.

Events (``Event``: frozen, each carrying ``now``) are what the drone's node adapter saw: a pairing,
a key grant, an authentic frame, a link's TBM state, the vehicle's region and ground state, a GS's
request or release, a fleet revision, time passing. ``GS_EVENTS`` are the ones a ground station
sent: a step the machine's table does not have for one of them is answered with a ``Reject``, never
raised.

Actions (``Action``: frozen) are what the adapter carries out: forward the frame, drop it (counted
per ``HaDrop`` reason), send a control message, command the failsafe, and the event log's notes.

Key grants have typed results. ``AuthorityMachine.grant(GrantHeard)`` returns ``GrantAccepted`` (the
adapter installs the key: live if the link has none, else a candidate the GS must prove) or
``GrantRejected(reason)`` (its ``Reject`` is among the actions), with the actions; ``check_grant``
refuses a grant whose content does not fit the fleet before it reaches the machine.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Mapping

from zdrone.core.keys import KEY_LEN
from zdrone.core.tbm import LinkState
from zdrone.core.uplink import UplinkClass
from zdrone.core.wire import Control, KeyGrant


class HaDrop(enum.Enum):
    """Why the HA refused to forward a frame (counted per reason)."""

    NOT_AUTHORITY = "not_authority"
    NOT_LINKED = "not_linked"
    FAILSAFE = "failsafe"
    DENIED_BY_POLICY = "denied_by_policy"


# ----------------------------------------------------------------------------- events
@dataclass(frozen=True, slots=True)
class Event:
    now: float


@dataclass(frozen=True, slots=True)
class PairingDone(Event):
    """Pairing with ``gs`` completed (the adapter already checked its static key)."""

    gs: str
    on_ground: bool = True


@dataclass(frozen=True, slots=True)
class GrantHeard(Event):
    """``sender`` (over its sealed link) hands the drone a link key for ``gs``."""

    sender: str
    gs: str


@dataclass(frozen=True, slots=True)
class Frame(Event):
    """An authentic MAVLink frame from ``gs``, classified by the drone's uplink policy."""

    gs: str
    uplink: UplinkClass


@dataclass(frozen=True, slots=True)
class LinkChanged(Event):
    """The TBM state of the link to ``gs`` changed."""

    gs: str
    state: LinkState


@dataclass(frozen=True, slots=True)
class RegionChanged(Event):
    """The set of GS coverage circles the vehicle is inside changed."""

    inside: frozenset[str]


@dataclass(frozen=True, slots=True)
class AuthorityAsked(Event):
    """``sender`` asks that authority pass to ``to`` (passed on to the owner, whose operator has
    ``timeout`` seconds to consent); from the owner for itself, its "allow takeover" setting."""

    sender: str
    to: str
    timeout: float = 0.0
    takeover: bool = False
    ask_id: int = 0
    takeover_to: str | None = None  # with ``takeover`` from the owner: the one GS it is for (None: any)


@dataclass(frozen=True, slots=True)
class Release(Event):
    """``sender`` releases authority of ``epoch`` to ``to`` (effective once ``to`` is proven)."""

    sender: str
    to: str
    epoch: int


@dataclass(frozen=True, slots=True)
class GroundChanged(Event):
    """The vehicle is on the ground (disarmed, or landed) or not, by its own HEARTBEAT and
    EXTENDED_SYS_STATE. The machine starts "in the air": the failsafe rule holds until told otherwise."""

    on_ground: bool


@dataclass(frozen=True, slots=True)
class Revised(Event):
    """A fleet revision was applied: ``authorized`` is the drone's authorized list under it."""

    authorized: frozenset[str]
    revision: int = 0
    why: str = ""  # not a revision: why the list shrank (the owner's lease lapsed)


@dataclass(frozen=True, slots=True)
class LinkClosed(Event):
    """The drone closes its link with ``gs`` (its own decision, ``zdrone.core.linkplan``): the machine
    forgets the link, unless ``gs`` may still be needed (``AuthorityMachine.may_close``)."""

    gs: str
    why: str = ""


@dataclass(frozen=True, slots=True)
class Tick(Event):
    """Time passes (the adapter ticks the machine at its loop rate)."""


GS_EVENTS = (PairingDone, GrantHeard, Frame, AuthorityAsked, Release)


# ---------------------------------------------------------------------------- actions
@dataclass(frozen=True, slots=True)
class Action:
    pass


@dataclass(frozen=True, slots=True)
class Forward(Action):
    """Forward the frame of the event being handled to the vehicle."""

    gs: str


@dataclass(frozen=True, slots=True)
class DropFrame(Action):
    gs: str
    reason: HaDrop


@dataclass(frozen=True, slots=True)
class SendControl(Action):
    gs: str
    msg: Control


@dataclass(frozen=True, slots=True)
class FailsafeCommand(Action):
    command: str  # "LAND" | "RTL"
    reason: str


@dataclass(frozen=True, slots=True)
class AuthorityChanged(Action):
    """For the event log: authority moved (``old`` None at first pairing)."""

    old: str | None
    new: str
    epoch: int
    kind: str  # "paired" | "handover" | "emergency" | "repaired" | "regained"


@dataclass(frozen=True, slots=True)
class Note(Action):
    """For the event log: something worth recording (region entered, hand-over timed out, ...)."""

    kind: str
    detail: str


# ------------------------------------------------------------------------- key grants
class GrantRejection(enum.Enum):
    """Why the drone rejected a key grant (each answered with a ``Reject`` to its sender)."""

    BAD_GRANT = "bad_grant"  # names no GS of the fleet, or a wrong sysid, or a secret of the wrong length
    ILLEGAL_STATE = "illegal_state"  # no grants while unpaired or in failsafe
    NOT_AUTHORITY = "not_authority"  # only the authority grants keys
    UNAUTHORIZED = "unauthorized"  # the key is for a GS not authorized for this drone


@dataclass(frozen=True, slots=True)
class GrantAccepted:
    """The grant of a link key for ``gs`` stands: install it and acknowledge it."""

    gs: str


@dataclass(frozen=True, slots=True)
class GrantRejected:
    """The grant of a link key for ``gs`` is rejected; ``detail`` is the ``Reject``'s text."""

    gs: str
    reason: GrantRejection
    detail: str


GrantResult = GrantAccepted | GrantRejected


def check_grant(grant: KeyGrant, gs_sysids: Mapping[str, int]) -> GrantRejected | None:
    """A grant's content against the fleet (``gs_sysids``: each ground station's sysid): it must name
    a GS of the fleet with its sysid and carry a whole link secret. None if it does."""
    if gs_sysids.get(grant.gs) != grant.sysid or len(grant.secret) != KEY_LEN:
        return GrantRejected(grant.gs, GrantRejection.BAD_GRANT,
                             f"unknown ground station or sysid: {grant.gs}/{grant.sysid}")
    return None

