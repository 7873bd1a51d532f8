"""Fixed keys, counters and frames -> exact sealed bytes: a change of wire format is noticed."""

import json
from pathlib import Path

from zdrone.core.envelope import Opened, SecureLink
from zdrone.core.keys import LinkKey

VECTORS = json.loads((Path(__file__).parent.parent / "vectors" / "envelope.json").read_text())


def _link(role, tx, rx):
    key = LinkKey.from_secret(VECTORS["drone"], VECTORS["gs"], bytes.fromhex(VECTORS["link_secret"]))
    return SecureLink(key=key, role=role, tx_keyexpr=tx, rx_keyexpr=rx, peer_sysid=None, now=0.0,
                      rekey_after=VECTORS["rekey_after"])


def test_sealed_bytes_match_vectors():
    links = {"gs": _link("gs", "zdrone/d1/up/A", "zdrone/d1/down/A"),
             "drone": _link("drone", "zdrone/d1/down/A", "zdrone/d1/up/A")}
    for case in VECTORS["cases"]:
        assert links[case["role"]].seal(bytes.fromhex(case["frame"])).hex() == case["sealed"], case


def test_vectors_open_on_the_other_side():
    receivers = {"gs": _link("drone", "zdrone/d1/down/A", "zdrone/d1/up/A"),
                 "drone": _link("gs", "zdrone/d1/up/A", "zdrone/d1/down/A")}
    for case in VECTORS["cases"]:
        got = receivers[case["role"]].open(bytes.fromhex(case["sealed"]), 1.0)
        assert isinstance(got, Opened) and got.plaintext.hex() == case["frame"]
