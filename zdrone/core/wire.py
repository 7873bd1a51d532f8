"""Control messages carried inside the sealed envelope next to MAVLink frames.

A sealed plaintext is either one MAVLink frame (first byte 0xFD or 0xFE) or ``CONTROL_PREFIX``
followed by one msgpack-encoded control message below (a msgspec tagged union, field ``t``), or, from
a drone to a GS only, a *batch*: ``BATCH_PREFIX`` followed by two or more such plaintexts in the
bundle format (``zdrone.core.bundle``: a 2-byte length before each), the messages of one pass of the
drone to that GS under one envelope (``SecureLink.seal_batch``): one header and tag per radio packet,
not per frame.
"""

from __future__ import annotations

import enum

import msgspec

CONTROL_PREFIX = b"\x01"
BATCH_PREFIX = b"\x02"


class AuthorityState(enum.Enum):
    """The handover authority's state, as the drone reports it (``authority.State`` is this enum)."""

    UNPAIRED = "unpaired"
    LINKED = "linked"
    HANDOVER_PENDING = "handover_pending"
    FAILSAFE = "failsafe"


class Control(msgspec.Struct, frozen=True, tag_field="t", forbid_unknown_fields=True):
    """Base of every control message."""


class KeyGrant(Control, frozen=True, tag="key_grant"):
    """Authority GS -> drone: install the link secret for GS ``gs`` (obtained over the backhaul)."""

    gs: str
    sysid: int
    secret: bytes
    grant_id: int
    #: GS ``gs``'s signed keys-lost notice (``zdrone.core.keyslost``): the key may replace its live one
    lost: bytes = b""


class KeyGrantAck(Control, frozen=True, tag="key_grant_ack"):
    gs: str
    grant_id: int


class HandoverRequest(Control, frozen=True, tag="handover_request"):
    """A GS asks for authority (``to`` is the GS that should receive it): the drone passes it on to
    the owner as an ``OperatorRequest`` whose operator may consent within ``timeout`` seconds. For
    itself with ``ask_id`` 0 (no operator's request): the owner's "allow takeover" setting
    (``takeover``) for this epoch, ignored from anyone else."""

    to: str
    epoch: int
    timeout: float = 0.0  # seconds the requester waits for the owner's consent (0: the owner's default)
    takeover: bool = False  # from the owner for itself: grant requests without asking its operator
    ask_id: int = 0  # the requester's number for its operator's request (re-sends keep it)
    takeover_to: str | None = None  # with ``takeover``: the one GS a consent's window is for (None: any)


class OperatorRequest(Control, frozen=True, tag="operator_request"):
    """Drone -> owner: GS ``requester`` (the sender of a sealed ``HandoverRequest``, never a name or
    sysid it claims) asks that authority of ``epoch`` pass to ``to``; its operator waits ``timeout`` s."""

    requester: str
    to: str
    epoch: int
    timeout: float = 0.0
    ask_id: int = 0


class HandoverRelease(Control, frozen=True, tag="handover_release"):
    """The current authority releases authority to ``to`` for epoch ``epoch``."""

    to: str
    epoch: int


class AuditHead(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """The newest checkpoint of the drone's authority record (``zdrone.core.audit``): entry ``seq``
    has hash ``head``, signed (``sig``) with the drone's fleet signing key; a GS countersigns it."""

    seq: int
    head: bytes
    sig: bytes


class AuditOffer(Control, frozen=True, tag="audit_offer"):
    """GS -> drone: a checkpoint of the GS's authority record that covers its decisions, for the
    drone to countersign in its own record (``zdrone.core.audit``), as the GS does the drone's."""

    head: AuditHead


class AuthorityAttestation(msgspec.Struct, frozen=True, forbid_unknown_fields=True, array_like=True):
    """The drone's own word on its authority (``zdrone.core.attestation``): ``owner`` holds it in
    ``epoch``, in ``state`` (handing it to ``pending_to``), allowing takeover (``takeover``, for
    ``takeover_to`` only, or any GS when None), said at the drone's time of day ``at``, its ``seq``-th
    signature since it started, signed (``sig``) with the drone's fleet signing key at every status
    beacon and at every change; a GS passes it on to the fleet's viewer as it came."""

    owner: str | None
    epoch: int
    state: AuthorityState
    pending_to: str | None
    takeover: bool
    takeover_to: str | None
    at: float
    seq: int
    sig: bytes


class AuthorityStatus(Control, frozen=True, tag="authority"):
    """Drone -> every linked GS: who holds authority, in which epoch, in which state."""

    owner: str | None
    epoch: int
    state: AuthorityState
    pending_to: str | None = None
    linked: list[str] = []  # GSs the drone holds a link key for
    takeover: bool = False  # the owner allows takeover in this epoch (its operator's setting)
    takeover_to: str | None = None  # ... for this GS only (a consent's window); None: for any
    fc_signed: bool | None = None  # the drone's link to its autopilot is MAVLink-signed (None: not said)
    audit: AuditHead | None = None  # the drone's newest authority-record checkpoint (None: none yet)
    attest: AuthorityAttestation | None = None  # the drone's signed word on this status (None: no key)


class Reject(Control, frozen=True, tag="reject"):
    """An authentic but illegal protocol step was refused."""

    what: str
    reason: str


class FailsafeNotice(Control, frozen=True, tag="failsafe"):
    """Drone -> any GS it can reach: the failsafe fired."""

    action: str
    reason: str


class SmHeartbeat(Control, frozen=True, tag="sm_heartbeat"):
    """The paper's separate security-layer heartbeat (``bench traffic`` "paper" variant only;
    zdrone itself reuses the MAVLink HEARTBEAT and sends no extra packets)."""

    seq: int


class LinkClosed(Control, frozen=True, tag="link_closed"):
    """Drone -> the GS whose link it closes, under that link's key, its last word on it: the drone has
    wiped the key (it left that GS behind, or needed room for a link ahead: ``zdrone.core.linkplan``);
    the GS wipes its end and stops heartbeating the drone."""

    reason: str


ControlMessage = (KeyGrant | KeyGrantAck | HandoverRequest | HandoverRelease | AuthorityStatus | Reject | FailsafeNotice
                  | SmHeartbeat | OperatorRequest | AuditOffer | LinkClosed)

_encoder = msgspec.msgpack.Encoder()
_decoder = msgspec.msgpack.Decoder(ControlMessage)


def encode_control(msg: Control) -> bytes:
    """Serialize a control message into a sealable plaintext."""
    return CONTROL_PREFIX + _encoder.encode(msg)


def decode_control(plaintext: bytes) -> Control:
    """Parse a control plaintext (with prefix); raise ``msgspec.DecodeError`` / ``ValueError``."""
    if not plaintext.startswith(CONTROL_PREFIX):
        raise ValueError("not a control message")
    return _decoder.decode(plaintext[1:])
