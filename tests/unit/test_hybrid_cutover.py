"""A revision requiring the hybrid pairing: classical keys not yet proven dropped and never promoted; a
link in use re-paired hybrid, make-before-break; the classical key wiped after the grace."""

from __future__ import annotations

from collections import Counter

import pytest
from pymavlink.dialects.v20 import common as mav

from gs.actions import Ask
from gs.linking import Context, Linking, PairDue, PairPhase, Reply
from tests.corepair import make_pair
from zdrone.bench.fleetnet import WALL0, FleetNet, make_fleet
from zdrone.core import records as rec
from zdrone.core.authority import State
from zdrone.core.envelope import SecureLink
from zdrone.core.kk import is_hybrid
from zdrone.core.linkslot import PREVIOUS_GRACE, LinkSlot
from zdrone.core.mavlink import FrameCodec
from zdrone.core.pairing import PairAccepted, PairingInitiator, PairingResponder, PairRefusal, PairRefused
from zdrone.core.revision import Changes, apply_revision, make_revision
from zdrone.fleet import keyexprs
from zdrone.fleet.files import load_base_fleet, load_fleet, load_fleet_signing_key, load_secret

SECRET = bytes(range(32))


@pytest.fixture(scope="module")
def fleet_dir(tmp_path_factory):
    return make_fleet(tmp_path_factory.mktemp("fleet"))


def pq_fleet(fleet_dir):
    base = load_base_fleet(fleet_dir)
    return apply_revision(base, make_revision(base, 1, Changes(pairing_pq=True), load_fleet_signing_key(fleet_dir, base)))


def proof(net: FleetNet, gs: str, key, now: float) -> bytes:
    """GS ``gs``'s first frame under ``key``: a heartbeat, as a GS proves a new key."""
    link = SecureLink(key=key, role="gs", tx_keyexpr=keyexprs.up("d1", gs), rx_keyexpr=keyexprs.down("d1", gs),
                      peer_sysid=net.fleet.nodes["d1"].sysid, now=now)
    return link.seal(FrameCodec(net.fleet.nodes[gs].sysid, 190).encode(mav.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3)))


def test_the_report_a_classical_candidate_answered_before_the_revision_is_dropped_and_never_promoted(fleet_dir):
    net = FleetNet(fleet_dir)  # the drone alone; A's side by hand
    net.run(0.5)
    drone, me, t = net.drone, load_secret(fleet_dir, "A", net.fleet).identity, net.now
    pub = net.fleet.nodes["d1"].public_bytes
    ini = PairingInitiator(me, "A", "d1", pub, stamp=WALL0 + t)
    ans, _ = drone.on_pair_query("A", ini.start(), t, SECRET, WALL0 + t)
    assert isinstance(ans, PairAccepted)
    outs = drone.on_revision(pq_fleet(fleet_dir), t + 0.05)  # 0.05 s after the answer
    assert drone.counters["classical_dropped:candidate"] == 1 and drone.slots["A"].candidates == []
    assert "A" not in drone.probation
    assert any(isinstance(getattr(o, "record", None), rec.Drop) and o.record.reason == "classical_key" for o in outs)
    outs = drone.on_envelope("A", proof(net, "A", ini.finish(ans.reply), t), t + 0.85)  # proven 0.8 s after
    assert "A" not in drone.links and drone.machine.state is State.UNPAIRED
    assert not any(isinstance(getattr(o, "record", None), (rec.LinkConfirmed, rec.Paired)) for o in outs)
    again = PairingInitiator(me, "A", "d1", pub, stamp=WALL0 + t + 1.0)  # control: a fresh classical one
    ans, _ = drone.on_pair_query("A", again.start(), t + 1.0, SECRET, WALL0 + t + 1.0)
    assert isinstance(ans, PairRefused) and ans.reason is PairRefusal.DOWNGRADE
    hyb = PairingInitiator(me, "A", "d1", pub, stamp=WALL0 + t + 1.1, hybrid=True)
    ans, _ = drone.on_pair_query("A", hyb.start(), t + 1.1, bytes(range(1, 33)), WALL0 + t + 1.1)
    drone.on_envelope("A", proof(net, "A", hyb.finish(ans.reply), t + 1.1), t + 1.2)
    assert drone.links["A"].hybrid and drone.machine.owner == "A"


def test_a_slot_requiring_hybrid_drops_and_refuses_classical_candidates_and_fallbacks():
    p, q, r = make_pair(bytes(range(32))), make_pair(bytes(range(1, 33))), make_pair(bytes(range(2, 34)))
    slot = LinkSlot()
    slot.install(p.drone, 0.0)
    r.drone.hybrid = True
    slot.offer(q.drone, 0.0, "pair")  # classical
    slot.offer(r.drone, 0.0, "grant")
    slot.fallback = make_pair(bytes(range(3, 35))).drone  # classical: a "revert" would promote it
    assert slot.require_hybrid(True) == ["candidate", "fallback"]
    assert [c.link for c in slot.candidates] == [r.drone] and slot.fallback is None
    assert not slot.offer(make_pair(bytes(range(4, 36))).drone, 1.0, "pair") and slot.classical_refused == 1
    assert slot.open(q.gs.seal(q.heartbeat()), 1.0)[1] is None and slot.live is p.drone  # the dropped one's proof


def test_a_gs_takes_no_key_from_a_classical_exchange_answered_across_the_revision(fleet_dir):
    fleet = load_fleet(fleet_dir)
    lk = Linking(Context("A", "d1", load_secret(fleet_dir, "A", fleet).identity, fleet, Counter()))
    m1 = next(a for a in lk.on_pair(PairDue(0.0, WALL0))[0] if isinstance(a, Ask)).payload
    drone = PairingResponder(load_secret(fleet_dir, "d1", fleet).identity, "d1", {"A": fleet.nodes["A"].public_bytes},
                             frozenset({"A"}))  # the drone has not applied the revision yet
    ans = drone.answer("A", m1, 0.0, SECRET)
    lk.ctx.fleet = pq_fleet(fleet_dir)  # as ``DroneSession.revised``
    assert lk.on_pair(Reply(0.8, ans.reply, None))[1] is None
    assert lk.pair_phase is PairPhase.IDLE and lk.ctx.counters["pair_reply_refused:classical"] == 1
    assert is_hybrid(next(a for a in lk.on_pair(PairDue(2.9, WALL0 + 2.9))[0] if isinstance(a, Ask)).payload)


def test_a_classical_key_confirmed_at_the_gs_after_the_revision_is_paired_again_hybrid(fleet_dir):
    net = FleetNet(fleet_dir)
    net.add_gs("A", pair=True)
    b = net.add_gs("B")
    net.cut.add("B")  # B's key is shared and granted classically, B hears nothing yet
    net.run(4.0)
    assert not net.drone.links["B"].hybrid and b.sessions["d1"].link is None
    fleet = pq_fleet(fleet_dir)
    net.drone_outs(net.drone.on_revision(fleet, net.now))
    for core in net.gss.values():
        core.fleet = fleet
    net.cut.discard("B")
    net.run(4.0)
    s = b.sessions["d1"]
    assert b.counters["repair_hybrid"] == 1 and s.link.hybrid and s.link.key == net.drone.links["B"].key
    assert net.drone.machine.owner == "A" and not net.commands
    net.run(PREVIOUS_GRACE + 0.5)
    assert net.drone.slots["B"].previous is None and s.slot.previous is None  # the classical key wiped


def test_a_replaced_key_is_wiped_at_its_grace_end_while_the_new_one_opens_everything():
    p, q = make_pair(bytes(range(32))), make_pair(bytes(range(1, 33)), now=1.0)
    slot = LinkSlot()
    slot.install(p.drone, 0.0)
    slot.offer(q.drone, 1.0, "pair")
    assert slot.open(q.gs.seal(q.heartbeat()), 1.1)[1] is not None and slot.previous is p.drone
    for i in range(1, 40):
        slot.open(q.gs.seal(q.heartbeat()), 1.1 + 0.1 * i)
    assert slot.previous is None


def test_a_key_shared_classically_is_never_granted_after_the_owner_applies_the_revision(fleet_dir):
    """Found by an attacker's review: the revision reached the drone first; B answered A's classical
    key-sharing query; the drone refused A's classical grant; A then applied the revision, re-paired
    hybrid and granted the classical key over the hybrid link, and the drone installed it as hybrid.
    Now A drops the classical share at the revision and asks again, hybrid."""
    net = FleetNet(fleet_dir)
    a = net.add_gs("A", pair=True)
    b = net.add_gs("B")
    net.cut.add("B")
    net.hung.add("B")  # B off the radio and not answering key sharing yet
    net.run(6.0)
    fleet = pq_fleet(fleet_dir)
    net.drone_outs(net.drone.on_revision(fleet, net.now))  # the revision reaches the drone first
    net.hung.discard("B")  # B answers A's classical query now
    net.run(3.0)
    assert net.drone.counters["grant_refused:downgrade"] >= 1 and "B" not in net.drone.links
    for core in net.gss.values():
        core.fleet = fleet
    net.run(4.0)
    assert a.counters["linkkey_dropped:classical"] + a.counters["linkkey_reply_refused:classical"] >= 1
    assert a.counters["repair_hybrid"] == 1 and net.drone.links["A"].hybrid
    granted = net.drone.links.get("B")
    assert granted is not None and granted.hybrid
    assert [c.link.hybrid for c in b.sessions["d1"].slot.candidates] == [True]  # B's key came from a hybrid exchange
    net.cut.discard("B")
    net.run(2.0)
    s = b.sessions["d1"]
    assert s.link is not None and s.link.hybrid and s.link.key == net.drone.links["B"].key
