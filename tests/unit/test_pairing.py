import dataclasses

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from zdrone.core.keys import Identity
from zdrone.core.pairing import (SILENT_REFUSALS, PairAccepted, PairingFailed, PairingInitiator, PairRefusal, PairRefused,
                                 PairRepeated, respond)

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
    assert r.answer("Z", m1, 0.0, SECRET) == PairRefused(PairRefusal.UNKNOWN)
    assert r.answer("X", m1, 0.0, SECRET) == PairRefused(PairRefusal.UNAUTHORIZED)
    policy = PairRefused(PairRefusal.FAILSAFE, "re-pair only on the ground")
    assert r.answer("A", m1, 0.0, SECRET, policy=policy) is policy
    assert policy.text == "failsafe: re-pair only on the ground" and not policy.silent
    # forged in B's name (not B's key): silent, no crypto, no token spent
    for _ in range(20):
        forged = PairingInitiator(GS, "B", "d1", DRONE.public).start()
        ans = r.answer("B", forged, 0.0, SECRET)
        assert ans == PairRefused(PairRefusal.BAD_MAC) and ans.silent and not ans.crypto and ans.refused == "bad_mac"
    answers = [r.answer("B", PairingInitiator(GS2, "B", "d1", DRONE.public).start(), 0.0, SECRET) for _ in range(3)]
    assert [type(a) for a in answers] == [PairAccepted, PairAccepted, PairRefused]
    assert answers[2] == PairRefused(PairRefusal.RATE_LIMITED) and answers[2].silent
    assert isinstance(r.answer("A", m1, 0.0, SECRET), PairAccepted)  # per GS


def test_pairing_responder_answers_a_repeated_message1_with_the_same_reply_and_no_key():
    r = _responder()
    ini = PairingInitiator(GS, "A", "d1", DRONE.public)
    m1 = ini.start()
    first = r.answer("A", m1, 0.0, SECRET)
    assert isinstance(first, PairAccepted) and first.crypto
    for t in (0.5, 10.0, 59.0):
        assert r.answer("A", m1, t, bytes(32)) == PairRepeated(first.reply)
    key = ini.finish(first.reply)
    assert not isinstance(key, PairingFailed) and key.same_as(first.key)
    late = r.answer("A", m1, 61.0, bytes(32))  # the cache forgot it: a new candidate, which only A could prove
    assert isinstance(late, PairAccepted) and not late.key.same_as(first.key)


def test_pair_results_are_frozen_and_each_refusal_has_one_tier():
    refused = PairRefused(PairRefusal.BAD_MAC)
    with pytest.raises(dataclasses.FrozenInstanceError):
        refused.reason = PairRefusal.STALE  # type: ignore[misc]
    with pytest.raises(dataclasses.FrozenInstanceError):
        PairRepeated(b"m2").reply = b""  # type: ignore[misc]
    # bad input: no answer, no crypto; authentic-looking but illegal: answered with the reason
    answered = {PairRefusal.UNKNOWN, PairRefusal.UNAUTHORIZED, PairRefusal.FAILSAFE, PairRefusal.OUTSIDE_COVERAGE,
                PairRefusal.FIRST_CLAIM, PairRefusal.AUTH_FAILED, PairRefusal.DOWNGRADE,
                    PairRefusal.LINKS_FULL, PairRefusal.LINKED}
    assert SILENT_REFUSALS | answered == set(PairRefusal) and not SILENT_REFUSALS & answered
    for reason in PairRefusal:
        r = PairRefused(reason)
        assert r.silent == (reason in SILENT_REFUSALS) and r.text == r.refused == reason.value
        assert r.crypto == (reason is PairRefusal.AUTH_FAILED)  # the only refusal after a handshake
    assert PairAccepted.crypto and not PairRepeated.crypto


def test_a_link_secret_of_the_wrong_length_is_a_programming_error():
    with pytest.raises(ValueError):
        _responder().answer("A", PairingInitiator(GS, "A", "d1", DRONE.public).start(), 0.0, bytes(31))


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=300), st.sampled_from(["A", "B", "X", "Z"]))
def test_any_bytes_as_message1_are_refused_silently_before_any_crypto(junk, gs):
    r = _responder()
    ans = r.answer(gs, junk, 0.0, SECRET)
    assert isinstance(ans, PairRefused) and not ans.crypto
    if gs in ("A", "B"):
        assert ans.reason in (PairRefusal.MALFORMED, PairRefusal.BAD_MAC) and ans.silent
        # no rate-limit token spent: the GS's genuine handshakes still go through
        for _ in range(2):
            m1 = PairingInitiator(GS if gs == "A" else GS2, gs, "d1", DRONE.public).start()
            assert isinstance(r.answer(gs, m1, 0.0, SECRET), PairAccepted)


QUERY = st.tuples(st.sampled_from(["A", "B", "X", "Z"]), st.sampled_from(["fresh", "forged", "again"]),
                  st.floats(0.0, 0.5, allow_nan=False))


@settings(max_examples=150, deadline=None)
@given(st.lists(QUERY, min_size=1, max_size=12))
def test_every_query_gets_one_result_that_matches_what_was_asked(queries):
    r = _responder(rate=1.0, burst=2.0)
    keys = {"A": GS, "B": GS2, "X": Identity(bytes([9]) * 32), "Z": STRANGER}
    sent: dict[str, tuple[bytes, bytes]] = {}  # gs -> (message 1, its first reply)
    now = 0.0
    for gs, kind, dt in queries:
        now += dt
        if kind == "again" and gs in sent:
            m1 = sent[gs][0]
        else:
            m1 = PairingInitiator(keys[gs] if kind != "forged" else STRANGER, gs, "d1", DRONE.public).start()
        ans = r.answer(gs, m1, now, SECRET)
        if gs == "Z":
            assert ans == PairRefused(PairRefusal.UNKNOWN)
        elif gs == "X":
            assert ans == PairRefused(PairRefusal.UNAUTHORIZED)
        elif kind == "forged":
            assert ans == PairRefused(PairRefusal.BAD_MAC)
        elif kind == "again" and gs in sent:
            assert ans == PairRepeated(sent[gs][1])  # the first answer again, whatever the rate limit
        elif isinstance(ans, PairAccepted):
            sent[gs] = (m1, ans.reply)
        else:
            assert ans == PairRefused(PairRefusal.RATE_LIMITED)


def test_a_gs_own_earlier_tries_replayed_around_a_restart_never_starve_it():
    """Issue 18, stale pairing: A's tries made while the companion was down, captured and replayed as
    it comes back, cost at most one handshake each, only if newer than every answer so far, and never
    keep A's own newest try from being answered; once A's newest is answered, every older one is stale."""
    from zdrone.core.pairing import PAIR_BURST, PairAccepted, PairingResponder

    ready = 1_800_000_000.0
    r = PairingResponder(DRONE, "d1", {"A": GS.public}, frozenset({"A"}), not_before=ready)
    tries = [PairingInitiator(GS, "A", "d1", DRONE.public, stamp=ready + dt).start() for dt in (-5.0, -0.8, -0.4)]
    genuine = PairingInitiator(GS, "A", "d1", DRONE.public, stamp=ready + 0.2).start()
    answers = [r.answer("A", m1, 0.0, SECRET, wall=ready + 0.3) for m1 in tries]
    assert [a.refused if not isinstance(a, PairAccepted) else "answered" for a in answers] == ["stale"] * 3
    late_try = PairingInitiator(GS, "A", "d1", DRONE.public, stamp=ready + 0.05).start()  # made after it was back
    assert isinstance(r.answer("A", late_try, 0.05, SECRET, wall=ready + 0.3), PairAccepted)
    assert isinstance(r.answer("A", genuine, 0.1, SECRET, wall=ready + 0.3), PairAccepted)
    assert r.answer("A", late_try, 0.2, SECRET, wall=ready + 0.4).__class__.__name__ == "PairRepeated"  # seen: same answer
    late = PairingInitiator(GS, "A", "d1", DRONE.public, stamp=ready + 0.1).start()  # never seen, older than answered
    assert r.answer("A", late, 0.3, SECRET, wall=ready + 0.4).refused == "stale"
    assert PAIR_BURST >= 2 * 5  # A's re-pairing rate (5/s) for two seconds of down time


def test_a_message_1_stamped_ahead_of_the_drone_clock_is_stale():
    """Review R2: a GS whose clock runs ahead would make its tries from while the companion was down
    look fresh; a stamp more than a second ahead of the drone's clock is stale."""
    from zdrone.core.pairing import MAX_AHEAD, PairAccepted, PairingResponder

    ready = 1_800_000_000.0
    r = PairingResponder(DRONE, "d1", {"A": GS.public}, frozenset({"A"}), not_before=ready)
    ahead = PairingInitiator(GS, "A", "d1", DRONE.public, stamp=ready + MAX_AHEAD + 4.0).start()
    assert r.answer("A", ahead, 0.0, SECRET, wall=ready + 0.5).refused == "stale"
    near = PairingInitiator(GS, "A", "d1", DRONE.public, stamp=ready + 1.2).start()
    assert isinstance(r.answer("A", near, 0.0, SECRET, wall=ready + 0.5), PairAccepted)
