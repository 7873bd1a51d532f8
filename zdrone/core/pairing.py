"""Pairing: a Noise KK handshake between a GS (initiator) and a drone (responder).

Theory of operation: both sides already know each other's static X25519 key from the fleet.
Message 1 (GS -> drone) proves the GS holds the fleet's static key for its name; message 2
(drone -> GS) proves the drone's and carries, encrypted with the handshake's forward-secret keys,
a fresh 32-byte link secret chosen by the drone. Both sides then derive the same ``LinkKey`` (one
key per direction). The prologue binds the protocol version and both names, so a transcript for
one (drone, gs) pair cannot be replayed for another.

Message 1 can be replayed (KK cannot tell a replay from a fresh one). It is therefore *fresh*: it
carries the GS's clock under its tag (``kk``), and the drone refuses (``stale``, silently, before
any other work) a message 1 made more than ``PAIR_MAX_AGE`` ago or before the drone's companion
became ready (``not_before``: a restarted companion has forgotten its answers, and a captured
message 1 from before it was back must not buy a new handshake). Within that age, the drone answers
a message 1 it has seen with the message 2 it sent then (``kk.ResponseCache``, kept twice as long),
and drops one older than the newest it answered for that GS (a GS's tries are stamped in order), so
a replay makes no new key, spends no rate-limit token and displaces no pending candidate; and it
treats the key of every pairing as a *candidate*: it replaces nothing until the GS proves it with
an authentic frame under it (see ``linkslot``). GS and drone clocks must agree to a few seconds
(GPS or NTP time on both; see the deployment guide). ``PairingResponder`` orders the checks
cheapest first; a forged message 1 fails a 16-byte tag (``kk``) before any Diffie-Hellman and
before it can spend the GS's rate-limit tokens.

Each query gets one typed result: ``PairAccepted`` (message 2 and a candidate key),
``PairRepeated`` (message 1 seen before: its first message 2 again, no key) or
``PairRefused(reason)``. Refusals come in two tiers: bad input (oversized, malformed, a failed tag,
over the rate limit) is dropped without an answer, counted by reason; an authentic-looking but
illegal query (unknown or unauthorized GS, re-pairing in failsafe in the air) is answered with the
reason. A programming error (a link secret of the wrong length) raises.

**Post-quantum hybrid.** ``PairingInitiator(hybrid=True)`` adds ML-KEM-768 next to X25519 (``kk``:
an ephemeral ML-KEM key in message 1, the drone's encapsulation in message 2, mixed in as Noise's
pre-shared key, so the link secret holds if either holds). The fleet turns it on (``pairing_pq`` in
``fleet.json5``, or a fleet revision); a responder with ``require_hybrid`` then refuses a classical
message 1 after its tag check, with an answer (``downgrade``): no downgrade, and a ground station
left on the old setting learns why. A responder without it still accepts a hybrid message 1.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import ClassVar

import msgspec

from zdrone.core.keys import KEY_LEN, Identity, LinkKey
from zdrone.core.kk import KKFail, KKInitiator, ResponseCache, check_message1, is_hybrid, respond as kk_respond, stamp_of
from zdrone.core.ratelimit import RateLimiter


class PairingFailed(msgspec.Struct, frozen=True):
    """The handshake could not complete; ``reason`` says why in one line."""

    reason: str


class PairingState(enum.Enum):
    IDLE = "idle"
    SENT = "sent"
    DONE = "done"
    FAILED = "failed"


def _prologue(drone: str, gs: str) -> bytes:
    return b"zdrone pair v1|" + drone.encode() + b"|" + gs.encode()


class PairingInitiator:
    """The GS side: ``start()`` gives message 1, ``finish(message2)`` gives the link key.

    A reply that does not prove the drone's key leaves the initiator waiting (``SENT``): the
    genuine reply may still come. The first authentic reply finishes it (``DONE``).
    """

    def __init__(self, me: Identity, gs: str, drone: str, drone_public: bytes, ephemeral: bytes | None = None,
                 stamp: float = 0.0, hybrid: bool = False, kem_seed: bytes | None = None) -> None:
        """``stamp``: the GS's clock (time of day) when message 1 is made: the drone refuses it
        once older than ``PAIR_MAX_AGE``. ``hybrid``: add ML-KEM-768 (the fleet's ``pairing_pq``);
        ``kem_seed`` fixes its key (test vectors only)."""
        self.gs, self.drone = gs, drone
        self.state = PairingState.IDLE
        self.peer_kept_key = False
        self._kk = KKInitiator(me, drone_public, _prologue(drone, gs), ephemeral, stamp=stamp, hybrid=hybrid,
                               kem_seed=kem_seed)

    def start(self) -> bytes:
        if self.state is not PairingState.IDLE:
            raise RuntimeError("pairing already started")
        self.state = PairingState.SENT
        return self._kk.message1

    def finish(self, message2: bytes) -> LinkKey | PairingFailed:
        if self.state is PairingState.IDLE:
            raise RuntimeError("finish() before start()")
        if self.state is not PairingState.SENT:
            return PairingFailed("pairing already finished")
        payload = self._kk.read_reply(message2)
        if isinstance(payload, KKFail):
            return PairingFailed(f"drone {self.drone} did not prove the fleet's static key ({payload.value})")
        if len(payload) not in (KEY_LEN, KEY_LEN + 1):
            self.state = PairingState.FAILED
            return PairingFailed("message 2 carries no link secret")
        self.state = PairingState.DONE
        # the drone says whether it still holds a live key of ours (then the silence that made us
        # pair again was the radio, not a restart: the old key stays, see ``gs.core``)
        self.peer_kept_key = payload[KEY_LEN:] == b"\x01"
        return LinkKey.from_secret(self.drone, self.gs, payload[:KEY_LEN])


def respond(
    me: Identity, drone: str, gs: str, gs_public: bytes, message1: bytes, secret: bytes, holds_key: bool = False
) -> tuple[bytes, LinkKey] | PairingFailed:
    """The drone side of one handshake: check message 1 from ``gs``; return message 2 and the
    (candidate) link key. ``secret`` is the fresh 32-byte link secret (the adapter draws it from
    ``os.urandom``; tests pass fixed bytes). ``PairingResponder`` adds the checks that come first."""
    if len(secret) != KEY_LEN:
        raise ValueError("link secret must be 32 bytes")
    msg2 = kk_respond(me, gs_public, _prologue(drone, gs), message1, secret + (b"\x01" if holds_key else b"\x00"))
    if isinstance(msg2, KKFail):
        return PairingFailed(f"ground station {gs} did not prove the fleet's static key ({msg2.value})")
    return msg2, LinkKey.from_secret(drone, gs, secret)


class PairRefusal(enum.Enum):
    """Why the drone refused a pairing query (counted as ``pair_refused:<value>``)."""

    OVERSIZE = "oversize"  # the query is longer than any handshake (checked by the adapter, not copied)
    UNKNOWN = "unknown"  # no ground station of the fleet
    UNAUTHORIZED = "unauthorized"  # not authorized for this drone
    FAILSAFE = "failsafe"  # the authority's rule: in failsafe, re-pair only on the ground
    OUTSIDE_COVERAGE = "outside_coverage"  # the authority's rule: a pairing that gives authority needs the vehicle in the GS's coverage
    FIRST_CLAIM = "first_claim"  # the authority's rule: after a restart on the ground its last owner pairs back first
    MALFORMED = "malformed"  # message 1 too short or too long
    BAD_MAC = "bad_mac"  # message 1's tag failed: forged or garbage, no crypto spent
    STALE = "stale"  # message 1's tagged time stamp is too old
    RATE_LIMITED = "rate_limited"  # the GS's handshakes per second are spent
    AUTH_FAILED = "auth_failed"  # the tag passed but the Noise handshake did not (should not happen)
    DOWNGRADE = "downgrade"  # a classical message 1 where the fleet requires the hybrid (ML-KEM-768) pairing
    LINKS_FULL = "links_full"  # the drone holds the fleet's ``links_max`` links and none may close (``linkplan``)
    #: the GS is the drone's owner, the drone holds its live key and heard it under that key within
    #: ``LINKED_HEARD_S``: it has not restarted, a new key would mend nothing, and the handshake would
    #: only load a drone that is late
    LINKED = "linked"


#: Bad input: dropped without an answer (counted; an answer would only help a prober).
SILENT_REFUSALS = frozenset({PairRefusal.OVERSIZE, PairRefusal.MALFORMED, PairRefusal.BAD_MAC, PairRefusal.STALE,
                             PairRefusal.RATE_LIMITED})


@dataclass(frozen=True, slots=True)
class PairAccepted:
    """A fresh handshake: send ``reply`` (message 2); ``key`` is a candidate until the GS proves it."""

    reply: bytes
    key: LinkKey
    crypto: ClassVar[bool] = True  # a handshake was computed (the adapter's per-turn budget)


@dataclass(frozen=True, slots=True)
class PairRepeated:
    """Message 1 seen before (a replay or a retransmission): send its first ``reply`` again; no key."""

    reply: bytes
    crypto: ClassVar[bool] = False


@dataclass(frozen=True, slots=True)
class PairRefused:
    """The query is refused for ``reason``; ``detail`` says more to the GS (may be empty)."""

    reason: PairRefusal
    detail: str = ""

    @property
    def silent(self) -> bool:
        """No answer at all (bad input), else the GS gets ``text`` as an error reply."""
        return self.reason in SILENT_REFUSALS

    @property
    def crypto(self) -> bool:
        """Whether a handshake was computed before the refusal."""
        return self.reason is PairRefusal.AUTH_FAILED

    @property
    def text(self) -> str:
        """The refusal in one line: the GS's error reply and the event's ``reason``."""
        return f"{self.reason.value}: {self.detail}" if self.detail else self.reason.value

    @property
    def refused(self) -> str:
        """The reason's name, as counted (``pair_refused:<refused>``)."""
        return self.reason.value


PairResult = PairAccepted | PairRepeated | PairRefused


def query_answer(result: PairResult) -> tuple[bytes | None, bytes | None] | None:
    """What the querying GS gets for ``result``: ``(reply, None)``, ``(None, error text)``, or None (no
    answer at all: a silent refusal)."""
    if isinstance(result, PairRefused):
        return None if result.silent else (None, result.text.encode())
    return result.reply, None


#: A message 1 made longer ago than this (by its tagged stamp, against the drone's clock) is stale.
PAIR_MAX_AGE = 30.0
#: Handshakes per second a GS's pairing queries may cost the drone (bursts of ``PAIR_BURST``): above
#: the owner's own re-pairing rate after a silence (5/s), so replays of its genuine tries cannot
#: starve it, and small enough that a flood of valid queries costs the drone nothing noticeable.
PAIR_RATE, PAIR_BURST = 5.0, 10.0
#: How far behind the drone's clock a GS's stamp may be when the drone compares it with the moment
#: it became ready: none. A message 1 made before the companion was back is stale however recent (a
#: replay of the owner's own probes while it was down must buy nothing); a GS whose clock is behind
#: the drone's by d simply re-pairs d later (it tries again every 0.2 s).
MAX_SKEW = 0.0
#: How far ahead of the drone's clock a message 1's stamp may be (clocks synchronised by GPS or NTP
#: agree far better): beyond it the message is stale, whatever its age would be.
MAX_AHEAD = 1.0
#: A message 1 seen within this time gets its first answer again (a replay creates nothing); at
#: least twice the maximum age, so a replay is either answered from the cache or stale.
PAIR_RESPONSE_TTL = 2 * PAIR_MAX_AGE


class PairingResponder:
    """Everything a drone checks for a pairing query, cheapest first.

    1. the GS is in the fleet and authorized for this drone (``policy``: the authority machine's
       extra rule, e.g. no re-pairing in failsafe in the air) -- refused with a reason;
    2. message 1's tag (``kk`` module: ~2 µs, no Diffie-Hellman) -- forged: silently dropped; and its
       stamp, given the drone's clock (``wall``) -- older than ``max_age`` or than ``not_before``:
       silently dropped as ``stale``;
    3. a message 1 seen before gets the same message 2 again, and no new key;
    4. the GS's rate limit (``rate`` handshakes per second, bursts of ``burst``), charged only now,
       so nobody without the GS's key can spend its tokens;
    5. the Noise handshake.

    With ``require_hybrid`` (the fleet's ``pairing_pq``; a revision may set it live), a classical
    message 1 that passed its tag is refused as ``downgrade`` (after 2, before 3).
    """

    def __init__(self, me: Identity, drone: str, ground_stations: dict[str, bytes], authorized: frozenset[str],
                 rate: float = PAIR_RATE, burst: float = PAIR_BURST, max_age: float = PAIR_MAX_AGE,
                 not_before: float | None = None, require_hybrid: bool = False) -> None:
        """``not_before``: the drone's clock when its companion became ready (message 1s stamped
        earlier than that, less ``MAX_SKEW``, are stale)."""
        self.me, self.drone = me, drone
        self.require_hybrid = require_hybrid
        self.max_age = max_age
        self.not_before = not_before
        self.newest: dict[str, float] = {}  # per GS: the stamp of the newest message 1 answered
        self.ground_stations = ground_stations
        self.authorized = authorized
        self.limiter = RateLimiter(rate, burst)
        self.cache = ResponseCache(PAIR_RESPONSE_TTL)

    def admit(self, gs: str) -> PairRefused | None:
        """Why a query from ``gs`` is refused before looking at it, or None."""
        if gs not in self.ground_stations:
            return PairRefused(PairRefusal.UNKNOWN)
        if gs not in self.authorized:
            return PairRefused(PairRefusal.UNAUTHORIZED)
        return None

    def answer(self, gs: str, message1: bytes, now: float, secret: bytes, policy: PairRefused | None = None,
               holds_key: bool = False, wall: float | None = None) -> PairResult:
        """The result of one pairing query from ``gs``. ``policy``: the authority machine's refusal
        (``AuthorityMachine.pair_refusal``), if any; ``holds_key``: the drone has a live key for
        ``gs`` (told to the GS inside message 2); ``wall``: the drone's clock (time of day), to
        check message 1's stamp (None: no freshness check, for tests of other rules)."""
        why = self.admit(gs) or policy
        if why is not None:
            return why
        prologue = _prologue(self.drone, gs)
        fail = check_message1(self.me, self.ground_stations[gs], prologue, message1, wall,
                              None if wall is None else self.max_age)
        if fail is not None:
            return PairRefused(PairRefusal(fail.value))
        if self.require_hybrid and not is_hybrid(message1):
            return PairRefused(PairRefusal.DOWNGRADE, "the fleet requires the hybrid (ML-KEM-768) pairing")
        stamp = stamp_of(message1)
        if wall is not None and stamp > wall + MAX_AHEAD:
            # stamped in the drone's future: a GS clock ahead of the drone's would let its tries made
            # while the companion was down pass for fresh ones once it is back
            return PairRefused(PairRefusal.STALE, "stamped ahead of the drone's clock")
        if wall is not None and self.not_before is not None and stamp < self.not_before - MAX_SKEW:
            return PairRefused(PairRefusal.STALE, "made before the companion started")
        cached = self.cache.get(message1, now)
        if cached is not None:
            return PairRepeated(cached)
        if wall is not None and stamp <= self.newest.get(gs, float("-inf")):
            # older than one already answered: a replay of the GS's own earlier try (its newer one
            # was answered), never a handshake, a token or a displaced candidate
            return PairRefused(PairRefusal.STALE, "older than a message 1 already answered")
        if not self.limiter.allow(gs, now):
            return PairRefused(PairRefusal.RATE_LIMITED)
        out = respond(self.me, self.drone, gs, self.ground_stations[gs], message1, secret, holds_key)
        if isinstance(out, PairingFailed):
            return PairRefused(PairRefusal.AUTH_FAILED)
        msg2, key = out
        self.cache.put(message1, msg2, now)
        if wall is not None:
            self.newest[gs] = stamp
        return PairAccepted(msg2, key)
