from zdrone.core.keys import Identity
from zdrone.core.pairing import PairingFailed, PairingInitiator, respond

DRONE, GS, STRANGER = Identity(bytes([1]) * 32), Identity(bytes([2]) * 32), Identity(bytes([3]) * 32)
GS2 = Identity(bytes([4]) * 32)
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
    assert len(m1) == 48 + 8 + 16  # Noise message 1, time stamp, pair tag


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


def _responder(rate: float = 1.0, burst: float = 2.0):
    from zdrone.core.pairing import PairingResponder

    x = Identity(bytes([9]) * 32)
    return PairingResponder(DRONE, "d1", {"A": GS.public, "B": GS2.public, "X": x.public}, frozenset({"A", "B"}),
                            rate=rate, burst=burst)


def test_pairing_responder_refuses_cheapest_first_and_rate_limits_only_authentic_queries():
    r = _responder()
    m1 = PairingInitiator(GS, "A", "d1", DRONE.public).start()
    assert r.answer("Z", m1, 0.0, SECRET).refused == "unknown"
    assert r.answer("X", m1, 0.0, SECRET).refused == "unauthorized"
    assert r.answer("A", m1, 0.0, SECRET, policy="failsafe: re-pair only on the ground").refused.startswith("failsafe")
    # forged in B's name (not B's key): silent, no crypto, no token spent
    for _ in range(20):
        forged = PairingInitiator(GS, "B", "d1", DRONE.public).start()
        ans = r.answer("B", forged, 0.0, SECRET)
        assert ans.refused == "bad_mac" and ans.silent and ans.reply is None and not ans.crypto
    answers = [r.answer("B", PairingInitiator(GS2, "B", "d1", DRONE.public).start(), 0.0, SECRET) for _ in range(3)]
    assert [a.key is not None for a in answers] == [True, True, False] and answers[2].refused == "rate_limited"
    assert r.answer("A", m1, 0.0, SECRET).key is not None  # per GS


def test_pairing_responder_answers_a_repeated_message1_with_the_same_reply_and_no_key():
    r = _responder()
    ini = PairingInitiator(GS, "A", "d1", DRONE.public)
    m1 = ini.start()
    first = r.answer("A", m1, 0.0, SECRET)
    assert first.key is not None and first.reply is not None
    for t in (0.5, 10.0, 59.0):
        again = r.answer("A", m1, t, bytes(32))
        assert again.reply == first.reply and again.key is None and again.refused == "repeated"
    key = ini.finish(first.reply)
    assert not isinstance(key, PairingFailed) and key.same_as(first.key)
    late = r.answer("A", m1, 61.0, bytes(32))  # the cache forgot it: a new candidate, which only A could prove
    assert late.key is not None and not late.key.same_as(first.key)
