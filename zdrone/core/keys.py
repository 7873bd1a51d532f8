"""Key material: X25519 identities, Ed25519 signing keys, directional link keys and their per-epoch ratchet.

Signing keys (Ed25519): the fleet's own (signs fleet revisions, ``zdrone.core.revision``; kept offline
with the CA key) and one per node (signs what the node records, e.g. its authority record). Their
public halves are in ``fleet.json5`` (``Fleet.fleet_key``, ``Node.signing_key``).

A link (drone, gs) has one 32-byte secret per direction ("up" GS->drone, "down" drone->GS). The
key used for epoch ``e`` of a direction comes from a chain: ``chain[0] = HKDF(secret, dir)`` and
``chain[e+1] = HKDF(chain[e], "rekey")``; ``key[e] = HKDF(chain[e], "aead")``. A sender moves to the
next epoch long before its counter could wrap; the receiver follows on the first authentic frame
of the new epoch. Old chain keys are forgotten, so a stolen current key does not open old traffic.
"""

from __future__ import annotations

import base64
import hmac
from dataclasses import dataclass, field

from cryptography.hazmat.primitives import hashes, serialization
from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey
from cryptography.hazmat.primitives.asymmetric.x25519 import X25519PrivateKey, X25519PublicKey
from cryptography.hazmat.primitives.kdf.hkdf import HKDF

KEY_LEN = 32
UP = "up"  # GS -> drone
DOWN = "down"  # drone -> GS


def hkdf(secret: bytes, info: bytes, length: int = KEY_LEN) -> bytes:
    """HKDF-SHA256 with an empty salt."""
    return HKDF(algorithm=hashes.SHA256(), length=length, salt=None, info=info).derive(secret)


def b64(data: bytes) -> str:
    return base64.b64encode(data).decode("ascii")


def unb64(text: str, length: int | None = None) -> bytes:
    """Decode base64 text; raise ValueError if it is not valid or not ``length`` bytes."""
    try:
        raw = base64.b64decode(text.encode("ascii"), validate=True)
    except Exception as exc:
        raise ValueError(f"not valid base64 ({exc})") from None
    if length is not None and len(raw) != length:
        raise ValueError(f"expected {length} bytes, got {len(raw)}")
    return raw


@dataclass(frozen=True, slots=True, repr=False)
class Identity:
    """A node's static X25519 key pair. Never printed or logged."""

    private: bytes

    @classmethod
    def generate(cls) -> "Identity":
        key = X25519PrivateKey.generate()
        raw = key.private_bytes(
            serialization.Encoding.Raw, serialization.PrivateFormat.Raw, serialization.NoEncryption()
        )
        return cls(raw)

    @property
    def public(self) -> bytes:
        key = X25519PrivateKey.from_private_bytes(self.private)
        return key.public_key().public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)

    def private_key(self) -> X25519PrivateKey:
        return X25519PrivateKey.from_private_bytes(self.private)

    def __repr__(self) -> str:
        return f"Identity(public={b64(self.public)[:12]}…)"


@dataclass(frozen=True, slots=True, repr=False)
class SigningKey:
    """An Ed25519 private key (32 raw bytes): the fleet's or a node's. Never printed or logged."""

    private: bytes
    #: the key object, made once (making it costs as much as a signature, and a node signs every status
    #: and lease with it); it lives and dies with this key, so a rotated key leaves no copy behind
    _key: Ed25519PrivateKey = field(init=False, compare=False, hash=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_key", Ed25519PrivateKey.from_private_bytes(self.private))

    @classmethod
    def generate(cls) -> "SigningKey":
        raw = Ed25519PrivateKey.generate().private_bytes(
            serialization.Encoding.Raw, serialization.PrivateFormat.Raw, serialization.NoEncryption())
        return cls(raw)

    def private_key(self) -> Ed25519PrivateKey:
        return self._key

    @property
    def public(self) -> bytes:
        return self._key.public_key().public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)

    def sign(self, message: bytes) -> bytes:
        """A 64-byte Ed25519 signature of ``message``."""
        return self._key.sign(message)

    def __repr__(self) -> str:
        return f"SigningKey(public={b64(self.public)[:12]}…)"


def verify_signature(public: bytes, message: bytes, signature: bytes) -> bool:
    """Whether ``signature`` is ``public``'s Ed25519 signature of ``message`` (a malformed key or
    signature is simply not valid)."""
    try:
        Ed25519PublicKey.from_public_bytes(public).verify(signature, message)
    except (InvalidSignature, ValueError):
        return False
    return True


def public_key(raw: bytes) -> X25519PublicKey:
    return X25519PublicKey.from_public_bytes(raw)


@dataclass(frozen=True, slots=True, repr=False)
class LinkKey:
    """The two directional secrets of one (drone, gs) link. Never printed or logged."""

    drone: str
    gs: str
    up: bytes
    down: bytes

    @classmethod
    def from_secret(cls, drone: str, gs: str, secret: bytes) -> "LinkKey":
        """Derive both directions from one 32-byte link secret (as handed over by pairing/backhaul)."""
        label = f"zdrone link {drone}|{gs}|".encode()
        return cls(drone, gs, hkdf(secret, label + b"up"), hkdf(secret, label + b"down"))

    def direction(self, name: str) -> bytes:
        return self.up if name == UP else self.down

    def same_as(self, other: "LinkKey") -> bool:
        return hmac.compare_digest(self.up + self.down, other.up + other.down)

    def __repr__(self) -> str:
        return f"LinkKey({self.drone}|{self.gs})"


@dataclass(slots=True, repr=False)
class KeyChain:
    """Per-direction ratchet: yields the AEAD key of each epoch, forgetting older chain keys."""

    epoch: int
    chain: bytes
    _next_cache: bytes | None = field(default=None)

    @classmethod
    def start(cls, direction_secret: bytes) -> "KeyChain":
        return cls(0, hkdf(direction_secret, b"zdrone chain 0"))

    def aead_key(self) -> bytes:
        return hkdf(self.chain, b"zdrone aead")

    def peek_next(self) -> bytes:
        """AEAD key of epoch+1, without advancing (receiver trying a new epoch)."""
        if self._next_cache is None:
            self._next_cache = hkdf(self.chain, b"zdrone rekey")
        return hkdf(self._next_cache, b"zdrone aead")

    def advance(self) -> None:
        nxt = self._next_cache if self._next_cache is not None else hkdf(self.chain, b"zdrone rekey")
        self.chain, self.epoch, self._next_cache = nxt, self.epoch + 1, None
