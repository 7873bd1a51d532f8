"""The drone node's records (its vocabulary: ``zdrone.core.records.DRONE_RECORDS``)."""

from __future__ import annotations

from typing import Any

import msgspec

from zdrone.core.tbm import LinkState
from zdrone.core.wire import AuthorityState

from zdrone.core.records.base import Position, Record


# ----------------------------------------------------------------------------- the drone node
class Start(Record, frozen=True, tag="start"):
    """The drone node started, flying the vehicle at ``vehicle`` (a connection string)."""

    vehicle: str


class LinkReport(msgspec.Struct, frozen=True, forbid_unknown_fields=True, omit_defaults=True):
    """One live link in a drone's status."""

    state: LinkState
    since_last: float  # seconds since the last authentic frame
    opened: int
    sent: int
    dropped: dict[str, int]  # frames dropped by the security module, per reason
    missing: int = 0  # the peer's frames that never arrived: out of range, not listened to, or lost on the way


class KeySlotReport(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """One GS's key slot in a drone's status."""

    live: bool
    candidates: int
    expired: int
    dropped_unlinked: dict[str, int]


class DroneState(Record, frozen=True, kw_only=True):
    """What the drone node knows at one instant (``DroneStatus`` twice a second, ``DroneStop`` last)."""

    owner: str | None
    epoch: int
    state: AuthorityState
    pending_to: str | None
    position: Position | None
    armed: bool
    mode: str
    landed_state: int  # MAV_LANDED_STATE_*
    autopilot: str | None = None
    vehicle_streams: dict[str, Any] = {}
    in_region: bool
    subscribed: tuple[str, ...]
    links: dict[str, LinkReport]
    keys: dict[str, KeySlotReport]
    ha_drops: dict[str, int]
    rejects: dict[str, int]
    counters: dict[str, int]
    forwarded_commands: dict[str, int]
    forwarded_epochs: dict[str, int] = {}
    inbox_dropped: dict[str, int] = {}
    out_of_coverage: dict[str, int]
    radio_lost: dict[str, int] = {}
    paths: dict[str, dict[str, Any]] = {}  # with a router per site: each path (open, connected)
    fc_signing: dict[str, Any] = {}  # MAVLink signing of the autopilot's link (``FcSigning.status``)
    revision: dict[str, Any] = {}  # the fleet revision in force and the ones refused (``RevisionKeeper.stats``)
    traffic: dict[str, tuple[int, int]] = {}  # what the GSs' envelopes carried: kind -> [messages, bytes] (``LinkTraffic``)
    links_follow: bool = False  # the drone's links follow it (``zdrone.core.linkplan``)
    links_peak: int = 0  # the most live links it held at once


class DroneStatus(DroneState, frozen=True, tag="status"):
    """The drone node's periodic status."""


class DroneStop(DroneState, frozen=True, tag="stop"):
    """The drone node's final status, written as it closes."""


class Subscribe(Record, frozen=True, tag="subscribe"):
    """The drone listens to GS ``gs``'s uplink."""

    gs: str


class Unsubscribe(Record, frozen=True, tag="unsubscribe"):
    """The drone no longer listens to GS ``gs``'s uplink."""

    gs: str


class LinkInstalled(Record, frozen=True, tag="link_installed"):
    """A key for ``gs`` is live at once (the link had none)."""

    gs: str
    how: str


class LinkCandidate(Record, frozen=True, tag="link_candidate"):
    """A key for ``gs`` waits for ``gs`` to prove it (the link has a live key)."""

    gs: str
    how: str


class LinkConfirmed(Record, frozen=True, tag="link_confirmed"):
    """GS ``gs`` proved a new key: it is the live key now."""

    gs: str
    how: str  # "pair", "grant"
    replaced: bool  # a live key existed and was replaced


class AuthorityMoved(Record, frozen=True):
    """Authority moved from ``from_`` to ``to`` (``AuthorityChange`` or ``HandoverComplete``)."""

    from_: str | None = msgspec.field(name="from")
    to: str
    epoch: int
    kind: str  # "paired", "handover", "emergency", "repaired", "regained", ...
    time: float
    position: Position | None


class AuthorityChange(AuthorityMoved, frozen=True, tag="authority"):
    """Authority given or taken back outside a hand-over (first pairing, regained, ...)."""


class HandoverComplete(AuthorityMoved, frozen=True, tag="handover_complete"):
    """A hand-over (or an emergency hand-over to an heir) completed."""


class Failsafe(Record, frozen=True, tag="failsafe"):
    """The drone commanded its vehicle to ``action`` (LAND, RTL)."""

    action: str
    reason: str
    detect_to_command_ms: float | None  # from the loss threshold to the command
    position: Position | None


class FailsafeConfirmed(Record, frozen=True, tag="failsafe_confirmed"):
    """The autopilot shows the failsafe the drone commanded (its mode, or on the ground and disarmed)."""

    action: str
    attempts: int  # sends of the command
    after_s: float  # since the first send
    seen: str


class FailsafeRetried(Record, frozen=True, tag="failsafe_retried"):
    """The autopilot did not show the failsafe in time: the command was sent again."""

    action: str
    attempts: int
    after_s: float
    seen: str  # the autopilot's mode meanwhile


class FailsafeUnconfirmed(Record, frozen=True, tag="failsafe_unconfirmed"):
    """The autopilot never showed the failsafe, out of attempts."""

    action: str
    attempts: int
    after_s: float
    seen: str


class VehicleFound(Record, frozen=True, tag="vehicle_found"):
    """The vehicle link found its autopilot: the drone's fleet sysid with the autopilot's component; over
    UDP its endpoint and how it proved itself (``fixed``, ``heartbeat``, ``signed``)."""

    sysid: int
    autopilot: str | None
    endpoint: str | None = None
    how: str | None = None


class FcUnsigned(Record, frozen=True, tag="fc_unsigned"):
    """The autopilot's link is not MAVLink-signed (``--fc-signing off``, or ``prefer`` with an autopilot
    that does not sign): shown to every GS (``fc_signed`` false); its positions grant no authority
    unless the operator opted in for this drone (``trust_unsigned_position``)."""

    mode: str
    state: str
    reason: str
    trust_unsigned_position: bool


class AuthorityForgotten(Record, frozen=True, tag="authority_forgotten"):
    """At start, no saved owner to come back to: a fresh start (a ground restart with a saved owner
    keeps its epoch and gives that owner the first claim instead: ``FirstClaim``)."""

    owner: str | None
    epoch: int
    state: AuthorityState


class Restarted(Record, frozen=True, tag="restarted"):
    """The node restarted in the air with its saved authority; waiting for the owner to re-pair."""

    owner: str | None
    epoch: int
    state: AuthorityState
    position: Position | None


class Drop(Record, frozen=True, tag="drop"):
    """An uplink envelope dropped by the security module (the first few of each reason)."""

    gs: str
    reason: str
    detail: str


class Paired(Record, frozen=True, tag="paired"):
    """GS ``gs`` proved its pairing key."""

    gs: str


class PairAnswered(Record, frozen=True, tag="pair_answered"):
    """The drone answered GS ``gs``'s pairing query (its key is a candidate until proven)."""

    gs: str


class PairRefused(Record, frozen=True, tag="pair_refused"):
    """The drone refused GS ``gs``'s pairing (the first few of each reason)."""

    gs: str
    reason: str


class LinkStateChanged(Record, frozen=True, tag="link_state"):
    """The link to ``gs`` went OK / DEGRADED / LOST (time between messages)."""

    gs: str
    state: LinkState


class AuthorityNote(Record, frozen=True):
    """Something the authority machine noted (``authority.Note``), with where the drone was."""

    detail: str
    position: Position | None


class RestoreRefused(AuthorityNote, frozen=True, tag="restore_refused"):
    """The saved owner may no longer command this drone."""


class Restored(AuthorityNote, frozen=True, tag="restored"):
    """The saved authority is back, waiting for its owner to re-pair."""


class FirstClaim(AuthorityNote, frozen=True, tag="first_claim"):
    """Restarted on the ground: the epoch is kept and the last owner may pair back first for a while."""


class FirstClaimOver(AuthorityNote, frozen=True, tag="first_claim_over"):
    """The last owner did not pair back within its first claim: any covering authorized GS may pair."""


class HandoverStart(AuthorityNote, frozen=True, tag="handover_start"):
    """The owner released authority toward another GS."""


class HandoverRequested(AuthorityNote, frozen=True, tag="handover_requested"):
    """A GS asked for authority."""


class TakeoverSetting(AuthorityNote, frozen=True, tag="takeover_setting"):
    """The owner told the drone whether its operator allows takeover in this epoch."""


class HandoverTimeout(AuthorityNote, frozen=True, tag="handover_timeout"):
    """The recipient did not prove its link in time: authority stays."""


class HandoverAborted(AuthorityNote, frozen=True, tag="handover_aborted"):
    """The link to the recipient was lost during the hand-over."""


class Reject(AuthorityNote, frozen=True, tag="reject"):
    """An authentic but illegal protocol step was refused."""


class KeyInstalled(AuthorityNote, frozen=True, tag="key_installed"):
    """The authority machine accepted a granted key."""


class FailsafeRecovered(AuthorityNote, frozen=True, tag="failsafe_recovered"):
    """A GS took control back after the failsafe."""


class FailsafeEntered(AuthorityNote, frozen=True, tag="failsafe_entered"):
    """The failsafe fired."""


class AuthorityLinkLost(AuthorityNote, frozen=True, tag="authority_link_lost"):
    """The authority's link was lost; authority went to an heir."""


class OwnerLinkLostOnGround(AuthorityNote, frozen=True, tag="owner_link_lost_on_ground"):
    """The owner's link was lost with the vehicle on the ground: no failsafe; the owner keeps authority."""


class RevokedNote(AuthorityNote, frozen=True, tag="revoked"):
    """A fleet revision took a GS off the authorized list: its link dropped, its keys erased."""


class LinkClosedNote(AuthorityNote, frozen=True, tag="link_closed"):
    """The drone closed a GS's link (links that follow the drone): the GS told, the key wiped."""


class LinkKeptNote(AuthorityNote, frozen=True, tag="link_kept"):
    """A link the drone meant to close may still be needed (owner, recipient, heir): kept."""


class RevisionApplied(Record, frozen=True, tag="revision_applied"):
    """A signed fleet revision was checked and applied (``zdrone.core.revision``)."""

    number: int
    revoked: tuple[str, ...]
    rotated: tuple[str, ...]
    pairing_pq: bool = False


class RevisionRefused(Record, frozen=True, tag="revision_refused"):
    """A fleet revision was refused (``malformed``, ``bad_signature``, ``stale``, ``replayed``, ...)."""

    reason: str
    number: int | None = None


class RegionEntered(AuthorityNote, frozen=True, tag="region_entered"):
    """The drone entered a region covered by more GSs (``detail``: the GSs covering it)."""


class RegionLeft(AuthorityNote, frozen=True, tag="region_left"):
    """The drone left a region covered by more GSs."""
