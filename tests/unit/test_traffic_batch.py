"""bench traffic's fix: a drone's pass to one GS under one envelope (``SecureLink.seal_batch``), its
items checked one by one, the in-memory fleet flying batched, and each receiver's count by kind
(``zdrone.core.linktraffic``)."""

from __future__ import annotations

import pytest
from pymavlink.dialects.v20 import common as mav

from zdrone.bench.fleetnet import FleetNet, make_fleet
from zdrone.bench.traffic import _rates
from zdrone.core import bundle, wire
from zdrone.core import records as rec
from zdrone.core.authority import State
from zdrone.core.envelope import DropReason, Dropped, Opened, SecureLink
from zdrone.core.keys import LinkKey
from zdrone.core.linktraffic import LinkTraffic
from zdrone.core.mavlink import FrameCodec


def _pair(cipher: str = "zdrone") -> tuple[SecureLink, SecureLink]:
    key = LinkKey.from_secret("d1", "A", bytes(range(32)))
    drone = SecureLink(key=key, role="drone", tx_keyexpr="zdrone/d1/down/A", rx_keyexpr="zdrone/d1/up/A/0",
                       peer_sysid=255, now=0.0, cipher=cipher)
    gs = SecureLink(key=key, role="gs", tx_keyexpr="zdrone/d1/up/A/0", rx_keyexpr="zdrone/d1/down/A",
                    peer_sysid=1, now=0.0, cipher=cipher)
    return drone, gs


def _frames(n: int, sysid: int = 1) -> list[bytes]:
    codec = FrameCodec(sysid, 1)
    return [codec.encode(mav.MAVLink_global_position_int_message(i, 473977420, 85455940, 30000, 30000, 0, 0, 0, 0))
            for i in range(n)]


def test_a_batch_costs_one_envelope_and_opens_to_its_items_in_order():
    drone, gs = _pair()
    frames = _frames(3)
    status = wire.encode_control(wire.AuthorityStatus("A", 1, wire.AuthorityState.LINKED))
    sealed = drone.seal_batch([*frames, status])
    inner = sum(len(f) for f in frames) + len(status)
    assert len(sealed) == inner + 24 + 1 + 2 * 4  # one header and tag, the batch's prefix and lengths
    assert drone.sent == 4
    got = gs.open(sealed, 0.5)
    assert isinstance(got, Opened) and [i.plaintext for i in got.items()] == [*frames, status]
    assert [i.header.msgid for i in got.items()[:3]] == [mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT] * 3
    assert isinstance(got.items()[3].control, wire.AuthorityStatus) and gs.opened == 4
    assert isinstance(gs.open(sealed, 0.6), Dropped)  # one counter for the batch: replayed whole
    single = drone.seal_batch(frames[:1])  # one message is sealed as itself
    assert len(single) == len(frames[0]) + 24 and gs.open(single, 0.7).items()[0].plaintext == frames[0]


def test_a_bad_item_of_an_authentic_batch_is_dropped_alone_and_a_gs_cannot_send_a_batch():
    drone, gs = _pair()
    good, foreign = _frames(1)[0], _frames(1, sysid=9)[0]
    got = gs.open(drone.seal(wire.BATCH_PREFIX + bundle.pack([good, foreign, b"\x01junk"])), 0.5)
    assert isinstance(got, Opened) and [i.plaintext for i in got.items()] == [good]
    assert gs.drops[DropReason.SYSID_MISMATCH] == 1 and gs.drops[DropReason.BAD_INNER] == 1
    assert isinstance(gs.open(drone.seal(wire.BATCH_PREFIX + b"\x00"), 0.6), Dropped)  # not a bundle
    # uplinks carry one message per envelope: the drone reads a batch as a bad control message
    up = gs.seal(wire.BATCH_PREFIX + bundle.pack([_frames(1, sysid=255)[0]] * 2))
    res = drone.open(up, 0.7)
    assert isinstance(res, Dropped) and res.reason is DropReason.BAD_INNER
    with pytest.raises(ValueError):
        gs.seal_batch([good, good])


@pytest.fixture(scope="module")
def fleet_dir(tmp_path_factory):
    return make_fleet(tmp_path_factory.mktemp("fleet"))


def test_the_in_memory_fleet_flies_both_hand_overs_batched(fleet_dir):
    net = FleetNet(fleet_dir, batch=True)
    net.add_gs("A", pair=True)
    net.add_gs("B")
    net.run(4.0)
    m = net.drone.machine
    assert m.owner == "A" and m.state is State.LINKED and set(net.drone.links) == {"A", "B"}
    a, b = net.centre("A"), net.centre("B")
    net.on_ground = False
    net.fly(a, b, 30.0)
    assert (m.owner, m.epoch) == ("B", 2)
    net.fly(b, a, 30.0)
    assert (m.owner, m.epoch) == ("A", 3) and not net.commands
    moves = [(r.from_, r.to) for r in net.records if isinstance(r, rec.HandoverComplete)]
    assert moves == [("A", "B"), ("B", "A")]
    heard = net.gss["A"].traffic.kinds
    # every step's frames and statuses to A came in fewer envelopes than messages
    assert heard["envelope"][0] < heard["mavlink"][0] + heard["status"][0] and heard["batch"][0] > 0
    assert heard["envelope"][1] == 24 * heard["envelope"][0]


def test_the_receivers_count_by_kind_and_the_bench_adds_them_up():
    drone, gs = _pair()
    t = LinkTraffic()
    frames = _frames(2)
    st = wire.AuthorityStatus("A", 1, wire.AuthorityState.LINKED, audit=wire.AuditHead(3, bytes(32), bytes(64)),
                              attest=wire.AuthorityAttestation("A", 1, wire.AuthorityState.LINKED, None, False, None, 1.5, 1,
                                                                 bytes(64)))
    plain = [*frames, wire.encode_control(st)]
    sealed = drone.seal_batch(plain)
    t.heard(sealed, gs.open(sealed, 0.1))
    k = t.kinds
    assert k["mavlink"] == [2, sum(len(f) for f in frames)] and k["envelope"] == [1, 24] and k["batch"] == [1, 1 + 2 * 3]
    assert k["attestation"][0] == k["audit_head"][0] == k["status"][0] == 1
    assert k["status"][1] + k["attestation"][1] + k["audit_head"][1] == len(plain[2])
    assert sum(c[1] for c in k.values()) == len(sealed)
    tap = {"first": 0.0, "last": 60.0, "keys": {"zdrone/d1/down/A": [1, len(sealed) + 2, 1], "zdrone/d1/up/A/0": [0, 0, 0],
                                                  "zdrone-fleet/revision/A": [6, 600, 6]}}
    r = _rates(tap, {"up": {}, "down": t.report()})
    assert r["down"]["frames"] == 3 and r["down"]["kinds"]["bundle_and_unopened"]["bytes_per_min"] == 2.0
    assert r["bytes_per_min"] == len(sealed) + 2 and r["revision_push"] == {"per_min": 6.0, "bytes_per_min": 600.0}
