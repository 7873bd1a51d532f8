"""GS-to-GS key sharing (Noise KK as query and reply): what an attacker with router passwords gets."""

from hypothesis import given, settings, strategies as st

from zdrone.core.keys import Identity
from zdrone.core.keyshare import KeyShareAsk, KeyShareResponder, Refused, ShareRefusal, answer, decode_query

A, B, X = Identity(bytes([5]) * 32), Identity(bytes([6]) * 32), Identity(bytes([7]) * 32)
SECRET = bytes(range(32))


def ask(me: Identity = A, asker: str = "A", owner_public: bytes = B.public, now: float = 0.0) -> KeyShareAsk:
    return KeyShareAsk(me, asker, "B", owner_public, "d1", now)


def test_owner_answers_an_authentic_query_and_only_the_asker_reads_the_secret():
    a = ask()
    q = decode_query(a.payload)
    assert not isinstance(q, Refused) and q.asker == "A" and len(q.m1) == 48 + 8 + 16  # Noise message 1, time stamp, pair tag
    reply = answer(B, "B", "d1", "A", A.public, q.m1, SECRET)
    assert isinstance(reply, bytes) and SECRET not in reply and len(reply) == 32 + 32 + 16 + 16
    assert a.on_reply(reply, 1.0) == SECRET


def test_query_claiming_another_gs_without_its_key_is_refused_before_any_secret():
    """Attack 2: a stolen router password of B, claiming asker B, without B's private key."""
    forged = KeyShareAsk(X, "A", "B", B.public, "d1", 0.0)  # X signs as "A"
    q = decode_query(forged.payload)
    assert not isinstance(q, Refused)
    out = answer(B, "B", "d1", "A", A.public, q.m1, SECRET)
    assert isinstance(out, Refused) and out.reason is ShareRefusal.BAD_MAC  # refused by the tag: no DH


def test_reply_from_anyone_but_the_owner_is_refused_and_does_not_spoil_the_ask():
    """Attack 1: the attacker answers (before or after the real owner) with its own secret."""
    a = ask()
    q = decode_query(a.payload)
    assert isinstance(answer(X, "B", "d1", "A", A.public, q.m1, bytes(32)), Refused)  # X cannot even read it
    other = KeyShareAsk(A, "A", "B", X.public, "d1", 0.0)  # a well-formed message 2 made with X's key
    evil = answer(X, "B", "d1", "A", A.public, decode_query(other.payload).m1, bytes(32))  # type: ignore[union-attr]
    assert isinstance(evil, bytes)
    got = a.on_reply(evil, 0.5)
    assert isinstance(got, Refused) and got.reason is ShareRefusal.BAD_MAC
    assert isinstance(a.on_reply(b"\x00" * 80, 0.6), Refused)
    real = answer(B, "B", "d1", "A", A.public, q.m1, SECRET)
    assert a.on_reply(real, 0.7) == SECRET  # the genuine reply still opens


def test_one_authentic_reply_per_ask_and_replays_do_not_open():
    a1, a2 = ask(), ask()
    r1 = answer(B, "B", "d1", "A", A.public, decode_query(a1.payload).m1, SECRET)  # type: ignore[union-attr]
    assert a1.on_reply(r1, 0.1) == SECRET
    second = answer(B, "B", "d1", "A", A.public, decode_query(a1.payload).m1, bytes(32))  # type: ignore[union-attr]
    late = a1.on_reply(second, 0.2)
    assert isinstance(late, Refused) and late.reason is ShareRefusal.NOT_WAITING
    replay = a2.on_reply(r1, 0.1)  # a captured reply to an earlier ask: bound to the old message 1
    assert isinstance(replay, Refused) and replay.reason is ShareRefusal.BAD_MAC


def test_transcript_bound_to_drone_owner_and_asker():
    a = ask()
    m1 = decode_query(a.payload).m1  # type: ignore[union-attr]
    assert isinstance(answer(B, "B", "d2", "A", A.public, m1, SECRET), Refused)
    assert isinstance(answer(B, "C", "d1", "A", A.public, m1, SECRET), Refused)


def test_expired_ask_accepts_nothing():
    a = ask(now=0.0)
    reply = answer(B, "B", "d1", "A", A.public, decode_query(a.payload).m1, SECRET)  # type: ignore[union-attr]
    out = a.on_reply(reply, 100.0)
    assert isinstance(out, Refused) and out.reason is ShareRefusal.NOT_WAITING


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=400))
def test_garbage_never_raises(data):
    q = decode_query(data)
    assert isinstance(q, Refused) or q.asker is not None
    a = ask()
    assert isinstance(a.on_reply(data, 0.1), Refused)
    assert isinstance(answer(B, "B", "d1", "A", A.public, data[:256], SECRET), Refused)


def test_bad_utf8_in_the_asker_name_is_malformed_not_a_crash():
    import msgspec

    payload = msgspec.msgpack.encode({"asker": "A", "m1": b"x"}).replace(b"\xa1A", b"\xa1\xff")
    q = decode_query(payload)
    assert isinstance(q, Refused) and q.reason is ShareRefusal.MALFORMED


def test_forged_replies_cost_no_attempt_so_a_flood_cannot_exhaust_the_ask():
    """Review F2: 8+ forged replies used to exhaust the ask before the real B's reply arrived."""
    a = ask()
    for i in range(1000):
        got = a.on_reply(bytes([i % 256]) * 96, 0.1)
        assert isinstance(got, Refused) and got.reason is ShareRefusal.BAD_MAC
    real = answer(B, "B", "d1", "A", A.public, decode_query(a.payload).m1, SECRET)  # type: ignore[union-attr]
    assert a.on_reply(real, 0.2) == SECRET


def test_responder_checks_the_tag_before_the_rate_limit_and_repeats_its_answer():
    """Review F2/F3: forged queries in A's name must not spend A's tokens; a replayed query gets the
    same answer and makes no new secret."""
    r = KeyShareResponder(B, "B", rate=1.0, burst=2.0)
    for _ in range(50):
        forged = KeyShareAsk(X, "A", "B", B.public, "d1", 0.0)
        out = r.answer("d1", "A", A.public, decode_query(forged.payload).m1, 0.0, SECRET)  # type: ignore[union-attr]
        assert isinstance(out, Refused) and out.reason is ShareRefusal.BAD_MAC
    a = ask()
    m1 = decode_query(a.payload).m1  # type: ignore[union-attr]
    first = r.answer("d1", "A", A.public, m1, 0.0, SECRET)
    assert isinstance(first, tuple) and first[1] is True  # a fresh secret
    for t in (0.1, 5.0, 29.0):
        again = r.answer("d1", "A", A.public, m1, t, bytes(32))
        assert again == (first[0], False)  # the same message 2, no new secret
    late = r.answer("d1", "A", A.public, m1, 61.0, bytes(32))  # review N2: after the cache, a replay is stale
    assert isinstance(late, Refused) and late.reason is ShareRefusal.STALE
    assert a.on_reply(first[0], 0.2) == SECRET
    second = ask()
    out = r.answer("d1", "A", A.public, decode_query(second.payload).m1, 0.0, bytes(32))  # type: ignore[union-attr]
    assert isinstance(out, tuple) and out[1] is True
    third = ask()
    limited = r.answer("d1", "A", A.public, decode_query(third.payload).m1, 0.0, bytes(32))  # type: ignore[union-attr]
    assert isinstance(limited, Refused) and limited.reason is ShareRefusal.RATE_LIMITED  # burst 2 spent by A itself


def test_the_time_stamp_is_under_the_tag_and_checked_against_the_owners_clock():
    """Review N2: a query captured and replayed after the response cache forgot it is refused."""
    r = KeyShareResponder(B, "B", rate=10.0, burst=10.0)
    old = KeyShareAsk(A, "A", "B", B.public, "d1", 0.0, wall=1_000.0)
    m1 = decode_query(old.payload).m1  # type: ignore[union-attr]
    out = r.answer("d1", "A", A.public, m1, 0.0, SECRET, wall=1_031.0)
    assert isinstance(out, Refused) and out.reason is ShareRefusal.STALE
    future = KeyShareAsk(A, "A", "B", B.public, "d1", 0.0, wall=2_000.0)
    out = r.answer("d1", "A", A.public, decode_query(future.payload).m1, 0.0, SECRET, wall=1_000.0)  # type: ignore[union-attr]
    assert isinstance(out, Refused) and out.reason is ShareRefusal.STALE
    bumped = bytearray(m1)
    bumped[-24:-16] = bytes(8)  # the stamp, moved to 0.0 by someone without the tag key
    out = r.answer("d1", "A", A.public, bytes(bumped), 0.0, SECRET, wall=0.0)
    assert isinstance(out, Refused) and out.reason is ShareRefusal.BAD_MAC
    assert isinstance(r.answer("d1", "A", A.public, m1, 0.0, SECRET, wall=1_010.0), tuple)
