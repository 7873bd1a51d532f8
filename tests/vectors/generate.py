"""Regenerate envelope.json and pairing.json. Run only when the wire format changes on purpose:

    .venv/bin/python -m tests.vectors.generate
"""

from __future__ import annotations

import json
from pathlib import Path

from zdrone.core.envelope import SecureLink
from zdrone.core.keys import LinkKey

HERE = Path(__file__).parent
FRAMES = [
    "fd0900000004be000000000000000608000403cb8a",  # HEARTBEAT from sysid 4 (trailing zeros cut)
    "fd1b0000000101210000010000000200000003000000040000000500000006000700080009c4a4",  # GLOBAL_POSITION_INT
]


def build() -> dict:
    cases = []
    for role, tx, rx in (("gs", "zdrone/d1/up/A", "zdrone/d1/down/A"), ("drone", "zdrone/d1/down/A", "zdrone/d1/up/A")):
        key = LinkKey.from_secret("d1", "A", bytes(range(32)))
        link = SecureLink(key=key, role=role, tx_keyexpr=tx, rx_keyexpr=rx, peer_sysid=None, now=0.0, rekey_after=2)
        for i in range(3):  # counters 0, 1 in epoch 0, then counter 0 in epoch 1
            frame = FRAMES[i % 2]
            cases.append({"role": role, "keyexpr": tx, "index": i, "frame": frame,
                          "sealed": link.seal(bytes.fromhex(frame)).hex()})
    return {"link_secret": bytes(range(32)).hex(), "drone": "d1", "gs": "A", "rekey_after": 2, "cases": cases}


PAIR_KEYS = {"gs_private": bytes([2]) * 32, "drone_private": bytes([1]) * 32, "ephemeral": bytes([5]) * 32,
             "responder_ephemeral": bytes([6]) * 32, "kem_seed": bytes(range(64)), "link_secret": bytes(range(32))}


def build_pairing() -> dict:
    """Pairing, classical and hybrid: message 1 is fixed by the keys (the initiator's ephemeral
    X25519 and ML-KEM keys given); message 2 as the drone answered it once (ML-KEM encapsulation
    draws its own randomness), which the initiator must accept and turn into the link key."""
    from zdrone.core import kk
    from zdrone.core.keys import Identity
    from zdrone.core.pairing import PairingInitiator, _prologue

    k = PAIR_KEYS
    gs, drone = Identity(k["gs_private"]), Identity(k["drone_private"])
    cases = []
    for hybrid in (False, True):
        ini = PairingInitiator(gs, "A", "d1", drone.public, ephemeral=k["ephemeral"], stamp=1000.0, hybrid=hybrid,
                               kem_seed=k["kem_seed"] if hybrid else None)
        m1 = ini.start()
        m2 = kk.respond(drone, gs.public, _prologue("d1", "A"), m1, k["link_secret"] + b"\x00",
                        ephemeral=k["responder_ephemeral"])
        assert isinstance(m2, bytes)
        cases.append({"hybrid": hybrid, "stamp": 1000.0, "message1": m1.hex(), "message2": m2.hex()})
    return {"drone": "d1", "gs": "A", **{name: v.hex() for name, v in k.items()}, "cases": cases}


if __name__ == "__main__":
    (HERE / "envelope.json").write_text(json.dumps(build(), indent=2) + "\n")
    (HERE / "pairing.json").write_text(json.dumps(build_pairing(), indent=2) + "\n")
