"""Typed event-log records: one frozen msgspec struct per event a node writes, tagged by ``type``.

Theory of operation: every line of an event log (``zdrone.net.eventlog``) is one JSON object with
the wall time ``t``, the writing ``node``, the event ``type`` and the event's own fields. Each kind
of writer has its vocabulary: the drone node (``DRONE_RECORDS``) and the ground station
(``GS_RECORDS``) here; the testbed registers its own (``zdrone.sil.records``: the attacker, the
emulated radio) with ``register_vocabulary``. One tag may name different shapes
for different writers (a drone's ``status`` is not a GS's), so each vocabulary is its own tagged
union, and a line is the record of the first vocabulary with a record that fits it exactly: no
field missing, none unknown, every value of its type. A line no record fits, or of a type no
vocabulary has, is an ``UntypedRecord`` holding its fields as written: nothing is lost.

Field names are the logged names (``from`` is ``from_`` in Python). A field with a default is one
that a writer may leave out, or that logs of earlier versions lack. ``t`` and ``node`` default to
"unset": the log that writes a record stamps them. Pure: no I/O.
"""

from __future__ import annotations

from typing import Any, Iterable, TypeVar, Union

import msgspec

from .tbm import LinkState
from .wire import AuthorityState

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


# ----------------------------------------------------------------------------- the ground station
class GsStart(Record, frozen=True, tag="start"):
    """The GS started, serving ``drones``."""

    drones: tuple[str, ...]


class GsLinkReport(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """The GS's live link to one drone."""

    opened: int
    sent: int
    dropped: dict[str, int]


class GsDroneReport(msgspec.Struct, frozen=True, forbid_unknown_fields=True, omit_defaults=True):
    """What the GS knows of one drone."""

    linked: bool
    owner: str | None
    epoch: int
    state: str  # the drone's authority state as last reported, or "unknown"
    stage: str  # the GS's mission stage for this drone
    position: Position | None
    commands_sent: dict[str, int]  # per MAVLink command id
    link: GsLinkReport | None
    key_candidates: int
    dropped_unlinked: dict[str, int]
    waiting: str | None = None  # what the GS waits for before it arms (None: nothing)
    fc_signed: bool | None = None  # the drone says its link to the autopilot is MAVLink-signed


class GsState(Record, frozen=True, kw_only=True):
    """What the GS knows at one instant (``GsStatus`` periodically, ``GsStop`` last)."""

    drones: dict[str, GsDroneReport]
    counters: dict[str, int]
    inbox_dropped: dict[str, int] = {}
    gateway: dict[str, Any] | None = None  # the GCS gateway's stats, when it runs one


class GsStatus(GsState, frozen=True, tag="status"):
    """The GS's periodic status."""


class GsStop(GsState, frozen=True, tag="stop"):
    """The GS's final status, written as it closes."""


class ControlRequested(Record, frozen=True, tag="control_requested"):
    """The GS asked the drone for authority (after a failsafe, on the operator's request)."""

    drone: str
    state: AuthorityState | None


class GsPairRefused(Record, frozen=True, tag="pair_refused"):
    """The drone refused the GS's pairing."""

    drone: str
    reason: str


class PairFailed(Record, frozen=True, tag="pair_failed"):
    """A pairing reply did not complete the handshake (forged or stale)."""

    drone: str
    reason: str


class PairNotNeeded(Record, frozen=True, tag="pair_not_needed"):
    """The drone still holds the GS's key: no new one."""

    drone: str


class GsPaired(Record, frozen=True, tag="paired"):
    """The GS paired with ``drone`` (``again``: it had a link before)."""

    drone: str
    again: bool = False


class LinkkeyRefused(Record, frozen=True, tag="linkkey_refused"):
    """The GS refused to share a link key with ``asker`` (the first few of each reason)."""

    drone: str
    asker: str
    reason: str
    detail: str


class LinkkeyShared(Record, frozen=True, tag="linkkey_shared"):
    """The GS shared its link key for ``drone`` with ``asker``."""

    drone: str
    asker: str


class LinkkeyError(Record, frozen=True, tag="linkkey_error"):
    """GS ``gs`` answered a key query with an error."""

    drone: str
    gs: str
    reason: str


class LinkkeyBadReply(Record, frozen=True, tag="linkkey_bad_reply"):
    """A key reply claiming to be from ``gs`` did not verify."""

    drone: str
    gs: str
    reason: str


class LinkkeyReceived(Record, frozen=True, tag="linkkey_received"):
    """The GS received ``gs``'s link key for ``drone`` (to grant it to the drone)."""

    drone: str
    gs: str


class GsLinkConfirmed(Record, frozen=True, tag="link_confirmed"):
    """The drone proved a new key of the GS's link."""

    drone: str
    how: str
    replaced: bool


class AutopilotFound(Record, frozen=True, tag="autopilot"):
    """The drone's autopilot, from its first heartbeat."""

    drone: str
    autopilot: str
    mav_type: int


class VehicleText(Record, frozen=True, tag="vehicle_text"):
    """A STATUSTEXT of the vehicle."""

    drone: str
    text: str
    severity: int | None = None


class AuthorityStatus(Record, frozen=True, tag="authority_status"):
    """The drone's authority status changed, as the GS heard it."""

    drone: str
    owner: str | None
    epoch: int
    state: AuthorityState
    pending_to: str | None


class FcSigningHeard(Record, frozen=True, tag="fc_signing"):
    """The drone says whether its link to its autopilot is MAVLink-signed (logged when it changes)."""

    drone: str
    signed: bool


class KeyGranted(Record, frozen=True, tag="key_granted"):
    """The drone acknowledged the key of ``gs`` granted by this GS."""

    drone: str
    gs: str


class Rejected(Record, frozen=True, tag="rejected"):
    """The drone refused a step of the GS (``what``) and said why."""

    drone: str
    what: str
    reason: str


class FailsafeNoticed(Record, frozen=True, tag="failsafe_notice"):
    """The drone said its failsafe fired."""

    drone: str
    action: str
    reason: str


class HandoverFailed(Record, frozen=True, tag="handover_failed"):
    """A hand-over away from this GS failed: it keeps authority and commands ``action``."""

    drone: str
    epoch: int
    action: str
    reason: str


class VehicleRefused(Record, frozen=True, tag="vehicle_refused"):
    """The vehicle refused (or did not answer) a mission step; ``try_``: how many times so far."""

    drone: str
    what: str
    result: int | None
    try_: int = msgspec.field(name="try")
    texts: tuple[str, ...]


class MissionFailed(Record, frozen=True, tag="mission_failed"):
    """The GS gave up the mission."""

    drone: str
    reason: str


class MissionRetry(Record, frozen=True, tag="mission_retry"):
    """A mission step (``what``: ``upload``) failed with ``result`` (None: no answer) and is tried again
    ``after`` seconds (backoff with jitter); ``try_``: failures so far."""

    drone: str
    what: str
    result: int | None
    try_: int = msgspec.field(name="try")
    after: float


class VehicleParam(Record, frozen=True, tag="vehicle_param"):
    """A vehicle parameter the mission needs was confirmed."""

    drone: str
    name: str
    value: float


class MissionUpload(Record, frozen=True, tag="mission_upload"):
    """The GS started uploading a mission of ``items`` items."""

    drone: str
    items: int
    autopilot: str | None = None


class MissionStarted(Record, frozen=True, tag="mission_started"):
    """The vehicle accepted the mission start."""

    drone: str
    result: int


class VehicleWaiting(Record, frozen=True, tag="vehicle_waiting"):
    """What the GS now waits for before it arms ``drone`` (None: ready, arming)."""

    drone: str
    waiting: str | None


class TakeoffConfirmed(Record, frozen=True, tag="takeoff_confirmed"):
    """After the mission start the vehicle left the ground (``restarts``: starts again before that)."""

    drone: str
    restarts: int


class TakeoffRestart(Record, frozen=True, tag="takeoff_restart"):
    """Started, the vehicle disarmed on the ground: the GS arms and starts it again."""

    drone: str
    reason: str
    restarts: int


class MissionProgress(Record, frozen=True, tag="mission_progress"):
    """The mission moved on to item ``seq`` (MISSION_CURRENT) or reached it (MISSION_ITEM_REACHED),
    with the vehicle's landed state and position (None: unknown) at that moment."""

    drone: str
    seq: int
    reached: bool
    landed_state: int
    position: Position | None


class MissionStartFailed(Record, frozen=True, tag="mission_start_failed"):
    """The vehicle refused the mission start for good."""

    drone: str
    result: int
    texts: tuple[str, ...]


class HandoverRelease(Record, frozen=True, tag="handover_release"):
    """The GS released authority over ``drone`` toward ``to`` at ``position`` (lat, lon)."""

    drone: str
    to: str
    epoch: int
    position: tuple[float, float]


class HandoverHold(Record, frozen=True, tag="handover_hold"):
    """The hand-over toward ``to`` waits for its key (known to be coming): the GS holds the vehicle
    where it is, in the autopilot's ``mode``, for a bounded time."""

    drone: str
    to: str
    epoch: int
    mode: str


class HandoverResume(Record, frozen=True, tag="handover_resume"):
    """The key is there: the GS resumes the mission it held ``held_s`` seconds, just before releasing."""

    drone: str
    to: str
    epoch: int
    held_s: float


class GcsApp(Record, frozen=True, tag="gcs_app"):
    """A GCS application appeared on the gateway, as GS component ``gs_compid``."""

    sysid: int
    compid: int
    gs_compid: int


class GcsAppGone(Record, frozen=True, tag="gcs_app_gone"):
    """A GCS application left the gateway (``reason``: why)."""

    sysid: int
    compid: int
    gs_compid: int
    reason: str


class OperatorControlRequested(Record, frozen=True, tag="operator_control_requested"):
    """A GCS application asked to take control of ``drone`` back (``app``: which one, by its signing
    key's name ``key:<name>`` or ``unsigned:<peer>``)."""

    drone: str
    by_sysid: int
    app: str = ""


class OperatorControlEvent(Record, frozen=True):
    """A step of MAVLink operator control at a GS (``gs.opcontrol``) about ``drone``."""

    drone: str


class OperatorControlAsked(OperatorControlEvent, frozen=True, tag="operator_control_asked"):
    """Our operator asked for control (``owner_allows``: the owner allowed takeover then)."""

    owner: str | None
    timeout: float
    owner_allows: bool
    app: str = ""  # the application that asked (its signing key's name, or unsigned:<peer>)


class OperatorRequestWithdrawn(OperatorControlEvent, frozen=True, tag="operator_request_withdrawn"):
    """Our operator withdrew its request."""

    app: str = ""


class OperatorRequestTimedOut(OperatorControlEvent, frozen=True, tag="operator_request_timed_out"):
    """Our request's timeout passed without control (``owner``: who still holds it)."""

    owner: str | None


class OperatorControlTaken(OperatorControlEvent, frozen=True, tag="operator_control_taken"):
    """Our request succeeded: control is ours (held by our operator) in ``epoch``."""

    epoch: int


class OperatorControlLetGo(OperatorControlEvent, frozen=True, tag="operator_control_let_go"):
    """Our operator let go of held control: automatic hand-overs again."""

    app: str = ""


class OperatorTakeoverSetting(OperatorControlEvent, frozen=True, tag="operator_takeover_setting"):
    """Our operator's "allow takeover" setting for ``epoch`` changed (nothing pending)."""

    allowed: bool
    epoch: int | None = None
    app: str = ""


class OperatorRequestReceived(OperatorControlEvent, frozen=True, tag="operator_request"):
    """As owner: the drone passed on ``requester``'s request (shown to our operator)."""

    requester: str
    to: str
    epoch: int
    timeout: float
    takeover_allowed: bool


class OperatorRequestStale(OperatorControlEvent, frozen=True, tag="operator_request_stale"):
    """A passed-on request for an epoch or an authority that is not ours: ignored."""

    requester: str
    epoch: int


class OperatorRequestGranted(OperatorControlEvent, frozen=True, tag="operator_request_granted"):
    """As owner: authority of ``epoch`` released to ``to`` (``why``: takeover allowed, or the operator's
    consent; ``app``: the application that consented or opened the window, "" for the station's policy)."""

    requester: str
    to: str
    why: str
    epoch: int = 0
    app: str = ""


class OperatorRequestDeclined(OperatorControlEvent, frozen=True, tag="operator_request_declined"):
    """As owner: our operator declined ``requester``'s request; it is not shown again for ``hold_s``."""

    requester: str
    hold_s: float = 0.0
    app: str = ""


class OperatorConsentRefused(OperatorControlEvent, frozen=True, tag="operator_consent_refused"):
    """As owner: an application's consent did not name the pending requester (``named``: the GS its p4
    names, None for none): nothing moved."""

    requester: str
    named: str | None
    reason: str
    app: str = ""


class TakeoverWindowOpened(OperatorControlEvent, frozen=True, tag="takeover_window_opened"):
    """As owner: our operator allowed ``to`` to take control of ``epoch`` for ``seconds``."""

    to: str
    epoch: int
    seconds: float
    app: str = ""


class OperatorRequestBusy(OperatorControlEvent, frozen=True, tag="operator_request_busy"):
    """As owner: ``requester`` asked while ``pending``'s request stands (one at a time): not shown yet."""

    requester: str
    pending: str


class OperatorRequestHeldOff(OperatorControlEvent, frozen=True, tag="operator_request_held_off"):
    """As owner: ``requester`` asked again within the hold after a decline or an expiry: not shown."""

    requester: str
    seconds_left: float


class OperatorRequestExpired(OperatorControlEvent, frozen=True, tag="operator_request_expired"):
    """As owner: ``requester``'s request timed out without consent (nothing moved)."""

    requester: str


class TakeoverWindowClosed(OperatorControlEvent, frozen=True, tag="takeover_window_closed"):
    """As owner: the window a consent opened for takeover closed."""


class OperatorRequestShown(OperatorControlEvent, frozen=True, tag="operator_request_shown"):
    """The GCS gateway presented ``requester``'s request to its ``apps`` applications."""

    requester: str
    apps: int


OPERATOR_CONTROL_RECORDS: tuple[type[Record], ...] = (
    OperatorControlAsked, OperatorRequestWithdrawn, OperatorRequestTimedOut, OperatorControlTaken,
    OperatorControlLetGo, OperatorTakeoverSetting, OperatorRequestReceived, OperatorRequestStale,
    OperatorRequestGranted, OperatorRequestDeclined, OperatorRequestExpired, TakeoverWindowClosed, OperatorRequestShown,
    OperatorConsentRefused, TakeoverWindowOpened, OperatorRequestBusy, OperatorRequestHeldOff,
)


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
    RevokedNote, RevisionApplied, RevisionRefused,
)
#: the ground station's records (its core's ``Log`` actions, its loop's, its GCS gateway's)
GS_RECORDS: tuple[type[Record], ...] = (
    GsStart, GsStatus, GsStop, Closed, Suppressed, PathOpen, PathState, ControlRequested, GsPairRefused, PairFailed,
    PairNotNeeded, GsPaired, LinkkeyRefused, LinkkeyShared, LinkkeyError, LinkkeyBadReply, LinkkeyReceived,
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
    vocabularies are here; the testbed registers its own (``zdrone.sil.records``)."""
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
