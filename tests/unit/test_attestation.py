"""The drone's signed word on who commands it (``zdrone.core.attestation``), in memory with explicit time:
the drone's status carries a valid attestation after pairing and after each hand-over, signed once per
change (never per status); the GSs pass it on in their picture for the viewer as it came."""

from __future__ import annotations

import pytest

from zdrone.bench.fleetnet import FleetNet, make_fleet
from zdrone.core.attestation import Attester, attestation_valid
from zdrone.core.keys import SigningKey
from zdrone.core.opspicture import FleetPicture, OpsReport
from zdrone.core.wire import AuthorityState
from zdrone.fleet.files import load_secret


@pytest.fixture(scope="module")
def fleet_dir(tmp_path_factory):
    return make_fleet(tmp_path_factory.mktemp("fleet"))


class _Counting(Attester):
    """Records what every status sent asked to be attested (in order)."""

    def __init__(self, *a) -> None:
        super().__init__(*a)
        self.asked: list[tuple] = []

    def attest(self, owner, epoch, state, pending_to, wall):
        self.asked.append((owner, epoch, state, pending_to))
        return super().attest(owner, epoch, state, pending_to, wall)

    def changes(self) -> int:
        return sum(1 for i, t in enumerate(self.asked) if i == 0 or t != self.asked[i - 1])


def _signing_net(fleet_dir) -> FleetNet:
    net = FleetNet(fleet_dir)
    key = load_secret(fleet_dir, "d1", net.fleet).signing
    assert key is not None
    net.drone.attester = _Counting("d1", key)  # as the drone node's adapter hands it the key from its secret
    return net


def test_an_attester_signs_once_per_change_and_its_word_checks_only_for_its_drone():
    key = SigningKey.generate()
    att = Attester("d1", key)
    first = att.attest("A", 1, AuthorityState.LINKED, None, 100.0)
    assert att.attest("A", 1, AuthorityState.LINKED, None, 101.0) is first and att.signed == 1
    pending = att.attest("A", 1, AuthorityState.HANDOVER_PENDING, "B", 102.0)
    assert att.signed == 2 and pending.pending_to == "B"
    assert attestation_valid("d1", first, [key.public]) and attestation_valid("d1", pending, [key.public])
    assert not attestation_valid("d2", first, [key.public])  # the drone's name is inside what it signed
    assert not attestation_valid("d1", first, [SigningKey.generate().public])


def test_the_status_carries_a_valid_attestation_after_pairing_and_each_hand_over_signed_once_per_change(fleet_dir):
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
    sent = len(net.drone.attester.asked)
    assert signed == net.drone.attester.signed == net.drone.attester.changes()
    net.run(5.0)  # status beacons: no new signature
    assert len(net.drone.attester.asked) >= sent + 4 and net.drone.counters["attestations_signed"] == signed
    net.on_ground = False
    net.fly(net.centre("A"), net.centre("B"), 30.0)
    assert (net.drone.machine.owner, net.drone.machine.epoch) == ("B", 2)
    # one signature per change the statuses told (B's epoch among them), none per status
    assert net.drone.counters["attestations_signed"] == net.drone.attester.changes() > signed
    assert ("B", 2, AuthorityState.LINKED, None) in net.drone.attester.asked
    picture = FleetPicture({"d1": public})
    for gs in ("A", "B"):
        ops = net.gss[gs].drone_ops("d1", net.now)
        assert ops.attest is not None and (ops.attest.owner, ops.attest.epoch) == ("B", 2)
        assert attestation_valid("d1", ops.attest, public)
        picture.on_report(OpsReport(gs, 0.0, 0, 1, [ops], []), net.now)
    row = picture.drone("d1", net.now)
    assert (row["owner"], row["epoch"], row["verified"], row["unverified"]) == ("B", 2, True, [])
    assert picture.check.checked == 1  # the same word from both GSs: one signature check
