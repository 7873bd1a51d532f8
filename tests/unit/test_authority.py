"""The handover authority table: scenarios and a hypothesis sweep over every (state, event) pair."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from zdrone.core import authority as ha
from zdrone.core.authority import (AuthorityChanged, AuthorityMachine, FailsafeCommand, Config, DropFrame, Forward,
                                   Frame, GrantAccepted, GrantRejected, GrantRejection, HaDrop, AuthorityAsked,
                                   IllegalTransition, GrantHeard, LinkChanged, PairingDone, RegionChanged, Release,
                                   SendControl, State, Tick, check_grant)
from zdrone.core.pairing import PairRefusal, PairRefused
from zdrone.core.tbm import LinkState
from zdrone.core.uplink import UplinkClass
from zdrone.core.wire import FailsafeNotice, KeyGrant, OperatorRequest, Reject

AUTH = frozenset({"A", "B"})
RO, AO, DENIED = UplinkClass.READ_ONLY, UplinkClass.AUTHORITY_ONLY, UplinkClass.DENIED


def machine(inside: frozenset[str] = frozenset({"A"})) -> AuthorityMachine:
    """A machine whose vehicle is inside ``inside`` (home: A's coverage; the first pairing needs it)."""
    m = AuthorityMachine(Config(authorized=AUTH, handover_timeout=5.0))
    m.handle(RegionChanged(0.0, inside))
    return m


def linked_with_b(m: AuthorityMachine, now: float = 1.0) -> None:
    m.handle(PairingDone(now, "A"))
    m.handle(LinkChanged(now, "A", LinkState.OK))
    m.handle(GrantHeard(now, "A", "B"))


def prove(m: AuthorityMachine, gs: str, now: float, n: int = 2) -> list:
    acts = m.handle(LinkChanged(now, gs, LinkState.OK))
    for i in range(n):
        acts += m.handle(Frame(now + 0.01 * i, gs, RO))
    return acts


def test_first_pairing_gives_authority_epoch_1():
    m = machine()
    acts = m.handle(PairingDone(0.0, "A"))
    assert m.state is State.LINKED and m.owner == "A" and m.epoch == 1
    assert m.subscribed == {"A"} and AuthorityChanged(None, "A", 1, "paired") in acts


def test_unauthorized_gs_cannot_pair_and_gets_a_reject():
    m = machine()
    acts = m.handle(PairingDone(0.0, "X"))
    assert m.state is State.UNPAIRED and m.owner is None
    assert any(isinstance(a, SendControl) and isinstance(a.msg, Reject) and a.gs == "X" for a in acts)
    assert m.rejects["unauthorized"] == 1


def test_only_authority_commands_are_forwarded():
    m = machine()
    linked_with_b(m)
    assert m.handle(Frame(2.0, "A", AO)) == [Forward("A")]
    assert m.handle(Frame(2.0, "B", AO)) == [DropFrame("B", HaDrop.NOT_AUTHORITY)]
    assert m.handle(Frame(2.0, "B", RO)) == [Forward("B")]  # heartbeats, parameter reads
    assert m.handle(Frame(2.0, "X", AO)) == [DropFrame("X", HaDrop.NOT_LINKED)]
    assert m.handle(Frame(2.0, "X", RO)) == [DropFrame("X", HaDrop.NOT_LINKED)]
    assert m.drops[HaDrop.NOT_AUTHORITY] == 1 and m.drops[HaDrop.NOT_LINKED] == 2


def test_denied_frames_are_dropped_for_everyone():
    m = machine()
    linked_with_b(m)
    assert m.handle(Frame(2.0, "A", DENIED)) == [DropFrame("A", HaDrop.DENIED_BY_POLICY)]  # the owner too
    assert m.handle(Frame(2.0, "B", DENIED)) == [DropFrame("B", HaDrop.DENIED_BY_POLICY)]
    assert m.handle(Frame(2.0, "X", DENIED)) == [DropFrame("X", HaDrop.NOT_LINKED)]  # not linked comes first
    assert m.drops[HaDrop.DENIED_BY_POLICY] == 2 and m.drops[HaDrop.NOT_AUTHORITY] == 0


def test_denied_frames_still_prove_a_link():
    m = machine()
    linked_with_b(m)
    m.handle(Release(3.0, "A", "B", 1))
    m.handle(LinkChanged(3.1, "B", LinkState.OK))
    m.handle(Frame(3.2, "B", DENIED))
    acts = m.handle(Frame(3.3, "B", DENIED))
    assert m.owner == "B" and acts[0] == DropFrame("B", HaDrop.DENIED_BY_POLICY)


def test_make_before_break_handover():
    m = machine()
    linked_with_b(m)
    m.handle(RegionChanged(10.0, frozenset({"A", "B"})))
    assert m.in_region and "B" in m.subscribed
    acts = m.handle(Release(11.0, "A", "B", 1))
    assert m.state is State.HANDOVER_PENDING and m.owner == "A"  # B not proven yet: A keeps authority
    assert m.handle(Frame(11.1, "A", AO)) == [Forward("A")]
    acts = prove(m, "B", 11.2)
    assert m.state is State.LINKED and m.owner == "B" and m.epoch == 2
    assert AuthorityChanged("A", "B", 2, "handover") in acts
    assert m.handle(Frame(11.3, "A", AO)) == [DropFrame("A", HaDrop.NOT_AUTHORITY)]
    assert m.handle(Frame(11.3, "B", AO)) == [Forward("B")]
    m.handle(RegionChanged(20.0, frozenset({"B"})))
    assert m.subscribed == {"B"}
    # history: never a moment with no owner or two
    assert [(o, e) for _, o, e in m.history] == [("A", 1), ("B", 2)]


def test_release_to_proven_gs_switches_at_once():
    m = machine()
    linked_with_b(m)
    m.handle(RegionChanged(10.0, frozenset({"A", "B"})))
    prove(m, "B", 10.5)
    acts = m.handle(Release(11.0, "A", "B", 1))
    assert m.state is State.LINKED and m.owner == "B" and m.epoch == 2
    assert any(isinstance(a, AuthorityChanged) for a in acts)


def test_handover_timeout_leaves_authority_where_it_was():
    m = machine()
    linked_with_b(m)
    m.handle(Release(11.0, "A", "B", 1))
    m.handle(Tick(15.9))
    assert m.state is State.HANDOVER_PENDING
    m.handle(Tick(16.0))
    assert m.state is State.LINKED and m.owner == "A" and m.epoch == 1 and m.pending_to is None


def test_pending_recipient_lost_aborts():
    m = machine()
    linked_with_b(m)
    m.handle(Release(11.0, "A", "B", 1))
    m.handle(LinkChanged(11.0, "B", LinkState.DEGRADED))
    m.handle(LinkChanged(12.0, "B", LinkState.LOST))
    assert m.state is State.LINKED and m.owner == "A" and m.pending_to is None


def test_illegal_releases_are_rejected():
    m = machine()
    linked_with_b(m)
    for ev, why in [(Release(2.0, "B", "B", 1), "not the authority"), (Release(2.0, "A", "B", 7), "stale epoch"),
                    (Release(2.0, "A", "X", 1), "unauthorized"), (GrantHeard(2.0, "B", "A"), "not the authority")]:
        acts = m.handle(ev)
        rej = [a.msg for a in acts if isinstance(a, SendControl) and isinstance(a.msg, Reject)]
        assert rej and why in rej[0].reason, (ev, rej)
    m2 = machine()
    m2.handle(PairingDone(0.0, "A"))
    acts = m2.handle(Release(1.0, "A", "B", 1))
    assert "no link" in [a.msg for a in acts if isinstance(a, SendControl)][0].reason


def test_authority_link_lost_without_heir_is_failsafe_land():
    m = machine()
    m.handle(PairingDone(0.0, "A"))
    m.handle(LinkChanged(0.5, "A", LinkState.OK))
    acts = m.handle(LinkChanged(3.5, "A", LinkState.LOST))
    assert m.state is State.FAILSAFE
    assert FailsafeCommand("LAND", "authority link to A lost") in acts
    assert SendControl("A", FailsafeNotice("LAND", "authority link to A lost")) in acts
    assert m.handle(Frame(4.0, "A", AO)) == [DropFrame("A", HaDrop.FAILSAFE)]
    assert m.handle(Frame(4.0, "A", DENIED)) == [DropFrame("A", HaDrop.DENIED_BY_POLICY)]
    assert m.handle(Frame(4.0, "A", RO)) == [Forward("A")]
    assert m.handle(Frame(4.0, "B", RO)) == [DropFrame("B", HaDrop.NOT_LINKED)]
    # terminal until a GS re-pairs on the ground
    m.handle(PairingDone(5.0, "A", on_ground=False))
    assert m.state is State.FAILSAFE
    m.handle(PairingDone(8.0, "B", on_ground=True))  # a GS whose coverage does not hold the vehicle: no
    assert m.state is State.FAILSAFE and m.rejects["failsafe"] == 1 and m.rejects["outside_coverage"] == 1
    m.handle(PairingDone(9.0, "A", on_ground=True))
    assert m.state is State.LINKED and m.owner == "A" and m.epoch == 2


def test_rtl_failsafe_configurable():
    m = AuthorityMachine(Config(authorized=AUTH, failsafe_action="RTL"))
    m.handle(RegionChanged(0.0, frozenset({"A"})))
    m.handle(PairingDone(0.0, "A"))
    acts = m.handle(LinkChanged(3.5, "A", LinkState.LOST))
    assert any(isinstance(a, FailsafeCommand) and a.command == "RTL" for a in acts)


def test_authority_link_lost_with_proven_heir_is_emergency_handover():
    m = machine()
    linked_with_b(m)
    m.handle(RegionChanged(10.0, frozenset({"A", "B"})))
    prove(m, "B", 10.0)
    acts = m.handle(LinkChanged(13.0, "A", LinkState.LOST))
    assert m.state is State.LINKED and m.owner == "B" and m.epoch == 2
    assert AuthorityChanged("A", "B", 2, "emergency") in acts
    assert not any(isinstance(a, FailsafeCommand) for a in acts)


def test_request_from_non_authority_is_passed_to_the_owner():
    m = machine()
    linked_with_b(m)
    acts = m.handle(AuthorityAsked(2.0, "B", "B", ask_id=1))  # its operator's request
    assert m.state is State.LINKED and m.owner == "A"
    assert any(isinstance(a, SendControl) and a.gs == "A" for a in acts)
    acts = m.handle(AuthorityAsked(2.0, "A", "B"))  # the owner asking = releasing
    assert m.state is State.HANDOVER_PENDING


def test_a_request_reaches_the_owner_naming_its_sealed_sender_and_moves_nothing():
    m = machine()
    linked_with_b(m)
    prove(m, "B", 2.0)
    acts = m.handle(AuthorityAsked(3.0, "B", "B", timeout=20.0, ask_id=1))
    asks = [a.msg for a in acts if isinstance(a, SendControl) and isinstance(a.msg, OperatorRequest)]
    assert asks == [OperatorRequest("B", "B", 1, 20.0, 1)]
    assert all(a.gs == "A" for a in acts if isinstance(a, SendControl))  # nobody but the owner hears of it
    assert (m.state, m.owner, m.epoch) == (State.LINKED, "A", 1)
    m.handle(Tick(60.0))
    assert (m.state, m.owner, m.epoch) == (State.LINKED, "A", 1)  # no consent: nothing moves, ever


def test_a_consented_transfer_may_go_to_a_gs_whose_coverage_does_not_hold_the_drone():
    m = machine()
    linked_with_b(m)
    m.handle(RegionChanged(2.0, frozenset({"A"})))  # only A covers the drone: B is an operations centre, say
    prove(m, "B", 2.0)
    assert not m.proven_in_cover("B")  # no heir: an emergency could never go to B
    m.handle(AuthorityAsked(3.0, "B", "B", timeout=10.0, ask_id=1))
    assert m.owner == "A"
    m.handle(Release(4.0, "A", "B", 1))  # A's operator consents
    assert (m.owner, m.epoch, m.state) == ("B", 2, State.LINKED)


def test_the_owners_takeover_setting_is_in_the_status_of_its_epoch_only():
    m = machine()
    linked_with_b(m)
    m.handle(RegionChanged(2.0, frozenset({"A", "B"})))  # the drone listens to B
    prove(m, "B", 2.0)
    assert not m.status().takeover
    acts = m.handle(AuthorityAsked(3.0, "B", "B", takeover=True))  # not the owner: no setting, and no request
    assert not m.status().takeover and not any(isinstance(a, SendControl) for a in acts)
    assert (m.owner, m.epoch) == ("A", 1)
    acts = m.handle(AuthorityAsked(3.0, "A", "A", takeover=True))
    assert m.status().takeover and m.owner == "A" and m.state is State.LINKED
    assert any(isinstance(a, SendControl) and a.gs == "B" and a.msg.takeover for a in acts)  # every GS it talks to sees it
    m.handle(Release(4.0, "A", "B", 1))  # consent: the owner releases; the new owner's epoch starts without it
    assert (m.owner, m.epoch) == ("B", 2) and not m.status().takeover
    m.handle(AuthorityAsked(5.0, "B", "B", takeover=True))
    assert m.status().takeover
    m.handle(AuthorityAsked(6.0, "B", "B", takeover=False))
    assert not m.status().takeover


def test_non_gs_event_missing_from_table_is_a_programming_error():
    class Bogus(ha.Event):
        pass

    with pytest.raises(IllegalTransition):
        machine().handle(Bogus(0.0))


# ------------------------------------------------------------------ hypothesis sweep
GS = st.sampled_from(["A", "B", "X"])
times = st.floats(0, 1000, allow_nan=False)
EVENTS = st.one_of(
    st.builds(PairingDone, times, GS, st.booleans()),
    st.builds(GrantHeard, times, GS, GS),
    st.builds(Frame, times, GS, st.sampled_from(list(UplinkClass))),
    st.builds(LinkChanged, times, GS, st.sampled_from(list(LinkState))),
    st.builds(RegionChanged, times, st.frozensets(GS)),
    st.builds(AuthorityAsked, times, GS, GS),
    st.builds(Release, times, GS, GS, st.integers(0, 4)),
    st.builds(Tick, times),
    st.builds(ha.GroundChanged, times, st.booleans()),
)


def check_invariants(m: AuthorityMachine) -> None:
    assert m.state in State
    if m.state is State.UNPAIRED:
        assert m.owner is None and m.epoch == 0
    else:
        assert m.owner in AUTH  # exactly one, authorized owner
    assert (m.pending_to is not None) == (m.state is State.HANDOVER_PENDING)
    if m.pending_to is not None:
        assert m.pending_to != m.owner and m.pending_to in AUTH and m.pending_deadline is not None
    if m.state in (State.LINKED, State.HANDOVER_PENDING):
        assert m.owner in m.subscribed
    assert set(m.links) <= AUTH
    epochs = [e for _, _, e in m.history]
    assert epochs == sorted(epochs)


def _rejects(acts: list) -> list[SendControl]:
    return [a for a in acts if isinstance(a, SendControl) and isinstance(a.msg, Reject)]


def check_grant_result(m: AuthorityMachine, ev: GrantHeard, result, acts: list, expected) -> None:
    """A grant's typed result says what its actions do: accepted, the GS is linked and nothing is
    rejected; rejected, exactly one ``Reject`` to the sender with the result's text."""
    assert result == (expected or GrantAccepted(ev.gs))
    if isinstance(result, GrantAccepted):
        assert not _rejects(acts) and ev.gs in m.links
    else:
        assert [(a.gs, a.msg.reason) for a in _rejects(acts)] == [(ev.sender, result.detail)]


@settings(max_examples=400, deadline=None)
@given(st.lists(EVENTS, max_size=40), EVENTS)
def test_every_state_event_pair_ends_valid(prefix, last):
    m = machine()
    for ev in prefix + [last]:
        before_owner, before_state, before_links = m.owner, m.state, set(m.links)
        if isinstance(ev, GrantHeard):  # never raises; its typed result agrees with its actions
            expected = m.grant_rejection(ev.sender, ev.gs)
            result, acts = m.grant(ev)
            check_grant_result(m, ev, result, acts, expected)
        else:
            acts = m.handle(ev)  # never raises for these events
        check_invariants(m)
        if isinstance(ev, Frame):
            verdicts = [a for a in acts if isinstance(a, (Forward, DropFrame))]
            assert len(verdicts) == 1 and verdicts[0].gs == ev.gs  # exactly one verdict per frame
            v = verdicts[0]
            if ev.gs not in before_links:
                assert v == DropFrame(ev.gs, HaDrop.NOT_LINKED)
            elif ev.uplink is DENIED:
                assert v == DropFrame(ev.gs, HaDrop.DENIED_BY_POLICY)
            elif ev.uplink is RO:
                assert v == Forward(ev.gs)
            elif before_state is State.FAILSAFE:
                assert v == DropFrame(ev.gs, HaDrop.FAILSAFE)
            else:
                assert v == (Forward(ev.gs) if ev.gs == before_owner else DropFrame(ev.gs, HaDrop.NOT_AUTHORITY))
        for a in acts:
            if isinstance(a, AuthorityChanged):
                assert a.new == m.owner and a.epoch == m.epoch


def test_table_covers_every_non_gs_event_in_every_state():
    for state in State:
        for ev in (LinkChanged, RegionChanged, Tick, ha.GroundChanged):
            assert (state, ev) in ha.TRANSITIONS
        for ev in (PairingDone, Frame):
            assert (state, ev) in ha.TRANSITIONS


def _failsafe_with_b_linked() -> AuthorityMachine:
    m = machine()
    linked_with_b(m)
    m.handle(LinkChanged(2.0, "A", LinkState.LOST))  # B not proven: no heir
    assert m.state is State.FAILSAFE
    return m


def test_failsafe_is_left_only_on_an_explicit_request_of_a_proven_authorized_gs():
    """Issue 11: regain control after the failsafe, never automatically (and, issue 18, only from
    inside the GS's coverage)."""
    m = _failsafe_with_b_linked()
    m.handle(RegionChanged(2.5, frozenset({"B"})))
    prove(m, "B", 3.0)
    assert m.state is State.FAILSAFE  # a proven link alone changes nothing
    acts = m.handle(AuthorityAsked(4.0, "B", "B"))
    assert m.state is State.LINKED and m.owner == "B" and m.epoch == 2
    assert AuthorityChanged("A", "B", 2, "regained") in acts
    assert not any(isinstance(a, FailsafeCommand) for a in acts)  # the vehicle goes on landing
    assert m.handle(Frame(4.1, "B", AO)) == [Forward("B")]


def test_failsafe_request_refused_unless_proven_for_itself_and_authorized():
    m = _failsafe_with_b_linked()
    m.handle(RegionChanged(2.9, frozenset({"B"})))
    acts = m.handle(AuthorityAsked(3.0, "B", "B"))  # B's link not proven yet
    assert m.state is State.FAILSAFE and any(isinstance(a, SendControl) and isinstance(a.msg, Reject) for a in acts)
    prove(m, "B", 3.5)
    m.handle(AuthorityAsked(4.0, "B", "A"))  # for someone else: no
    m.handle(AuthorityAsked(4.0, "X", "X"))
    assert m.state is State.FAILSAFE and m.owner == "A"
    assert m.rejects["failsafe"] == 1 and m.rejects["unauthorized"] == 1 and m.rejects["not proven"] == 1


def test_a_restarted_companion_waits_for_its_owner_to_re_pair():
    """Issue 11: restore(owner, epoch); the owner re-pairs in time and keeps its epoch."""
    m = machine()
    m.restore("A", 4, 100.0, grace=3.0)
    assert m.state is State.LINKED and m.owner == "A" and m.epoch == 4 and not m.is_proven("A")
    m.handle(PairingDone(101.0, "B", on_ground=False))  # another GS re-pairs: a link, never the authority
    assert m.owner == "A" and m.epoch == 4
    m.handle(PairingDone(101.5, "A", on_ground=False))
    m.handle(LinkChanged(101.6, "A", LinkState.OK))
    m.handle(Tick(104.0))  # past the grace: the owner is back, nothing happens
    assert m.state is State.LINKED and m.owner == "A" and m.epoch == 4


def test_a_restarted_companion_whose_owner_never_comes_back_fails_safe_or_hands_over():
    m = machine()
    m.restore("A", 4, 100.0, grace=3.0)
    acts = m.handle(Tick(103.1))
    assert m.state is State.FAILSAFE and FailsafeCommand("LAND", "authority link to A lost") in acts
    m2 = machine()
    m2.restore("A", 4, 100.0, grace=3.0)
    m2.handle(RegionChanged(100.2, frozenset({"A", "B"})))
    m2.handle(PairingDone(100.5, "B", on_ground=False))
    prove(m2, "B", 101.0)
    m2.handle(Tick(103.1))
    assert m2.state is State.LINKED and m2.owner == "B" and m2.epoch == 5  # the emergency hand-over


def test_restore_only_at_start_and_only_for_an_authorized_owner():
    m = machine()
    assert m.restore("X", 2, 0.0, grace=3.0)[0].kind == "restore_refused" and m.state is State.UNPAIRED
    m.handle(PairingDone(0.0, "A"))
    with pytest.raises(IllegalTransition):
        m.restore("A", 1, 1.0, grace=3.0)


# ------------------------------------------------- a restart on the ground (review R1)
def test_a_ground_restart_gives_the_last_owner_the_first_claim_and_the_epoch_goes_on():
    """Restarted on the ground in the overlap: UNPAIRED with epoch 4 kept; B (covering, authorized)
    asks first and is refused first_claim; A pairs back and gets epoch 5, never 1."""
    m = machine(frozenset({"A", "B"}))
    acts = m.restore_on_ground("A", 4, 100.0, window=5.0)
    assert [a.kind for a in acts] == ["first_claim"]
    assert m.state is State.UNPAIRED and m.owner is None and m.epoch == 4 and m.get_timer() == 105.0
    assert m.pair_refusal("B", True, 100.1) == PairRefused(
        PairRefusal.FIRST_CLAIM, "A held authority before the restart and pairs first (4.9 s left)")
    acts = m.handle(PairingDone(100.1, "B"))
    assert _rejects(acts) == [SendControl("B", Reject("pair", "first_claim: A held authority before the restart and "
                                                              "pairs first (4.9 s left)"))]
    assert m.state is State.UNPAIRED and m.rejects["first_claim"] == 1
    acts = m.handle(PairingDone(100.3, "A"))
    assert m.state is State.LINKED and m.owner == "A" and m.epoch == 5
    assert AuthorityChanged(None, "A", 5, "paired") in acts
    assert m.first_claim is None and m.get_timer() is None  # the claim is spent: nothing pending
    m.handle(PairingDone(100.5, "B"))  # B may pair now: a link, never the authority
    assert m.owner == "A" and m.epoch == 5 and "B" in m.links


def test_after_the_first_claim_a_covering_gs_may_pair_and_the_epoch_still_goes_on():
    m = machine(frozenset({"A", "B"}))
    m.restore_on_ground("A", 4, 100.0, window=5.0)
    assert m.handle_timer(104.9) == [] and m.first_claim == "A"
    acts = m.handle_timer(105.0)
    assert [a.kind for a in acts if isinstance(a, ha.Note)] == ["first_claim_over"] and m.first_claim is None
    assert m.pair_refusal("B", True, 105.0) is None
    acts = m.handle(PairingDone(105.2, "B"))
    assert m.owner == "B" and m.epoch == 5 and AuthorityChanged(None, "B", 5, "paired") in acts
    # the window is exact even before the timer is handled
    m2 = machine(frozenset({"A", "B"}))
    m2.restore_on_ground("A", 4, 100.0, window=5.0)
    m2.handle(PairingDone(105.0, "B"))
    assert m2.owner == "B" and m2.epoch == 5


def test_the_last_owner_still_needs_its_coverage_to_hold_the_vehicle():
    """Landed in B's coverage only, last owner A: A is refused outside_coverage, B first_claim inside
    the window; after it B pairs (epoch last + 1)."""
    m = machine(frozenset({"B"}))
    m.restore_on_ground("A", 7, 0.0, window=5.0)
    assert m.pair_refusal("A", True, 1.0).reason is PairRefusal.OUTSIDE_COVERAGE  # type: ignore[union-attr]
    assert m.pair_refusal("B", True, 1.0).reason is PairRefusal.FIRST_CLAIM  # type: ignore[union-attr]
    m.handle(PairingDone(1.0, "A"))
    assert m.state is State.UNPAIRED
    m.handle(PairingDone(6.0, "B"))
    assert m.owner == "B" and m.epoch == 8


def test_a_ground_restart_for_an_owner_no_longer_authorized_keeps_the_epoch_without_a_claim():
    m = machine(frozenset({"A", "B"}))
    assert [a.kind for a in m.restore_on_ground("X", 3, 0.0)] == ["restore_refused"]
    assert m.first_claim is None and m.get_timer() is None and m.pair_refusal("B", True, 0.1) is None
    m.handle(PairingDone(0.1, "B"))
    assert m.owner == "B" and m.epoch == 4
    with pytest.raises(IllegalTransition):
        m.restore_on_ground("A", 4, 1.0)


def test_the_timer_says_when_to_wake_the_machine():
    """Issue 12: get_timer()/handle_timer(now), as aioquic's connection: no Tick on every loop pass."""
    m = machine()
    linked_with_b(m)
    assert m.get_timer() is None  # nothing pending: the node may sleep until input
    m.handle(Release(2.0, "A", "B", 1))
    assert m.state is State.HANDOVER_PENDING and m.get_timer() == 7.0
    assert m.handle_timer(6.9) == [] and m.state is State.HANDOVER_PENDING
    acts = m.handle_timer(7.0)
    assert m.state is State.LINKED and m.owner == "A" and m.get_timer() is None
    assert any(isinstance(a, ha.Note) and a.kind == "handover_timeout" for a in acts)
    r = machine()
    r.restore("A", 3, 10.0, grace=3.0)
    assert r.get_timer() == 13.0


def test_one_pass_after_any_event_completes_a_proven_hand_over_and_sends_one_status_each():
    m = machine()
    linked_with_b(m)
    prove(m, "B", 1.5)
    acts = m.handle(Release(2.0, "A", "B", 1))  # B proven already: the same step switches
    assert m.state is State.LINKED and m.owner == "B" and m.epoch == 2
    statuses = [a for a in acts if isinstance(a, SendControl) and a.msg.__class__.__name__ == "AuthorityStatus"]
    assert len({a.gs for a in statuses}) == len(statuses)  # once per GS
    assert all(a.msg.state is State.LINKED and a.msg.owner == "B" for a in statuses)  # the state after the step


# ------------------------------------------------------------------ typed results
def test_a_grant_is_accepted_from_the_authority_only_and_for_authorized_gss_only():
    m = machine()
    result, acts = m.grant(GrantHeard(0.5, "A", "B"))
    assert result == GrantRejected("B", GrantRejection.ILLEGAL_STATE, "illegal in state unpaired")
    assert _rejects(acts) == [SendControl("A", Reject("GrantHeard", "illegal in state unpaired"))]
    m.handle(PairingDone(1.0, "A"))
    result, acts = m.grant(GrantHeard(1.0, "B", "B"))
    assert result.reason is GrantRejection.NOT_AUTHORITY and "B" not in m.links
    assert _rejects(acts) == [SendControl("B", Reject("key_grant", "not the authority: only the authority grants keys"))]
    result, acts = m.grant(GrantHeard(1.0, "A", "X"))
    assert result == GrantRejected("X", GrantRejection.UNAUTHORIZED, "unauthorized: X is not authorized for this drone")
    result, acts = m.grant(GrantHeard(1.0, "A", "B"))
    assert result == GrantAccepted("B") and "B" in m.links and not _rejects(acts)
    assert dict(m.rejects) == {"illegal in state unpaired": 1, "not the authority": 1, "unauthorized": 1}


def test_a_grant_that_does_not_fit_the_fleet_is_bad():
    sysids = {"A": 4, "B": 5}
    assert check_grant(KeyGrant("B", 5, bytes(32), 1), sysids) is None
    for grant in (KeyGrant("B", 6, bytes(32), 1), KeyGrant("Q", 5, bytes(32), 1), KeyGrant("B", 5, bytes(31), 1)):
        bad = check_grant(grant, sysids)
        assert bad == GrantRejected(grant.gs, GrantRejection.BAD_GRANT,
                                    f"unknown ground station or sysid: {grant.gs}/{grant.sysid}")


def test_the_pairing_rule_is_a_typed_refusal_and_its_reject_keeps_its_text():
    m = machine()
    assert m.pair_refusal("X", True, 0.0) == PairRefused(PairRefusal.UNAUTHORIZED, "X is not authorized for this drone")
    acts = m.handle(PairingDone(0.0, "X"))
    assert _rejects(acts) == [SendControl("X", Reject("pair", "unauthorized: X is not authorized for this drone"))]
    m = _failsafe_with_b_linked()
    assert m.pair_refusal("B", on_ground=False, now=3.0) == PairRefused(PairRefusal.FAILSAFE, "re-pair only on the ground")
    assert m.pair_refusal("B", on_ground=True, now=3.0) == PairRefused(
        PairRefusal.OUTSIDE_COVERAGE, "its coverage does not hold the vehicle")
    m.handle(RegionChanged(3.0, frozenset({"B"})))
    assert m.pair_refusal("B", on_ground=True, now=3.0) is None
    acts = m.handle(PairingDone(3.0, "B", on_ground=False))
    assert _rejects(acts) == [SendControl("B", Reject("pair", "failsafe: re-pair only on the ground"))]
    assert m.rejects["failsafe"] == 1


# ------------------------------------------------------------- least privilege (issue 18)
def test_an_heir_outside_its_coverage_never_takes_authority():
    """B re-pairs and proves its link while the drone is outside B's coverage; A's link is lost:
    failsafe, never B."""
    m = machine()
    linked_with_b(m)
    m.handle(RegionChanged(5.0, frozenset({"A"})))
    prove(m, "B", 6.0, n=20)
    assert m.is_proven("B") and not m.is_heir("B")
    acts = m.handle(LinkChanged(9.0, "A", LinkState.LOST))
    assert m.state is State.FAILSAFE and m.owner == "A"
    assert any(isinstance(a, FailsafeCommand) for a in acts)
    m.handle(AuthorityAsked(9.5, "B", "B"))  # nor after the failsafe, from outside
    assert m.state is State.FAILSAFE and m.rejects["outside coverage"] == 1


def test_a_proof_made_outside_coverage_does_not_count_once_inside():
    m = machine()
    linked_with_b(m)
    m.handle(RegionChanged(5.0, frozenset({"A"})))
    prove(m, "B", 6.0, n=20)
    m.handle(RegionChanged(7.0, frozenset({"A", "B"})))  # now inside, no frame since
    assert not m.is_heir("B")
    m.handle(Frame(7.1, "B", RO))
    assert not m.is_heir("B")
    m.handle(Frame(7.2, "B", RO))
    assert m.is_heir("B")
    m.handle(RegionChanged(8.0, frozenset({"A"})))  # leaving the coverage starts the count again
    m.handle(RegionChanged(8.5, frozenset({"A", "B"})))
    assert not m.is_heir("B")


def test_an_unknown_position_is_inside_no_coverage():
    m = machine()
    linked_with_b(m)
    m.handle(RegionChanged(5.0, frozenset({"A", "B"})))
    prove(m, "B", 6.0)
    m.handle(RegionChanged(6.5, frozenset()))  # the vehicle lost its fix
    m.handle(LinkChanged(9.0, "A", LinkState.LOST))
    assert m.state is State.FAILSAFE


def test_a_consented_release_may_go_to_a_gs_outside_coverage():
    m = machine()
    linked_with_b(m)
    m.handle(RegionChanged(5.0, frozenset({"A"})))
    prove(m, "B", 6.0)
    m.handle(Release(7.0, "A", "B", 1))
    assert m.state is State.LINKED and m.owner == "B" and m.epoch == 2


def _status_key(m: AuthorityMachine) -> tuple:
    s = m.status()
    return s.owner, s.epoch, s.state, s.pending_to, s.takeover, s.takeover_to


@settings(max_examples=400, deadline=None)
@given(st.lists(EVENTS, max_size=40))
def test_the_effects_follow_from_the_state_change(events):
    """Whom the drone listens to and who hears the status follow from the state before and after each
    step (``_effects``): the listened GSs are the state's rule in LINKED and HANDOVER_PENDING; the
    status goes once per GS, as it is after the step; a changed status reaches every listened GS and
    the owner before and after, unless the step entered the failsafe (its notice tells them)."""
    m = machine()
    for ev in sorted(events, key=lambda e: e.now):
        key, owner, state = _status_key(m), m.owner, m.state
        acts = m.handle(ev)
        statuses = [a for a in acts if isinstance(a, SendControl) and type(a.msg).__name__ == "AuthorityStatus"]
        assert len({a.gs for a in statuses}) == len(statuses)
        assert all(a.msg == m.status() for a in statuses)
        if m.state in (State.LINKED, State.HANDOVER_PENDING):
            assert m.subscribed == ({g for g in m.links if g in m.inside} | {g for g in (m.owner, m.pending_to) if g})
        if _status_key(m) != key and not (m.state is State.FAILSAFE and state is not State.FAILSAFE):
            told = {a.gs for a in statuses}
            assert told >= m.subscribed | {g for g in (owner, m.owner) if g}


def test_a_settle_rule_cannot_choose_a_state_outside_its_row(monkeypatch):
    """The rules of state and time alone are table rows too: a rule that chose a state its row does
    not allow would be a programming error, raised, not applied."""
    m = machine()
    linked_with_b(m)
    m.handle(Release(2.0, "A", "B", 1))
    assert m.state is State.HANDOVER_PENDING
    rows = [(states, rule, allowed) for states, rule, allowed in ha.SETTLE]
    rows[1] = (rows[1][0], lambda self, now: (State.FAILSAFE, []), rows[1][2])  # the hand-over deadline, wrong
    monkeypatch.setattr(ha, "SETTLE", tuple(rows))
    with pytest.raises(IllegalTransition):
        m.handle(Tick(10.0))


@settings(max_examples=400, deadline=None)
@given(st.lists(EVENTS, max_size=30))
def test_least_privilege_over_any_event_sequence(events):
    """Whatever the events, authority taken without the owner's release (an emergency, regained after
    the failsafe) lands on a GS whose coverage holds the drone at that instant."""
    m = machine()
    for ev in sorted(events, key=lambda e: e.now):
        acts = m.handle(ev)
        for a in acts:
            if isinstance(a, AuthorityChanged) and a.kind in ("emergency", "regained"):
                assert a.new in m.inside, (a, m.inside)


# ------------------------------------------------------------------ the vehicle on the ground
def _on_ground_with_a(inside: frozenset[str] = frozenset({"A"})) -> AuthorityMachine:
    m = machine(inside)
    linked_with_b(m)
    m.handle(ha.GroundChanged(1.0, True))
    return m


def test_the_owners_link_lost_on_the_ground_is_no_failsafe_and_the_owner_has_it_back():
    """As the autopilots: no link-loss failsafe while on the ground (a radio glitch before take-off
    used to ground the drone for good)."""
    m = _on_ground_with_a()
    acts = m.handle(LinkChanged(5.0, "A", LinkState.LOST))
    assert (m.state, m.owner, m.epoch) == (State.LINKED, "A", 1)
    assert not any(isinstance(a, FailsafeCommand) for a in acts)
    assert any(isinstance(a, ha.Note) and a.kind == "owner_link_lost_on_ground" for a in acts)
    m.handle(LinkChanged(8.0, "A", LinkState.OK))
    assert m.handle(Frame(8.1, "A", AO)) == [Forward("A")]  # its commands pass again, same epoch
    assert m.handle(Frame(8.2, "B", AO)) == [DropFrame("B", HaDrop.NOT_AUTHORITY)]
    assert m.handle(GrantHeard(9.0, "A", "B")) is not None and m.state is State.LINKED  # key grants still taken


def test_lifting_off_with_the_owners_link_lost_is_the_failsafe_at_once():
    m = _on_ground_with_a()
    m.handle(LinkChanged(5.0, "A", LinkState.LOST))
    acts = m.handle(ha.GroundChanged(6.0, False))
    assert m.state is State.FAILSAFE and any(isinstance(a, FailsafeCommand) for a in acts)


def test_lifting_off_with_the_owners_link_lost_goes_to_a_proven_heir():
    m = _on_ground_with_a(frozenset({"A", "B"}))
    prove(m, "B", 2.0)
    m.handle(LinkChanged(5.0, "A", LinkState.LOST))
    assert m.owner == "A"
    acts = m.handle(ha.GroundChanged(6.0, False))
    assert (m.state, m.owner, m.epoch) == (State.LINKED, "B", 2)
    assert AuthorityChanged("A", "B", 2, "emergency") in acts


def test_after_a_failsafe_landing_the_owners_link_back_gives_it_the_vehicle():
    m = machine()
    linked_with_b(m)
    m.handle(ha.GroundChanged(1.5, False))  # in the air
    m.handle(LinkChanged(5.0, "A", LinkState.LOST))
    assert m.state is State.FAILSAFE
    m.handle(ha.GroundChanged(20.0, True))  # landed by the failsafe
    assert m.state is State.FAILSAFE
    acts = prove(m, "A", 30.0)
    assert (m.state, m.owner, m.epoch) == (State.LINKED, "A", 2)
    assert AuthorityChanged("A", "A", 2, "regained") in acts


def test_after_a_failsafe_landing_outside_the_owners_coverage_nothing_moves_by_itself():
    m = machine()
    linked_with_b(m)
    m.handle(ha.GroundChanged(1.5, False))
    m.handle(LinkChanged(5.0, "A", LinkState.LOST))
    m.handle(RegionChanged(10.0, frozenset()))  # came down outside every coverage
    m.handle(ha.GroundChanged(20.0, True))
    prove(m, "A", 30.0)
    assert m.state is State.FAILSAFE
