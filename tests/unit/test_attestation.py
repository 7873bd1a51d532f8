"""The drone's signed word on who commands it (``zdrone.core.attestation``), in memory with explicit time:
the drone's status carries a valid attestation after pairing and after each hand-over, signed anew at
every status beacon and at every change (its counter rising), reused between them; the GSs pass it on in
their picture for the viewer as it came."""

from __future__ import annotations

import msgspec
import pytest

from zdrone.bench.fleetnet import FleetNet, make_fleet
from zdrone.core.attestation import BEACON_S, Attester, attestation_valid
from zdrone.core.keys import SigningKey
from zdrone.core.opspicture import FleetPicture, OpsReport
from zdrone.core.wire import AuthorityState, AuthorityStatus, encode_control
from zdrone.fleet.files import load_secret


@pytest.fixture(scope="module")
def fleet_dir(tmp_path_factory):
    return make_fleet(tmp_path_factory.mktemp("fleet"))


class _Counting(Attester):
    """Records what every status sent asked to be attested (in order), and whether a beacon asked."""

    def __init__(self, *a) -> None:
        super().__init__(*a)
        self.asked: list[tuple[tuple, bool]] = []

    def attest(self, st, wall, renew=False):
        self.asked.append(((st.owner, st.epoch, st.state, st.pending_to, st.takeover, st.takeover_to), renew))
        return super().attest(st, wall, renew)

    def expected(self) -> int:
        """Signatures due: one per beacon, one per change of what the statuses said."""
        return sum(1 for i, (t, renew) in enumerate(self.asked) if renew or i == 0 or t != self.asked[i - 1][0])


def _signing_net(fleet_dir) -> FleetNet:
    net = FleetNet(fleet_dir)
    key = load_secret(fleet_dir, "d1", net.fleet).signing
    assert key is not None
    net.drone.attester = _Counting("d1", key)  # as the drone node's adapter hands it the key from its secret
    return net


def _status(owner="A", epoch=1, state=AuthorityState.LINKED, pending_to=None, **kw) -> AuthorityStatus:
    return AuthorityStatus(owner, epoch, state, pending_to, **kw)


def test_an_attester_signs_at_every_beacon_and_change_and_its_word_checks_only_for_its_drone():
    key = SigningKey.generate()
    att = Attester("d1", key)
    first = att.attest(_status(), 100.0)
    assert att.attest(_status(), 100.5) is first and att.signed == 1  # no beacon, no change: reused
    beacon = att.attest(_status(), 101.0, renew=True)  # a beacon: the same word, signed anew, newer
    assert (beacon.owner, beacon.epoch, beacon.at, beacon.seq) == ("A", 1, 101.0, 2) and beacon.sig != first.sig
    pending = att.attest(_status(state=AuthorityState.HANDOVER_PENDING, pending_to="B"), 101.2)
    window = att.attest(_status(takeover=True, takeover_to="B"), 101.3)  # the takeover window is signed too
    assert (att.signed, pending.pending_to, pending.seq, window.takeover, window.takeover_to) == (4, "B", 3, True, "B")
    for a in (first, beacon, pending, window):
        assert attestation_valid("d1", a, [key.public])
    assert not attestation_valid("d2", first, [key.public])  # the drone's name is inside what it signed
    assert not attestation_valid("d1", first, [SigningKey.generate().public])
    assert not attestation_valid("d1", msgspec.structs.replace(window, takeover_to=None), [key.public])
    assert not attestation_valid("d1", msgspec.structs.replace(beacon, seq=9), [key.public])


def test_the_status_carries_a_valid_attestation_after_pairing_and_each_hand_over_signed_per_beacon_and_change(fleet_dir):
    net = _signing_net(fleet_dir)
    public = [net.fleet.nodes["d1"].signing_public_bytes]
    net.add_gs("A", pair=True)
    net.add_gs("B")
    net.run(4.0)
    assert net.drone.machine.owner == "A"
    for gs in ("A", "B"):  # each GS keeps the drone's newest word and puts it in its picture as it came
        ops = net.gss[gs].drone_ops("d1", net.now)
        assert ops.attest is not None and (ops.attest.owner, ops.attest.epoch) == ("A", 1)
        assert ops.attest.state is AuthorityState.LINKED and attestation_valid("d1", ops.attest, public)
    signed = net.drone.counters["attestations_signed"]
    assert signed == net.drone.attester.signed == net.drone.attester.expected()
    seq = net.gss["A"].drone_ops("d1", net.now).attest.seq
    net.run(5.0)  # status beacons: a new signature each, its counter rising, and only then
    beacons = sum(1 for _, renew in net.drone.attester.asked if renew)
    assert net.drone.counters["attestations_signed"] - signed >= 4
    assert net.drone.counters["attestations_signed"] == net.drone.attester.expected()
    assert net.gss["A"].drone_ops("d1", net.now).attest.seq >= seq + 4 and beacons >= 4
    net.on_ground = False
    net.fly(net.centre("A"), net.centre("B"), 30.0)
    assert (net.drone.machine.owner, net.drone.machine.epoch) == ("B", 2)
    # one signature per beacon and per change the statuses told (B's epoch among them)
    assert net.drone.counters["attestations_signed"] == net.drone.attester.expected()
    assert any(t[:4] == ("B", 2, AuthorityState.LINKED, None) for t, _ in net.drone.attester.asked)
    picture = FleetPicture({"d1": frozenset({"A", "B"})}, {"d1": public})
    for gs in ("A", "B"):
        ops = net.gss[gs].drone_ops("d1", net.now)
        assert ops.attest is not None and (ops.attest.owner, ops.attest.epoch) == ("B", 2)
        assert attestation_valid("d1", ops.attest, public)
        picture.on_report(OpsReport(gs, 0.0, 0, 1, [ops], []), net.now, net.now)
    row = picture.drone("d1", net.now, net.now)
    assert (row["owner"], row["epoch"], row["verified"], row["unverified"]) == ("B", 2, True, [])
    assert picture.check.checked <= 2  # the same word from both GSs: one check (two if a beacon fell between)


def test_the_radio_cost_of_an_attestation_per_beacon():
    """What signing at every beacon adds on the radio: the attestation in each status (the status goes
    at every beacon anyway), at most 150 bytes; at one beacon a second to each linked GS, under 9 KB a
    minute per GS link."""
    key = SigningKey.generate()
    st = _status("GS-alpha", 12, AuthorityState.HANDOVER_PENDING, "GS-bravo", linked=["GS-alpha", "GS-bravo"],
                 takeover=True, takeover_to="GS-bravo")
    att = Attester("drone-042", key).attest(st, 1_800_000_000.123, renew=True)
    added = len(encode_control(msgspec.structs.replace(st, attest=att))) - len(encode_control(st))
    assert 100 <= added <= 150, added
    assert added * 60 / BEACON_S <= 9000


def test_the_drone_signs_its_failsafe_to_every_gs_at_once_not_at_the_next_beacon(fleet_dir):
    """Found: on its failsafe the drone sent its GSs an unsigned notice only; the viewer showed it "live,
    no failsafe" until the next beacon (up to a second)."""
    net = _signing_net(fleet_dir)
    net.add_gs("A", pair=True)
    net.add_gs("B")
    net.run(4.0)
    assert net.drone.machine.owner == "A" and "B" in net.drone.links
    net.on_ground = False
    net.cut.add("A")  # the owner's link goes silent; B covers nothing where the drone is: the failsafe
    for _ in range(1000):
        if net.drone.machine.state is AuthorityState.FAILSAFE:
            break
        net.step(0.01)
    assert net.drone.machine.state is AuthorityState.FAILSAFE
    att = net.gss["B"].drone_ops("d1", net.now).attest
    assert att is not None and att.state is AuthorityState.FAILSAFE  # in the same step, signed


def test_a_drone_whose_keys_the_fleet_rotated_signs_and_pairs_under_the_new_ones(fleet_dir):
    from zdrone.core.attestation import attestation_message
    from zdrone.core.keys import Identity, verify_signature

    net = _signing_net(fleet_dir)
    net.add_gs("A", pair=True)
    net.add_gs("B")
    net.run(4.0)
    identity, signing = Identity.generate(), SigningKey.generate()
    net.drone.adopt_own_keys(identity, signing)
    net.run(2.0)
    att = net.gss["A"].drone_ops("d1", net.now).attest
    assert verify_signature(signing.public, attestation_message("d1", att), att.sig)
    assert net.drone.responder.me is identity and net.drone.machine.owner == "A"  # live links go on
    net.drone.adopt_own_keys(None, None)  # the bundle does not hold the new keys: no word signed at all
    net.run(2.0)
    assert net.drone.attester is None
