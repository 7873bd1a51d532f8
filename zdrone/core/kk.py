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

Hybrid (post-quantum) mode
--------------------------
With ``hybrid=True`` the exchange adds ML-KEM-768 (FIPS 203) next to X25519, so that the secret
message 2 carries stays secret if *either* holds. The chosen shape is an *ephemeral* ML-KEM key of
the initiator, the responder encapsulating, the KEM secret mixed in as a Noise pre-shared key:

* message 1 = Noise message 1 || the initiator's fresh ML-KEM-768 public key (1 184 bytes) || stamp
  || tag; the public key is hashed into the Noise prologue (``hybrid_prologue``), so it is bound to
  the transcript that the static X25519 keys authenticate (a swapped key fails the responder's
  Noise read, and the tag before it);
* the responder encapsulates to it: (secret, ciphertext); the pattern is ``KKpsk2`` and the PSK is
  HKDF(KEM secret). ``psk2`` mixes it into the chaining key after ``ee, se``: the key that encrypts
  message 2's payload depends on the Diffie-Hellman chain *and* the KEM secret (as WireGuard's PSK
  slot, and what Noise's ``hfs`` pattern does with its ``ekem1`` token);
* message 2 = Noise message 2 || ciphertext (1 088 bytes) || tag. A ciphertext changed on the way
  decapsulates to another secret (ML-KEM's implicit rejection), so the payload does not open: the
  pairing fails (``auth_failed``), even for one who could forge the tag.

Why ephemeral and not a static ML-KEM key of the responder: the threat a hybrid answers today is
"record now, decrypt later" with a future quantum computer. An ephemeral KEM key gives forward
secrecy against it (a drone captured later yields nothing of past pairings), needs no new key
material in the fleet, no distribution and no rotation, and its public key needs no separate
authentication (the transcript binds it). What it does not give is post-quantum *authentication*:
an attacker with a quantum computer at pairing time could impersonate a static X25519 key. That
needs post-quantum signatures or static KEM keys in the fleet, a later step. The cost: +1 184 bytes
in message 1, +1 088 in message 2, one ML-KEM key generation and one decapsulation at the
initiator, one encapsulation at the responder (``zdrone bench crypto``).

The mode is in the message: a message 1 longer than ``CLASSICAL_MAX`` is hybrid (``is_hybrid``) and
the reply follows it (its tag covers the hybrid prologue, so no one can strip it to classical). A
responder that requires hybrid refuses a classical message 1 (the callers' ``downgrade``); one that
does not still accepts a hybrid one (a fleet turning it on reaches the ground stations first).
"""

from __future__ import annotations

import enum
import functools
import hashlib
import hmac
import struct
import warnings
from collections import OrderedDict
from typing import NamedTuple

from cryptography.hazmat.primitives.asymmetric.mlkem import MLKEM768PrivateKey, MLKEM768PublicKey
from cryptography.hazmat.primitives.asymmetric.x25519 import X25519PrivateKey, X25519PublicKey
from noise.connection import Keypair, NoiseConnection

from zdrone.core.keys import Identity, hkdf

PROTOCOL = b"Noise_KK_25519_ChaChaPoly_SHA256"
PROTOCOL_HYBRID = b"Noise_KKpsk2_25519_ChaChaPoly_SHA256"
MAX_REPLY_ATTEMPTS = 8
#: a classical message is at most this long; a longer message 1 is a hybrid one
CLASSICAL_MAX = 512
KEM_PUBLIC_LEN = 1184  # ML-KEM-768 encapsulation key
KEM_CIPHERTEXT_LEN = 1088  # ML-KEM-768 ciphertext
KEM_SEED_LEN = 64
MAX_MESSAGE = 2048
TAG_LEN = 16
STAMP_LEN = 8
EPHEMERAL_LEN = 32


class KKFail(enum.Enum):
    """Why a KK message was not accepted (counted per reason by the callers)."""

    MALFORMED = "malformed"  # too short or too long
    BAD_MAC = "bad_mac"  # the cheap tag failed: forged or garbage, no crypto spent
    STALE = "stale"  # message 1 made too long ago (its tagged time stamp): a replay
    AUTH_FAILED = "auth_failed"  # the tag passed but the Noise message (or the KEM ciphertext) did not
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


def hybrid_prologue(prologue: bytes, kem_public: bytes) -> bytes:
    """The prologue of a hybrid exchange: the caller's, the mode, and the initiator's ML-KEM key."""
    return prologue + b"|hybrid mlkem768|" + hashlib.sha256(kem_public).digest()


def _kem_psk(kem_secret: bytes) -> bytes:
    return hkdf(kem_secret, b"zdrone kk mlkem768 psk v1")


#: the PSK slot's content before the KEM secret is known (message 1 of ``KKpsk2`` does not use it)
_NO_PSK = bytes(32)


def _conn(me: Identity, peer_public: bytes, prologue: bytes, initiator: bool,
          ephemeral: bytes | None = None, psk: bytes | None = None) -> NoiseConnection:
    conn = NoiseConnection.from_name(PROTOCOL if psk is None else PROTOCOL_HYBRID)
    conn.set_keypair_from_private_bytes(Keypair.STATIC, me.private)
    conn.set_keypair_from_public_bytes(Keypair.REMOTE_STATIC, peer_public)
    conn.set_prologue(prologue)
    if psk is not None:
        conn.set_psks(psk=psk)
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


def is_hybrid(message1: bytes) -> bool:
    """Whether a message 1 is a hybrid one (by its length; ``check_message1`` checks the rest)."""
    return len(message1) > CLASSICAL_MAX


class _Message1(NamedTuple):
    noise: bytes  # Noise message 1
    kem_public: bytes  # the initiator's ML-KEM-768 key (empty in a classical message)
    stamp: float
    tag: bytes


def _split1(message1: bytes) -> _Message1 | None:
    """Message 1 on the wire: Noise message 1, (hybrid) the ML-KEM key, the initiator's time stamp, the tag."""
    parts = _split(message1)
    kem_len = KEM_PUBLIC_LEN if is_hybrid(message1) else 0
    if parts is None or len(parts[0]) < EPHEMERAL_LEN + kem_len + STAMP_LEN:
        return None
    body, tag = parts
    noise_end = len(body) - STAMP_LEN - kem_len
    return _Message1(body[:noise_end], body[noise_end:-STAMP_LEN], struct.unpack(">d", body[-STAMP_LEN:])[0], tag)


def _mode_prologue(prologue: bytes, kem_public: bytes) -> bytes:
    return hybrid_prologue(prologue, kem_public) if kem_public else prologue


class KKInitiator:
    """The initiator of one KK exchange: ``message1`` to send, ``read_reply`` for each reply.
    ``hybrid``: add ML-KEM-768 (see the module's text; ``kem_seed`` fixes its key, for vectors)."""

    def __init__(self, me: Identity, peer_public: bytes, prologue: bytes, ephemeral: bytes | None = None,
                 stamp: float = 0.0, hybrid: bool = False, kem_seed: bytes | None = None) -> None:
        self._me, self._peer = me, peer_public
        self._ephemeral = ephemeral if ephemeral is not None else Identity.generate().private
        self._mac = pair_mac_key(me.private, peer_public)
        self._kem: MLKEM768PrivateKey | None = None
        kem_public = b""
        if hybrid:
            self._kem = (MLKEM768PrivateKey.from_seed_bytes(kem_seed) if kem_seed is not None
                         else MLKEM768PrivateKey.generate())
            kem_public = self._kem.public_key().public_bytes_raw()
        self._prologue = _mode_prologue(prologue, kem_public)
        self._m1 = bytes(self._fresh(None if self._kem is None else _NO_PSK).write_message(b""))
        body = self._m1 + kem_public + struct.pack(">d", stamp)
        self.message1 = body + _tag(self._mac, b"1", self._prologue, body)
        self.attempts = 0

    @property
    def hybrid(self) -> bool:
        return self._kem is not None

    def _fresh(self, psk: bytes | None) -> NoiseConnection:
        return _conn(self._me, self._peer, self._prologue, True, self._ephemeral, psk)

    def read_reply(self, message2: bytes) -> bytes | KKFail:
        """The payload of an authentic message 2, or why it was not accepted."""
        parts = _split(bytes(message2))
        if parts is None:
            return KKFail.MALFORMED
        m2, tag = parts
        if self._kem is not None and len(m2) < EPHEMERAL_LEN + KEM_CIPHERTEXT_LEN:
            return KKFail.MALFORMED
        if not hmac.compare_digest(tag, _tag(self._mac, b"2", self._prologue, self._m1, m2)):
            return KKFail.BAD_MAC  # forged, replayed or garbage: no attempt spent
        if self.attempts >= MAX_REPLY_ATTEMPTS:
            return KKFail.EXHAUSTED
        self.attempts += 1
        psk = None
        if self._kem is not None:
            m2, ciphertext = m2[:-KEM_CIPHERTEXT_LEN], m2[-KEM_CIPHERTEXT_LEN:]
            psk = _kem_psk(self._kem.decapsulate(ciphertext))
        conn = self._fresh(psk)
        conn.write_message(b"")
        try:
            payload = bytes(conn.read_message(m2))
        except Exception:  # noise raises several types for bad input
            return KKFail.AUTH_FAILED
        return payload if conn.handshake_finished else KKFail.AUTH_FAILED


def check_message1(me: Identity, peer_public: bytes, prologue: bytes, message1: bytes,
                   now: float | None = None, max_age: float | None = None) -> KKFail | None:
    """The cheap check of message 1 (no Diffie-Hellman once the peer's tag key is cached): its tag,
    and with ``max_age`` its tagged time stamp against the responder's clock ``now``. Classical or
    hybrid, as the message is (``is_hybrid``)."""
    parts = _split1(bytes(message1))
    if parts is None:
        return KKFail.MALFORMED
    if not hmac.compare_digest(parts.tag, _tag(pair_mac_key(me.private, peer_public), b"1",
                                               _mode_prologue(prologue, parts.kem_public),
                                               bytes(message1[:-TAG_LEN]))):
        return KKFail.BAD_MAC
    if max_age is not None and now is not None and not abs(now - parts.stamp) <= max_age:
        return KKFail.STALE
    return None


def stamp_of(message1: bytes) -> float:
    """The initiator's tagged time stamp of a message 1 (call after ``check_message1`` passed)."""
    parts = _split1(bytes(message1))
    return parts.stamp if parts is not None else float("-inf")


def ephemeral_of(message1: bytes) -> bytes:
    """The initiator's ephemeral public key (sent in clear): the identity of one exchange."""
    return bytes(message1[:EPHEMERAL_LEN])


def respond(me: Identity, peer_public: bytes, prologue: bytes, message1: bytes, payload: bytes,
            ephemeral: bytes | None = None) -> bytes | KKFail:
    """Check message 1 from the peer (tag, then Noise); return message 2 carrying ``payload``. A
    hybrid message 1 gets a hybrid message 2 (the ML-KEM ciphertext mixed in as the PSK).
    ``ephemeral`` fixes the responder's ephemeral key (vectors only)."""
    fail = check_message1(me, peer_public, prologue, message1)
    if fail is not None:
        return fail
    parts = _split1(bytes(message1))
    assert parts is not None  # checked above
    psk, ciphertext = None, b""
    if parts.kem_public:
        try:
            kem_secret, ciphertext = MLKEM768PublicKey.from_public_bytes(parts.kem_public).encapsulate()
        except ValueError:  # not a valid ML-KEM-768 key (under a valid tag: should not happen)
            return KKFail.AUTH_FAILED
        psk = _kem_psk(kem_secret)
    mode_prologue = _mode_prologue(prologue, parts.kem_public)
    conn = _conn(me, peer_public, mode_prologue, False, ephemeral, psk)
    try:
        conn.read_message(parts.noise)
    except Exception:
        return KKFail.AUTH_FAILED
    m2 = bytes(conn.write_message(payload)) + ciphertext
    if not conn.handshake_finished:
        return KKFail.AUTH_FAILED
    return m2 + _tag(pair_mac_key(me.private, peer_public), b"2", mode_prologue, parts.noise, m2)


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
