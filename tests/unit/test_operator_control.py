"""MAVLink operator control between two real station cores and the drone's real authority machine,
in memory: every step a sealed control message (the drone side's links open what the GSs send)."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import pytest

from gs.core import Log, Put, Say, StationCore
from gs.opcontrol import GRANT_WINDOW_S, Answer
from zdrone.core import authority as ha
from zdrone.core import wire
from zdrone.core.envelope import Opened, SecureLink
from zdrone.core.geometry import offset
from zdrone.core.mavcontrol import OperatorControlRequest
from zdrone.core.pairing import respond
from zdrone.core.reference import HOME
from zdrone.core.tbm import LinkState
from zdrone.core.uplink import UplinkClass
from zdrone.fleet import keyexprs as kx

from tests.unit.test_station_core import core, fleet_dir, ident  # noqa: F401  (fixture)


def ask(takeover: bool = False, timeout: float = 5.0, request: bool = True) -> OperatorControlRequest:
    return OperatorControlRequest(request, takeover, timeout, 255)


@dataclass
class Net:
    """GS A (paired first: the authority) and GS B, both paired with d1, and d1's authority machine."""

    cores: dict[str, StationCore]
    machine: ha.AuthorityMachine
    drone_links: dict[str, SecureLink]
    now: float = 0.0
    logs: dict[str, list[Log]] = field(default_factory=lambda: {"A": [], "B": []})
    said: list[str] = field(default_factory=list)
    queue: deque = field(default_factory=deque)
    pumping: bool = False

    def deliver(self, gs: str, actions: list) -> None:
        """Carry out one core's actions: its sealed messages reach the drone, the drone's answers reach
        the GSs, each in the order sent (a queue, as a network delivers them)."""
        self.queue.extend((gs, a) for a in actions)
        if self.pumping:
            return
        self.pumping = True
        try:
            while self.queue:
                g, a = self.queue.popleft()
                if g == "drone":
                    self._to_gs(a)
                else:
                    self._to_drone(g, a)
        finally:
            self.pumping = False

    def _to_drone(self, gs: str, a) -> None:
        if isinstance(a, Log):
            self.logs[gs].append(a)
        elif isinstance(a, Say):
            self.said.append(a.text)
        elif isinstance(a, Put) and a.keyexpr == kx.up("d1", gs):
            res = self.drone_links[gs].open(a.payload, self.now)
            assert isinstance(res, Opened)
            if res.control is None:
                self.drone_acts(self.machine.handle(ha.Frame(self.now, gs, UplinkClass.READ_ONLY)))
            elif isinstance(res.control, wire.HandoverRequest):
                m = res.control
                self.drone_acts(self.machine.handle(ha.HandoverRequest(self.now, gs, m.to, m.timeout, m.takeover)))
            elif isinstance(res.control, wire.HandoverRelease):
                self.drone_acts(self.machine.handle(ha.Release(self.now, gs, res.control.to, res.control.epoch)))

    def _to_gs(self, a) -> None:
        sealed = self.drone_links[a.gs].seal_control(a.msg)
        self.deliver(a.gs, self.cores[a.gs].on_envelope("d1", sealed, self.now))

    def drone_acts(self, actions: list) -> None:
        self.deliver("drone", [a for a in actions if isinstance(a, ha.SendControl)])

    def run(self, until: float, step: float = 0.1) -> None:
        while self.now < until:
            self.now = round(self.now + step, 6)
            self.drone_acts(self.machine.handle(ha.Tick(self.now)))
            for g, c in self.cores.items():
                self.deliver(g, c.tick(self.now))

    def command(self, gs: str, req: OperatorControlRequest) -> Answer:
        answer, actions = self.cores[gs].operator_command(self.cores[gs].views["d1"], req, self.now)
        self.deliver(gs, actions)
        return answer

    def kinds(self, gs: str) -> list[str]:
        return [x.kind for x in self.logs[gs]]

    @property
    def owner(self) -> str | None:
        return self.machine.owner


def make_net(fleet_dir, **a_opts) -> Net:
    machine = ha.AuthorityMachine(ha.Config(authorized=frozenset({"A", "B"}), handover_timeout=2.0))
    cores = {"A": core(fleet_dir, "A", pair=True, **a_opts), "B": core(fleet_dir, "B", pair=True)}
    links: dict[str, SecureLink] = {}
    net = Net(cores, machine, links)
    machine.handle(ha.RegionChanged(0.0, frozenset({"A", "B"})))  # in both coverages: the drone listens to both
    for g, sysid in (("A", 4), ("B", 3)):
        c = cores[g]
        m1 = next(x for x in c.tick(0.0) if type(x).__name__ == "Ask")
        m2, key = respond(ident(fleet_dir, "d1"), "d1", g, c.fleet.nodes[g].public_bytes, m1.payload, bytes([sysid]) * 32)
        links[g] = SecureLink(key=key, role="drone", tx_keyexpr=kx.down("d1", g), rx_keyexpr=kx.up("d1", g),
                              peer_sysid=sysid, now=0.0)
        net.deliver(g, c.on_pair_reply("d1", m2, None, 0.0))
        net.drone_acts(machine.handle(ha.Paired(0.0, g)))
        net.drone_acts(machine.handle(ha.LinkChanged(0.0, g, LinkState.OK)))
    net.run(1.0)
    assert net.owner == "A" and cores["B"].views["d1"].owner == "A" and machine.is_proven("B")
    return net


def test_without_consent_nothing_moves(fleet_dir):
    net = make_net(fleet_dir)
    assert net.command("B", ask(timeout=3.0)) is Answer.FAILED  # the spec's answer: the owner is asked
    net.run(1.5)
    assert "operator_request" in net.kinds("A") and any("B requests control of d1" in t for t in net.said)
    a_req = net.cores["A"].views["d1"].operator.request
    assert a_req is not None and (a_req.requester, a_req.to, a_req.timeout) == ("B", "B", 3.0)
    net.run(6.0)
    assert net.owner == "A" and net.machine.epoch == 1
    assert "operator_request_expired" in net.kinds("A") and "operator_request_timed_out" in net.kinds("B")
    assert net.kinds("A").count("operator_request") == 1  # B's re-sends are the same request, shown once


def test_consent_by_release_hands_control_to_the_requester_which_holds_it(fleet_dir):
    net = make_net(fleet_dir)
    net.command("B", ask(timeout=10.0))
    net.run(1.5)
    assert net.command("A", ask(request=False)) is Answer.ACCEPTED  # A's operator: release to the requester
    net.run(2.0)
    assert (net.owner, net.machine.epoch) == ("B", 2)
    b = net.cores["B"].views["d1"]
    assert "operator_control_taken" in net.kinds("B") and b.operator.holds(b)
    assert net.cores["B"].holds_authority(b) and not net.cores["A"].holds_authority(net.cores["A"].views["d1"])
    b.position = offset(HOME, 0.0, 200.0)  # in the overlap, nearer A: B would hand back to A by itself
    net.run(5.0)
    assert net.owner == "B"  # held: no automatic hand-over while B's operator holds control
    assert net.command("B", ask(request=False)) is Answer.ACCEPTED  # B's operator lets go
    assert "operator_control_let_go" in net.kinds("B")
    net.run(6.0)
    assert (net.owner, net.machine.epoch) == ("A", 3)  # the automatic hand-over toward A's centre


def test_consent_by_allowing_takeover_grants_now_and_for_the_window(fleet_dir):
    net = make_net(fleet_dir)
    net.command("B", ask(timeout=10.0))
    net.run(1.5)
    assert net.command("A", ask(takeover=True)) is Answer.ACCEPTED
    net.run(2.0)
    assert net.owner == "B"
    a = net.cores["A"].views["d1"].operator
    assert a.window_until is not None and not a.allow_takeover  # the window, not the standing setting
    granted = [x for x in net.logs["A"] if x.kind == "operator_request_granted"]
    assert granted and granted[0].fields["requester"] == "B"


def test_declined_requests_and_late_answers_move_nothing(fleet_dir):
    net = make_net(fleet_dir)
    net.command("B", ask(timeout=10.0))
    net.run(1.5)
    net.command("A", ask(takeover=False))  # A's operator re-requests with p2 = 0: declined
    assert "operator_request_declined" in net.kinds("A")
    net.run(3.0)
    assert net.command("A", ask(request=False)) is Answer.ACCEPTED  # nobody asking any more: nothing to give
    net.run(5.0)
    assert net.owner == "A" and net.machine.epoch == 1


def test_with_takeover_allowed_the_request_takes_control_at_once(fleet_dir):
    net = make_net(fleet_dir, allow_takeover=True)  # ``zdrone gs --allow-takeover`` at A
    net.run(2.0)
    assert net.machine.status().takeover and net.cores["B"].views["d1"].takeover  # what B's CONTROL_STATUS says
    b = net.cores["B"].views["d1"]
    assert b.operator.shown_takeover(b, net.now)
    t0 = net.now
    assert net.command("B", ask(takeover=False)) is Answer.IN_PROGRESS
    net.run(t0 + 0.2, step=0.05)
    assert net.owner == "B" and net.machine.epoch == 2
    assert not net.machine.status().takeover  # B's own setting (p2 = 0) holds in its epoch
    net.run(t0 + 1.0)
    assert not b.takeover and not b.operator.shown_takeover(b, net.now)
    assert net.command("A", ask(timeout=3.0)) is Answer.FAILED  # A must now ask B's operator
    net.run(t0 + 6.0)
    assert net.owner == "B"


def test_the_owners_apps_set_takeover_and_the_requesters_p2_is_its_own_setting(fleet_dir):
    net = make_net(fleet_dir)
    net.command("A", ask(takeover=True))  # nobody asking: A's standing setting
    net.run(1.5)
    assert net.machine.status().takeover
    net.command("B", ask(takeover=True))
    net.run(2.0)
    assert net.owner == "B"
    net.run(3.0)
    assert net.machine.status().takeover  # B allows takeover in its epoch, as its request said
    net.command("A", ask())
    net.run(3.5)
    assert net.owner == "A" and net.machine.epoch == 3


def test_a_passed_on_request_for_another_epoch_or_at_a_non_owner_is_ignored(fleet_dir):
    net = make_net(fleet_dir)
    b = net.cores["B"]
    out = b._on_control(b.views["d1"], wire.OperatorRequest("A", "A", 1, 5.0), net.now)  # B is not the owner
    assert [x.kind for x in out if isinstance(x, Log)] == ["operator_request_stale"]
    a = net.cores["A"]
    out = a._on_control(a.views["d1"], wire.OperatorRequest("B", "B", 7, 5.0), net.now)  # another epoch
    assert [x.kind for x in out if isinstance(x, Log)] == ["operator_request_stale"]
    assert a.views["d1"].operator.request is None


def test_no_link_no_request(fleet_dir):
    c = core(fleet_dir, "B")
    answer, actions = c.operator_command(c.views["d1"], ask(), 0.0)
    assert answer is Answer.TEMPORARILY_REJECTED and actions == []


def test_the_grant_window_closes(fleet_dir):
    net = make_net(fleet_dir)
    net.command("B", ask(timeout=10.0))
    net.run(1.5)
    net.command("A", ask(takeover=True))
    net.run(1.5 + GRANT_WINDOW_S + 0.5)
    a = net.cores["A"].views["d1"].operator
    assert a.window_until is None and "takeover_window_closed" in net.kinds("A")
