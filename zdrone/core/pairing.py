"""Pairing: a Noise KK handshake between a GS (initiator) and a drone (responder).

Theory of operation: both sides already know each other's static X25519 key from the fleet.
Message 1 (GS -> drone) proves the GS holds the fleet's static key for its name; message 2
(drone -> GS) proves the drone's and carries, encrypted with the handshake's forward-secret keys,
a fresh 32-byte link secret chosen by the drone. Both sides then derive the same ``LinkKey`` (one
key per direction). The prologue binds the protocol version and both names, so a transcript for
one (drone, gs) pair cannot be replayed for another.

Message 1 can be replayed (KK cannot tell a replay from a fresh one), so the drone treats the key
of every pairing as a *candidate*: it replaces nothing until the GS proves it with an authentic
frame under it (see ``linkslot``). A replayed message 1 therefore yields a candidate that only the
real GS could prove, and that expires. The drone checks that the GS is authorized and within its
rate limit before any crypto (``PairingGuard``).
"""

from __future__ import annotations

import enum

import msgspec

from .keys import KEY_LEN, Identity, LinkKey
from .kk import KKInitiator, respond as kk_respond
from .ratelimit import RateLimiter


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

    def __init__(self, me: Identity, gs: str, drone: str, drone_public: bytes, ephemeral: bytes | None = None) -> None:
        self.gs, self.drone = gs, drone
        self.state = PairingState.IDLE
        self._kk = KKInitiator(me, drone_public, _prologue(drone, gs), ephemeral)

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
        secret = self._kk.read_reply(message2)
        if secret is None:
            return PairingFailed(f"drone {self.drone} did not prove the fleet's static key (handshake failed)")
        if len(secret) != KEY_LEN:
            self.state = PairingState.FAILED
            return PairingFailed("message 2 carries no link secret")
        self.state = PairingState.DONE
        return LinkKey.from_secret(self.drone, self.gs, secret)


def respond(
    me: Identity, drone: str, gs: str, gs_public: bytes, message1: bytes, secret: bytes
) -> tuple[bytes, LinkKey] | PairingFailed:
    """The drone side: check message 1 from ``gs``; return message 2 and the (candidate) link key.

    ``secret`` is the fresh 32-byte link secret (the adapter draws it from ``os.urandom``;
    tests pass fixed bytes).
    """
    if len(secret) != KEY_LEN:
        raise ValueError("link secret must be 32 bytes")
    msg2 = kk_respond(me, gs_public, _prologue(drone, gs), message1, secret)
    if msg2 is None:
        return PairingFailed(f"ground station {gs} did not prove the fleet's static key (handshake failed)")
    return msg2, LinkKey.from_secret(drone, gs, secret)


class PairingGuard:
    """What a drone checks before it spends any crypto on a pairing request.

    ``admit(gs, now)`` is None when the request may go on to the handshake, else the reason it is
    refused: not a ground station of the fleet, not authorized for this drone, or over its rate
    limit (``rate`` handshakes per second per GS, bursts of ``burst``).
    """

    def __init__(self, ground_stations: frozenset[str], authorized: frozenset[str], rate: float = 1.0,
                 burst: float = 3.0) -> None:
        self.ground_stations = ground_stations
        self.authorized = authorized
        self.limiter = RateLimiter(rate, burst)

    def admit(self, gs: str, now: float) -> str | None:
        if gs not in self.ground_stations:
            return "unknown"
        if gs not in self.authorized:
            return "unauthorized"
        if not self.limiter.allow(gs, now):
            return "rate_limited"
        return None
