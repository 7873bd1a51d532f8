"""Key sharing across a fleet (gs.linking): every other GS asked at once, the queries out to one owner
bounded, and the owner's bucket sized to the drones both GSs serve."""

from collections import Counter

import pytest

from gs.actions import Ask, AskKind
from gs.linking import ASK_WAIT_S, ASKS_IN_FLIGHT, LINKKEY_BURST, Context, KeyOwner, Linking
from zdrone.core.ratelimit import RateLimiter
from zdrone.fleet.files import init_fleet, load_fleet, load_secret, scale_nodes

K = ASKS_IN_FLIGHT + 6


@pytest.fixture(scope="module")
def fleet_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("fleet")
    init_fleet(d, nodes_spec=scale_nodes(K, 3))
    return d


def _linkings(fleet_dir, n: int) -> list[Linking]:
    fleet = load_fleet(fleet_dir)
    me, counters, out = load_secret(fleet_dir, "A", fleet).identity, Counter(), {}
    return [Linking(Context("A", f"d{i + 1}", me, fleet, counters, asks_out=out)) for i in range(n)]


def _asks(actions) -> list[Ask]:
    return [a for a in actions if isinstance(a, Ask) and a.kind is AskKind.LINKKEY]


def test_every_other_gs_is_asked_at_once(fleet_dir):
    (lk,) = _linkings(fleet_dir, 1)
    assert sorted(a.gs for a in _asks(lk.share_keys(0.0, 0.0, lambda m: []))) == ["B", "C"]


def test_queries_out_to_one_owner_are_bounded_and_freed(fleet_dir):
    lks = _linkings(fleet_dir, K)
    asked = [_asks(lk.share_keys(0.0, 0.0, lambda m: [])) for lk in lks]
    to_b = [i for i, a in enumerate(asked) if any(x.gs == "B" for x in a)]
    assert len(to_b) == ASKS_IN_FLIGHT and lks[0].ctx.counters["linkkey_ask_waited"] > 0
    waiting = lks[K - 1]
    assert waiting.deadline(0.0, sharing=True) == pytest.approx(ASK_WAIT_S)  # looks again soon
    lks[to_b[0]].on_share_reply("B", None, b"unauthorized", 0.1)  # an answer frees its place
    assert any(x.gs == "B" for x in _asks(waiting.share_keys(0.2, 0.2, lambda m: [])))


def test_owner_bucket_holds_a_handshake_per_shared_drone(fleet_dir, tmp_path):
    fleet = load_fleet(fleet_dir)
    owner = KeyOwner(load_secret(fleet_dir, "B", fleet).identity, "B", fleet, Counter())
    assert owner.responder.limiter.burst == K and owner.responder.limiter.rate == 5.0
    init_fleet(tmp_path / "small")
    small = load_fleet(tmp_path / "small")
    assert KeyOwner(load_secret(tmp_path / "small", "B", small).identity, "B", small,
                    Counter()).responder.limiter.burst == LINKKEY_BURST


def test_set_burst_fills_no_bucket():
    lim = RateLimiter(5.0, 10.0)
    assert all(lim.allow("A", 0.0) for _ in range(10)) and not lim.allow("A", 0.0)
    lim.set_burst(300.0)
    assert not lim.allow("A", 0.0) and lim.allow("A", 0.2)  # the rate refills it, not the new depth
    lim.set_burst(2.0)
    assert lim._buckets["A"].tokens <= 2.0


def test_an_unanswered_pairing_query_ends_its_exchange_and_is_asked_again_soon(fleet_dir):
    from gs.linking import PairDue, PairPhase, Reply, UNANSWERED_RETRY_S

    (lk,) = _linkings(fleet_dir, 1)
    out, _ = lk.on_pair(PairDue(0.0, 0.0, unanswered=UNANSWERED_RETRY_S))
    m1 = out[0].payload
    lk.pair_unanswered(b"another exchange's", 0.01)
    assert lk.pair_phase is PairPhase.ASKING  # not its message 1: nothing
    lk.pair_unanswered(m1, 0.01)
    assert lk.pair_phase is PairPhase.IDLE and lk.ctx.counters["pair_unanswered"] == 1
    assert lk.pair_retry_due(0.01, 2.0, UNANSWERED_RETRY_S) == pytest.approx(UNANSWERED_RETRY_S)
    assert lk.pair_retry_due(0.01, 1.0) == pytest.approx(1.0)  # a silent drone's slow retry stays slow
    due = PairDue(0.2, 0.2, unanswered=UNANSWERED_RETRY_S)
    assert lk.on_pair(due)[0] == [] and lk.on_pair(PairDue(0.5, 0.5, unanswered=UNANSWERED_RETRY_S))[0]  # not 2 s
    m1 = lk._m1
    lk.on_pair(Reply(0.6, None, b"outside_coverage"))  # answered (refused): its end closes nothing
    lk.pair_unanswered(m1, 0.61)
    assert lk.pair_phase is PairPhase.ASKING and lk.pair_retry_due(0.61, 2.0, UNANSWERED_RETRY_S) == pytest.approx(3.5)
