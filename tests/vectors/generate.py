"""Regenerate envelope.json. Run only when the wire format changes on purpose:

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


if __name__ == "__main__":
    (HERE / "envelope.json").write_text(json.dumps(build(), indent=2) + "\n")
