"""The ground station's records (its vocabulary: ``zdrone.core.records.GS_RECORDS``)."""

from __future__ import annotations

from typing import Any

import msgspec

from zdrone.core.wire import AuthorityState

from zdrone.core.records.base import Position, Record


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
    traffic: dict[str, tuple[int, int]] = {}  # what the drones' envelopes carried: kind -> [messages, bytes] (``LinkTraffic``)


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


class GsLinkClosed(Record, frozen=True, tag="link_closed"):
    """The drone closed our link (it left our coverage behind, or needed room): our key wiped."""

    drone: str
    reason: str


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
    """Our operator refused takeover with nothing pending: the window a consent opened in ``epoch`` is
    closed (``allowed`` is False; an "allow takeover" with nothing pending is refused, never a setting)."""

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
    consent; ``app``: the application that consented or opened the window, "" for the station's policy;
    ``decided_by``: who decided, ``operator`` (that application) or ``station_policy`` (``--allow-takeover``))."""

    requester: str
    to: str
    why: str
    epoch: int = 0
    app: str = ""
    decided_by: str = "operator"


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
