"""Regenerate revision.json (fleet revisions: fixed keys -> exact signed bytes, and the refusals).
Run only when the revision format changes on purpose:

    .venv/bin/python -m tests.vectors.generate_revision
"""

from __future__ import annotations

import json
from pathlib import Path

import msgspec

from zdrone.core.fleet import Coverage, Fleet, Node
from zdrone.core.keys import Identity, SigningKey, b64
from zdrone.core.revision import (Changes, apply_revision, encode_revision, make_revision, with_authorized,
                                  with_coverage, with_keys, with_revoked)

HERE = Path(__file__).parent
FLEET_SEED = bytes(range(32))


def _node(i: int, role: str, **kw) -> Node:
    return Node(role=role, sysid=i, public_key=b64(Identity(bytes([i]) * 32).public),  # type: ignore[arg-type]
                signing_key=b64(SigningKey(bytes([(100 + i) % 256]) * 32).public), **kw)


def base_fleet() -> Fleet:
    cov = Coverage(48.0, 11.0, 600.0)
    nodes = {"A": _node(200, "gs", coverage=cov), "B": _node(201, "gs", coverage=cov),
             "C": _node(202, "gs", coverage=cov), "d1": _node(1, "drone", authorized_gs=["A", "B"])}
    return Fleet(version=1, nodes=nodes, fleet_key=b64(SigningKey(FLEET_SEED).public))


def build() -> dict:
    base, key = base_fleet(), SigningKey(FLEET_SEED)
    c1 = with_revoked(Changes(), "B")
    r1 = make_revision(base, 1, c1, key, note="B's host lost")
    c2 = with_coverage(with_authorized(with_keys(c1, "A", Identity(b"\x07" * 32).public, SigningKey(b"\x08" * 32).public),
                                       "d1", ["A", "C"]), "C", Coverage(48.001, 11.0, 700.0))
    r2 = make_revision(base, 2, msgspec.structs.replace(c2, pairing_pq=True), key)
    unrevoke = make_revision(base, 3, Changes(), key)
    other = SigningKey(b"\x09" * 32)
    forged = msgspec.structs.replace(r2, number=5)
    wrong_key = msgspec.structs.replace(r2, number=4, fleet_key=b64(other.public))
    wrong_key = msgspec.structs.replace(wrong_key, signature=b64(other.sign(wrong_key.signed_bytes())))
    eff2 = apply_revision(base, r2)
    return {
        "fleet_seed": FLEET_SEED.hex(),
        "base": msgspec.to_builtins(base),
        "accepted": [
            {"current": None, "revision": encode_revision(r1).decode(), "signed_hex": r1.signed_bytes().hex(),
             "revoked": ["B"], "authorized_d1": ["A"]},
            {"current": 1, "revision": encode_revision(r2).decode(), "signed_hex": r2.signed_bytes().hex(),
             "revoked": ["B"], "authorized_d1": ["A", "C"], "public_key_A": eff2.nodes["A"].public_key,
             "pairing_pq": True},
        ],
        "refused": [
            {"current": 2, "revision": encode_revision(r1).decode(), "reason": "stale"},
            {"current": 2, "revision": encode_revision(r2).decode(), "reason": "replayed"},
            {"current": 2, "revision": encode_revision(unrevoke).decode(), "reason": "unrevokes"},
            {"current": 2, "revision": encode_revision(forged).decode(), "reason": "bad_signature"},
            {"current": 2, "revision": encode_revision(wrong_key).decode(), "reason": "wrong_fleet"},
            {"current": 2, "revision": "{\"number\": 9}", "reason": "malformed"},
        ],
    }


if __name__ == "__main__":
    (HERE / "revision.json").write_text(json.dumps(build(), indent=2) + "\n")
