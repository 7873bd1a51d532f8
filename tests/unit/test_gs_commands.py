"""What a GS counts as commands sent is what the drone forwards, in memory (``zdrone.bench.fleetnet``:
the drone's and the GSs' pure cores, real crypto, explicit time): from the moment a GS sends its
HANDOVER_RELEASE, or learns it no longer owns the drone (a revision revoked it), no frame that commands
the vehicle leaves it, whichever part of the GS made it, and none is counted."""

from __future__ import annotations

import pytest
from pymavlink.dialects.v20 import common as mav

from zdrone.bench.fleetnet import FleetNet, make_fleet
from zdrone.core.authority import HaDrop, State
from zdrone.core.revision import Changes, apply_revision, make_revision, with_revoked
from zdrone.fleet.files import load_base_fleet, load_fleet_signing_key


@pytest.fixture(scope="module")
def fleet_dir(tmp_path_factory):
    return make_fleet(tmp_path_factory.mktemp("fleet"))


def command(core) -> bytes:
    return core.codec.encode(mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_REQUEST_MESSAGE, 0, 242, 0, 0, 0, 0, 0, 0))


def armed_net(fleet_dir) -> FleetNet:
    net = FleetNet(fleet_dir)
    net.add_gs("A", pair=True, command_rate=5.0)
    net.add_gs("B", command_rate=5.0)
    net.run(4.0)
    for core in net.gss.values():
        core.sessions["d1"].armed = True  # the vehicle's HEARTBEAT would say so: the command stream runs
    net.on_ground = False
    return net


def test_from_its_release_on_a_gs_sends_and_counts_no_command(fleet_dir):
    net = armed_net(fleet_dir)
    a_core = net.gss["A"]
    a, b = net.centre("A"), net.centre("B")
    for i in range(1, 301):
        net.position = net.between(a, b, i / 300)
        net.step(0.1)
        if not a_core.holds_authority("d1"):
            break  # A's release is out (the drone may already name B)
    else:
        pytest.fail("A never released")
    sent = a_core.commands_sent("d1")
    assert a_core.send_frame("d1", command(a_core)) == [] and a_core.commands_sent("d1") == sent
    assert a_core.counters["command_not_sent"] == 1
    net.fly(net.position, b, 10.0)
    m = net.drone.machine
    assert m.owner == "B" and m.state is State.LINKED
    for g, core in net.gss.items():
        assert core.commands_sent("d1") == net.drone.forwarded[g], g
    assert a_core.commands_sent("d1") == sent and net.gss["B"].commands_sent("d1") > 0
    assert m.drops[HaDrop.NOT_AUTHORITY] == 0


def test_a_gs_the_fleet_revoked_stops_commanding_at_once(fleet_dir):
    net = armed_net(fleet_dir)
    a_core = net.gss["A"]
    net.run(2.0)
    assert a_core.holds_authority("d1") and a_core.commands_sent("d1") > 0
    base = load_base_fleet(fleet_dir)
    fleet = apply_revision(base, make_revision(base, 1, with_revoked(Changes(), "A"), load_fleet_signing_key(fleet_dir, base)))
    a_core.fleet = fleet  # A hears the revision before the drone does
    sent, pairs = a_core.commands_sent("d1"), a_core.counters["pair_sent"]
    net.run(3.0)
    assert not a_core.holds_authority("d1") and a_core.commands_sent("d1") == sent
    assert a_core.counters["pair_sent"] == pairs  # no re-pairing of a drone it may no longer command
    assert a_core.commands_sent("d1") == net.drone.forwarded["A"]
