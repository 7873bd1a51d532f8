"""The drone's pure core with the ground stations' pure cores, in memory (``tests.fleetnet``): pairing,
key sharing, both hand-overs, the failsafe and the least-privilege rules of issue 18, with real crypto
and explicit time — no sockets, no processes."""

from __future__ import annotations

import dataclasses

import pytest

from zdrone.bench.fleetnet import FleetNet, make_fleet
from zdrone.core.authority import State
from zdrone.core.keyshare import KeyShareAsk
from zdrone.core.pairing import PairingInitiator
from zdrone.core import records as rec


@pytest.fixture(scope="module")
def fleet_dir(tmp_path_factory):
    return make_fleet(tmp_path_factory.mktemp("fleet"))


def linked(fleet_dir) -> FleetNet:
    """A paired with the drone on the ground at home, B's key shared and granted."""
    net = FleetNet(fleet_dir)
    net.add_gs("A", pair=True)
    net.add_gs("B")
    net.run(4.0)
    m = net.drone.machine
    assert m.owner == "A" and m.state is State.LINKED and m.epoch == 1
    assert set(net.drone.links) == {"A", "B"}, "B's key was shared by A and granted to the drone"
    return net


def test_pairing_key_sharing_and_both_hand_overs_in_memory(fleet_dir):
    net = linked(fleet_dir)
    a, b = net.centre("A"), net.centre("B")
    net.on_ground = False
    net.fly(a, b, 30.0)
    m = net.drone.machine
    assert m.owner == "B" and m.epoch == 2, net.record_types()
    net.fly(b, a, 30.0)
    assert m.owner == "A" and m.epoch == 3
    moves = [(r.from_, r.to, r.kind) for r in net.records if isinstance(r, rec.HandoverComplete)]
    assert moves == [("A", "B", "handover"), ("B", "A", "handover")]
    assert not net.commands  # no failsafe
    # the drone's owner changes were persisted as they happened
    assert net.persisted is not None and (net.persisted.owner, net.persisted.epoch) == ("A", 3)


def test_a_silent_authority_lands_the_drone_on_time_when_no_heir_covers_it(fleet_dir):
    net = linked(fleet_dir)
    net.on_ground = False
    net.fly(net.centre("A"), net.between(net.centre("A"), net.centre("B"), 0.2), 5.0)
    net.hung.add("A")
    net.run(4.0, dt=0.01)
    assert [c.command for c in net.commands] == ["LAND"]
    assert 0.0 <= net.commands[0].detect_to_command_ms <= 20.0  # at the threshold, to the step
    assert net.drone.machine.state is State.FAILSAFE and net.drone.machine.owner == "A"


def test_insider_heir_b_repairing_from_outside_its_coverage_never_takes_authority(fleet_dir):
    """Issue 18, finding 1: B re-pairs again and again in flight and keeps its link proven while the
    drone is outside B's coverage; A hangs. Failsafe, never B."""
    net = linked(fleet_dir)
    net.on_ground = False
    home = net.centre("A")
    net.fly(home, net.between(home, net.centre("B"), 0.1), 3.0)
    b = net.gss["B"]
    for _ in range(3):  # B's operator (or an attacker holding B's keys) pairs again in flight
        b.sessions["d1"].link = None
        b.opts = dataclasses.replace(b.opts, pair=True)
        net.run(1.0)
    assert "B" in net.drone.links and net.drone.machine.is_proven("B") and not net.drone.machine.is_heir("B")
    net.hung.add("A")
    net.run(4.0)
    m = net.drone.machine
    assert m.state is State.FAILSAFE and m.owner == "A"
    assert not any(isinstance(r, rec.AuthorityMoved) and r.to == "B" for r in net.records)


def test_an_heir_inside_its_coverage_takes_authority_when_the_owner_is_lost(fleet_dir):
    net = linked(fleet_dir)
    net.on_ground = False
    a, b = net.centre("A"), net.centre("B")
    net.fly(a, net.between(a, b, 0.5), 10.0)  # the overlap, A still the owner (nearer A)
    assert net.drone.machine.owner == "A" and net.drone.machine.is_heir("B")
    net.hung.add("A")
    net.run(4.0)
    assert net.drone.machine.owner == "B" and not net.commands


def test_key_escrow_a_asked_for_its_own_key_answers_nothing_while_its_link_is_alive(fleet_dir):
    """Issue 18, finding 2: B asks A (genuinely) for a key of link (d1, A): A refuses (live_link) and
    keeps no candidate; its live link is untouched."""
    net = linked(fleet_dir)
    a, b = net.gss["A"], net.gss["B"]
    ask = KeyShareAsk(b.identity, "B", "A", net.fleet.nodes["A"].public_bytes, "d1", net.now, wall=1_800_000_000.0 + net.now)
    answer, _logs = a.on_linkkey_query("d1", ask.payload, net.now, bytes(32), 1_800_000_000.0 + net.now)
    assert answer.reply is None and answer.error == b"live_link" and not answer.crypto
    assert a.sessions["d1"].slot.candidates == [] and a.counters["linkkey_refused:live_link"] == 1


def test_stale_pairing_replays_around_a_companion_restart_cost_nothing_and_the_owner_comes_back(fleet_dir):
    """Issue 18, finding 3: captured message 1s of A replayed right after a companion restart are stale
    (made before the companion started): no handshake, no token, no candidate displaced; A re-pairs
    within the grace and keeps its epoch."""
    net = linked(fleet_dir)
    net.on_ground = False
    net.fly(net.centre("A"), net.between(net.centre("A"), net.centre("B"), 0.2), 5.0)
    captured = [m1 for gs, m1 in net.captured_pairings if gs == "A"]
    assert captured
    net.restart_drone()
    drone = net.drone
    for m1 in captured * 5:  # replayed at once, before A's own re-pairing
        ans, _ = drone.on_pair_query("A", m1, net.now, bytes(32), 1_800_000_000.0 + net.now)
        assert ans.refused == "stale"  # type: ignore[union-attr]
    assert drone.counters["pair_refused:stale"] == len(captured) * 5 and "A" not in drone.slots
    restarted = net.now
    net.run(3.0, dt=0.05)
    m = drone.machine
    assert m.owner == "A" and m.state is State.LINKED and m.epoch == 1 and not net.commands
    paired = [r for r in net.records if isinstance(r, rec.Paired) and r.gs == "A"]
    assert paired, "A re-paired"
    # A notices the silence after 1 s and then tries every 0.2 s: back well inside the 3 s grace
    assert drone.machine.links["A"].state.value == "ok" and net.now - restarted <= 3.0


def test_a_pairing_message_older_than_30_s_is_stale_even_for_a_fresh_companion(fleet_dir):
    net = FleetNet(fleet_dir)
    gs = net.add_gs("A")
    old = PairingInitiator(gs.identity, "A", "d1", net.fleet.nodes["d1"].public_bytes, stamp=1_800_000_000.0 - 40).start()
    net.step(0.1)  # the vehicle's position: at home, in A's coverage
    ans, _ = net.drone.on_pair_query("A", old, 0.1, bytes(32), 1_800_000_000.0)
    assert ans.refused == "stale" and ans.silent  # type: ignore[union-attr]


def test_a_third_partys_grant_never_replaces_a_live_link_on_the_drone(fleet_dir):
    """The authority (here A, as if malicious) grants a fresh key for B while B's link is alive and
    proves it as B: the drone keeps B's live key and counts the attempt."""
    from zdrone.core.wire import KeyGrant

    net = linked(fleet_dir)
    a = net.gss["A"]
    view = a.sessions["d1"]
    net.run(1.0)
    live_b = net.drone.links["B"]
    secret = bytes(range(32))
    net.gs_outs("A", a.send_control(view, KeyGrant("B", net.fleet.nodes["B"].sysid, secret, 99)))
    assert len(net.drone.slots["B"].candidates) == 1
    from zdrone.core.envelope import SecureLink
    from zdrone.core.keys import LinkKey
    from zdrone.core.mavlink import FrameCodec
    from pymavlink.dialects.v20 import common as mav

    forged = SecureLink(key=LinkKey.from_secret("d1", "B", secret), role="gs", tx_keyexpr="zdrone/d1/up/B",
                        rx_keyexpr="zdrone/d1/down/B", peer_sysid=1, now=net.now)
    hb = FrameCodec(net.fleet.nodes["B"].sysid, 190).encode(mav.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))
    net.drone_outs(net.drone.on_envelope("B", forged.seal(hb), net.now))
    assert net.drone.links["B"] is live_b and net.drone.slots["B"].live_protected == 1


# ------------------------------------------------- a companion restart on the ground (review R1)
def _in_the_overlap_after_two_hand_overs(fleet_dir, on_ground: bool) -> FleetNet:
    """A -> B -> A (epoch 3, A the owner), then the vehicle in the overlap of A and B (still A's),
    on the ground or in the air."""
    net = linked(fleet_dir)
    a, b = net.centre("A"), net.centre("B")
    net.on_ground = False
    net.fly(a, b, 30.0)
    net.fly(b, a, 30.0)
    net.fly(a, net.between(a, b, 0.5), 10.0)
    net.on_ground = on_ground
    net.run(1.0)
    m = net.drone.machine
    assert m.owner == "A" and m.epoch == 3 and m.inside >= {"A", "B"} and (net.persisted.owner, net.persisted.epoch) == ("A", 3)
    return net


def _b_asks_to_pair(net: FleetNet) -> None:
    """B (authorized, covering the vehicle) pairs as if it had no link: its first try goes out at once."""
    b = net.gss["B"]
    b.sessions["d1"].link = None
    b.opts = dataclasses.replace(b.opts, pair=True)


def test_a_ground_restart_in_the_overlap_gives_a_the_first_claim_even_if_b_asks_first(fleet_dir):
    net = _in_the_overlap_after_two_hand_overs(fleet_dir, on_ground=True)
    net.records.clear()
    net.restart_drone()
    assert (net.persisted.owner, net.persisted.epoch) == ("A", 3), "the saved authority is not cleared on the ground"
    m = net.drone.machine
    assert m.state is State.UNPAIRED and m.epoch == 3 and m.first_claim == "A"
    _b_asks_to_pair(net)
    net.step(0.1)  # B's query reaches the drone first: refused, with the reason
    assert net.drone.counters["pair_refused:first_claim"] == 1 and m.owner is None
    [refused] = [r for r in net.records if isinstance(r, rec.PairRefused)]
    assert refused.gs == "B" and refused.reason.startswith("first_claim: A held authority before the restart")
    net.run(2.0)  # A hears the silence after 1 s and re-pairs
    assert m.owner == "A" and m.epoch == 4 and m.state is State.LINKED
    moved = [(r.from_, r.to, r.epoch, r.kind) for r in net.records if isinstance(r, rec.AuthorityMoved)]
    assert moved == [(None, "A", 4, "paired")]
    assert [type(r) for r in net.records if isinstance(r, (rec.FirstClaim, rec.FirstClaimOver))] == [rec.FirstClaim]
    assert (net.persisted.owner, net.persisted.epoch) == ("A", 4)
    net.run(4.0)  # B tries again: a link now, never the authority
    assert m.owner == "A" and m.epoch == 4 and "B" in net.drone.links and not net.commands
    assert net.gss["A"].sessions["d1"].epoch == 4 and net.gss["B"].sessions["d1"].epoch == 4


def test_after_the_first_claim_without_a_a_covering_b_pairs_in_the_next_epoch(fleet_dir):
    net = _in_the_overlap_after_two_hand_overs(fleet_dir, on_ground=True)
    net.records.clear()
    net.hung.add("A")  # A's station is gone
    net.restart_drone()
    _b_asks_to_pair(net)
    net.run(4.0)  # B asks at once and 3 s later: both inside the window
    m = net.drone.machine
    assert m.owner is None and net.drone.counters["pair_refused:first_claim"] == 2
    net.run(3.0)  # the window is over: B's next try gives it authority, epoch 4
    assert m.owner == "B" and m.epoch == 4 and m.state is State.LINKED
    tags = net.record_types()
    assert tags.index("first_claim") < tags.index("first_claim_over") < tags.index("authority")
    moved = [(r.from_, r.to, r.epoch, r.kind) for r in net.records if isinstance(r, rec.AuthorityMoved)]
    assert moved == [(None, "B", 4, "paired")] and (net.persisted.owner, net.persisted.epoch) == ("B", 4)


def test_a_restart_in_the_air_in_the_overlap_still_waits_for_its_owner_in_the_same_epoch(fleet_dir):
    """As before: LINKED(A, 3) restored, B's pairing is a link only, A re-pairs and keeps epoch 3."""
    net = _in_the_overlap_after_two_hand_overs(fleet_dir, on_ground=False)
    net.records.clear()
    net.restart_drone()
    m = net.drone.machine
    assert m.state is State.LINKED and m.owner == "A" and m.epoch == 3 and m.first_claim is None
    _b_asks_to_pair(net)
    net.run(2.5)
    assert m.owner == "A" and m.epoch == 3 and {"A", "B"} <= set(net.drone.links) and not net.commands
    assert "pair_refused:first_claim" not in net.drone.counters
    assert not [r for r in net.records if isinstance(r, (rec.AuthorityMoved, rec.FirstClaim))]


def test_a_pairing_refusal_is_answered_only_to_a_query_that_passed_its_tag_check(fleet_dir):
    """Issue 29: ``first_claim`` (with the seconds left) was answered to any query claiming to be B; a
    message 1 that fails its tag is now dropped silently and counted as such, whatever the policy says."""
    import os

    from zdrone.bench.fleetnet import WALL0
    from zdrone.core.keys import Identity
    from zdrone.core.pairing import PairRefused, PairRefusal

    net = _in_the_overlap_after_two_hand_overs(fleet_dir, on_ground=True)
    net.restart_drone()
    assert net.drone.machine.first_claim == "A"
    drone_public = net.fleet.nodes["d1"].public_bytes
    forged = PairingInitiator(Identity(os.urandom(32)), "B", "d1", drone_public).start()  # not B's key
    ans, outs = net.drone.on_pair_query("B", forged, net.now, os.urandom(32), WALL0 + net.now)
    assert isinstance(ans, PairRefused) and ans.reason is PairRefusal.BAD_MAC and ans.silent
    assert net.drone.counters["pair_refused:bad_mac"] == 1 and "pair_refused:first_claim" not in net.drone.counters
    _b_asks_to_pair(net)  # the real B's query passes its tag: refused with the reason, as before
    net.step(0.1)
    assert net.drone.counters["pair_refused:first_claim"] == 1


def _untrusted_positions(net: FleetNet) -> None:
    """From now on the vehicle's positions come over a link that is not signed (no opt-in)."""
    core = net.drone
    on_vehicle = core.on_vehicle
    core.on_vehicle = lambda pos, on_ground, now, trusted=True: on_vehicle(pos, on_ground, now, False)  # type: ignore[method-assign]


def test_an_untrusted_position_is_inside_no_coverage_so_it_makes_no_heir(fleet_dir):
    """Issue 29, behaviour 4: a position that did not come signed grants no authority. The same flight as
    the heir test above: in the overlap, the owner lost -- with unsigned positions, the failsafe, not B."""
    net = linked(fleet_dir)
    net.on_ground = False
    a, b = net.centre("A"), net.centre("B")
    net.fly(a, net.between(a, b, 0.5), 10.0)
    assert net.drone.machine.is_heir("B")
    _untrusted_positions(net)
    net.step()
    m = net.drone.machine
    assert m.inside == frozenset() and not m.is_heir("B") and net.drone.position is not None
    assert net.drone.report(net.now)["position"] is not None  # still shown, never counted
    net.hung.add("A")
    net.run(4.0)
    assert m.state is State.FAILSAFE and m.owner == "A" and [c.command for c in net.commands] == ["LAND"]
    assert not any(isinstance(r, rec.AuthorityMoved) and r.to == "B" for r in net.records)


def test_an_untrusted_position_grants_no_first_pairing(fleet_dir):
    """A fresh drone pairs only with a GS whose coverage holds its position: an unsigned one holds none."""
    net = FleetNet(fleet_dir)
    _untrusted_positions(net)
    net.add_gs("A", pair=True)
    net.run(3.0)
    assert net.drone.machine.owner is None and net.drone.counters["pair_refused:outside_coverage"] >= 1


def test_a_late_companion_loop_judges_its_links_after_what_waited_in_its_queue(fleet_dir):
    """The companion's loop stood still 3.5 s in the air (a stall, the machine starved) while A and B
    went on sending: what they sent waits in the adapter's queue. Handling the queue in turn (the
    vehicle's input first), the drone does not judge its authority's link by one input while a frame of
    it still waits: A never DEGRADED or LOST, no failsafe, A still commands. (Judged after each input,
    A's link was LOST at the vehicle's input and the drone landed.) Its silence is judged by the
    timer, after the queue."""
    from zdrone.bench.fleetnet import WALL0
    from zdrone.core.tbm import LinkState

    net = linked(fleet_dir)
    net.on_ground = False
    net.run(1.0)
    queued: list[tuple[str, bytes]] = []
    net._put_up = lambda gs, a: queued.append((gs, a.payload))  # the companion's loop stands still:
    net._ask = lambda gs, a: None  # it answers no query either
    for _ in range(35):
        net.now = round(net.now + 0.1, 6)
        for name, core in net.gss.items():
            if net.now >= core.get_timer():
                net.gs_outs(name, core.handle_timer(net.now, WALL0 + net.now))
    del net._put_up, net._ask
    assert {gs for gs, _ in queued} == {"A", "B"}
    d, before = net.drone, len(net.records)
    pos = net.centre("A")
    net.drone_outs(d.on_vehicle((pos.lat, pos.lon, 30.0), False, net.now))  # the first input it takes
    for gs, payload in queued:
        net.drone_outs(d.on_envelope(gs, payload, net.now))
    timer = d.get_timer()
    if timer is not None and net.now >= timer:
        net.drone_outs(d.handle_timer(net.now))
    judged = [(r.gs, r.state) for r in net.records[before:] if isinstance(r, rec.LinkStateChanged)]
    assert all(state is LinkState.OK for gs, state in judged if gs == "A"), judged  # B's may be judged early:
    assert judged[-1:] != [("B", LinkState.LOST)], judged  # then its queued frames prove it again
    assert not net.commands and d.machine.state is State.LINKED and d.machine.owner == "A"
    # and with nothing queued, the silence is judged by the timer alone: LOST 3 s after A's last frame
    net.hung.add("A")
    net.run(3.2, dt=0.01)
    assert [c.command for c in net.commands] == ["LAND"]


def test_a_late_loop_never_hands_over_to_a_gs_that_really_went_silent_meanwhile(fleet_dir):
    """In the overlap, B goes silent and the companion's loop stands still 3.5 s; A's release to B waits
    in the queue. B's silence is judged at the first input (only the authority's own link waits for the
    timer), so the release finds B unproven: no hand-over to a GS that is gone, A keeps authority, no
    failsafe."""
    from zdrone.bench.fleetnet import WALL0
    from zdrone.core import wire

    net = linked(fleet_dir)
    net.on_ground = False
    mid = net.between(net.centre("A"), net.centre("B"), 0.5)
    net.position = mid
    net.run(3.0)
    d, m = net.drone, net.drone.machine
    assert m.owner == "A" and m.proven_in_cover("B")
    a_link = net.gss["A"].sessions["d1"].link
    net.hung.add("B")
    queued: list[tuple[str, bytes]] = []
    net._put_up = lambda gs, a: queued.append((gs, a.payload))
    net._ask = lambda gs, a: None
    for _ in range(35):
        net.now = round(net.now + 0.1, 6)
        if net.now >= net.gss["A"].get_timer():
            net.gs_outs("A", net.gss["A"].handle_timer(net.now, WALL0 + net.now))
    del net._put_up, net._ask
    queued.append(("A", a_link.seal_control(wire.HandoverRelease("B", m.epoch))))
    net.drone_outs(d.on_vehicle((mid.lat, mid.lon, 30.0), False, net.now))
    for gs, payload in queued:
        net.drone_outs(d.on_envelope(gs, payload, net.now))
    if net.now >= d.get_timer():
        net.drone_outs(d.handle_timer(net.now))
    assert m.owner == "A" and m.epoch == 1 and m.state in (State.LINKED, State.HANDOVER_PENDING), m.state
    assert not [r for r in net.records if isinstance(r, rec.HandoverComplete)] and not net.commands


def test_a_pairing_from_a_gs_the_drone_hears_under_its_live_key_costs_no_handshake(fleet_dir):
    """A drone whose word reaches its owner late (a loaded companion, a one-way fault) is re-paired by it
    after a second: it still holds the owner's key and hears it, so a handshake would mend nothing. It
    refuses as ``linked``, no crypto; once it has not heard the GS for ``LINKED_HEARD_S`` it answers as
    before (a GS it lost, or that lost it)."""
    from zdrone.bench.fleetnet import WALL0
    from zdrone.core.pairing import PairAccepted, PairRefused, PairRefusal
    from zdrone.nodes.drone_core import LINKED_HEARD_S

    net = linked(fleet_dir)
    drone, a = net.drone, net.gss["A"]
    answered = drone.counters["pair_answered"]

    def ask():
        m1 = PairingInitiator(a.st.identity, "A", "d1", net.fleet.nodes["d1"].public_bytes, stamp=WALL0 + net.now).start()
        return drone.on_pair_query("A", m1, net.now, bytes(32), WALL0 + net.now)[0]

    ans = ask()
    assert isinstance(ans, PairRefused) and ans.reason is PairRefusal.LINKED and not ans.crypto
    assert drone.counters["pair_refused:linked"] == 1 and drone.counters["pair_answered"] == answered
    b = net.gss["B"]  # a GS that is not the owner pairs as before (the rule is the owner's silence rule's)
    m1 = PairingInitiator(b.st.identity, "B", "d1", net.fleet.nodes["d1"].public_bytes, stamp=WALL0 + net.now).start()
    assert isinstance(drone.on_pair_query("B", m1, net.now, bytes(32), WALL0 + net.now)[0], PairAccepted)
    answered += 1
    net.cut.add("A")  # A's frames stop reaching the drone
    net.run(LINKED_HEARD_S + 0.2)
    ans = ask()
    assert isinstance(ans, PairAccepted) and drone.counters["pair_answered"] == answered + 1
