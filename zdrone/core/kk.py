"""Noise KK handshakes (two messages) as used by pairing and key sharing, with a cheap pre-check.

Theory of operation
-------------------
Both sides know each other's static X25519 key from the fleet. Message 1 (initiator -> responder:
``e, es, ss``) proves the initiator's static key; message 2 (responder -> initiator: ``e, ee, se``)
proves the responder's, is bound to the initiator's fresh ephemeral, and carries a payload (a link
secret) encrypted with the handshake's forward-secret keys. Noise's own transport ciphers are not
used.

**Cheap pre-check (the "pair MAC").** Checking a Noise message costs two X25519 operations and the
noise library's Python (~0.3 ms); anyone with a leaked router password could make a node spend that
on garbage, or out-race the genuine message with forged ones. So both messages also carry a 16-byte
keyed BLAKE2s tag under a key that only the two fleet members can compute: HKDF of their
static-static X25519 secret, computed once per peer and cached. Message 1's tag covers the prologue
and message 1; message 2's covers the prologue, message 1 and message 2 (so an old reply fails it).
A forged message fails the tag in ~2 µs, is counted as ``bad_mac`` and costs nothing else: no
handshake attempt, no rate-limit token. The tag adds no new trust (the same static keys prove the
Noise messages); it only makes forgery cheap to refuse.

A failed ``read_message`` leaves a Noise handshake state spoiled, so ``KKInitiator`` keeps its
ephemeral key and replays its own side into a fresh state for every reply it tries. Replies that
pass the tag can only come from the responder, so the number of full attempts per exchange is
small and bounded (``MAX_REPLY_ATTEMPTS``).

Message 1 also carries the initiator's clock (8 bytes, under the tag). A responder that asks for
it (key sharing between ground stations, whose clocks agree) refuses a message 1 older than
``max_age`` (``stale``), before any other work; within that age, it answers a repeated message 1 with
the *same* message 2 (``ResponseCache``, kept at least twice as long): a replay, or a copy
forwarded by an on-path party, creates no second secret and evicts nothing, and the genuine
initiator still gets its answer.
"""

from __future__ import annotations

import enum
import functools
import hashlib
import hmac
import struct
import warnings
from collections import OrderedDict

from cryptography.hazmat.primitives.asymmetric.x25519 import X25519PrivateKey, X25519PublicKey
from noise.connection import Keypair, NoiseConnection

from .keys import Identity, hkdf

PROTOCOL = b"Noise_KK_25519_ChaChaPoly_SHA256"
MAX_REPLY_ATTEMPTS = 8
MAX_MESSAGE = 512
TAG_LEN = 16
STAMP_LEN = 8
EPHEMERAL_LEN = 32


class KKFail(enum.Enum):
    """Why a KK message was not accepted (counted per reason by the callers)."""

    MALFORMED = "malformed"  # too short or too long
    BAD_MAC = "bad_mac"  # the cheap tag failed: forged or garbage, no crypto spent
    STALE = "stale"  # message 1 made too long ago (its tagged time stamp): a replay
    AUTH_FAILED = "auth_failed"  # the tag passed but the Noise message did not (should not happen)
    EXHAUSTED = "exhausted"  # too many authentic-looking replies to one exchange


@functools.lru_cache(maxsize=1024)
def pair_mac_key(my_private: bytes, peer_public: bytes) -> bytes:
    """The tag key shared by two fleet members (symmetric: both sides compute the same)."""
    shared = X25519PrivateKey.from_private_bytes(my_private).exchange(X25519PublicKey.from_public_bytes(peer_public))
    return hkdf(shared, b"zdrone kk pair-mac v1")


def _tag(key: bytes, label: bytes, *parts: bytes) -> bytes:
    h = hashlib.blake2s(key=key, digest_size=TAG_LEN, person=b"zdronekk")
    h.update(label)
    for p in parts:
        h.update(len(p).to_bytes(4, "big"))
        h.update(p)
    return h.digest()


def _conn(me: Identity, peer_public: bytes, prologue: bytes, initiator: bool,
          ephemeral: bytes | None = None) -> NoiseConnection:
    conn = NoiseConnection.from_name(PROTOCOL)
    conn.set_keypair_from_private_bytes(Keypair.STATIC, me.private)
    conn.set_keypair_from_public_bytes(Keypair.REMOTE_STATIC, peer_public)
    conn.set_prologue(prologue)
    if ephemeral is not None:
        conn.set_keypair_from_private_bytes(Keypair.EPHEMERAL, ephemeral)
    conn.set_as_initiator() if initiator else conn.set_as_responder()
    with warnings.catch_warnings():
        # noise warns when an ephemeral is preset; ours is fresh per exchange (see module doc)
        warnings.simplefilter("ignore", UserWarning)
        conn.start_handshake()
    return conn


def _split(message: bytes) -> tuple[bytes, bytes] | None:
    if len(message) < EPHEMERAL_LEN + TAG_LEN or len(message) > MAX_MESSAGE:
        return None
    return message[:-TAG_LEN], message[-TAG_LEN:]


def _split1(message1: bytes) -> tuple[bytes, float, bytes] | None:
    """Message 1 on the wire: Noise message 1, the initiator's time stamp, the tag."""
    parts = _split(message1)
    if parts is None or len(parts[0]) < EPHEMERAL_LEN + STAMP_LEN:
        return None
    body, tag = parts
    return body[:-STAMP_LEN], struct.unpack(">d", body[-STAMP_LEN:])[0], tag


class KKInitiator:
    """The initiator of one KK exchange: ``message1`` to send, ``read_reply`` for each reply."""

    def __init__(self, me: Identity, peer_public: bytes, prologue: bytes, ephemeral: bytes | None = None,
                 stamp: float = 0.0) -> None:
        self._me, self._peer, self._prologue = me, peer_public, prologue
        self._ephemeral = ephemeral if ephemeral is not None else Identity.generate().private
        self._mac = pair_mac_key(me.private, peer_public)
        self._m1 = bytes(self._fresh().write_message(b""))
        body = self._m1 + struct.pack(">d", stamp)
        self.message1 = body + _tag(self._mac, b"1", prologue, body)
        self.attempts = 0

    def _fresh(self) -> NoiseConnection:
        return _conn(self._me, self._peer, self._prologue, True, self._ephemeral)

    def read_reply(self, message2: bytes) -> bytes | KKFail:
        """The payload of an authentic message 2, or why it was not accepted."""
        parts = _split(bytes(message2))
        if parts is None:
            return KKFail.MALFORMED
        m2, tag = parts
        if not hmac.compare_digest(tag, _tag(self._mac, b"2", self._prologue, self._m1, m2)):
            return KKFail.BAD_MAC  # forged, replayed or garbage: no attempt spent
        if self.attempts >= MAX_REPLY_ATTEMPTS:
            return KKFail.EXHAUSTED
        self.attempts += 1
        conn = self._fresh()
        conn.write_message(b"")
        try:
            payload = bytes(conn.read_message(m2))
        except Exception:  # noise raises several types for bad input
            return KKFail.AUTH_FAILED
        return payload if conn.handshake_finished else KKFail.AUTH_FAILED


def check_message1(me: Identity, peer_public: bytes, prologue: bytes, message1: bytes,
                   now: float | None = None, max_age: float | None = None) -> KKFail | None:
    """The cheap check of message 1 (no Diffie-Hellman once the peer's tag key is cached): its tag,
    and with ``max_age`` its tagged time stamp against the responder's clock ``now``."""
    parts = _split1(bytes(message1))
    if parts is None:
        return KKFail.MALFORMED
    m1, stamp, tag = parts
    if not hmac.compare_digest(tag, _tag(pair_mac_key(me.private, peer_public), b"1", prologue,
                                         bytes(message1[:-TAG_LEN]))):
        return KKFail.BAD_MAC
    if max_age is not None and now is not None and not abs(now - stamp) <= max_age:
        return KKFail.STALE
    return None


def stamp_of(message1: bytes) -> float:
    """The initiator's tagged time stamp of a message 1 (call after ``check_message1`` passed)."""
    parts = _split1(bytes(message1))
    return parts[1] if parts is not None else float("-inf")


def ephemeral_of(message1: bytes) -> bytes:
    """The initiator's ephemeral public key (sent in clear): the identity of one exchange."""
    return bytes(message1[:EPHEMERAL_LEN])


def respond(me: Identity, peer_public: bytes, prologue: bytes, message1: bytes, payload: bytes) -> bytes | KKFail:
    """Check message 1 from the peer (tag, then Noise); return message 2 carrying ``payload``."""
    fail = check_message1(me, peer_public, prologue, message1)
    if fail is not None:
        return fail
    m1 = bytes(message1[:-(TAG_LEN + STAMP_LEN)])
    conn = _conn(me, peer_public, prologue, False)
    try:
        conn.read_message(m1)
    except Exception:
        return KKFail.AUTH_FAILED
    m2 = bytes(conn.write_message(payload))
    if not conn.handshake_finished:
        return KKFail.AUTH_FAILED
    return m2 + _tag(pair_mac_key(me.private, peer_public), b"2", prologue, m1, m2)


class ResponseCache:
    """Message 2 sent for each recent message 1 (by the initiator's ephemeral), so a repeated
    message 1 gets the same answer and creates nothing new. Bounded in size and age."""

    def __init__(self, ttl: float, max_entries: int = 256) -> None:
        self.ttl, self.max_entries = ttl, max_entries
        self._entries: OrderedDict[bytes, tuple[float, bytes]] = OrderedDict()

    def get(self, message1: bytes, now: float) -> bytes | None:
        self._expire(now)
        hit = self._entries.get(bytes(message1))
        return None if hit is None else hit[1]

    def put(self, message1: bytes, message2: bytes, now: float) -> None:
        self._entries[bytes(message1)] = (now + self.ttl, message2)
        self._entries.move_to_end(bytes(message1))
        while len(self._entries) > self.max_entries:
            self._entries.popitem(last=False)

    def _expire(self, now: float) -> None:
        while self._entries:
            key, (until, _) = next(iter(self._entries.items()))
            if until > now:
                return
            del self._entries[key]

    def __len__(self) -> int:
        return len(self._entries)
