"""The drone's signed word on who commands it (an authority attestation), and the viewer's check of it.

Theory of operation
-------------------
Each GS tells the fleet's viewer who commands the drones it serves (``zdrone.core.opspicture``), and
one authorized GS may be hostile: "I own d1 at epoch 99" costs it nothing to say. Only the drone
knows who commands it, so the drone says it itself, signed: whenever what its authority status says
of (owner, epoch, state, pending recipient) changes, the drone signs it once (``Attester``; never per message, the
status beacon repeats the same signature) with its fleet Ed25519 signing key (``Node.signing_key``),
over a domain-separated message naming the drone, the owner, the epoch, the state, the pending
recipient and the drone's time of day (``attestation_message``). The result (``wire.AuthorityAttestation``) rides in every
``AuthorityStatus``; a GS keeps the newest it heard per drone and puts it, as it came, in its
picture for the viewer.

The viewer (``AttestationCheck``) checks an attestation against the drone's public keys: every key
the fleet gave the drone over time (``zdrone.fleet.revisions.signing_key_history``), so a drone
whose key was rotated is still believed for what it signed before. The drone's name is inside the
signed message: an attestation of d2 shown for d1 fails. A valid attestation is kept (bounded) and
never checked again; a failed one is remembered per (GS, drone) so the same bytes repeated cost
nothing; new ones cost a signature check each, at most ``CHECK_RATE`` (or one per drone) a second per
GS beyond a burst of a few per drone (a hostile GS sending a new forgery in every report gets the rest counted, not
checked). What a valid attestation proves: the drone said so at ``at``, not that it is still so; the
viewer shows the highest (epoch, time) among the valid ones, so an old one replayed loses to a newer.

Pure: no clock (the time of day comes in), no files.
"""

from __future__ import annotations

from collections import Counter, OrderedDict
from typing import Mapping, Sequence

import msgspec

from .keys import SigningKey, verify_signature
from .ratelimit import TokenBucket
from .wire import AuthorityAttestation, AuthorityState

DOMAIN = b"zdrone-authority-attestation/v1\0"
#: New attestations checked per GS per second beyond the burst, at least (one per drone a second in a
#: larger fleet: a signature check costs about 0.1 ms, so a GS forging without end costs at most a tenth
#: of a core at 1000 drones).
CHECK_RATE = 50.0
#: Valid attestations remembered per drone known (the newest few of each, the cache's bound).
KEPT_PER_DRONE = 8

_enc = msgspec.msgpack.Encoder()


def attestation_message(drone: str, owner: str | None, epoch: int, state: AuthorityState, pending_to: str | None,
                        at: float) -> bytes:
    """The bytes a drone signs: the domain, then the fields in a fixed order (msgpack)."""
    return DOMAIN + _enc.encode((drone, owner, epoch, state.value, pending_to, at))


class Attester:
    """The drone's side: one signature per change of (owner, epoch, state, pending_to), reused meanwhile."""

    def __init__(self, drone: str, key: SigningKey) -> None:
        self.drone, self.key = drone, key
        self.current: AuthorityAttestation | None = None
        self.signed = 0  # signatures made

    def attest(self, owner: str | None, epoch: int, state: AuthorityState, pending_to: str | None,
               wall: float) -> AuthorityAttestation:
        """The attestation of (owner, epoch, state, pending_to): the one made at its change, or a new
        one (at ``wall``)."""
        cur = self.current
        if cur is not None and (cur.owner, cur.epoch, cur.state, cur.pending_to) == (owner, epoch, state, pending_to):
            return cur
        at = round(wall, 3)
        sig = self.key.sign(attestation_message(self.drone, owner, epoch, state, pending_to, at))
        self.current = AuthorityAttestation(owner, epoch, state, pending_to, at, sig)
        self.signed += 1
        return self.current


def attestation_valid(drone: str, att: AuthorityAttestation, keys: Sequence[bytes]) -> bool:
    """Whether ``att`` is ``drone``'s signature under one of ``keys`` (its keys over time)."""
    message = attestation_message(drone, att.owner, att.epoch, att.state, att.pending_to, att.at)
    return any(verify_signature(k, message, att.sig) for k in keys)


class AttestationCheck:
    """The viewer's side: is this attestation, said by GS ``gs`` to be drone ``drone``'s, the drone's?"""

    def __init__(self, keys: Mapping[str, Sequence[bytes]]) -> None:
        """``keys``: each drone's public signing keys over time (oldest first); a drone without any
        has no valid attestation."""
        self.keys = {d: tuple(k) for d, k in keys.items() if k}
        self._valid: OrderedDict[tuple[str, AuthorityAttestation], None] = OrderedDict()
        self._failed: dict[tuple[str, str], AuthorityAttestation] = {}  # (gs, drone) -> its last forgery
        self._buckets: dict[str, TokenBucket] = {}
        self.checked = 0  # signature checks made
        self.counts: Counter[str] = Counter()  # why an attestation was not believed


    def valid(self, gs: str, drone: str, att: AuthorityAttestation | None, now: float) -> bool:
        """Whether ``att`` is drone ``drone``'s own (checked once, then remembered)."""
        if att is None:
            return False
        keys = self.keys.get(drone)
        if keys is None:
            self.counts["unknown_drone"] += 1
            return False
        key = (drone, att)
        if key in self._valid:
            self._valid.move_to_end(key)
            return True
        if self._failed.get((gs, drone)) == att:
            self.counts["bad_signature_repeated"] += 1
            return False
        bucket = self._buckets.get(gs)
        if bucket is None:
            n = len(self.keys)
            bucket = self._buckets[gs] = TokenBucket.full(max(CHECK_RATE, float(n)), 4.0 * n + 64.0, now)
        if not bucket.take(now):
            self.counts["rate_limited"] += 1  # not remembered: checked when the GS's budget allows
            return False
        self.checked += 1
        if not attestation_valid(drone, att, keys):
            self.counts["bad_signature"] += 1
            self._failed[(gs, drone)] = att
            return False
        self._valid[key] = None
        while len(self._valid) > KEPT_PER_DRONE * max(1, len(self.keys)):
            self._valid.popitem(last=False)
        return True
