"""Key confirmation: no new key replaces a live one until its holder proves it (attacks 2 and 3)."""

from __future__ import annotations

from hypothesis import given, settings, strategies as st

from tests.corepair import make_pair
from zdrone.core.envelope import DropReason, Dropped, Opened
from zdrone.core.keys import Identity
from zdrone.core.linkslot import MAX_CANDIDATES, PREVIOUS_GRACE, LinkSlot
from zdrone.core.pairing import PairingInitiator, respond
from zdrone.core.tbm import LinkState

OLD, NEW, OTHER = bytes(range(32)), bytes(range(1, 33)), bytes(range(2, 34))


def drone_slot(now: float = 0.0):
    p = make_pair(OLD, now=now)
    slot = LinkSlot()
    slot.install(p.drone, now)
    return p, slot


def test_replayed_pairing_never_replaces_the_live_link():
    """Attack 3: a captured message 1 replayed in flight yields a candidate; the live key keeps working,
    the candidate expires unproven, and nothing is counted against the live link meanwhile."""
    drone_id, gs_id = Identity(bytes([1]) * 32), Identity(bytes([2]) * 32)
    p, slot = drone_slot()
    m1 = PairingInitiator(gs_id, "A", "d1", drone_id.public).start()  # captured earlier
    _msg2, key = respond(drone_id, "d1", "A", gs_id.public, m1, NEW)  # type: ignore[misc]
    cand = make_pair(NEW).drone
    assert cand.key.same_as(key)
    slot.offer(cand, 1.0, "pair", ttl=10.0)
    for i in range(50):  # the real GS goes on under the old key
        res, promoted = slot.open(p.gs.seal(p.heartbeat()), 1.0 + 0.1 * i)
        assert isinstance(res, Opened) and promoted is None
    assert slot.live is p.drone and sum(p.drone.drops.values()) == 0
    slot.expire(20.0)
    assert slot.candidates == [] and slot.expired == 1 and slot.live is p.drone


def test_candidate_proven_by_its_holder_becomes_live_and_carries_the_link_state():
    p, slot = drone_slot()
    slot.open(p.gs.seal(p.heartbeat()), 0.1)
    assert p.drone.tbm.poll(0.2) is LinkState.OK
    q = make_pair(NEW, now=1.0)
    slot.offer(q.drone, 1.0, "pair")
    res, promoted = slot.open(q.gs.seal(q.heartbeat()), 1.1)
    assert isinstance(res, Opened) and promoted is not None and promoted.replaced and promoted.origin == "pair"
    assert slot.live is q.drone and slot.candidates == []
    assert q.drone.tbm.poll(1.2) is None  # OK already reported for this link: no spurious change
    assert q.drone.tbm.poll(5.0) is LinkState.LOST  # and a silent new key is reported LOST
    # frames in flight under the old key still open during the grace period, then no more
    assert isinstance(slot.open(p.gs.seal(p.heartbeat()), 1.2)[0], Opened)
    late = slot.open(p.gs.seal(p.heartbeat()), 1.1 + PREVIOUS_GRACE + 0.1)[0]
    assert isinstance(late, Dropped) and late.reason is DropReason.AUTH_FAILED


def test_forged_frames_are_counted_once_on_the_live_link():
    p, slot = drone_slot()
    slot.offer(make_pair(NEW).drone, 0.0, "pair")
    forger = make_pair(OTHER)
    for _ in range(7):
        res, promoted = slot.open(forger.gs.seal(forger.heartbeat()), 0.5)
        assert isinstance(res, Dropped) and promoted is None
    assert p.drone.drops[DropReason.AUTH_FAILED] == 7
    assert all(sum(c.link.drops.values()) == 0 for c in slot.candidates)


def test_candidates_are_bounded():
    _, slot = drone_slot()
    for i in range(MAX_CANDIDATES + 5):
        slot.offer(make_pair(bytes([i]) * 32).drone, float(i), f"linkkey:{i}", ttl=100.0)
    assert len(slot.candidates) == MAX_CANDIDATES


def test_a_newer_candidate_of_the_same_origin_replaces_the_older():
    """Review F3: replays from one origin used to evict another origin's candidate."""
    _, slot = drone_slot()
    slot.offer(make_pair(bytes([1]) * 32).drone, 0.0, "grant", ttl=100.0)
    for i in range(10):
        slot.offer(make_pair(bytes([i + 2]) * 32).drone, float(i), "pair", ttl=100.0)
    assert [c.origin for c in slot.candidates] == ["grant", "pair"]


def test_empty_slot_counts_drops_as_unlinked():
    slot = LinkSlot()
    res, _ = slot.open(b"junk" * 10, 0.0)
    assert isinstance(res, Dropped) and slot.unlinked[res.reason] == 1


def test_owner_answering_a_linkkey_query_keeps_its_live_link():
    """Attack 2: B's password, a query claiming to be B; even a genuine query only adds a candidate."""
    p, slot = drone_slot()  # here: A's side of link (d1, A) is the "live" one
    slot.offer(make_pair(NEW).gs, 0.5, "linkkey:B", ttl=900.0)
    res, promoted = slot.open(p.gs.seal(p.heartbeat()), 0.6)
    assert isinstance(res, Opened) and promoted is None and slot.live is p.drone


@settings(max_examples=100, deadline=None)
@given(st.lists(st.binary(max_size=120), max_size=20))
def test_garbage_never_raises_nor_promotes(blobs):
    p, slot = drone_slot()
    slot.offer(make_pair(NEW).drone, 0.0, "pair")
    for b in blobs:
        res, promoted = slot.open(b, 0.1)
        assert isinstance(res, Dropped) and promoted is None
    assert slot.live is p.drone


def test_a_third_partys_candidate_never_replaces_a_live_link_that_is_alive():
    """Issue 18, key escrow: a secret handed out over the backhaul (or granted by the authority) is a
    candidate; an authentic frame under it, forged by whoever obtained the secret, changes nothing
    while the live link is alive, and is counted."""
    for origin in ("linkkey:B", "grant"):
        p, slot = drone_slot()
        slot.open(p.gs.seal(p.heartbeat()), 0.1)
        q = make_pair(NEW, now=1.0)
        slot.offer(q.drone, 1.0, origin)
        res, promoted = slot.open(q.gs.seal(q.heartbeat()), 1.1)
        assert isinstance(res, Dropped) and promoted is None and slot.live is p.drone and slot.live_protected == 1
        res, _ = slot.open(p.gs.seal(p.heartbeat()), 1.2)  # the real peer goes on under the live key
        assert isinstance(res, Opened)
        # once the live link is LOST (3 s of silence), a backhaul secret may be proven (the drone restarted);
        # a grant never replaces a live key
        res, promoted = slot.open(q.gs.seal(q.heartbeat()), 4.5)
        if origin == "grant":
            assert isinstance(res, Dropped) and slot.live is p.drone and slot.live_protected == 2
        else:
            assert isinstance(res, Opened) and promoted is not None and slot.live is q.drone


def test_a_backhaul_key_that_replaced_a_lost_link_gives_way_when_the_peer_speaks_under_the_old_one():
    """Issue 18, key escrow while the answering GS's link is LOST (the drone away): the asker proves the
    escrowed secret and replaces the LOST live key; the drone, back in range, still speaks under the old
    key, and the slot takes it back at once."""
    p, slot = drone_slot()
    slot.open(p.gs.seal(p.heartbeat()), 0.1)
    q = make_pair(NEW, now=1.0)
    slot.offer(q.drone, 1.0, "linkkey:B")
    res, promoted = slot.open(q.gs.seal(q.heartbeat()), 5.0)  # 4.9 s of silence: LOST, the forged proof
    assert promoted is not None and slot.live is q.drone and slot.fallback is p.drone
    res, promoted = slot.open(p.gs.seal(p.heartbeat()), 6.0)  # the real peer is back under the old key
    assert isinstance(res, Opened) and promoted is not None and promoted.origin == "revert"
    assert slot.live is p.drone and slot.fallback is None


def test_the_fallback_is_the_peers_own_key_however_often_a_third_party_replaces_it():
    p, slot = drone_slot()
    slot.open(p.gs.seal(p.heartbeat()), 0.1)
    for i, secret in enumerate((NEW, OTHER)):  # escrowed twice while the link stays LOST
        q = make_pair(secret, now=1.0)
        slot.offer(q.drone, 5.0 + i, "linkkey:B")
        res, promoted = slot.open(q.gs.seal(q.heartbeat()), 5.0 + 4.0 * i)
        assert promoted is not None and slot.fallback is p.drone
    res, promoted = slot.open(p.gs.seal(p.heartbeat()), 20.0)
    assert promoted is not None and promoted.origin == "revert" and slot.live is p.drone and slot.fallback is None


def test_a_drop_after_authentication_is_counted_once():
    """Issue 29: replays (authentic, then refused by the replay window) were counted twice, by the link's
    ``open`` and again by the slot; each is one drop, on the live link and on a candidate alike."""
    p, slot = drone_slot()
    frames = [p.gs.seal(p.heartbeat()) for _ in range(3)]
    for f in frames:
        assert isinstance(slot.open(f, 0.1)[0], Opened)
    for f in frames * 5:  # 15 replays
        res, _ = slot.open(f, 0.2)
        assert isinstance(res, Dropped) and res.reason is DropReason.REPLAY
    assert p.drone.drops[DropReason.REPLAY] == 15 and sum(p.drone.drops.values()) == 15
    q = make_pair(NEW, now=1.0)  # a candidate's drops after authentication: once, on the candidate
    slot.offer(q.drone, 1.0, "pair")
    first = q.gs.seal(q.heartbeat())
    assert slot.open(first, 1.1)[1] is not None  # proven: live now
    for _ in range(4):
        slot.open(first, 1.2)
    assert q.drone.drops[DropReason.REPLAY] == 4 and p.drone.drops[DropReason.REPLAY] == 15
