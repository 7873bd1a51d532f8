"""The GS's linking sub-machine (gs.linking): both tables, every row and every pair not in them."""

from collections import Counter

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gs.actions import Ask, AskKind, Emit
from gs.linking import (PAIR_TABLE, SHARE_TABLE, Context, GrantAcked, KeysLost, Linking, PeerKeysLost, PairDue, PairPhase, Reply,
                        Share, ShareDue, SharePhase)
from zdrone.core import wire
from zdrone.core.keyshare import KeyShareAsk
from zdrone.core.pairing import PairingInitiator
from zdrone.fleet.files import init_fleet, load_fleet, load_secret


@pytest.fixture(scope="module")
def fleet_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("fleet")
    init_fleet(d)
    return d


def _linking(fleet_dir) -> Linking:
    fleet = load_fleet(fleet_dir)
    return Linking(Context("A", "d1", load_secret(fleet_dir, "A", fleet).identity, fleet, Counter()))


def _in_pair_phase(lk: Linking, phase: PairPhase, now: float) -> None:
    if phase is PairPhase.ASKING:
        c = lk.ctx
        lk.pairing = PairingInitiator(c.identity, "A", "d1", c.fleet.nodes["d1"].public_bytes, stamp=now)
        lk.pairing.start()
        lk.pairing_deadline = now + 3.0
    lk.pair_phase = phase


def _in_share_phase(lk: Linking, phase: SharePhase, now: float) -> None:
    s, c = lk.shares.setdefault("B", Share()), lk.ctx
    if phase is SharePhase.ASKED:
        s.ask = KeyShareAsk(c.identity, "A", "B", c.fleet.nodes["B"].public_bytes, "d1", now)
    if phase is SharePhase.GRANTING:
        s.grant = wire.KeyGrant("B", c.fleet.nodes["B"].sysid, bytes(32), 7)
    s.phase = phase


REPLIES = st.sampled_from([None, b"", b"\x00" * 48, b"x" * 80])
ERRORS = st.sampled_from([None, b"live_link", b"unauthorized"])
NOW = st.floats(0, 10)
PAIR_EVENTS = st.one_of(st.builds(PairDue, NOW, NOW, st.sampled_from([0.0, 0.2, 2.0]), st.sampled_from([0.2, 3.0])),
                        st.builds(Reply, NOW, REPLIES, ERRORS))
SHARE_EVENTS = st.one_of(st.builds(ShareDue, NOW, NOW), st.builds(Reply, NOW, REPLIES, ERRORS),
                         st.builds(GrantAcked, NOW, st.sampled_from([7, 8])), st.builds(KeysLost, NOW),
                         st.builds(PeerKeysLost, NOW, st.just(b"notice"), st.sampled_from([0.0, 5.0])))


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(phase=st.sampled_from(list(PairPhase)), ev=PAIR_EVENTS)
def test_pairing_follows_its_table(fleet_dir, phase, ev):
    lk = _linking(fleet_dir)
    _in_pair_phase(lk, phase, 1.0)
    expired = phase is PairPhase.ASKING and ev.now >= lk.pairing_deadline
    start = PairPhase.IDLE if expired else phase  # an exchange past its deadline is IDLE first
    row = PAIR_TABLE.get((start, type(ev)))
    out, paired = lk.on_pair(ev)
    if row is None:
        assert out == [] and paired is None and lk.pair_phase is start
    else:
        assert lk.pair_phase is start or lk.pair_phase in row[1]
    assert paired is None  # no event here carries a genuine message 2
    assert all(isinstance(x, (Ask, Emit)) for x in out)
    assert all(x.kind is AskKind.PAIR for x in out if isinstance(x, Ask))


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(phase=st.sampled_from(list(SharePhase)), ev=SHARE_EVENTS, linked=st.booleans())
def test_key_sharing_follows_its_table(fleet_dir, phase, ev, linked):
    lk = _linking(fleet_dir)
    lk.drone_listed({"A", "B"} if linked else {"A"}, -10.0)
    _in_share_phase(lk, phase, 1.0)
    row = SHARE_TABLE.get((phase, type(ev)))
    sent: list = []
    if isinstance(ev, ShareDue):
        out = lk.share_keys(ev.now, ev.wall, lambda m: sent.append(m) or [])
    elif isinstance(ev, Reply):
        out = lk.on_share_reply("B", ev.ok, ev.err, ev.now)
    elif isinstance(ev, GrantAcked):
        out = lk.on_grant_ack("B", ev.grant_id, ev.now)
    elif isinstance(ev, PeerKeysLost):
        lk.peer_keys_lost("B", ev.notice, ev.since, ev.now, ev.since)
        out = []
    else:
        lk.keys_lost(ev.now)
        out = []
    after = lk.shares["B"].phase
    if row is None:
        assert after is phase
        assert not [x for x in out if isinstance(x, Ask)]
    else:
        assert after is phase or after in row[1]
    assert all(isinstance(m, wire.KeyGrant) for m in sent)  # only grants are re-sent, and only while GRANTING
    assert not sent or phase is SharePhase.GRANTING


def test_a_grant_is_acknowledged_once_and_only_with_its_id(fleet_dir):
    lk = _linking(fleet_dir)
    _in_share_phase(lk, SharePhase.GRANTING, 1.0)
    assert lk.on_grant_ack("B", 8, 1.1) == [] and lk.granting("B")
    assert [x.kind for x in lk.on_grant_ack("B", 7, 1.2)] == ["key_granted"] and lk.granted("B")
    assert lk.on_grant_ack("B", 7, 1.3) == []
    lk.keys_lost(2.0)
    assert lk.shares["B"].phase is SharePhase.NONE and lk.drone_links == {"A"} and lk.lost_key_at == 2.0
