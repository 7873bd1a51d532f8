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
