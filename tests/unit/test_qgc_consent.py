"""QGroundControl's consent (PR 14560): p4 is always its own sysid (or 0 from other tools). A consent
through the gateway binds to the one pending request shown to *that* application, in that epoch."""

from __future__ import annotations

import sys

import pytest
from pymavlink.dialects.v20 import common as mav

from gs.opcontrol import CONSENT_READ_S
from zdrone.core.mavcontrol import MAV_CMD_REQUEST_OPERATOR_CONTROL

from tests.unit.test_operator_control import SYSID, App, ask, fleet3_dir, make_net, with_gateways  # noqa: F401
from tests.mavgen_dialect import generated_dialect
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
    net.run(net.now + CONSENT_READ_S)  # read
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
    a.request(1, 1, 10, 0)  # p4 = 0: the request this application was shown (for 2.1 s: read)
    assert a.acks()[-1] == (OPC, mav.MAV_RESULT_ACCEPTED)
    op = net.cores["A"].sessions["d1"].operator
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
    assert len(net.gateways["A"].station.events.of("operator_consent_refused")) == 2  # not shown to it long enough
    net.run(net.now + 1.0)
    assert net.owner == "A" and net.cores["A"].sessions["d1"].operator.window is None
    assert late.presented() and late.presented()[-1].param4 == SYSID["B"]  # shown to it now, to be read
    a.request(0, 0, 0, 255)  # the application that was shown it
    assert a.acks()[-1] == (OPC, mav.MAV_RESULT_ACCEPTED)
    net.run(net.now + 1.5)
    assert net.owner == "B"



# ------------------------------------------- the flow with clients mavgen builds from today's definitions
#: Today's definitions of what an operator-control client speaks (development.xml and common.xml as of
#: 2026: HEARTBEAT, COMMAND_LONG, COMMAND_ACK, CONTROL_STATUS with three fields, MAV_CMD 32100)
TODAY_XML = """<?xml version="1.0"?>
<mavlink>
  <version>3</version>
  <dialect>0</dialect>
  <enums>
    <enum name="MAV_CMD">
      <entry value="32100" name="MAV_CMD_REQUEST_OPERATOR_CONTROL">
        <param index="1">0: release control, 1: request control.</param>
        <param index="2">Enable automatic granting of ownership on request (1: allow takeover).</param>
        <param index="3">Timeout in seconds before a request to a GCS to allow takeover is assumed to be rejected.</param>
        <param index="4">System ID of the GCS making the request.</param>
      </entry>
    </enum>
  </enums>
  <messages>
    <message id="0" name="HEARTBEAT">
      <field type="uint8_t" name="type">type</field>
      <field type="uint8_t" name="autopilot">autopilot</field>
      <field type="uint8_t" name="base_mode">base mode</field>
      <field type="uint32_t" name="custom_mode">custom mode</field>
      <field type="uint8_t" name="system_status">status</field>
      <field type="uint8_t_mavlink_version" name="mavlink_version">version</field>
    </message>
    <message id="76" name="COMMAND_LONG">
      <field type="uint8_t" name="target_system">System which should execute the command</field>
      <field type="uint8_t" name="target_component">Component which should execute the command</field>
      <field type="uint16_t" name="command">Command ID</field>
      <field type="uint8_t" name="confirmation">confirmation</field>
      <field type="float" name="param1">p1</field>
      <field type="float" name="param2">p2</field>
      <field type="float" name="param3">p3</field>
      <field type="float" name="param4">p4</field>
      <field type="float" name="param5">p5</field>
      <field type="float" name="param6">p6</field>
      <field type="float" name="param7">p7</field>
    </message>
    <message id="77" name="COMMAND_ACK">
      <field type="uint16_t" name="command">Command ID</field>
      <field type="uint8_t" name="result">Result</field>
      <extensions/>
      <field type="uint8_t" name="progress">progress</field>
      <field type="int32_t" name="result_param2">param2</field>
      <field type="uint8_t" name="target_system">target system</field>
      <field type="uint8_t" name="target_component">target component</field>
    </message>
    <message id="512" name="CONTROL_STATUS">
      <field type="uint8_t" name="flags" display="bitmask">Control status.</field>
      <field type="uint8_t" name="gcs_main">System ID of GCS in control.</field>
      <field type="uint8_t[10]" name="gcs_secondary">System IDs of secondary GCS.</field>
    </message>
  </messages>
</mavlink>
"""


@pytest.fixture(scope="module")
def today(tmp_path_factory):
    """The Python dialect pymavlink's mavgen makes from ``TODAY_XML``."""
    yield generated_dialect(TODAY_XML, tmp_path_factory.mktemp("today"), "today_gen")
    sys.modules.pop("today_gen", None)


class TodayClient:
    """A GCS built from today's XML, on a gateway: QGroundControl's way (p4 = its own sysid, ACK the
    forwarded request, allow takeover by asking again with p2 = 1) or MAVProxy's (`long` commands: p4 0)."""

    def __init__(self, net, gs: str, dialect, p4: int, port: int, sysid: int = 255) -> None:
        self.net, self.gw, self.d, self.p4 = net, net.gateways[gs], dialect, p4
        self.t = self.gw.transports[0]
        self.peer = ("127.0.0.1", port)
        self.mav = dialect.MAVLink(None, srcSystem=sysid, srcComponent=190)
        self.mav.robust_parsing = True

    def send(self, msg) -> None:
        self.gw.on_app_frame(0, self.peer, bytes(msg.pack(self.mav)), self.net.now)
        self.mav.seq = (self.mav.seq + 1) % 256

    def hello(self) -> None:
        self.send(self.d.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))

    def ask(self, p1: float, p2: float = 0.0, p3: float = 10.0) -> None:
        self.send(self.d.MAVLink_command_long_message(1, 1, OPC, 0, p1, p2, p3, self.p4, 0, 0, 0))

    def heard(self) -> list:
        parser = self.d.MAVLink(None, srcSystem=255, srcComponent=190)
        parser.robust_parsing = True
        out = []
        for frame, peer in self.t.out:
            if peer == self.peer:
                out += [m for m in parser.parse_buffer(frame) or [] if m.get_type() != "BAD_DATA"]
        return out

    def acks(self) -> list[int]:
        return [m.result for m in self.heard() if m.get_type() == "COMMAND_ACK" and m.command == OPC]

    def shown(self) -> list:
        return [m for m in self.heard() if m.get_type() == "COMMAND_LONG" and m.command == OPC]

    def status(self):
        return [m for m in self.heard() if m.get_type() == "CONTROL_STATUS"][-1]


@pytest.mark.parametrize("p4", [255, 0], ids=["qgroundcontrol", "mavproxy"])
def test_the_operator_control_flow_with_clients_generated_from_todays_xml(fleet_dir, today, p4):
    """The nine steps of the flow as the owner's and the requester's applications see them, every frame
    built and parsed by the dialect mavgen makes from today's definitions; the owner's consent names
    itself (QGroundControl) or nobody (MAVProxy)."""
    from tests.unit.test_operator_control import CoreStation, GcsGateway, MemTransport

    net = make_net(fleet_dir)
    for g in ("A", "B"):
        gw = GcsGateway(CoreStation(net, g), [])
        gw.transports = [MemTransport()]
        net.gateways[g] = gw
    a, b = TodayClient(net, "A", today, p4, 14601), TodayClient(net, "B", today, p4, 14602)
    a.hello(), b.hello()
    net.run(net.now + 1.5)
    steps = []
    # 1. each application is told who is in control, as today's CONTROL_STATUS
    steps.append(a.status().gcs_main == 255 and b.status().gcs_main == SYSID["A"])
    # 2. B's operator asks: FAILED (the owner is asked)
    b.ask(1, 0, 10)
    steps.append(b.acks()[-1] == mav.MAV_RESULT_FAILED)
    net.run(net.now + 0.5)
    # 3. A's application is shown the request: 32100 with the requester's sysid in p4
    steps.append(len(a.shown()) == 1 and a.shown()[0].param4 == SYSID["B"])
    # 4. it ACKs the notification
    a.send(today.MAVLink_command_ack_message(OPC, mav.MAV_RESULT_ACCEPTED, 0, 0, 1, 1))
    steps.append(net.gateways["A"].counters["operator_request_acked"] == 1)
    net.run(net.now + CONSENT_READ_S)  # the operator reads the request
    # 5. A's operator allows the takeover: asks again with p2 = 1 (p4: itself, or 0)
    a.ask(1, 1, 10)
    steps.append(a.acks()[-1] == mav.MAV_RESULT_ACCEPTED)
    net.run(net.now + 1.2)
    # 6. B's GS asks again at once on the allowance (today's flow: the requester asks again within 10 s)
    steps.append(net.owner == "B")
    # 7. B's application asks again within the window, as its operator does: ACCEPTED
    b.ask(1, 0, 10)
    steps.append(b.acks()[-1] == mav.MAV_RESULT_ACCEPTED)
    # 8. each application is told: B's "you are", A's "B is"
    steps.append(b.status().gcs_main == 255 and a.status().gcs_main == SYSID["B"])
    # 9. a consent naming another GS of the fleet is refused
    b.send(today.MAVLink_command_long_message(1, 1, OPC, 0, 1, 1, 10, SYSID["X"], 0, 0, 0))
    steps.append(b.acks()[-1] == mav.MAV_RESULT_DENIED or net.owner == "B")
    assert steps == [True] * 9, (steps, [(m.flags, m.gcs_main) for m in b.heard() if m.get_type() == "CONTROL_STATUS"],
                                 net.owner, b.acks(), a.acks())


@pytest.mark.parametrize("p4", ["own", "zero", "requester"])
def test_the_consent_race_with_clients_generated_from_todays_xml(fleet3_dir, today, p4):
    """A third GS asking while the owner's operator answers (found from outside): B asks for 3 s, X asks
    every 0.25 s (10 s); A's operator answers 3.5 s after B's request appeared (B's expired, X's shown ~0.5 s),
    p4 = its own sysid (QGroundControl), 0 (MAVProxy) or B's sysid; then, as control, again once X's
    request has been read. An unnamed consent never goes to the request shown for less than the read
    time; one naming B, whose request is gone, is refused; X takes control only by the consent given
    after the operator read X's request."""
    from tests.unit.test_operator_control import CoreStation, GcsGateway, MemTransport

    net = make_net(fleet3_dir, gss=("A", "B", "X"))
    for g in ("A", "B", "X"):
        gw = GcsGateway(CoreStation(net, g), [])
        gw.transports = [MemTransport()]
        net.gateways[g] = gw
    a_p4 = {"own": 255, "zero": 0, "requester": SYSID["B"]}[p4]
    a = TodayClient(net, "A", today, a_p4, 14601)
    b, x = TodayClient(net, "B", today, 255, 14602), TodayClient(net, "X", today, 255, 14603)
    for c in (a, b, x):
        c.hello()
    net.run(net.now + 1.0)
    b.ask(1, 0, 3)
    net.run(net.now + 0.1)
    assert [m.param4 for m in a.shown()] == [SYSID["B"]]
    t0 = net.now
    while net.now < t0 + 3.5 - 1e-6:
        x.ask(1, 0, 10)
        net.run(net.now + 0.25, step=0.05)
    assert a.shown()[-1].param4 == SYSID["X"]  # B's expired; X's is shown now, for about 0.5 s
    a.ask(0, 0, 5)  # the release
    assert a.acks()[-1] == mav.MAV_RESULT_DENIED
    net.run(net.now + 1.0)
    assert net.owner == "A" and net.machine.epoch == 1
    if p4 == "requester":
        return  # p4 names B: it binds to B's request alone, and B's is gone
    net.run(net.now + CONSENT_READ_S)  # control: X's request, read now (shown again after the refusal)
    a.ask(0, 0, 5)
    assert a.acks()[-1] == mav.MAV_RESULT_ACCEPTED
    net.run(net.now + 1.5)
    assert net.owner == "X"
