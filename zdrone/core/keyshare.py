"""Key sharing over the backhaul: GS-to-GS, mutually authenticated and fresh (Noise KK).

Theory of operation
-------------------
The authority GS A needs a link key for (drone, B) before the drone reaches B's coverage. A asks
B's queryable ``backhaul/B/linkkey/<drone>``; the query payload is a ``LinkKeyQuery``: the asker's
name and a Noise ``KK`` message 1 (``e, es, ss``). B's reply is message 2 (``e, ee, se``) whose
encrypted payload is a fresh 32-byte link secret for (drone, B).

* The request proves A's fleet static key: message 1's tag is made with ``ss`` (A's static key with
  B's), so a party that claims to be A without A's private key fails B's check — before B draws any
  secret or touches any state. A leaked router password is not enough.
* The reply proves B's static key (``se``) and is bound to A's fresh ephemeral (``ee``): a reply
  captured earlier, or sealed by anyone but B, does not open; nobody but A and B learns the secret
  (forward secrecy from the ephemerals).
* The prologue binds the protocol version, drone, owner and asker: a transcript for one triple is
  worthless for another.
* Both messages carry the cheap tag of ``kk`` (a key from A's and B's static keys): forged queries
  and replies are refused in microseconds, before any Diffie-Hellman, before they can spend A's
  rate-limit tokens at B, and without using up A's reply attempts.
* A replayed message 1 gets B's first answer again (``kk.ResponseCache``) and creates nothing. A
  new secret is only ever a *pending* one (one per asker: the newest replaces the older) until the
  drone speaks under it: B's live link is never touched (key confirmation, see ``linkslot``).
* Exactly one authentic reply per query: the handshake state of A accepts one message 2; after it
  the ask is finished and every later reply (a second queryable, a consolidation artefact, a
  replay) is counted and ignored. Two different authentic replies to one ask are impossible.

Post-quantum hybrid: ``KeyShareAsk(hybrid=True)`` adds ML-KEM-768 exactly as pairing does (``kk``'s
module text); a ``KeyShareResponder`` with ``require_hybrid`` (the fleet's ``pairing_pq``) refuses a
classical query after its tag check (``downgrade``). The secret handed on ends up as a link key the
drone installs, so a classical ask would be the weak door into a hybrid fleet.

Alternatives considered: HPKE Auth mode (sender-authenticated, but the request would still need its
own proof and freshness) and a static-static MAC (no forward secrecy). Noise KK gives both proofs,
freshness and forward secrecy in two 48/64-byte messages, with the same code as drone pairing.
"""

from __future__ import annotations

import enum

import msgspec

from zdrone.core.keys import KEY_LEN, Identity
from zdrone.core.kk import MAX_MESSAGE, KKFail, KKInitiator, ResponseCache, check_message1, is_hybrid, respond
from zdrone.core.ratelimit import RateLimiter

#: How long an ask waits for B's reply before it is given up (the adapter asks again later).
ASK_TIMEOUT = 5.0


class LinkKeyQuery(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Payload of a linkkey query: who asks, and Noise KK message 1 proving it."""

    asker: str
    m1: bytes


class ShareRefusal(enum.Enum):
    """Why a linkkey query or reply was refused (counted per reason)."""

    MALFORMED = "malformed"
    UNKNOWN_ASKER = "unknown_asker"
    UNAUTHORIZED = "unauthorized"
    BAD_MAC = "bad_mac"  # failed the cheap tag: forged or garbage, no crypto spent
    STALE = "stale"  # message 1 older than MAX_AGE by its tagged time stamp: a replay
    AUTH_FAILED = "auth_failed"
    RATE_LIMITED = "rate_limited"
    EXHAUSTED = "exhausted"  # too many tag-valid replies to one ask
    NOT_WAITING = "not_waiting"  # a reply after the ask finished, expired or was never made
    LIVE_LINK = "live_link"  # the answering GS's own link to the drone is alive: it needs no new key
    DOWNGRADE = "downgrade"  # a classical query where the fleet requires the hybrid (ML-KEM-768) exchange


class Refused(msgspec.Struct, frozen=True):
    reason: ShareRefusal
    detail: str = ""


_encoder = msgspec.msgpack.Encoder()
_decoder = msgspec.msgpack.Decoder(LinkKeyQuery)


def _prologue(drone: str, owner: str, asker: str) -> bytes:
    return b"\0".join((b"zdrone linkkey v2", drone.encode(), owner.encode(), asker.encode()))


def decode_query(payload: bytes) -> LinkKeyQuery | Refused:
    """Parse a query payload (no crypto): the adapter checks the asker against the fleet next."""
    try:
        q = _decoder.decode(payload)
    except (msgspec.DecodeError, msgspec.ValidationError, ValueError) as exc:  # ValueError: bad UTF-8 in a name
        return Refused(ShareRefusal.MALFORMED, str(exc)[:80])
    if len(q.m1) > MAX_MESSAGE:
        return Refused(ShareRefusal.MALFORMED, "message 1 too long")
    return q


class KeyShareAsk:
    """The asking GS's side of one key-sharing exchange (one query, at most one accepted reply)."""

    def __init__(self, me: Identity, asker: str, owner: str, owner_public: bytes, drone: str, now: float,
                 timeout: float = ASK_TIMEOUT, ephemeral: bytes | None = None, wall: float | None = None,
                 hybrid: bool = False) -> None:
        self.asker, self.owner, self.drone = asker, owner, drone
        self.deadline = now + timeout
        self.done = False
        self._kk = KKInitiator(me, owner_public, _prologue(drone, owner, asker), ephemeral,
                               stamp=now if wall is None else wall, hybrid=hybrid)
        self.payload = _encoder.encode(LinkKeyQuery(asker, self._kk.message1))

    def expired(self, now: float) -> bool:
        return now >= self.deadline

    def on_reply(self, reply: bytes, now: float) -> bytes | Refused:
        """The link secret from the owner's authentic reply; a ``Refused`` for anything else."""
        if self.done or self.expired(now):
            return Refused(ShareRefusal.NOT_WAITING, f"ask to {self.owner} already finished")
        secret = self._kk.read_reply(reply)
        if isinstance(secret, KKFail):  # forged, replayed or garbage: the genuine reply may still come
            return Refused(ShareRefusal(secret.value), f"reply does not prove {self.owner}'s static key")
        if len(secret) != KEY_LEN:
            return Refused(ShareRefusal.MALFORMED, "reply carries no link secret")
        self.done = True  # one authentic reply per ask: any later one is NOT_WAITING
        return secret


def answer(me: Identity, owner: str, drone: str, asker: str, asker_public: bytes, m1: bytes,
           secret: bytes) -> bytes | Refused:
    """The owner's side of the handshake: check message 1 from ``asker``; return message 2
    carrying ``secret`` (fresh randomness from the adapter). ``KeyShareResponder`` adds the checks
    that come first."""
    if len(secret) != KEY_LEN:
        raise ValueError("link secret must be 32 bytes")
    msg2 = respond(me, asker_public, _prologue(drone, owner, asker), m1, secret)
    if isinstance(msg2, KKFail):
        return Refused(ShareRefusal(msg2.value), f"query does not prove {asker}'s static key")
    return msg2


#: A query made longer ago than this (by the asker's clock, under the tag) is a replay: refused.
#: Ground stations' clocks must agree within it (NTP or GPS time).
MAX_AGE = 30.0
#: A message 1 seen within this time gets its first answer again (a replay creates nothing); at
#: least twice ``MAX_AGE``, so no replay can be both fresh and forgotten.
SHARE_RESPONSE_TTL = 2 * MAX_AGE


class KeyShareResponder:
    """The owner's checks for one authenticated query, cheapest first, after the caller checked
    that the asker is a GS of the fleet authorized for the drone (no crypto for those):

    1. message 1's tag (~2 µs, no Diffie-Hellman): forged -> ``BAD_MAC``; made more than ``MAX_AGE``
       ago by its tagged stamp -> ``STALE``;
    2. a message 1 seen before gets the same message 2 again and no new secret (``repeated``);
    3. the asker's rate limit, charged only now (nobody without its key can spend its tokens);
    4. the Noise handshake.

    With ``require_hybrid`` a classical query that passed its tag is refused (``DOWNGRADE``).
    """

    def __init__(self, me: Identity, owner: str, rate: float, burst: float, require_hybrid: bool = False) -> None:
        self.me, self.owner = me, owner
        self.require_hybrid = require_hybrid
        self.limiter = RateLimiter(rate, burst)
        self.cache = ResponseCache(SHARE_RESPONSE_TTL)

    def answer(self, drone: str, asker: str, asker_public: bytes, m1: bytes, now: float,
               secret: bytes, wall: float | None = None) -> tuple[bytes, bool] | Refused:
        """(message 2, new secret?) or why the query is refused. ``wall`` is this GS's clock (time of
        day, to compare with the asker's stamp; ``now`` is monotonic)."""
        fail = check_message1(self.me, asker_public, _prologue(drone, self.owner, asker), m1,
                              now if wall is None else wall, MAX_AGE)
        if fail is KKFail.STALE:
            return Refused(ShareRefusal.STALE, f"query made more than {MAX_AGE:.0f} s ago: a replay")
        if fail is not None:
            return Refused(ShareRefusal(fail.value), f"query does not prove {asker}'s static key")
        if self.require_hybrid and not is_hybrid(m1):
            return Refused(ShareRefusal.DOWNGRADE, "the fleet requires the hybrid (ML-KEM-768) exchange")
        cached = self.cache.get(m1, now)
        if cached is not None:
            return cached, False
        if not self.limiter.allow(asker, now):
            return Refused(ShareRefusal.RATE_LIMITED, asker)
        msg2 = answer(self.me, self.owner, drone, asker, asker_public, m1, secret)
        if isinstance(msg2, Refused):
            return msg2
        self.cache.put(m1, msg2, now)
        return msg2, True
