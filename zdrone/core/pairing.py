"""Pairing on the ground: a Noise KK handshake between a GS (initiator) and a drone (responder).

Theory of operation: both sides already know each other's static X25519 key from the fleet.
KK takes two messages: message 1 (GS -> drone) proves the GS holds the fleet's static key for its
name; message 2 (drone -> GS) proves the drone's and carries, encrypted with the handshake's
forward-secret keys, a fresh 32-byte link secret chosen by the drone. Both sides then derive the
same ``LinkKey`` (one key per direction). Noise's own transport ciphers are not used: they need
in-order lossless delivery, which pub/sub does not give. The prologue binds the protocol version
and both names, so a transcript for one (drone, gs) pair cannot be replayed for another.
"""

from __future__ import annotations

import enum

import msgspec
from noise.connection import Keypair, NoiseConnection

from .keys import KEY_LEN, Identity, LinkKey

PROTOCOL = b"Noise_KK_25519_ChaChaPoly_SHA256"


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


def _noise(me: Identity, peer_public: bytes, initiator: bool, prologue: bytes) -> NoiseConnection:
    conn = NoiseConnection.from_name(PROTOCOL)
    conn.set_keypair_from_private_bytes(Keypair.STATIC, me.private)
    conn.set_keypair_from_public_bytes(Keypair.REMOTE_STATIC, peer_public)
    conn.set_prologue(prologue)
    if initiator:
        conn.set_as_initiator()
    else:
        conn.set_as_responder()
    conn.start_handshake()
    return conn


class PairingInitiator:
    """The GS side: ``start()`` gives message 1, ``finish(message2)`` gives the link key."""

    def __init__(self, me: Identity, gs: str, drone: str, drone_public: bytes) -> None:
        self.gs, self.drone = gs, drone
        self.state = PairingState.IDLE
        self._conn = _noise(me, drone_public, True, _prologue(drone, gs))

    def start(self) -> bytes:
        if self.state is not PairingState.IDLE:
            raise RuntimeError("pairing already started")
        self.state = PairingState.SENT
        return bytes(self._conn.write_message(b""))

    def finish(self, message2: bytes) -> LinkKey | PairingFailed:
        if self.state is not PairingState.SENT:
            raise RuntimeError("finish() before start()")
        try:
            secret = bytes(self._conn.read_message(bytes(message2)))
        except Exception:  # noise raises several types for bad or forged input
            self.state = PairingState.FAILED
            return PairingFailed(f"drone {self.drone} did not prove the fleet's static key (handshake failed)")
        if len(secret) != KEY_LEN or not self._conn.handshake_finished:
            self.state = PairingState.FAILED
            return PairingFailed("message 2 carries no link secret")
        self.state = PairingState.DONE
        return LinkKey.from_secret(self.drone, self.gs, secret)


def respond(
    me: Identity, drone: str, gs: str, gs_public: bytes, message1: bytes, secret: bytes
) -> tuple[bytes, LinkKey] | PairingFailed:
    """The drone side: check message 1 from ``gs``; return message 2 and the link key.

    ``secret`` is the fresh 32-byte link secret (the adapter draws it from ``os.urandom``;
    tests pass fixed bytes).
    """
    if len(secret) != KEY_LEN:
        raise ValueError("link secret must be 32 bytes")
    conn = _noise(me, gs_public, False, _prologue(drone, gs))
    try:
        conn.read_message(bytes(message1))
    except Exception:
        return PairingFailed(f"ground station {gs} did not prove the fleet's static key (handshake failed)")
    msg2 = bytes(conn.write_message(secret))
    if not conn.handshake_finished:
        return PairingFailed("handshake did not finish")
    return msg2, LinkKey.from_secret(drone, gs, secret)
