"""QGroundControl's consent (PR 14560): p4 is always its own sysid (or 0 from other tools). A consent
through the gateway binds to the one pending request shown to *that* application, in that epoch."""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mav

from gs.opcontrol import Answer
from zdrone.core.mavcontrol import MAV_CMD_REQUEST_OPERATOR_CONTROL

from tests.unit.test_operator_control import SYSID, App, ask, fleet3_dir, make_net, with_gateways  # noqa: F401
from tests.unit.test_station_core import fleet_dir  # noqa: F401  (fixture)

OPC = MAV_CMD_REQUEST_OPERATOR_CONTROL


class PeerApp(App):
    """An application with its own address on a gateway shared with others (its frames only)."""

    def __init__(self, net, gs: str, port: int, sysid: int = 255) -> None:
        super().__init__(net, gs, sysid)
        self.peer = ("127.0.0.1", port)

    def frames(self) -> list[bytes]:
        return [f for f, p in self.t.out if p == self.peer]

    def hello(self) -> None:
        self.send(mav.MAVLink_heartbeat_message(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))


def test_a_qgc_release_naming_itself_goes_to_the_request_it_was_shown(fleet_dir):
    """p1 = 0, p4 = 255 (QGC's own sysid): a release to B, the requester A's application was shown."""
    net = make_net(fleet_dir)
    a, _ = with_gateways(net)
    net.command("B", ask(timeout=10.0))
    net.run(net.now + 1.0)
    assert a.presented()[-1].param4 == SYSID["B"]  # shown: B's sysid
    a.send(mav.MAVLink_command_ack_message(OPC, mav.MAV_RESULT_ACCEPTED, 0, 0, 1, 1))  # QGC ACKs the notification
    a.request(0, 0, 0, 255)  # QGC's releaseOperatorControl(): p4 = its own sysid
    assert a.acks()[-1] == (OPC, mav.MAV_RESULT_ACCEPTED)
    assert "operator_consent_refused" not in net.kinds("A")
    net.run(net.now + 1.5)
    assert (net.owner, net.machine.epoch) == ("B", 2)
    granted = [x for x in net.logs["A"] if x.kind == "operator_request_granted"]
    assert granted[-1].fields["requester"] == "B" and granted[-1].fields["epoch"] == 1


def test_a_qgc_allow_takeover_with_p4_zero_or_itself_opens_the_window_for_the_shown_requester(fleet3_dir):
    """B asks; X asks 1.1 s later (not shown: busy). A's QGC re-requests with p2 = 1: first p4 = X's
    sysid (refused: not the one shown), then p4 = 0 (bound to B): B takes control, never X."""
    net = make_net(fleet3_dir, gss=("A", "B", "X"))
    a, _ = with_gateways(net)
    net.command("B", ask(timeout=10.0))
    net.run(net.now + 1.1)
    net.command("X", ask(timeout=10.0))
    net.run(net.now + 1.0)
    assert [m.param4 for m in a.presented()] == [SYSID["B"]]  # only B's request was shown
    a.request(1, 1, 10, SYSID["X"])  # p4 names another fleet GS: refused, nothing moves
    assert a.acks()[-1] == (OPC, mav.MAV_RESULT_DENIED)
    refused = [x for x in net.logs["A"] if x.kind == "operator_consent_refused"]
    assert refused[-1].fields["named"] == "X" and refused[-1].fields["requester"] == "B"
    a.request(1, 1, 10, 0)  # p4 = 0: the request this application was shown
    assert a.acks()[-1] == (OPC, mav.MAV_RESULT_ACCEPTED)
    op = net.cores["A"].views["d1"].operator
    assert op.window is not None and (op.window.to, op.window.epoch) == ("B", 1)
    net.run(net.now + 2.0)  # B's standing request, sent again each second, is granted
    assert (net.owner, net.machine.epoch) == ("B", 2)
    net.run(net.now + 3.0)
    assert net.owner == "B"  # X never


def test_a_consent_naming_itself_from_an_app_not_shown_the_request_is_refused(fleet_dir):
    """A second application joins A's gateway after B's request was shown: its p4 = 255 consent has
    no shown request to bind to (DENIED, nothing moves); the one that was shown may consent."""
    net = make_net(fleet_dir)
    a, _ = with_gateways(net)
    net.command("B", ask(timeout=10.0))
    net.run(net.now + 1.0)
    late = PeerApp(net, "A", 14600)
    late.hello()
    net.run(net.now + 0.5)
    assert a.presented() and not late.presented()
    late.request(0, 0, 0, 255)
    assert late.acks()[-1] == (OPC, mav.MAV_RESULT_DENIED)
    late.request(1, 1, 10, 255)
    assert late.acks()[-1] == (OPC, mav.MAV_RESULT_DENIED)
    assert net.kinds("A").count("operator_consent_refused") == 2
    net.run(net.now + 1.0)
    assert net.owner == "A" and net.cores["A"].views["d1"].operator.window is None
    a.request(0, 0, 0, 255)  # the application that was shown it
    assert a.acks()[-1] == (OPC, mav.MAV_RESULT_ACCEPTED)
    net.run(net.now + 1.5)
    assert net.owner == "B"

