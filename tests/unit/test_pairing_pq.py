"""The hybrid (X25519 + ML-KEM-768) pairing and key sharing: fixed vectors, a tampered ciphertext, no
downgrade once the fleet requires it, classical unchanged while it does not."""

import json
from pathlib import Path

import pytest

from zdrone.core import kk
from zdrone.core.fleet import encode_fleet, parse_fleet
from zdrone.core.keys import Identity, LinkKey
from zdrone.core.keyshare import KeyShareAsk, KeyShareResponder, Refused, ShareRefusal
from zdrone.core.pairing import (PairAccepted, PairingFailed, PairingInitiator, PairingResponder, PairRefusal,
                                 PairRefused, _prologue, respond)

VECTORS = json.loads((Path(__file__).parent.parent / "vectors" / "pairing.json").read_text())
DRONE, GS, STRANGER = Identity(bytes([1]) * 32), Identity(bytes([2]) * 32), Identity(bytes([3]) * 32)
SECRET = bytes(range(32))


def _retag2(message2: bytes, message1: bytes, prologue: bytes) -> bytes:
    """Message 2 with its cheap tag made again: what one who has the tag key (or breaks X25519) can do."""
    parts = kk._split1(message1)
    mode = kk._mode_prologue(prologue, parts.kem_public)
    body = message2[:-kk.TAG_LEN]
    return body + kk._tag(kk.pair_mac_key(DRONE.private, GS.public), b"2", mode, parts.noise, body)


def _retag1(message1: bytes, prologue: bytes, kem_public: bytes) -> bytes:
    body = message1[:-kk.TAG_LEN]
    return body + kk._tag(kk.pair_mac_key(GS.private, DRONE.public), b"1", kk._mode_prologue(prologue, kem_public), body)


@pytest.mark.parametrize("case", VECTORS["cases"], ids=lambda c: "hybrid" if c["hybrid"] else "classical")
def test_vectors(case):
    v = VECTORS
    gs, drone = Identity(bytes.fromhex(v["gs_private"])), Identity(bytes.fromhex(v["drone_private"]))
    ini = PairingInitiator(gs, v["gs"], v["drone"], drone.public, ephemeral=bytes.fromhex(v["ephemeral"]),
                           stamp=case["stamp"], hybrid=case["hybrid"],
                           kem_seed=bytes.fromhex(v["kem_seed"]) if case["hybrid"] else None)
    assert ini.start().hex() == case["message1"]  # the wire format of message 1 is fixed
    key = ini.finish(bytes.fromhex(case["message2"]))
    assert isinstance(key, LinkKey)
    assert key.same_as(LinkKey.from_secret(v["drone"], v["gs"], bytes.fromhex(v["link_secret"])))
    # the drone accepts the vector's message 1 (its own answer is fresh randomness each time)
    out = respond(drone, v["drone"], v["gs"], gs.public, bytes.fromhex(case["message1"]), SECRET)
    assert not isinstance(out, PairingFailed)


def test_hybrid_both_sides_get_the_same_key_and_the_sizes():
    ini = PairingInitiator(GS, "A", "d1", DRONE.public, hybrid=True)
    m1 = ini.start()
    m2, drone_key = respond(DRONE, "d1", "A", GS.public, m1, SECRET)
    gs_key = ini.finish(m2)
    assert isinstance(gs_key, LinkKey) and gs_key.same_as(drone_key)
    assert len(m1) == 48 + kk.KEM_PUBLIC_LEN + 8 + 16
    assert len(m2) == 32 + 33 + 16 + kk.KEM_CIPHERTEXT_LEN + 16  # e, the sealed secret, ciphertext, tag
    assert kk.is_hybrid(m1) and SECRET not in m1 + m2


@pytest.mark.parametrize("where", [0, 500, kk.KEM_CIPHERTEXT_LEN - 1])
def test_a_tampered_ciphertext_fails_the_pairing(where):
    ini = PairingInitiator(GS, "A", "d1", DRONE.public, hybrid=True)
    m1 = ini.start()
    m2, _ = respond(DRONE, "d1", "A", GS.public, m1, SECRET)
    at = len(m2) - kk.TAG_LEN - kk.KEM_CIPHERTEXT_LEN + where
    bad = bytearray(m2)
    bad[at] ^= 0x01
    # as sent: the cheap tag already refuses it
    assert ini.finish(bytes(bad)) == PairingFailed("drone d1 did not prove the fleet's static key (bad_mac)")
    # with the tag made again (one who broke X25519 could): the KEM secret differs, the payload does not open
    out = ini.finish(_retag2(bytes(bad), m1, _prologue("d1", "A")))
    assert out == PairingFailed("drone d1 did not prove the fleet's static key (auth_failed)")
    assert isinstance(ini.finish(m2), LinkKey)  # the genuine reply still completes it


def test_a_swapped_kem_key_in_message1_fails_at_the_drone():
    ini = PairingInitiator(GS, "A", "d1", DRONE.public, hybrid=True)
    m1 = ini.start()
    other = kk.KKInitiator(GS, DRONE.public, b"x", hybrid=True).message1
    kem = other[48:48 + kk.KEM_PUBLIC_LEN]
    swapped = _retag1(m1[:48] + kem + m1[48 + kk.KEM_PUBLIC_LEN:], _prologue("d1", "A"), kem)
    out = respond(DRONE, "d1", "A", GS.public, swapped, SECRET)
    assert isinstance(out, PairingFailed) and "auth_failed" in out.reason


def test_a_hybrid_reply_stripped_to_classical_fails():
    ini = PairingInitiator(GS, "A", "d1", DRONE.public, hybrid=True)
    m1 = ini.start()
    m2, _ = respond(DRONE, "d1", "A", GS.public, m1, SECRET)
    stripped = m2[:-(kk.TAG_LEN + kk.KEM_CIPHERTEXT_LEN)]
    tag = kk._tag(kk.pair_mac_key(DRONE.private, GS.public), b"2", _prologue("d1", "A"), m1[:48], stripped)
    assert isinstance(ini.finish(stripped + tag), PairingFailed)


def _responder(require_hybrid: bool) -> PairingResponder:
    return PairingResponder(DRONE, "d1", {"A": GS.public}, frozenset({"A"}), require_hybrid=require_hybrid)


def test_a_classical_pairing_is_refused_once_hybrid_is_required():
    r = _responder(True)
    ans = r.answer("A", PairingInitiator(GS, "A", "d1", DRONE.public).start(), 0.0, SECRET)
    assert ans == PairRefused(PairRefusal.DOWNGRADE, "the fleet requires the hybrid (ML-KEM-768) pairing")
    assert not ans.silent and not ans.crypto  # answered (the GS learns why), no handshake computed
    # a forged classical message 1 is still only a bad tag, silently dropped
    forged = r.answer("A", PairingInitiator(STRANGER, "A", "d1", DRONE.public).start(), 0.0, SECRET)
    assert forged == PairRefused(PairRefusal.BAD_MAC)
    assert isinstance(r.answer("A", PairingInitiator(GS, "A", "d1", DRONE.public, hybrid=True).start(), 0.0,
                               SECRET), PairAccepted)


def test_classical_still_works_when_hybrid_is_off_and_hybrid_is_accepted_too():
    r = _responder(False)
    for hybrid in (False, True):
        ini = PairingInitiator(GS, "A", "d1", DRONE.public, hybrid=hybrid)
        ans = r.answer("A", ini.start(), 0.0, SECRET)
        assert isinstance(ans, PairAccepted)
        assert isinstance(ini.finish(ans.reply), LinkKey)


def test_a_message1_of_no_known_length_is_malformed():
    m1 = PairingInitiator(GS, "A", "d1", DRONE.public, hybrid=True).start()
    assert _responder(False).answer("A", m1[:700], 0.0, SECRET) == PairRefused(PairRefusal.MALFORMED)


def test_key_sharing_hybrid_and_no_downgrade():
    owner = KeyShareResponder(DRONE, "B", rate=100.0, burst=100.0, require_hybrid=True)
    classical = KeyShareAsk(GS, "A", "B", DRONE.public, "d1", 0.0)
    out = owner.answer("d1", "A", GS.public, classical._kk.message1, 0.0, SECRET)
    assert isinstance(out, Refused) and out.reason is ShareRefusal.DOWNGRADE
    ask = KeyShareAsk(GS, "A", "B", DRONE.public, "d1", 0.0, hybrid=True)
    out = owner.answer("d1", "A", GS.public, ask._kk.message1, 0.0, SECRET)
    assert isinstance(out, tuple) and ask.on_reply(out[0], 0.0) == SECRET


def test_the_fleet_setting_reads_and_is_left_out_when_off():
    raw = {"version": 1, "nodes": {}}
    assert parse_fleet(json.dumps(raw)).pairing_pq is False
    assert "pairing_pq" not in encode_fleet(parse_fleet(json.dumps(raw)))
    on = parse_fleet(json.dumps({**raw, "pairing_pq": True}))
    assert on.pairing_pq and parse_fleet(encode_fleet(on)).pairing_pq
