"""A GS that just became a drone's owner never decides a release from a position heard before its
authority (in memory: the drone's and the GSs' pure cores, ``zdrone.bench.fleetnet``, real crypto):
the standby stream gave it positions up to an interval old, and a new owner deciding from one of them
would hand the drone straight back. A position reported after the status that made it the owner counts."""

from __future__ import annotations

import pytest
from pymavlink.dialects.v20 import common as mav

from zdrone.bench.fleetnet import FleetNet, make_fleet
from zdrone.core import wire
from zdrone.core.authority import State


@pytest.fixture(scope="module")
def fleet_dir(tmp_path_factory):
    return make_fleet(tmp_path_factory.mktemp("fleet"))


def test_a_new_owner_releases_only_from_a_position_reported_after_its_authority(fleet_dir):
    net = FleetNet(fleet_dir)
    net.add_gs("A", pair=True)
    b_core = net.add_gs("B")
    net.run(4.0)
    assert net.drone.machine.owner == "A" and set(net.drone.links) == {"A", "B"}
    a, b = net.centre("A"), net.centre("B")
    here = net.between(a, b, 0.4)  # inside both coverages, nearer A's centre: B would release toward A
    link = net.drone.links["B"]  # what the drone seals to B, as it would

    def position() -> bytes:
        return link.seal(net.codec.encode(mav.MAVLink_global_position_int_message(
            0, int(here.lat * 1e7), int(here.lon * 1e7), 30000, 30000, 0, 0, 0, 0)))

    epoch = net.drone.machine.epoch + 1
    status = link.seal_control(wire.AuthorityStatus("B", epoch, State.LINKED, linked=["A", "B"]))
    t = net.now + 0.01
    b_core.on_envelope("d1", position(), t)  # a standby position, heard before B's authority
    b_core.on_envelope("d1", status, t)
    b_core.handle_timer(t)
    assert b_core.holds_authority("d1") and b_core.counters["release_waits_position"] >= 1  # not from that one
    b_core.on_envelope("d1", position(), t + 0.01)  # the drone's next report: after the authority change
    b_core.handle_timer(t + 0.01)
    assert not b_core.holds_authority("d1")  # released toward A, from a position it may trust
    assert b_core.sessions["d1"].handover.to == "A"
