"""MAVLink operator control between two real station cores and the drone's real authority machine,
in memory: every step a sealed control message (the drone side's links open what the GSs send)."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import pytest
from pymavlink.dialects.v20 import common as mav

from gs.actions import Emit, Put, ToOperator
from gs.core import StationCore
from gs.gateway import GcsGateway
from gs.opcontrol import CONSENT_READ_S, DECLINE_HOLD_S, GRANT_WINDOW_S, Answer
from zdrone.core import authority as ha
from zdrone.core import wire
from zdrone.core.envelope import Opened, SecureLink
from zdrone.core.geometry import offset
from zdrone.core.mavcontrol import (FLAG_SYSTEM_MANAGER, FLAG_TAKEOVER_ALLOWED, MAV_CMD_REQUEST_OPERATOR_CONTROL,
                                    MAV_RESULT_NOT_IN_CONTROL, ControlStatus, OperatorControlRequest,
                                    decode_control_status, encode_control_status)
from zdrone.core.mavlink import FrameCodec
from zdrone.core.pairing import respond
from zdrone.core.records import HandoverComplete
from zdrone.core.reference import HOME
from zdrone.core.tbm import LinkState
from zdrone.core.uplink import UplinkClass
from zdrone.fleet import keyexprs

from tests.unit.test_gateway_apps import MemTransport, StubEvents
from tests.unit.test_station_core import core, fleet_dir, ident  # noqa: F401  (fixture)


SYSID = {"A": 4, "B": 3, "X": 7}


def ask(takeover: bool = False, timeout: float = 5.0, request: bool = True, p4: int = 255) -> OperatorControlRequest:
    return OperatorControlRequest(request, takeover, timeout, p4)


def consent(to: str = "B", takeover: bool = False, request: bool = False) -> OperatorControlRequest:
    """The owner's operator answering the request it was shown (p4: the requester's sysid)."""
    return OperatorControlRequest(request, takeover, 5.0, SYSID[to])


@dataclass
class Net:
    """GS A (paired first: the authority) and GS B, both paired with d1, and d1's authority machine."""

    cores: dict[str, StationCore]
    machine: ha.AuthorityMachine
    drone_links: dict[str, SecureLink]
    now: float = 0.0
    logs: dict[str, list[Emit]] = field(default_factory=lambda: {"A": [], "B": [], "X": []})
    said: list[str] = field(default_factory=list)
    queue: deque = field(default_factory=deque)
    gateways: dict[str, GcsGateway] = field(default_factory=dict)
    vehicle: FrameCodec = field(default_factory=lambda: FrameCodec(1, 1))
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
        if isinstance(a, Emit):
            self.logs[gs].append(a)
        elif isinstance(a, ToOperator):
            self.said.append(a.text)
        elif isinstance(a, Put) and a.peer == "d1":
            res = self.drone_links[gs].open(a.payload, self.now)
            assert isinstance(res, Opened)
            if res.control is None:
                self.drone_acts(self.machine.handle(ha.Frame(self.now, gs, UplinkClass.READ_ONLY)))
            elif isinstance(res.control, wire.HandoverRequest):
                m = res.control
                self.drone_acts(self.machine.handle(ha.AuthorityAsked(self.now, gs, m.to, m.timeout, m.takeover, m.ask_id, m.takeover_to)))
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
            for g in self.machine.telemetry_targets():  # the vehicle's heartbeat: the GSs hear the drone
                frame = self.vehicle.encode(mav.MAVLink_heartbeat_message(2, 12, 0, 0, 4, 3))
                self.deliver(g, self.cores[g].on_envelope("d1", self.drone_links[g].seal(frame), self.now))
            for g, c in self.cores.items():
                self.deliver(g, c.handle_timer(self.now))
            for gw in self.gateways.values():
                gw.poll(self.now)

    def command(self, gs: str, req: OperatorControlRequest) -> Answer:
        answer, actions = self.cores[gs].operator_command(self.cores[gs].sessions["d1"], req, self.now)
        self.deliver(gs, actions)
        return answer

    def kinds(self, gs: str) -> list[str]:
        return [x.kind for x in self.logs[gs]]

    @property
    def owner(self) -> str | None:
        return self.machine.owner


@pytest.fixture(scope="module")
def fleet3_dir(tmp_path_factory):
    """A fleet whose d1 has three authorized GSs: A, B and X (X's coverage at home, as A's)."""
    from zdrone.core.reference import DEFAULT_NODES
    from zdrone.fleet.files import init_fleet

    d = tmp_path_factory.mktemp("fleet3")
    nodes = [(n, r, sid, c, ["A", "B", "X"] if n == "d1" else a) for n, r, sid, c, a in DEFAULT_NODES]
    init_fleet(d, nodes_spec=nodes)
    return d


def make_net(fleet_dir, gss: tuple[str, ...] = ("A", "B"), **a_opts) -> Net:
    machine = ha.AuthorityMachine(ha.Config(authorized=frozenset(gss), handover_timeout=2.0))
    cores = {g: core(fleet_dir, g, pair=True, **(a_opts if g == "A" else {})) for g in gss}
    links: dict[str, SecureLink] = {}
    net = Net(cores, machine, links)
    machine.handle(ha.RegionChanged(0.0, frozenset(gss)))  # in every coverage: the drone listens to all
    for g in gss:
        sysid = cores[g].fleet.nodes[g].sysid
        c = cores[g]
        m1 = next(x for x in c.handle_timer(0.0) if type(x).__name__ == "Ask")
        m2, key = respond(ident(fleet_dir, "d1"), "d1", g, c.fleet.nodes[g].public_bytes, m1.payload, bytes([sysid]) * 32)
        links[g] = SecureLink(key=key, role="drone", tx_keyexpr=keyexprs.down("d1", g), rx_keyexpr=keyexprs.up("d1", g),
                              peer_sysid=sysid, now=0.0)
        net.deliver(g, c.on_pair_reply("d1", m2, None, 0.0))
        net.drone_acts(machine.handle(ha.PairingDone(0.0, g)))
        net.drone_acts(machine.handle(ha.LinkChanged(0.0, g, LinkState.OK)))
    net.run(1.0)
    assert net.owner == "A" and cores["B"].sessions["d1"].owner == "A" and machine.is_proven("B")
    return net


def test_without_consent_nothing_moves(fleet_dir):
    net = make_net(fleet_dir)
    assert net.command("B", ask(timeout=3.0)) is Answer.FAILED  # the spec's answer: the owner is asked
    net.run(1.5)
    assert "operator_request" in net.kinds("A") and any("B requests control of d1" in t for t in net.said)
    a_req = net.cores["A"].sessions["d1"].operator.request
    assert a_req is not None and (a_req.requester, a_req.to, a_req.timeout) == ("B", "B", 3.0)
    net.run(6.0)
    assert net.owner == "A" and net.machine.epoch == 1
    assert "operator_request_expired" in net.kinds("A") and "operator_request_timed_out" in net.kinds("B")
    assert net.kinds("A").count("operator_request") == 1  # B's re-sends are the same request, shown once


def test_consent_by_release_hands_control_to_the_requester_which_holds_it(fleet_dir):
    net = make_net(fleet_dir)
    net.command("B", ask(timeout=10.0))
    net.run(1.5)
    assert net.command("A", ask(request=False)) is Answer.DENIED  # p4 must name the requester (B: 3)
    assert net.owner == "A" and "operator_consent_refused" in net.kinds("A")
    assert net.command("A", consent("B")) is Answer.ACCEPTED  # A's operator: release to the requester
    net.run(2.0)
    assert (net.owner, net.machine.epoch) == ("B", 2)
    b = net.cores["B"].sessions["d1"]
    assert "operator_control_taken" in net.kinds("B") and b.operator.holds(b)
    assert net.cores["B"].holds_authority(b) and not net.cores["A"].holds_authority(net.cores["A"].sessions["d1"])
    b.position = offset(HOME, 0.0, 200.0)  # in the overlap, nearer A: B would hand back to A by itself
    net.run(5.0)
    assert net.owner == "B"  # held: no automatic hand-over while B's operator holds control
    assert net.command("B", ask(request=False)) is Answer.ACCEPTED  # B's operator lets go
    assert "operator_control_let_go" in net.kinds("B")
    net.run(6.0)
    assert (net.owner, net.machine.epoch) == ("A", 3)  # the automatic hand-over toward A's centre


def test_consent_by_allowing_takeover_opens_a_window_for_the_requester_which_asks_again(fleet_dir):
    net = make_net(fleet_dir)
    net.command("B", ask(timeout=10.0))
    net.run(1.5)
    assert net.command("A", consent("B", takeover=True, request=True), ) is Answer.ACCEPTED
    a = net.cores["A"].sessions["d1"].operator
    assert a.window is not None and a.window.to == "B" and not a.allow_takeover  # the window, not a setting
    assert net.owner == "A"  # nothing moves until the requester asks again (today's flow)
    assert net.machine.status().takeover and net.machine.status().takeover_to == "B"  # told to every GS
    while net.owner == "A" and net.now < 3.0:
        net.run(net.now + 0.05, step=0.05)
    assert net.owner == "B" and net.now <= 1.5 + 0.3  # B asked again at once on hearing it
    granted = [x for x in net.logs["A"] if x.kind == "operator_request_granted"]
    assert granted and granted[0].fields["requester"] == "B" and granted[0].fields["epoch"] == 1


def test_declined_requests_and_late_answers_move_nothing(fleet_dir):
    net = make_net(fleet_dir)
    net.command("B", ask(timeout=10.0))
    net.run(1.5)
    net.command("A", consent("B", request=True))  # A's operator re-requests with p2 = 0: declined
    assert "operator_request_declined" in net.kinds("A")
    net.run(3.0)
    assert net.command("A", ask(request=False)) is Answer.ACCEPTED  # nobody asking any more: nothing to give
    net.run(5.0)
    assert net.owner == "A" and net.machine.epoch == 1


def test_with_takeover_allowed_the_request_takes_control_at_once(fleet_dir):
    net = make_net(fleet_dir, allow_takeover=True)  # ``zdrone gs --allow-takeover`` at A
    net.run(2.0)
    assert net.machine.status().takeover and net.cores["B"].sessions["d1"].takeover  # what B's CONTROL_STATUS says
    b = net.cores["B"].sessions["d1"]
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


def test_allow_takeover_is_no_standing_setting_of_an_operator_nor_of_a_requesters_p2(fleet_dir):
    """Found from outside: a late "allow takeover" (nothing pending) became the owner's setting for its epoch
    and the next asker took the drone; a requester's p2 became its setting once in control. Only the
    station's configuration is a standing setting now."""
    net = make_net(fleet_dir)
    assert net.command("A", ask(takeover=True)) is Answer.DENIED  # nothing pending: refused, not a setting
    refused = [x for x in net.logs["A"] if x.kind == "operator_consent_refused"]
    assert refused and "no request is pending" in refused[-1].fields["reason"]
    net.run(1.5)
    assert not net.machine.status().takeover
    assert net.command("B", ask(takeover=True, timeout=3.0)) is Answer.FAILED  # A's operator is asked
    net.run(net.now + 1.0)
    assert net.command("A", consent("B")) is Answer.ACCEPTED
    net.run(net.now + 1.5)
    assert net.owner == "B"
    net.run(net.now + 1.0)
    assert not net.machine.status().takeover  # B's p2 = 1 is not carried into the epoch it took
    assert net.command("A", ask(timeout=3.0)) is Answer.FAILED
    net.run(net.now + 3.5)
    assert net.owner == "B"


def test_a_passed_on_request_for_another_epoch_or_at_a_non_owner_is_ignored(fleet_dir):
    net = make_net(fleet_dir)
    b = net.cores["B"]
    out = b.sessions["d1"].on_control(wire.OperatorRequest("A", "A", 1, 5.0), net.now)  # B is not the owner
    assert [x.kind for x in out if isinstance(x, Emit)] == ["operator_request_stale"]
    a = net.cores["A"]
    out = a.sessions["d1"].on_control(wire.OperatorRequest("B", "B", 7, 5.0), net.now)  # another epoch
    assert [x.kind for x in out if isinstance(x, Emit)] == ["operator_request_stale"]
    assert a.sessions["d1"].operator.request is None


def test_no_link_no_request(fleet_dir):
    c = core(fleet_dir, "B")
    answer, actions = c.operator_command(c.sessions["d1"], ask(), 0.0)
    assert answer is Answer.TEMPORARILY_REJECTED and actions == []


def test_the_grant_window_closes(fleet_dir):
    net = make_net(fleet_dir)
    net.command("B", ask(timeout=3.0))
    net.run(1.5)
    net.command("A", consent("B", takeover=True, request=True))
    net.command("B", ask(request=False))  # B's operator withdraws: it does not ask again
    net.run(1.5 + GRANT_WINDOW_S + 0.5)
    a = net.cores["A"].sessions["d1"].operator
    assert a.window is None and "takeover_window_closed" in net.kinds("A") and net.owner == "A"


# ------------------------------------------------------------------ through the GCS gateways
class CoreStation:
    """The parts of ``GroundStation`` the gateway uses, over a real station core in the ``Net``."""

    def __init__(self, net: Net, gs: str) -> None:
        self.net, self.core = net, net.cores[gs]
        self.name, self.sysid, self.fleet, self.views = gs, self.core.sysid, self.core.fleet, self.core.sessions
        self.frame_listeners: list = []
        self.loop_hooks: list = []
        self.events = StubEvents()

    @property
    def drones(self) -> tuple[str, ...]:
        return self.core.drones

    def drone_status(self, drone: str, now: float):
        return self.core.drone_status(drone, now)

    def holds_authority(self, view) -> bool:
        return self.core.holds_authority(view)

    def send_frame(self, view, frame: bytes) -> None:
        self.net.deliver(self.name, self.core.send_frame(view, frame))

    def send_control(self, view, msg) -> None:
        self.net.deliver(self.name, self.core.send_control(view, msg))

    def operator_command(self, view, req, now: float, app: str = "", app_sysid: int | None = None) -> int:
        answer, actions = self.core.operator_command(view, req, now, app=app, app_sysid=app_sysid)
        self.net.deliver(self.name, actions)
        return int(answer)


class App:
    """One MAVLink application on a gateway (sysid 255, as QGroundControl and MAVProxy by default)."""

    def __init__(self, net: Net, gs: str, sysid: int = 255) -> None:
        self.gw = net.gateways[gs]
        self.t = self.gw.transports[0]
        self.codec = FrameCodec(sysid, 190)
        self.peer = ("127.0.0.1", 14550 + len(net.gateways))
        self.net = net
        self.seen = 0

    def send(self, msg) -> None:
        self.gw.on_app_frame(0, self.peer, self.codec.encode(msg), self.net.now)

    def request(self, p1: float, p2: float = 0, p3: float = 5, p4: float = 255) -> None:
        self.send(mav.MAVLink_command_long_message(1, 1, MAV_CMD_REQUEST_OPERATOR_CONTROL, 0, p1, p2, p3, p4, 0, 0, 0))

    def frames(self) -> list[bytes]:
        return [f for f, _ in self.t.out]

    def acks(self) -> list[tuple[int, int]]:
        out = []
        for f in self.frames():
            m = self.codec.decode(f)
            if m is not None and m.get_type() == "COMMAND_ACK":
                out.append((m.command, m.result))
        return out

    def statuses(self) -> list[ControlStatus]:
        return [st for f in self.frames() if (st := decode_control_status(f)) is not None]

    def presented(self) -> list:
        out = []
        for f in self.frames():
            m = self.codec.decode(f)
            if m is not None and m.get_type() == "COMMAND_LONG" and m.command == MAV_CMD_REQUEST_OPERATOR_CONTROL:
                out.append(m)
        return out


def with_gateways(net: Net) -> tuple[App, App]:
    for g in ("A", "B"):
        gw = GcsGateway(CoreStation(net, g), [])
        gw.transports = [MemTransport()]
        net.gateways[g] = gw
    a, b = App(net, "A"), App(net, "B")
    a.send(mav.MAVLink_heartbeat_message(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))
    b.send(mav.MAVLink_heartbeat_message(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))
    return a, b


def test_through_the_gateways_a_request_is_presented_refused_then_consented(fleet_dir):
    net = make_net(fleet_dir)
    a, b = with_gateways(net)
    net.run(net.now + 1.5)
    assert b.statuses()[-1] == ControlStatus(FLAG_SYSTEM_MANAGER, 4)  # A (sysid 4) in control, no takeover
    assert a.statuses()[-1] == ControlStatus(FLAG_SYSTEM_MANAGER, 255)  # A's own application: "you are"
    b.send(mav.MAVLink_command_long_message(1, 1, mav.MAV_CMD_DO_SET_MODE, 0, 1, 4, 3, 0, 0, 0, 0))
    assert b.acks()[-1] == (mav.MAV_CMD_DO_SET_MODE, MAV_RESULT_NOT_IN_CONTROL)
    b.send(mav.MAVLink_param_request_read_message(1, 1, b"NAV_DLL_ACT", -1))  # a read: passes
    assert net.drone_links["B"].opened >= 1 and net.cores["B"].counters["no_link"] == 0
    b.request(1, 0, 4)
    assert b.acks()[-1] == (MAV_CMD_REQUEST_OPERATOR_CONTROL, mav.MAV_RESULT_FAILED)
    net.run(net.now + 0.5)
    shown = a.presented()
    assert len(shown) == 1 and (shown[0].param1, shown[0].param3, shown[0].param4) == (1, 4, 3)  # B's sysid
    assert (shown[0].target_system, shown[0].target_component) == (255, 190)
    a.send(mav.MAVLink_command_ack_message(MAV_CMD_REQUEST_OPERATOR_CONTROL, 0, 0, 0, 1, 1))  # the app's ACK: kept
    assert net.gateways["A"].counters["operator_request_acked"] == 1
    net.run(net.now + 5.0)
    assert net.owner == "A" and b.statuses()[-1].gcs_main == 4  # no consent: nothing moved
    b.request(1, 0, 10)
    net.run(net.now + 0.5)
    assert len(a.presented()) == 2  # expired unanswered: B may ask again at once
    a.request(0, 0, 5, 7)  # p4 = X's sysid (another fleet GS, not the one shown): refused, nothing moves
    assert a.acks()[-1] == (MAV_CMD_REQUEST_OPERATOR_CONTROL, mav.MAV_RESULT_DENIED)
    a.request(0, 0, 5, 3)  # A's operator releases to the requester it was shown (p4 = B's sysid)
    assert a.acks()[-1] == (MAV_CMD_REQUEST_OPERATOR_CONTROL, mav.MAV_RESULT_ACCEPTED)
    net.run(net.now + 1.0)
    assert net.owner == "B"
    assert b.statuses()[-1] == ControlStatus(FLAG_SYSTEM_MANAGER, 255)  # B's application: "you are in control"
    assert a.statuses()[-1] == ControlStatus(FLAG_SYSTEM_MANAGER, 3)  # A's: B (sysid 3) is


def test_through_the_gateways_takeover_allowed_is_shown_and_taken_at_once(fleet_dir):
    net = make_net(fleet_dir, allow_takeover=True)  # the station's configuration: its policy, every epoch
    a, b = with_gateways(net)
    net.run(net.now + 1.5)
    assert b.statuses()[-1] == ControlStatus(FLAG_SYSTEM_MANAGER | FLAG_TAKEOVER_ALLOWED, 4)
    assert a.statuses()[-1].takeover_allowed
    b.request(1, 1, 5)  # p2 = 1: not carried into B's epoch (no standing setting from an operator)
    assert b.acks()[-1] == (MAV_CMD_REQUEST_OPERATOR_CONTROL, mav.MAV_RESULT_IN_PROGRESS)
    net.run(net.now + 0.3, step=0.05)
    assert net.owner == "B"
    assert b.acks()[-1] == (MAV_CMD_REQUEST_OPERATOR_CONTROL, mav.MAV_RESULT_ACCEPTED)  # the final answer
    assert not a.presented()  # takeover allowed: A's operator was not asked
    granted = [x for x in net.logs["A"] if x.kind == "operator_request_granted"]
    assert granted[-1].fields["decided_by"] == "station_policy" and granted[-1].fields["app"] == ""
    net.run(net.now + 1.0)
    assert b.statuses()[-1] == ControlStatus(FLAG_SYSTEM_MANAGER, 255)


def test_the_vehicles_own_control_status_and_bad_requests_stay_at_the_gateway(fleet_dir):
    net = make_net(fleet_dir)
    a, _ = with_gateways(net)
    gw = net.gateways["A"]
    before = len(a.frames())
    gw.on_drone_frame("d1", encode_control_status(ControlStatus(1, 9), 1, 1))
    assert len(a.frames()) == before and gw.counters["vehicle_control_status"] == 1
    a.request(2)  # p1 must be 0 or 1
    assert a.acks()[-1] == (MAV_CMD_REQUEST_OPERATOR_CONTROL, mav.MAV_RESULT_DENIED)
    assert gw.counters["operator_request_bad"] == 1


# ------------------------------------------------------------------ with the drone's own core
def test_with_the_drone_core_a_request_needs_consent_and_takeover_allowed_grants_it(tmp_path_factory):
    """The same steps over the shipped DroneCore (``zdrone.bench.fleetnet``): its sealed links, its
    listening rules and its pass-on of the request."""
    from zdrone.bench.fleetnet import FleetNet, make_fleet

    net = FleetNet(make_fleet(tmp_path_factory.mktemp("fleetnet")))
    a, b = net.add_gs("A", pair=True), net.add_gs("B")
    net.run(4.0)
    net.on_ground = False
    net.fly(net.centre("A"), net.between(net.centre("A"), net.centre("B"), 0.35), 8.0)  # in both coverages, nearer A
    net.run(2.0)
    m = net.drone.machine
    assert m.owner == "A" and "B" in net.listening

    def command(core: StationCore, req: OperatorControlRequest) -> Answer:
        answer, actions = core.operator_command(core.sessions["d1"], req, net.now)
        net.gs_outs(core.name, actions)
        return answer

    assert command(b, ask(timeout=3.0)) is Answer.FAILED
    net.run(1.0)
    assert a.sessions["d1"].operator.request is not None and a.sessions["d1"].operator.request.requester == "B"
    net.run(4.0)
    assert (m.owner, m.epoch) == ("A", 1)  # no consent: nothing moved
    command(b, ask(timeout=10.0))
    net.run(1.0)
    assert command(a, ask(takeover=True, request=True)) is Answer.DENIED  # p4 = 255: not the requester
    assert command(a, consent("B", takeover=True, request=True)) is Answer.ACCEPTED  # the window, for B
    assert (m.owner, m.epoch) == ("A", 1)
    net.run(1.5)  # B's request, sent again each second, is granted
    assert (m.owner, m.epoch) == ("B", 2) and b.holds_authority(b.sessions["d1"])
    moves = [(r.from_, r.to, r.kind) for r in net.records if isinstance(r, HandoverComplete)]
    assert moves == [("A", "B", "handover")]


# ------------------------------------------------------------------ consent bound to what the operator saw
def test_consent_goes_to_the_requester_it_names_never_to_whoever_asked_last(fleet3_dir):
    """B asks; X asks 1.1 s later; A's operator consents naming B (p4 = 3): B takes control, not X."""
    net = make_net(fleet3_dir, gss=("A", "B", "X"))
    assert net.command("B", ask(timeout=10.0)) is Answer.FAILED
    net.run(net.now + 1.1)
    assert net.command("X", ask(timeout=10.0)) is Answer.FAILED
    net.run(net.now + 1.5)
    op = net.cores["A"].sessions["d1"].operator
    assert op.request is not None and op.request.requester == "B"  # one pending at a time: B's
    assert "operator_request_busy" in net.kinds("A") and net.kinds("A").count("operator_request_busy") == 1
    assert net.command("A", consent("X")) is Answer.DENIED  # X is not the one shown
    refused = [x for x in net.logs["A"] if x.kind == "operator_consent_refused"]
    assert refused[-1].fields["requester"] == "B" and refused[-1].fields["named"] == "X"
    assert net.command("A", consent("B")) is Answer.ACCEPTED
    net.run(net.now + 2.0)
    assert (net.owner, net.machine.epoch) == ("B", 2)


def test_a_window_for_one_requester_does_not_let_another_in(fleet3_dir):
    net = make_net(fleet3_dir, gss=("A", "B", "X"))
    net.command("B", ask(timeout=3.0))
    net.run(net.now + 1.0)
    assert net.command("A", consent("B", takeover=True, request=True)) is Answer.ACCEPTED
    net.command("B", ask(request=False))  # B's operator withdraws before it is granted
    net.run(net.now + 0.6)
    x = net.cores["X"].sessions["d1"]
    assert x.takeover and x.takeover_to == "B"
    assert net.command("X", ask(timeout=10.0)) is Answer.FAILED  # the window is not for X
    net.run(net.now + 3.0)
    assert net.owner == "A"


def test_allow_takeover_holds_for_the_owners_epoch_only(fleet_dir):
    """A's operator allows B takeover in answer to B's request (epoch 1); B takes it, hands it back (epoch
    3); B asks again: A's operator is asked, nothing moves by itself."""
    net = make_net(fleet_dir)
    assert net.command("B", ask(timeout=10.0)) is Answer.FAILED
    net.run(net.now + 1.0)
    assert net.command("A", consent("B", takeover=True, request=True)) is Answer.ACCEPTED
    net.run(net.now + 1.0)
    assert (net.owner, net.machine.epoch) == ("B", 2)
    granted = [x for x in net.logs["A"] if x.kind == "operator_request_granted"]
    assert granted[-1].fields["decided_by"] == "operator"
    assert net.command("B", ask(request=False)) is Answer.ACCEPTED  # B's operator lets go
    assert net.command("A", ask(timeout=10.0)) is Answer.FAILED
    net.run(net.now + 1.0)
    assert net.command("B", consent("A")) is Answer.ACCEPTED  # B's operator gives it back
    net.run(net.now + 1.5)
    assert (net.owner, net.machine.epoch) == ("A", 3)
    assert not net.machine.status().takeover and not net.cores["A"].sessions["d1"].operator.takeover_allowed(
        net.cores["A"].sessions["d1"], net.now)
    assert net.command("B", ask(timeout=10.0)) is Answer.FAILED  # A's operator is asked again
    net.run(net.now + 3.0)
    assert net.owner == "A" and net.machine.epoch == 3


def test_a_decline_holds_that_requester_off_and_the_operator_is_told_for_how_long(fleet_dir):
    net = make_net(fleet_dir)
    net.command("B", ask(timeout=10.0))
    net.run(net.now + 1.0)
    assert net.command("A", consent("B", request=True)) is Answer.ACCEPTED  # p1 = 1, p2 = 0: declined
    declined = [x for x in net.logs["A"] if x.kind == "operator_request_declined"]
    assert declined[-1].fields["hold_s"] == DECLINE_HOLD_S
    assert any(f"not shown for {DECLINE_HOLD_S:.0f} s" in t for t in net.said)
    shown_at = [net.now]
    for _ in range(int(DECLINE_HOLD_S) // 5):  # B's operator asks again and again
        net.command("B", ask(timeout=3.0))
        net.run(net.now + 5.0)
    assert net.kinds("A").count("operator_request") == 1  # not one more prompt during the hold
    net.command("B", ask(timeout=3.0))
    net.run(net.now + 1.0)
    assert net.kinds("A").count("operator_request") == 2 and net.now - shown_at[0] >= DECLINE_HOLD_S


def prompts_per_minute(fleet_dir, answer: str) -> int:
    """The prompts one requester causes at the owner in 60 s when it asks without pause (3 s, the
    shortest timeout) and the owner's operator ``answer``s each: "ignore" or "decline"."""
    net = make_net(fleet_dir)
    t0 = net.now
    while net.now < t0 + 60.0:
        if net.cores["B"].sessions["d1"].operator.asked_until is None:
            net.command("B", ask(timeout=3.0))
        net.run(net.now + 0.5)
        if answer == "decline" and net.cores["A"].sessions["d1"].operator.live_request(net.cores["A"].sessions["d1"], net.now):
            net.command("A", consent("B", request=True))
    return net.kinds("A").count("operator_request")


def test_a_requester_causes_few_prompts_a_minute(fleet_dir):
    ignored, declined = prompts_per_minute(fleet_dir, "ignore"), prompts_per_minute(fleet_dir, "decline")
    assert ignored <= 60 / 3.0 + 1 and declined <= 60 / DECLINE_HOLD_S + 1


def test_allow_takeover_naming_a_gs_that_asked_nothing_is_refused_not_a_setting_for_anyone(fleet3_dir):
    """Found by ``zdrone check --consent``: p1 = 1, p2 = 1, p4 = B with nothing pending used to become the
    owner's setting for anyone, and C then took control."""
    net = make_net(fleet3_dir, gss=("A", "B", "X"))
    assert net.command("A", consent("B", takeover=True, request=True)) is Answer.DENIED
    net.run(net.now + 1.0)
    assert not net.machine.status().takeover
    assert net.command("X", ask(timeout=5.0)) is Answer.FAILED
    net.run(net.now + 3.0)
    assert net.owner == "A"


def test_a_declined_requester_is_not_granted_by_a_later_allow_takeover_during_the_hold(fleet3_dir):
    net = make_net(fleet3_dir, gss=("A", "B", "X"))
    net.command("X", ask(timeout=10.0))
    net.run(net.now + 1.0)
    net.command("A", consent("X", request=True))  # declined
    assert net.command("A", ask(takeover=True)) is Answer.DENIED  # nothing pending: no setting for anyone
    net.run(net.now + 3.0)  # X's standing request is sent again meanwhile
    assert net.owner == "A"
    assert net.command("B", ask(timeout=5.0)) is Answer.FAILED  # anyone else: A's operator is asked
    net.run(net.now + 1.0)
    assert net.owner == "A"


def test_an_answer_naming_a_gs_with_nothing_pending_is_denied_and_a_late_decline_still_holds(fleet_dir):
    """Found from outside: p1 = 0 naming B with nothing pending was answered ACCEPTED (as a let-go), and
    a decline arriving just after a 3 s request ended was taken as "takeover refused" and held nothing."""
    net = make_net(fleet_dir)
    assert net.command("A", consent("B")) is Answer.DENIED  # release to B: B asked nothing
    net.command("B", ask(timeout=3.0))
    net.run(net.now + 3.5)  # shown, then expired unanswered
    assert "operator_request_expired" in net.kinds("A")
    assert net.command("A", consent("B", request=True)) is Answer.ACCEPTED  # the operator's decline, late
    assert "operator_request_declined" in net.kinds("A")
    shown = net.kinds("A").count("operator_request")
    net.command("B", ask(timeout=3.0))
    net.run(net.now + 5.0)
    assert net.kinds("A").count("operator_request") == shown and "operator_request_held_off" in net.kinds("A")


# ------------------------------------------------ the consent race, through the gateways (issue: a consent
# goes to a GS the operator never saw)
def with_three_gateways(net: Net) -> dict[str, App]:
    apps = {}
    for g in ("A", "B", "X"):
        gw = GcsGateway(CoreStation(net, g), [])
        gw.transports = [MemTransport()]
        net.gateways[g] = gw
        apps[g] = App(net, g)
        apps[g].send(mav.MAVLink_heartbeat_message(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))
    return apps


def race(fleet3_dir, answer_after: float, p1: int, p2: int, p4: int | None = None):
    """B asks (3 s); X asks every 0.25 s; A's application (sysid 255, as QGroundControl) answers
    ``answer_after`` s after B's request was shown to it, p4 = its own sysid (or ``p4``)."""
    net = make_net(fleet3_dir, gss=("A", "B", "X"))
    apps = with_three_gateways(net)
    net.run(net.now + 1.0)
    apps["B"].request(1, 0, 3)
    net.run(net.now + 0.1)
    assert [int(m.param4) for m in apps["A"].presented()] == [3]  # B's request, shown
    t_shown = net.now
    while net.now < t_shown + answer_after - 1e-6:
        apps["X"].request(1, 0, 3)  # X asks every 0.25 s
        net.run(net.now + 0.25, step=0.05)
    apps["A"].request(p1, p2, 5, 255 if p4 is None else p4)
    answer = apps["A"].acks()[-1]
    net.run(net.now + 3.0)
    return net, apps, answer


@pytest.mark.parametrize("p1,p2", [(0, 0), (1, 1)])  # a release, and "allow takeover"
@pytest.mark.parametrize("p4", [None, 0])  # QGroundControl (its own sysid) and MAVProxy (0)
def test_a_consent_not_naming_the_requester_never_goes_to_a_request_shown_for_less_than_the_read_time(
        fleet3_dir, p1, p2, p4):
    net, apps, answer = race(fleet3_dir, 3.5, p1, p2, p4)  # B's expired at 3 s; X's shown ~0.5 s
    assert answer == (MAV_CMD_REQUEST_OPERATOR_CONTROL, mav.MAV_RESULT_DENIED)
    assert net.owner == "A" and net.machine.epoch == 1  # X did not take the drone
    refused = net.gateways["A"].station.events.of("operator_consent_refused")
    assert refused and refused[-1]["requester"] == "X" and "shown" in refused[-1]["reason"]
    assert net.gateways["A"].counters["operator_consent_unread"] == 1
    assert int(apps["A"].presented()[-1].param4) == 7  # X's request shown again, to be read


@pytest.mark.parametrize("p1,p2", [(0, 0), (1, 1)])
def test_control_a_consent_after_the_read_time_goes_to_the_request_shown(fleet3_dir, p1, p2):
    net, apps, answer = race(fleet3_dir, CONSENT_READ_S + 0.5, p1, p2)
    assert answer == (MAV_CMD_REQUEST_OPERATOR_CONTROL, mav.MAV_RESULT_ACCEPTED)
    assert (net.owner, net.machine.epoch) == ("B", 2)
    granted = [x for x in net.logs["A"] if x.kind == "operator_request_granted"]
    assert granted[-1].fields["to"] == "B" and granted[-1].fields["decided_by"] == "operator"


def test_a_consent_naming_the_requester_binds_to_it_at_once(fleet3_dir):
    net, apps, answer = race(fleet3_dir, 0.5, 0, 0, p4=3)  # p4 = B's sysid, 0.5 s after it was shown
    assert answer == (MAV_CMD_REQUEST_OPERATOR_CONTROL, mav.MAV_RESULT_ACCEPTED)
    assert net.owner == "B"


def test_a_late_allow_takeover_is_no_setting_the_next_asker_takes(fleet3_dir):
    """Found from outside: "allow takeover" just after B's request expired became the epoch's setting and
    X's next request took the drone."""
    net = make_net(fleet3_dir, gss=("A", "B", "X"))
    apps = with_three_gateways(net)
    net.run(net.now + 1.0)
    apps["B"].request(1, 0, 3)
    net.run(net.now + 3.1)  # shown, then expired unanswered
    apps["A"].request(1, 1, 5)  # the late "allow takeover", p4 = its own sysid
    assert apps["A"].acks()[-1] == (MAV_CMD_REQUEST_OPERATOR_CONTROL, mav.MAV_RESULT_DENIED)
    for _ in range(8):
        apps["X"].request(1, 0, 3)
        net.run(net.now + 0.25, step=0.05)
    assert net.owner == "A" and not net.machine.status().takeover
