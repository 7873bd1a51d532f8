from zdrone.core.keys import Identity
from zdrone.core.pairing import PairingFailed, PairingInitiator, respond

DRONE, GS, STRANGER = Identity(bytes([1]) * 32), Identity(bytes([2]) * 32), Identity(bytes([3]) * 32)
SECRET = bytes(range(32))


def test_kk_both_sides_get_the_same_directional_keys():
    ini = PairingInitiator(GS, "A", "d1", DRONE.public)
    m1 = ini.start()
    out = respond(DRONE, "d1", "A", GS.public, m1, SECRET)
    assert not isinstance(out, PairingFailed)
    m2, drone_key = out
    gs_key = ini.finish(m2)
    assert not isinstance(gs_key, PairingFailed)
    assert gs_key.same_as(drone_key) and gs_key.up != gs_key.down
    assert SECRET not in m1 + m2  # never in clear
    assert len(m1) == 48


def test_initiator_without_fleet_key_fails():
    ini = PairingInitiator(STRANGER, "A", "d1", DRONE.public)
    out = respond(DRONE, "d1", "A", GS.public, ini.start(), SECRET)
    assert isinstance(out, PairingFailed) and "ground station A" in out.reason


def test_responder_without_fleet_key_fails():
    ini = PairingInitiator(GS, "A", "d1", DRONE.public)
    ini.start()  # the real GS sent its message 1; an impostor answers it
    fake = PairingInitiator(GS, "A", "d1", STRANGER.public)  # someone answering as d1 with another key
    out = respond(STRANGER, "d1", "A", GS.public, fake.start(), SECRET)
    assert not isinstance(out, PairingFailed)
    got = ini.finish(out[0])
    assert isinstance(got, PairingFailed) and "drone d1" in got.reason


def test_transcript_bound_to_names():
    ini = PairingInitiator(GS, "A", "d1", DRONE.public)
    out = respond(DRONE, "d1", "B", GS.public, ini.start(), SECRET)  # same keys, claimed as B
    assert isinstance(out, PairingFailed)


def test_garbage_message_fails_cleanly():
    assert isinstance(respond(DRONE, "d1", "A", GS.public, b"\x00" * 5, SECRET), PairingFailed)
    ini = PairingInitiator(GS, "A", "d1", DRONE.public)
    ini.start()
    assert isinstance(ini.finish(b"junk"), PairingFailed)


def test_forged_reply_does_not_spoil_the_genuine_one():
    ini = PairingInitiator(GS, "A", "d1", DRONE.public)
    m1 = ini.start()
    fake = respond(STRANGER, "d1", "A", GS.public, m1, SECRET)
    assert isinstance(fake, PairingFailed) or isinstance(ini.finish(fake[0]), PairingFailed)
    assert isinstance(ini.finish(b"\x01" * 80), PairingFailed)
    m2, drone_key = respond(DRONE, "d1", "A", GS.public, m1, SECRET)  # type: ignore[misc]
    key = ini.finish(m2)
    assert not isinstance(key, PairingFailed) and key.same_as(drone_key)
    assert isinstance(ini.finish(m2), PairingFailed)  # finished: a second reply changes nothing


def test_replayed_message1_gives_a_key_the_replayer_cannot_use():
    ini = PairingInitiator(GS, "A", "d1", DRONE.public)
    m1 = ini.start()
    first = respond(DRONE, "d1", "A", GS.public, m1, SECRET)
    replay = respond(DRONE, "d1", "A", GS.public, m1, bytes(32))  # KK cannot tell: hence key confirmation
    assert not isinstance(first, PairingFailed) and not isinstance(replay, PairingFailed)
    assert not first[1].same_as(replay[1])


def test_pairing_guard_refuses_before_crypto_and_rate_limits():
    from zdrone.core.pairing import PairingGuard

    g = PairingGuard(frozenset({"A", "B", "X"}), frozenset({"A", "B"}), rate=1.0, burst=2)
    assert g.admit("Z", 0.0) == "unknown" and g.admit("X", 0.0) == "unauthorized"
    assert [g.admit("B", 0.0) for _ in range(4)] == [None, None, "rate_limited", "rate_limited"]
    assert g.admit("A", 0.0) is None  # per peer
    assert g.admit("B", 1.0) is None and g.admit("B", 1.0) == "rate_limited"
