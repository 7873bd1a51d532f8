"""The drone's signed word on who commands it (an authority attestation), and the viewer's check of it.

Theory of operation
-------------------
Each GS tells the fleet's viewer who commands the drones it serves (``zdrone.core.opspicture``), and
one authorized GS may be hostile: "I own d1 at epoch 99" costs it nothing to say. Only the drone
knows who commands it, so the drone says it itself, signed, and *fresh*: at every status beacon
(``BEACON_S``) and at every change of what its authority status says (owner, epoch, state, pending
recipient, takeover and its window), the drone signs it anew (``Attester``) with its fleet Ed25519
signing key, over a domain-separated message naming the drone, those fields, the drone's time of
day ``at`` and a counter ``seq`` (``attestation_message``). The result (``wire.AuthorityAttestation``,
90 to 125 bytes with the fleet's names) rides in every ``AuthorityStatus`` (the drone sends one to
each linked GS at every beacon anyway: a signature a second more for the drone, 3 bytes more a status
than a word signed once per change); a GS keeps the newest it heard per
drone and puts it, as it came, in its picture for the viewer. A word signed once per change would
prove only that the drone said so *once*: a GS could replay an old one (epoch 2 after epoch 3
happened) and nothing would tell it from the truth. Signed at every beacon, the newest word is at
most a beacon old while the drone is heard, so the viewer can ask "how recent is the drone's own
word?" and show the drone stale when the answer is "not recent".

The viewer (``AttestationCheck``) checks an attestation against the drone's public keys: every key
the fleet gave the drone over time (``zdrone.fleet.revisions.signing_key_history``; a key a live
revision rotates in is added, ``add_key``). The drone's name is inside the signed message: an
attestation of d2 shown for d1 fails. **Key in force**: the newest key the revisions held give the
drone (the last of its history, or the one a revision taken live adds) is in force from the moment
the view holds that revision, and every older one is retired: an attestation under one of them is
refused (``retired_key``), however new it says it is, whether or not the view ever heard the drone
speak under its new key (a thief of the old key cannot speak for the drone; the drone itself never
signs under a key a revision it applied retired, ``DroneCore.adopt_own_keys``, so until it holds
its new key it is shown stale). A valid attestation is kept (bounded) with the key that
verified it; a failed one is remembered per (GS, drone) so the same bytes repeated cost nothing; new
ones cost a signature check each, at most ``max(CHECK_RATE, 2 x drones)`` a second per GS beyond a
burst (a hostile GS sending a new forgery in every report gets the rest counted, not checked).

Pure: no clock (the time of day comes in), no files.
"""

from __future__ import annotations

from collections import Counter, OrderedDict
from typing import Mapping, Sequence

import msgspec

from zdrone.core.keys import SigningKey, verify_signature
from zdrone.core.ratelimit import TokenBucket
from zdrone.core.wire import AuthorityAttestation, AuthorityStatus

DOMAIN = b"zdrone-authority-attestation/v2\0"
#: The drone signs its authority status at least this often (its status beacon: ``DroneCore``'s
#: ``STATUS_BEACON_S`` is this), and at every change.
BEACON_S = 1.0
#: New attestations checked per GS per second beyond the burst, at least (twice the drones in a
#: larger fleet: each signs one per beacon; a signature check costs about 0.1 ms, so a GS forging
#: without end costs at most a fifth of a core at 1000 drones).
CHECK_RATE = 50.0
#: Valid attestations remembered per drone known (the newest few of each, the cache's bound).
KEPT_PER_DRONE = 8

_enc = msgspec.msgpack.Encoder()


def attestation_message(drone: str, att: AuthorityAttestation) -> bytes:
    """The bytes a drone signs: the domain, then the fields in a fixed order (msgpack)."""
    return DOMAIN + _enc.encode((drone, att.owner, att.epoch, att.state.value, att.pending_to, att.takeover,
                                 att.takeover_to, att.at, att.seq))


class Attester:
    """The drone's side: a new signature at every beacon (``renew``) and at every change of what the
    status says of its authority; between them the last one is reused."""

    def __init__(self, drone: str, key: SigningKey) -> None:
        self.drone, self.key = drone, key
        self.current: AuthorityAttestation | None = None
        self.signed = 0  # signatures made (the last one's ``seq``)

    def attest(self, st: AuthorityStatus, wall: float, renew: bool = False) -> AuthorityAttestation:
        """The attestation of status ``st``: the current one while nothing it says changed and no
        beacon asks for a new one (``renew``), else a new one at ``wall``."""
        fields = (st.owner, st.epoch, st.state, st.pending_to, st.takeover, st.takeover_to)
        cur = self.current
        if cur is not None and not renew and \
                (cur.owner, cur.epoch, cur.state, cur.pending_to, cur.takeover, cur.takeover_to) == fields:
            return cur
        at = round(wall, 3)
        if cur is not None:
            at = max(at, cur.at)  # never older than the last (a clock stepped back): ``seq`` orders them
        self.signed += 1
        unsigned = AuthorityAttestation(*fields, at=at, seq=self.signed, sig=b"")
        sig = self.key.sign(attestation_message(self.drone, unsigned))
        self.current = msgspec.structs.replace(unsigned, sig=sig)
        return self.current


def attestation_key(drone: str, att: AuthorityAttestation, keys: Sequence[bytes]) -> int | None:
    """The index in ``keys`` (the drone's keys over time, oldest first) of the key ``att`` is
    ``drone``'s signature under, newest tried first; None: under none of them."""
    message = attestation_message(drone, att)
    for i in range(len(keys) - 1, -1, -1):
        if verify_signature(keys[i], message, att.sig):
            return i
    return None


def attestation_valid(drone: str, att: AuthorityAttestation, keys: Sequence[bytes]) -> bool:
    """Whether ``att`` is ``drone``'s signature under one of ``keys`` (its keys over time)."""
    return attestation_key(drone, att, keys) is not None


class AttestationCheck:
    """The viewer's side: is this attestation, said by GS ``gs`` to be drone ``drone``'s, the drone's,
    under a key still in force?"""

    def __init__(self, keys: Mapping[str, Sequence[bytes]]) -> None:
        """``keys``: each drone's public signing keys over time (oldest first), as the revisions the
        view holds give them: the last is in force, every earlier one retired; a drone without any
        has no valid attestation."""
        self.keys: dict[str, list[bytes]] = {d: list(k) for d, k in keys.items() if k}
        self.in_force: dict[str, int] = {d: len(k) - 1 for d, k in self.keys.items()}  # drone -> its key in force
        self._valid: OrderedDict[tuple[str, AuthorityAttestation], int] = OrderedDict()  # -> key index
        self._failed: dict[tuple[str, str], AuthorityAttestation] = {}  # (gs, drone) -> its last forgery
        self._buckets: dict[str, TokenBucket] = {}
        self.checked = 0  # signature checks made
        self.counts: Counter[str] = Counter()  # why an attestation was not believed

    def add_key(self, drone: str, public: bytes) -> None:
        """A revision in force gives ``drone`` the signing key ``public`` (taken live): it is the newest
        of its keys and in force at once, every earlier one retired."""
        keys = self.keys.setdefault(drone, [])
        if keys[-1:] != [public]:
            keys.append(public)
            self._failed = {k: v for k, v in self._failed.items() if k[1] != drone}  # worth another look
            self._buckets.clear()  # the budgets are sized by the drones known
        self.in_force[drone] = len(keys) - 1

    def newest_key(self, drone: str) -> int | None:
        keys = self.keys.get(drone)
        return len(keys) - 1 if keys else None

    def key_of(self, gs: str, drone: str, att: AuthorityAttestation | None, now: float) -> int | None:
        """The index of the key ``att`` is drone ``drone``'s signature under, if that key is in force
        (checked once, then remembered); None: not the drone's, or under a retired key, or not
        checked for want of ``gs``'s budget (each counted in ``counts``)."""
        if att is None:
            return None
        keys = self.keys.get(drone)
        if keys is None:
            self.counts["attest_unknown_drone"] += 1
            return None
        cached = (drone, att)
        idx = self._valid.get(cached)
        if idx is None:
            if self._failed.get((gs, drone)) == att:
                self.counts["bad_signature_repeated"] += 1
                return None
            bucket = self._buckets.get(gs)
            if bucket is None:
                n = len(self.keys)
                bucket = self._buckets[gs] = TokenBucket.full(max(CHECK_RATE, 2.0 * n), 4.0 * n + 64.0, now)
            if not bucket.take(now):
                self.counts["check_rate_limited"] += 1  # not remembered: checked when the GS's budget allows
                return None
            self.checked += 1
            idx = attestation_key(drone, att, keys)
            if idx is None:
                self.counts["bad_signature"] += 1
                self._failed[(gs, drone)] = att
                return None
            self._valid[cached] = idx
            while len(self._valid) > KEPT_PER_DRONE * max(1, len(self.keys)):
                self._valid.popitem(last=False)
        else:
            self._valid.move_to_end(cached)
        if idx < self.in_force.get(drone, 0):
            self.counts["retired_key"] += 1
            return None
        return idx

    def valid(self, gs: str, drone: str, att: AuthorityAttestation | None, now: float) -> bool:
        """Whether ``att`` is drone ``drone``'s own under a key in force (``key_of``)."""
        return self.key_of(gs, drone, att, now) is not None
