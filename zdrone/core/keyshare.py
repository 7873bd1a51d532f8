"""Key sharing over the backhaul: a link secret sealed with HPKE (RFC 9180) to the asking GS.

GS B answers ``backhaul/B/linkkey/<drone>`` with a fresh 32-byte secret for link (drone, B),
sealed to the asking GS's fleet static key (X25519 / HKDF-SHA256 / ChaCha20-Poly1305). The info
string binds drone, owner and asker, so a reply cannot be reused for another pair. Neither the
router nor anyone else on the backhaul can read it.
"""

from __future__ import annotations

import msgspec
from cryptography.hazmat.primitives import hpke

from .keys import KEY_LEN, Identity, public_key

SUITE = hpke.Suite(hpke.KEM.X25519, hpke.KDF.HKDF_SHA256, hpke.AEAD.CHACHA20_POLY1305)


class LinkKeyRequest(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Payload of a linkkey query: who asks (checked against the fleet by the answering GS)."""

    asker: str


def _info(drone: str, owner: str, asker: str) -> bytes:
    return f"zdrone linkkey v1|{drone}|{owner}|{asker}".encode()


def seal_secret(secret: bytes, asker_public: bytes, drone: str, owner: str, asker: str) -> bytes:
    if len(secret) != KEY_LEN:
        raise ValueError("link secret must be 32 bytes")
    return SUITE.encrypt(secret, public_key(asker_public), info=_info(drone, owner, asker))


def open_secret(sealed: bytes, me: Identity, drone: str, owner: str, asker: str) -> bytes | None:
    """The secret, or None if the reply does not open for us (forged, or for someone else)."""
    try:
        out = SUITE.decrypt(sealed, me.private_key(), info=_info(drone, owner, asker))
    except Exception:  # InvalidTag and friends
        return None
    return out if len(out) == KEY_LEN else None
