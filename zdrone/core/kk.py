"""Noise KK handshakes (two messages) as used by pairing and key sharing.

Theory of operation: both sides know each other's static X25519 key from the fleet. Message 1
(initiator -> responder: ``e, es, ss``) proves the initiator's static key; message 2 (responder ->
initiator: ``e, ee, se``) proves the responder's, is bound to the initiator's fresh ephemeral, and
carries a payload (a link secret) encrypted with the handshake's forward-secret keys. Noise's own
transport ciphers are not used.

A failed ``read_message`` leaves a Noise handshake state spoiled, so a forged reply that arrives
before the genuine one would otherwise make the genuine one fail too. ``KKInitiator`` therefore
keeps its ephemeral key and replays its own side of the handshake into a fresh state for every
reply it tries: a forged reply costs one attempt, never the exchange. The number of attempts per
exchange is bounded (``MAX_REPLY_ATTEMPTS``).
"""

from __future__ import annotations

import warnings

from noise.connection import Keypair, NoiseConnection

from .keys import Identity

PROTOCOL = b"Noise_KK_25519_ChaChaPoly_SHA256"
MAX_REPLY_ATTEMPTS = 8
MAX_MESSAGE = 512


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


class KKInitiator:
    """The initiator of one KK exchange: ``message1`` to send, ``read_reply`` for each reply."""

    def __init__(self, me: Identity, peer_public: bytes, prologue: bytes, ephemeral: bytes | None = None) -> None:
        self._me, self._peer, self._prologue = me, peer_public, prologue
        self._ephemeral = ephemeral if ephemeral is not None else Identity.generate().private
        self.message1 = bytes(self._fresh().write_message(b""))
        self.attempts = 0

    def _fresh(self) -> NoiseConnection:
        return _conn(self._me, self._peer, self._prologue, True, self._ephemeral)

    def read_reply(self, message2: bytes) -> bytes | None:
        """The payload of an authentic message 2, or None (forged, replayed, garbage, too many tries)."""
        if self.attempts >= MAX_REPLY_ATTEMPTS or len(message2) > MAX_MESSAGE:
            return None
        self.attempts += 1
        conn = self._fresh()
        conn.write_message(b"")
        try:
            payload = bytes(conn.read_message(bytes(message2)))
        except Exception:  # noise raises several types for bad or forged input
            return None
        return payload if conn.handshake_finished else None


def respond(me: Identity, peer_public: bytes, prologue: bytes, message1: bytes, payload: bytes) -> bytes | None:
    """Check message 1 from the peer; return message 2 carrying ``payload``, or None if it fails."""
    if len(message1) > MAX_MESSAGE:
        return None
    conn = _conn(me, peer_public, prologue, False)
    try:
        conn.read_message(bytes(message1))
    except Exception:
        return None
    msg2 = bytes(conn.write_message(payload))
    return msg2 if conn.handshake_finished else None
