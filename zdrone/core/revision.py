"""Signed fleet revisions: how the fleet changes after its bundles left (revoke, rotate, re-authorize).

Theory of operation
-------------------
``fleet.json5`` (the *base* fleet) travels in every bundle and pins the fleet's Ed25519 public key
(``Fleet.fleet_key``); the private half stays offline with the CA key. Every later change is a
``Revision``: a number that only grows, the changes, and the fleet key's signature over both.

A revision is *cumulative*: it carries every change since the base fleet, not the difference from
the revision before it. A node that missed revisions 3 and 4 needs only 5; a node never needs a
history, only the latest revision it has seen (kept durably in its bundle folder).

The changes (``Changes``):

* ``revoked``: nodes removed from the fleet for good (a lost GS host, a drone gone hostile); a
  revocation is never undone: a revision that drops one the node already applied is refused
  (``unrevokes``);
* ``keys``: a node's rotated public keys (X25519 static key, Ed25519 signing key);
* ``authorized``: a drone's new authorized-GS list; ``coverage``: a GS's new coverage circle;
* ``pairing_pq``: pairing must use the hybrid post-quantum handshake from now on;
* ``revision_lease``: the owner's lease (s) from now on (None: the base fleet's).

A *revision stamp* (``RevisionStamp``) is a GS's signed word "I hold revision N at time T and vouch
for drones D" (D: the drones it is authorized for in that revision): every GS pushes one with its
revision (``zdrone.fleet.revisions``). It renews drone d's owner lease only if it names d and comes,
under its key in force, from a GS authorized for d in the revision in force other than the owner
(``zdrone.core.lease``), and renews it to the stamp's own time, never later: a replayed stamp buys
nothing past its time.

Checking (``check_revision``), in order, each refusal a ``RevisionRefused(reason)`` counted by the
adapter: the bytes decode (``malformed``) -> the revision names the pinned fleet key
(``wrong_fleet``) -> the signature verifies (``bad_signature``) -> its number is above the one in
force (``replayed`` for the same number, ``stale`` for a lower one) -> it revokes at least what the
one in force revoked (``unrevokes``) -> its changes fit the base fleet (``invalid``).

Applying (``apply_revision``) gives a new effective ``Fleet`` (``zdrone.core.fleet``, the value every
part reads): keys, lists and coverage replaced, every revoked node taken off every authorized list
and marked ``Fleet.revoked``, ``Fleet.revision`` set to the number. The base fleet is never changed.

The signed bytes are ``DOMAIN`` followed by the JSON of the revision without its signature, encoded
by msgspec (fields in declaration order, mappings in the order given; ``make_revision`` sorts
them). A verifier re-encodes what it decoded: any change to the content, its order included, breaks
the signature.

Pure: no clock, no IO; the signing key comes in as a ``SigningKey``.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Annotated, Iterable

import msgspec

from zdrone.core.errors import ConfigError
from zdrone.core.fleet import Coverage, Fleet, Name
from zdrone.core.keys import SigningKey, b64, unb64, verify_signature

DOMAIN = b"zdrone fleet revision v1\n"
SIGNATURE_LEN = 64


class RevisionError(ConfigError):
    """A revision that cannot be made or applied (bad change, unknown node): one line."""


class NodeKeys(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """A node's rotated public keys."""

    public_key: str
    signing_key: str = ""


class Changes(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Every change since the base fleet."""

    revoked: list[Name] = []
    keys: dict[Name, NodeKeys] = {}
    authorized: dict[Name, list[Name]] = {}
    coverage: dict[Name, Coverage] = {}
    pairing_pq: bool = False
    revision_lease: Annotated[float, msgspec.Meta(ge=0, le=86400)] | None = None


class Revision(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """One signed revision of the fleet."""

    number: Annotated[int, msgspec.Meta(ge=1)]
    fleet_key: str  # the fleet key it is signed with (must be the pinned one)
    changes: Changes
    note: str = ""  # what the operator said it is for (``zdrone fleet revoke B --note "host lost"``)
    signature: str = ""

    def builtins(self) -> dict:
        """The revision as JSON values; a lease left as it was is left out (such a revision encodes and
        signs as revisions did before the lease existed)."""
        raw = msgspec.to_builtins(self)
        if raw["changes"].get("revision_lease") is None:
            raw["changes"].pop("revision_lease", None)
        return raw

    def signed_bytes(self) -> bytes:
        return DOMAIN + msgspec.json.encode(msgspec.structs.replace(self, signature="").builtins())


class RevisionRefusal(enum.Enum):
    MALFORMED = "malformed"
    WRONG_FLEET = "wrong_fleet"
    BAD_SIGNATURE = "bad_signature"
    REPLAYED = "replayed"
    STALE = "stale"
    UNREVOKES = "unrevokes"
    INVALID = "invalid"


@dataclass(frozen=True, slots=True)
class RevisionAccepted:
    revision: Revision
    fleet: Fleet  # the effective fleet under it


@dataclass(frozen=True, slots=True)
class RevisionRefused:
    reason: RevisionRefusal
    number: int | None = None  # the refused revision's number when it decoded


RevisionResult = RevisionAccepted | RevisionRefused

_DECODER = msgspec.json.Decoder(Revision)  # built at import (``zdrone.core.fleet``)


def encode_revision(rev: Revision) -> bytes:
    """The wire and file form of a signed revision."""
    return msgspec.json.format(msgspec.json.encode(rev.builtins()), indent=2) + b"\n"


def decode_revision(data: bytes) -> Revision:
    """Decode (not check) a revision; ``RevisionError`` if it is not one."""
    try:
        return _DECODER.decode(data)
    except (msgspec.DecodeError, msgspec.ValidationError, UnicodeDecodeError) as exc:
        raise RevisionError(f"not a fleet revision: {str(exc).splitlines()[0]}") from None


def _sorted_changes(c: Changes) -> Changes:
    return Changes(revoked=sorted(set(c.revoked)), keys=dict(sorted(c.keys.items())),
                   authorized={k: list(v) for k, v in sorted(c.authorized.items())},
                   coverage=dict(sorted(c.coverage.items())), pairing_pq=c.pairing_pq,
                   revision_lease=c.revision_lease)


def make_revision(base: Fleet, number: int, changes: Changes, key: SigningKey, note: str = "") -> Revision:
    """Sign revision ``number`` of ``changes`` with the fleet key (``RevisionError`` if the changes do
    not fit ``base`` or the key is not the one ``base`` pins)."""
    if base.fleet_key_bytes != key.public:
        raise RevisionError("the signing key is not the fleet key that fleet.json5 pins")
    unsigned = Revision(number=number, fleet_key=base.fleet_key, changes=_sorted_changes(changes), note=note)
    apply_revision(base, unsigned)  # the changes fit
    return msgspec.structs.replace(unsigned, signature=b64(key.sign(unsigned.signed_bytes())))


def apply_revision(base: Fleet, rev: Revision) -> Fleet:
    """The effective fleet: ``base`` with ``rev``'s changes (``RevisionError`` if they do not fit)."""
    c = rev.changes
    nodes = dict(base.nodes)
    for name in [*c.revoked, *c.keys, *c.authorized, *c.coverage]:
        if name not in nodes:
            raise RevisionError(f"revision {rev.number}: {name!r} is not a node of the fleet")
    for name, keys in c.keys.items():
        try:
            unb64(keys.public_key, 32)
            if keys.signing_key:
                unb64(keys.signing_key, 32)
        except ValueError as exc:
            raise RevisionError(f"revision {rev.number}: keys of {name}: {exc}") from None
        nodes[name] = msgspec.structs.replace(nodes[name], public_key=keys.public_key,
                                              signing_key=keys.signing_key or nodes[name].signing_key)
    for name, cov in c.coverage.items():
        if nodes[name].role != "gs":
            raise RevisionError(f"revision {rev.number}: {name} is not a ground station (coverage)")
        nodes[name] = msgspec.structs.replace(nodes[name], coverage=cov)
    for name, gss in c.authorized.items():
        if nodes[name].role != "drone":
            raise RevisionError(f"revision {rev.number}: {name} is not a drone (authorized list)")
        bad = [g for g in gss if g not in nodes or nodes[g].role != "gs"]
        if bad:
            raise RevisionError(f"revision {rev.number}: authorized list of {name}: {bad[0]!r} is not a ground station")
        nodes[name] = msgspec.structs.replace(nodes[name], authorized_gs=list(dict.fromkeys(gss)))
    revoked = frozenset(c.revoked)
    for name, node in nodes.items():
        if node.role == "drone" and revoked & set(node.authorized_gs):
            nodes[name] = msgspec.structs.replace(node, authorized_gs=[g for g in node.authorized_gs if g not in revoked])
    lease = base.revision_lease if c.revision_lease is None else c.revision_lease
    return msgspec.structs.replace(base, nodes=nodes, revision=rev.number, revoked=revoked,
                                   pairing_pq=c.pairing_pq, revision_lease=lease)


def check_revision(data: bytes, base: Fleet, current: Revision | None) -> RevisionResult:
    """Check revision bytes against the pinned fleet key and the revision in force (``current``,
    None before the first); never raises on bad input."""
    try:
        rev = _DECODER.decode(data)
    except (msgspec.DecodeError, msgspec.ValidationError, UnicodeDecodeError):
        return RevisionRefused(RevisionRefusal.MALFORMED)
    pinned = base.fleet_key_bytes
    if pinned is None or rev.fleet_key != base.fleet_key:
        return RevisionRefused(RevisionRefusal.WRONG_FLEET, rev.number)
    try:
        sig = unb64(rev.signature, SIGNATURE_LEN)
    except ValueError:
        return RevisionRefused(RevisionRefusal.BAD_SIGNATURE, rev.number)
    if not verify_signature(pinned, rev.signed_bytes(), sig):
        return RevisionRefused(RevisionRefusal.BAD_SIGNATURE, rev.number)
    have = current.number if current is not None else 0
    if rev.number <= have:
        return RevisionRefused(RevisionRefusal.REPLAYED if rev.number == have else RevisionRefusal.STALE, rev.number)
    if current is not None and not set(current.changes.revoked) <= set(rev.changes.revoked):
        return RevisionRefused(RevisionRefusal.UNREVOKES, rev.number)
    try:
        fleet = apply_revision(base, rev)
    except RevisionError:
        return RevisionRefused(RevisionRefusal.INVALID, rev.number)
    return RevisionAccepted(rev, fleet)


def next_changes(current: Revision | None) -> Changes:
    """The changes in force (to build the next revision from)."""
    return current.changes if current is not None else Changes()


def with_revoked(c: Changes, node: str) -> Changes:
    return msgspec.structs.replace(c, revoked=sorted({*c.revoked, node}))


def with_keys(c: Changes, node: str, public_key: bytes, signing_key: bytes) -> Changes:
    return msgspec.structs.replace(c, keys={**c.keys, node: NodeKeys(b64(public_key), b64(signing_key))})


def with_authorized(c: Changes, drone: str, gss: list[str]) -> Changes:
    return msgspec.structs.replace(c, authorized={**c.authorized, drone: list(gss)})


def with_lease(c: Changes, seconds: float) -> Changes:
    return msgspec.structs.replace(c, revision_lease=seconds)


# ------------------------------------------------------------------ revision stamps
STAMP_DOMAIN = b"zdrone revision stamp v2\n"  # v2: the stamp names its drones
#: a push that carries a stamp starts with these bytes (a bare revision is JSON: it starts with "{")
STAMP_MAGIC = b"ZDRS1"
#: a stamp dated further ahead of the receiver's clock than this is refused (clocks disagree)
STAMP_AHEAD_S = 5.0


class RevisionStamp(msgspec.Struct, frozen=True, array_like=True, forbid_unknown_fields=True):
    """GS ``gs`` says it holds revision ``number`` at time of day ``wall`` (s) and vouches for ``drones``
    (sorted: the drones it is authorized for in that revision), signed with its key."""

    gs: str
    number: int
    wall: float
    drones: tuple[str, ...]
    signature: bytes = b""

    def names(self, drone: str) -> bool:
        return drone in self.drones

    def signed_bytes(self) -> bytes:
        return STAMP_DOMAIN + msgspec.msgpack.encode(msgspec.structs.replace(self, signature=b""))


_STAMP_DECODER = msgspec.msgpack.Decoder(RevisionStamp)


def make_push(gs: str, number: int, wall: float, key: SigningKey, revision: bytes | None,
              drones: Iterable[str] = ()) -> bytes:
    """A GS's push: its signed stamp naming ``drones``, then the revision bytes it holds (if any)."""
    stamp = RevisionStamp(gs, number, round(wall, 3), tuple(sorted(set(drones))))
    body = msgspec.msgpack.encode(msgspec.structs.replace(stamp, signature=key.sign(stamp.signed_bytes())))
    if len(body) > 0xFFFF:  # its length travels in two bytes
        raise ValueError(f"a stamp naming {len(stamp.drones)} drones is {len(body)} bytes: over 65535")
    return STAMP_MAGIC + len(body).to_bytes(2, "big") + body + (revision or b"")


def split_push(data: bytes) -> tuple[bytes | None, bytes | None]:
    """(stamp bytes, revision bytes) of a push; a bare revision has no stamp; never raises."""
    if not data.startswith(STAMP_MAGIC):
        return None, data
    n = len(STAMP_MAGIC)
    size = int.from_bytes(data[n:n + 2], "big")
    stamp, rest = data[n + 2:n + 2 + size], data[n + 2 + size:]
    return (stamp if len(stamp) == size else None), (rest or None)


def check_stamp(data: bytes, fleet: Fleet) -> RevisionStamp | None:
    """The stamp if it decodes and is signed by its GS's key in force in ``fleet`` (a GS of the fleet,
    not revoked); else None. Freshness and who may renew are the drone's (``DroneCore``)."""
    try:
        stamp = _STAMP_DECODER.decode(data)
    except (msgspec.DecodeError, msgspec.ValidationError):
        return None
    return stamp if fleet.gs_signed(stamp.gs, stamp.signed_bytes(), stamp.signature) else None


def with_coverage(c: Changes, gs: str, coverage: Coverage) -> Changes:
    return msgspec.structs.replace(c, coverage={**c.coverage, gs: coverage})


__all__ = ["Changes", "NodeKeys", "Revision", "RevisionAccepted", "RevisionError", "RevisionRefusal",
           "RevisionRefused", "RevisionResult", "apply_revision", "check_revision", "decode_revision",
           "encode_revision", "make_revision", "next_changes", "with_authorized", "with_coverage",
           "with_keys", "with_lease", "with_revoked", "RevisionStamp", "STAMP_AHEAD_S", "check_stamp", "make_push",
           "split_push"]
