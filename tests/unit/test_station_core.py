"""The GS core with explicit time: key sharing, pairing and the attacks on them, no sockets."""

from __future__ import annotations

import pytest

from zdrone.core import wire
from zdrone.core.keys import Identity
from zdrone.core.keyshare import KeyShareAsk, answer, decode_query
from zdrone.core.pairing import respond
from zdrone.fleet.files import init_fleet, load_fleet, load_secret
from gs.actions import Ask, AskKind, Emit, Put, ToOperator
from gs.core import CoreOptions, StationCore
from gs.mission import Stage
from zdrone.core.mavlink import FrameCodec


@pytest.fixture(scope="module")
def fleet_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("fleet")
    init_fleet(d)
    return d


def core(fleet_dir, name: str, **kw) -> StationCore:
    fleet = load_fleet(fleet_dir)
    drones = tuple(x for x in fleet.drones() if fleet.is_authorized(x, name))
    return StationCore(name, fleet, load_secret(fleet_dir, name, fleet).identity, drones, CoreOptions(**kw))


def ident(fleet_dir, name: str) -> Identity:
    return load_secret(fleet_dir, name).identity


def paired_a(fleet_dir) -> StationCore:
    """GS A, paired with d1 (the drone side of the handshake done here by hand) and holding authority."""
    a = core(fleet_dir, "A", pair=True)
    asks = [x for x in a.handle_timer(0.0) if isinstance(x, Ask)]
    assert [x.kind for x in asks] == [AskKind.PAIR]
    m2, _key = respond(ident(fleet_dir, "d1"), "d1", "A", a.fleet.nodes["A"].public_bytes, asks[0].payload, bytes(32))
    out = a.on_pair_reply("d1", m2, None, 0.1)
    assert any(isinstance(x, Put) for x in out)  # the proof of the new key goes out at once
    a.sessions["d1"].owner, a.sessions["d1"].epoch = "A", 1
    return a


def share(a: StationCore, b: StationCore, now: float) -> Ask:
    asks = [x for x in a.handle_timer(now) if isinstance(x, Ask) and x.kind is AskKind.LINKKEY]
    assert len(asks) == 1 and asks[0].gs == "B" and asks[0].keyexpr == "backhaul/B/linkkey/d1"
    return asks[0]


def test_key_sharing_end_to_end_leaves_the_owner_live_link_alone(fleet_dir):
    a, b = paired_a(fleet_dir), core(fleet_dir, "B")
    ask = share(a, b, 1.0)
    ans, logs = b.on_linkkey_query("d1", ask.payload, 1.1, bytes(range(32)))
    assert ans.reply is not None and ans.crypto and [x.kind for x in logs] == ["linkkey_shared"]
    assert b.sessions["d1"].link is None and len(b.sessions["d1"].slot.candidates) == 1  # pending the drone's proof
    out = a.on_linkkey_reply("d1", "B", ans.reply, None, 1.2)
    assert [x.kind for x in out if isinstance(x, Emit)] == ["linkkey_received"]
    assert a.sessions["d1"].linking.shares["B"].grant.secret == bytes(range(32))


def test_attack1_forged_reply_before_and_after_the_real_one(fleet_dir):
    a, b = paired_a(fleet_dir), core(fleet_dir, "B")
    ask = share(a, b, 1.0)
    # the attacker has B's router password and its own key pair: a well-formed message 2, not B's
    x = Identity.generate()
    other = KeyShareAsk(ident(fleet_dir, "A"), "A", "B", x.public, "d1", 0.0)
    forged = answer(x, "B", "d1", "A", a.fleet.nodes["A"].public_bytes, decode_query(other.payload).m1, bytes(32))  # type: ignore[union-attr]
    assert isinstance(forged, bytes)
    a.on_linkkey_reply("d1", "B", forged, None, 1.1)
    a.on_linkkey_reply("d1", "B", b"\x00" * 80, None, 1.1)
    assert a.counters["linkkey_reply:bad_mac"] == 2 and not a.sessions["d1"].linking.grants_pending  # refused by the tag
    ans, _ = b.on_linkkey_query("d1", ask.payload, 1.2, bytes(range(32)))
    a.on_linkkey_reply("d1", "B", ans.reply, None, 1.3)
    assert a.sessions["d1"].linking.shares["B"].grant.secret == bytes(range(32))
    a.on_linkkey_reply("d1", "B", forged, None, 1.4)  # later replies: nobody is waiting
    assert a.counters["linkkey_reply:not_waiting"] == 1 and a.sessions["d1"].linking.shares["B"].grant.secret == bytes(range(32))


def test_attack2_query_claiming_b_without_b_key_is_refused_and_changes_nothing(fleet_dir):
    a = paired_a(fleet_dir)
    live = a.sessions["d1"].link
    x = Identity.generate()
    forged = KeyShareAsk(x, "B", "A", a.fleet.nodes["A"].public_bytes, "d1", 0.0)  # claims to be B
    ans, logs = a.on_linkkey_query("d1", forged.payload, 2.0, bytes(32))
    # refused by the tag before any crypto, and silently (no error to learn from)
    assert ans.reply is None and ans.error is None and not ans.crypto and a.counters["linkkey_refused:bad_mac"] == 1
    ans, _ = a.on_linkkey_query("d1", b"junk", 2.0, bytes(32))
    assert ans.error == b"malformed" and not ans.crypto
    assert a.sessions["d1"].link is live and not a.sessions["d1"].slot.candidates


def test_unauthorized_asker_and_rate_limit_refused_before_crypto(fleet_dir):
    b = core(fleet_dir, "B")
    x_ask = KeyShareAsk(ident(fleet_dir, "X"), "X", "B", b.fleet.nodes["B"].public_bytes, "d1", 0.0)
    ans, _ = b.on_linkkey_query("d1", x_ask.payload, 0.0, bytes(32))
    assert ans.error == b"unauthorized" and not ans.crypto
    from gs.linking import LINKKEY_BURST

    a_id = ident(fleet_dir, "A")
    burst, more = int(LINKKEY_BURST), 7
    results = [b.on_linkkey_query("d1", KeyShareAsk(a_id, "A", "B", b.fleet.nodes["B"].public_bytes, "d1", 0.0).payload,
                                  0.0, bytes(32))[0] for _ in range(burst + more)]
    assert sum(r.crypto for r in results) == burst  # the burst; the rest cost no handshake and get no answer
    assert all(r.reply is None and r.error is None for r in results[burst:])
    assert b.counters["linkkey_refused:rate_limited"] == more


def test_forged_pairing_reply_does_not_spoil_pairing(fleet_dir):
    a = core(fleet_dir, "A", pair=True)
    ask = [x for x in a.handle_timer(0.0) if isinstance(x, Ask)][0]
    a.on_pair_reply("d1", b"\x02" * 64, None, 0.1)
    assert a.counters["pair_bad_reply"] == 1 and a.sessions["d1"].link is None
    m2, _ = respond(ident(fleet_dir, "d1"), "d1", "A", a.fleet.nodes["A"].public_bytes, ask.payload, bytes(32))
    a.on_pair_reply("d1", m2, None, 0.2)
    assert a.sessions["d1"].link is not None
    assert a.on_pair_reply("d1", m2, None, 0.3) == [] and a.counters["pair_reply_late"] == 1


def test_mission_stages_are_a_table(fleet_dir):
    from gs.mission import TABLE, FlightAck, FlightTick

    assert {s for s, _ in TABLE} <= set(Stage)
    a = paired_a(fleet_dir)
    assert a.sessions["d1"].mission.stage is Stage.IDLE
    a.opts = CoreOptions(pair=True, mission=None)
    a.handle_timer(5.0)
    assert a.sessions["d1"].mission.stage is Stage.IDLE  # no mission: nothing to fly
    assert a.sessions["d1"].flight(FlightAck(5.0, 400, True, 0)) == []
    assert a.sessions["d1"].flight(FlightTick(5.0)) == []


def _in_overlap_nearer_b(a: StationCore, links: set[str]) -> None:
    from zdrone.core.geometry import offset
    from zdrone.core.reference import HOME

    view = a.sessions["d1"]
    view.position = offset(HOME, 0.0, 300.0)  # 300 m from A's centre, 200 m from B's: inside both
    view.linking.drone_links = links


def test_no_release_toward_a_gs_the_drone_has_no_key_for_the_vehicle_comes_home(fleet_dir):
    """Review F2: with key sharing blocked, A used to release anyway (refused by the drone), keep
    flying out of its coverage, and the drone failsafe-landed far from home. While B's key is still
    being asked for, A waits (inside 90 % of its radius); then the hand-over has failed: RTL."""
    from zdrone.core.geometry import offset
    from zdrone.core.reference import HOME

    a = paired_a(fleet_dir)
    _in_overlap_nearer_b(a, {"A"})
    out = a.handle_timer(10.0)
    assert [x.gs for x in out if isinstance(x, Ask) and x.kind is AskKind.LINKKEY] == ["B"]  # B's key: asked for
    assert not [x for x in out if isinstance(x, Emit) and x.kind in ("handover_failed", "handover_release")]
    a.sessions["d1"].position = offset(HOME, 0.0, 320.0)  # past 90 % of A's 350 m: no more waiting
    out = a.handle_timer(10.5)
    failed = [x for x in out if isinstance(x, Emit) and x.kind == "handover_failed"]
    assert len(failed) == 1 and "no link to B" in failed[0].fields["reason"] and failed[0].fields["action"] == "RTL"
    assert not a.sessions["d1"].handover.released and a.holds_authority(a.sessions["d1"])
    assert not [x for x in a.handle_timer(11.0) if isinstance(x, Emit) and x.kind in ("handover_failed", "handover_release")]


def test_a_key_sharing_query_refused_for_a_live_link_is_asked_again_soon(fleet_dir):
    """A restarted drone holds no key for B, but B hears the silence only at the loss threshold and
    refuses to share its key meanwhile (``live_link``). A asks again ``LIVE_LINK_RETRY_S`` later, not
    after the query's 5 s: the key must be there before the overlap."""
    from gs.linking import LIVE_LINK_RETRY_S

    a = paired_a(fleet_dir)
    ask = share(a, core(fleet_dir, "B"), 1.0)
    a.on_linkkey_reply("d1", "B", None, b"live_link", 1.05)
    assert not [x for x in a.handle_timer(1.2) if isinstance(x, Ask) and x.kind is AskKind.LINKKEY]
    again = [x for x in a.handle_timer(1.05 + LIVE_LINK_RETRY_S + 0.01) if isinstance(x, Ask) and x.kind is AskKind.LINKKEY]
    assert len(again) == 1 and again[0].payload != ask.payload and a.counters["linkkey_asked_again"] == 1
    a.on_linkkey_reply("d1", "B", None, b"rate_limited", 1.7)  # any other refusal: the query's own timeout
    assert not [x for x in a.handle_timer(2.5) if isinstance(x, Ask) and x.kind is AskKind.LINKKEY]


def test_a_refused_release_is_a_failed_hand_over(fleet_dir):
    """Refused while the vehicle is not leaving A's coverage: authority stays, the release is tried again
    after ``HANDOVER_RETRY_S``; refused again once it is flying out of A's coverage: RTL, once."""
    from zdrone.core import wire
    from zdrone.core.geometry import offset
    from zdrone.core.reference import HOME
    from gs.context import HANDOVER_RETRY_S

    a = paired_a(fleet_dir)
    view = a.sessions["d1"]
    _in_overlap_nearer_b(a, {"A", "B"})
    out = a.handle_timer(10.0)
    assert [x.fields["to"] for x in out if isinstance(x, Emit) and x.kind == "handover_release"] == ["B"]
    out = view.on_control(wire.Reject("release", "no link: no key installed for B"), 10.5)
    failed = [x for x in out if isinstance(x, Emit) and x.kind == "handover_failed"]
    assert len(failed) == 1 and failed[0].fields["reason"].startswith("release refused")
    assert failed[0].fields["action"] == "retry" and a.holds_authority(view)
    assert not [x for x in a.handle_timer(10.6) if isinstance(x, Emit) and x.kind == "handover_release"]  # the retry waits
    view.position = offset(HOME, 0.0, 340.0)  # 40 m farther from A's centre: leaving A's coverage
    assert [x for x in a.handle_timer(10.5 + HANDOVER_RETRY_S + 0.01) if isinstance(x, Put)]  # the release again
    out = view.on_control(wire.Reject("release", "no link: no key installed for B"), 13.0)
    failed = [x for x in out if isinstance(x, Emit) and x.kind == "handover_failed"]
    assert [x.fields["action"] for x in failed] == ["RTL"] and a.holds_authority(view)
    assert any(isinstance(x, Put) for x in out)  # the RTL command
    a.handle_timer(15.1)
    out = view.on_control(wire.Reject("release", "no link: no key installed for B"), 15.2)
    assert not [x for x in out if isinstance(x, Emit) and x.kind == "handover_failed"]  # counted, not logged again
    assert not [x for x in out if isinstance(x, Put)]  # RTL once per epoch


def test_a_timed_out_hand_back_is_tried_again_when_the_vehicle_flies_into_our_coverage(fleet_dir):
    """B got authority by the emergency rule in the overlap, nearer A: its hand-back to A times out
    (A's site is down) while the vehicle flies toward B. No RTL (that would take it out of B's
    coverage); the hand-back is tried again, and a target that came back takes authority."""
    from zdrone.core import wire
    from zdrone.core.authority import State as HaState
    from zdrone.core.geometry import offset
    from zdrone.core.reference import HOME
    from gs.context import HANDOVER_RETRY_S

    b = core(fleet_dir, "B")
    view = b.sessions["d1"]
    from zdrone.core.keys import LinkKey
    view.slot.install(view.new_link(LinkKey.from_secret("d1", "B", bytes(32)), 0.0), 0.0)
    view.link = view.slot.live
    view.owner, view.epoch, view.linking.drone_links = "B", 2, {"A", "B"}
    view.position = offset(HOME, 0.0, 200.0)  # nearer A's centre than B's
    out = b.handle_timer(1.0)
    assert [x.fields["to"] for x in out if isinstance(x, Emit) and x.kind == "handover_release"] == ["A"]
    view.on_control(wire.AuthorityStatus("B", 2, HaState.HANDOVER_PENDING, "A", ["A", "B"]), 1.1)
    view.position = offset(HOME, 0.0, 220.0)  # flying toward B
    out = view.on_control(wire.AuthorityStatus("B", 2, HaState.LINKED, None, ["A", "B"]), 3.6)
    failed = [x for x in out if isinstance(x, Emit) and x.kind == "handover_failed"]
    assert [(x.fields["action"], x.fields["reason"]) for x in failed] == [("retry", "release timed out")]
    assert not [x for x in out if isinstance(x, Put)]  # no RTL
    assert not [x for x in b.handle_timer(4.0) if isinstance(x, Emit) and x.kind == "handover_release"]
    out = b.handle_timer(3.6 + HANDOVER_RETRY_S + 0.01)
    assert [x.fields["to"] for x in out if isinstance(x, Emit) and x.kind == "handover_release"] == ["A"]


def test_a_gs_cut_off_learns_who_holds_authority_before_it_acts(fleet_dir):
    """A held authority, then heard nothing for more than ``STALE_VIEW_S`` (its site was down): the
    drone may have handed authority on meanwhile. A sends no release, no command, until the drone's
    authority status says who holds it."""
    from zdrone.core import wire
    from zdrone.core.authority import State as HaState
    from gs.context import STALE_VIEW_S

    a = paired_a(fleet_dir)
    view = a.sessions["d1"]
    _in_overlap_nearer_b(a, {"A", "B"})
    a.opts = CoreOptions(pair=True, command_rate=5.0)
    view.armed = True
    view.link.tbm.observe(1.0)  # the drone was heard, then fell silent
    out = a.handle_timer(1.0 + STALE_VIEW_S + 0.5)
    assert view.stale and not a.holds_authority(view)
    assert not [x for x in out if isinstance(x, Emit) and x.kind in ("handover_release", "handover_failed")]
    assert not [x for x in out if isinstance(x, Put) and len(x.payload) > 60]  # no command (heartbeats only)
    view.on_control(wire.AuthorityStatus("B", 2, HaState.LINKED, None, ["A", "B"]), 3.0)
    assert not view.stale and view.owner == "B" and not a.holds_authority(view)
    assert not [x for x in a.handle_timer(3.1) if isinstance(x, Emit) and x.kind in ("handover_release", "handover_failed")]
    view.on_control(wire.AuthorityStatus("A", 3, HaState.LINKED, None, ["A", "B"]), 4.0)
    assert a.holds_authority(view)  # handed back: A acts again


def test_after_a_failsafe_the_gs_asks_for_control_only_with_the_operators_request(fleet_dir):
    from zdrone.core import wire

    for standing in (False, True):
        a = paired_a(fleet_dir)
        a.opts = CoreOptions(pair=True, take_control=standing)
        a.sessions["d1"].on_control(wire.FailsafeNotice("LAND", "authority link to A lost"), 5.0)
        assert not a.holds_authority(a.sessions["d1"])  # the drone obeys nobody in its failsafe
        asked = [x for x in a.handle_timer(6.0) if isinstance(x, Emit) and x.kind == "control_requested"]
        assert len(asked) == (1 if standing else 0)
        assert not [x for x in a.handle_timer(6.5) if isinstance(x, Emit) and x.kind == "control_requested"]  # 1/s at most


def _flying_core(fleet_dir, autopilot: str) -> StationCore:
    from gs.planner import reference_plan

    a = paired_a(fleet_dir)
    a.opts = CoreOptions(pair=True, mission=reference_plan())
    a.sessions["d1"].mission.plan = a.opts.mission
    a.sessions["d1"].autopilot = autopilot
    return a


def test_the_mission_is_encoded_for_the_autopilot_found(fleet_dir):
    from gs.mission import FlightParam, FlightTick

    px4 = _flying_core(fleet_dir, "px4")
    logs = [x for x in px4.sessions["d1"].flight(FlightTick(1.0)) if isinstance(x, Emit)]
    assert logs[-1].kind == "mission_upload" and logs[-1].fields["items"] == 7  # no second take-off
    ap = _flying_core(fleet_dir, "ardupilot")
    assert ap.sessions["d1"].flight(FlightTick(1.0)) and ap.sessions["d1"].mission.stage is Stage.PREPARING  # MIS_OPTIONS first
    assert ap.sessions["d1"].flight(FlightParam(1.1, "MIS_OPTIONS", 0.0)) == []  # not yet set
    logs = [x for x in ap.sessions["d1"].flight(FlightParam(1.2, "MIS_OPTIONS", 4.0)) if isinstance(x, Emit)]
    assert logs[-1].fields["items"] == 9 and ap.sessions["d1"].mission.stage is Stage.UPLOADING  # home placeholder + both take-offs


def _uploaded(a: StationCore) -> None:
    view = a.sessions["d1"]
    view.mission.stage, view.mission.stage_time, view.mission.tries, view.mission.next_try = Stage.WAITING_READY, 10.0, 0, 0.0


def _says(out) -> list[str]:
    return [x.text for x in out if isinstance(x, ToOperator)]


def _ekf(view, absolute: bool) -> None:
    from pymavlink.dialects.v20 import ardupilotmega as apm
    from pymavlink.dialects.v20 import common as mav

    from zdrone.core.reference import HOME

    codec = FrameCodec(1, 1)
    flags = apm.EKF_ATTITUDE | apm.EKF_POS_HORIZ_REL | (apm.EKF_POS_HORIZ_ABS if absolute else apm.EKF_CONST_POS_MODE)
    for m in (mav.MAVLink_gps_raw_int_message(0, 6, 0, 0, 0, 80, 120, 0, 65535, 14),
              mav.MAVLink_global_position_int_message(0, int(HOME.lat * 1e7), int(HOME.lon * 1e7), 0, 0, 0, 0, 0, 0),
              apm.MAVLink_ekf_status_report_message(flags, 0, 0, 0, 0, 0, 0)):
        view.fix.on_message(codec.decode(codec.encode(m)))


def test_arming_waits_until_the_autopilot_can_fly_the_mission_and_says_what_it_waits_for(fleet_dir):
    """Issue 22: the GS armed on the pre-arm bit alone and gave up after a retry counter ran out;
    ArduCopter's AUTO needs its EKF to use GPS, which comes long after its pre-arm checks pass."""
    from pymavlink.dialects.v20 import common as mav

    from gs.mission import FlightAck, FlightTick

    a = _flying_core(fleet_dir, "ardupilot")
    view = a.sessions["d1"]
    _uploaded(a)
    view.prearm_ok = False
    view.texts = [(9.0, "PreArm: EKF attitude is bad")]
    out = view.flight(FlightTick(11.0))
    assert not [x for x in out if isinstance(x, Put)] and view.mission.stage is Stage.WAITING_READY  # not ready: no ARM
    assert _says(out) == ["zdrone gs A: d1 not ready: pre-arm checks failing (PreArm: EKF attitude is bad)"]
    assert view.flight(FlightTick(11.5)) == []  # said once, until it changes
    view.prearm_ok = True
    _ekf(view, absolute=False)  # a GPS fix and a position, but the EKF does not use GPS yet
    assert view.position is None
    out = view.flight(FlightTick(12.0))
    assert _says(out) == ["zdrone gs A: d1 not ready: waiting for the EKF to use GPS "
                          "(EKF_STATUS_REPORT: no absolute position)"]
    for i in range(200):  # no retry counter runs out while the vehicle is not ready
        view.flight(FlightTick(13.0 + i))
    assert view.mission.stage is Stage.WAITING_READY
    _ekf(view, absolute=True)
    out = view.flight(FlightTick(300.0))
    assert _says(out) == ["zdrone gs A: d1 ready: arming"] and view.mission.stage is Stage.ARMING
    assert len([x for x in out if isinstance(x, Put)]) == 1  # the ARM
    # refused all the same, with its reason: waited for, however often
    for i in range(20):
        view.mission.stage, view.texts = Stage.ARMING, [(301.0 + i, "Arm: Accels inconsistent")]
        view.flight(FlightAck(301.0 + i, mav.MAV_CMD_COMPONENT_ARM_DISARM, False, mav.MAV_RESULT_FAILED))
        out = view.flight(FlightTick(301.6 + i))
        assert view.mission.stage is Stage.WAITING_READY, i
    refused = [x for x in out if isinstance(x, Emit) and x.kind == "vehicle_refused"]
    assert refused and refused[0].fields["texts"] == ["Arm: Accels inconsistent"]
    # a refusal nothing explains (no reason, the vehicle says it is ready) is tried a few times only
    from gs.mission import MAX_UNEXPLAINED

    for i in range(MAX_UNEXPLAINED):
        view.mission.stage, view.texts = Stage.ARMING, []
        view.flight(FlightAck(400.0 + i, mav.MAV_CMD_COMPONENT_ARM_DISARM, False, mav.MAV_RESULT_FAILED))
        out = view.flight(FlightTick(400.6 + i))
    assert view.mission.stage is Stage.FAILED and any(isinstance(x, Emit) and x.kind == "mission_failed" for x in out)


def test_a_refusal_is_classified_with_the_reason_that_follows_its_ack(fleet_dir):
    """Issue 22: ArduCopter answers MISSION_START FAILED first and says "requires position" 0.3 ms
    later; the GS read only the texts before the ACK and gave up."""
    from pymavlink.dialects.v20 import common as mav

    from gs.mission import FlightAck, FlightTick

    b = _flying_core(fleet_dir, "ardupilot")
    vb = b.sessions["d1"]
    _ekf(vb, absolute=True)
    vb.mission.stage, vb.armed, vb.prearm_ok = Stage.STARTING, True, True
    assert vb.flight(FlightAck(30.0, mav.MAV_CMD_MISSION_START, False, mav.MAV_RESULT_FAILED)) == []
    vb.texts = [(30.0003, "Mode change to AUTO failed: requires position")]  # after the ACK
    assert vb.flight(FlightTick(30.2)) == [] and vb.mission.stage is Stage.REFUSED  # a moment for the reasons
    out = vb.flight(FlightTick(30.6))
    assert vb.mission.stage is Stage.WAITING_READY and vb.mission.next_try > 30.6
    assert "not ready yet" in _says(out)[0] and "requires position" in _says(out)[0]
    _ekf(vb, absolute=False)  # armed, but no absolute position: no MISSION_START until there is one
    out = vb.flight(FlightTick(33.0))
    assert not [x for x in out if isinstance(x, Put)] and "EKF to use GPS" in _says(out)[0]
    _ekf(vb, absolute=True)
    assert [x for x in vb.flight(FlightTick(34.0)) if isinstance(x, Put)] and vb.mission.stage is Stage.STARTING
    # PX4's infeasible mission: refused for good, whatever order its words and its ACK come in
    a = _flying_core(fleet_dir, "px4")
    view = a.sessions["d1"]
    view.mission.stage, view.armed, view.landed_state = Stage.STARTING, True, mav.MAV_LANDED_STATE_ON_GROUND
    view.flight(FlightAck(30.1, mav.MAV_CMD_MISSION_START, False, mav.MAV_RESULT_DENIED))
    view.texts = [(30.1, "Mission rejected: takeoff not first waypoint item")]
    out = view.flight(FlightTick(30.7))
    failed = [x for x in out if isinstance(x, Emit) and x.kind == "mission_failed"]
    assert view.mission.stage is Stage.FAILED and "takeoff not first waypoint item" in failed[0].fields["reason"]
    assert any(isinstance(x, ToOperator) for x in out) and len([x for x in out if isinstance(x, Put)]) == 1  # the DISARM


def test_take_off_is_verified_and_a_disarm_on_the_ground_arms_and_starts_again(fleet_dir):
    """Issue 22: ArduCopter disarmed itself on the ground after the start, and the GS believed it flew."""
    from pymavlink.dialects.v20 import common as mav

    from gs.mission import FlightAck, FlightTick

    a = _flying_core(fleet_dir, "ardupilot")
    view = a.sessions["d1"]
    _ekf(view, absolute=True)
    view.mission.stage, view.prearm_ok, view.armed = Stage.STARTING, True, True
    view.landed_state = mav.MAV_LANDED_STATE_ON_GROUND
    view.flight(FlightAck(40.0, mav.MAV_CMD_MISSION_START, True, mav.MAV_RESULT_ACCEPTED))
    assert view.mission.stage is Stage.TAKING_OFF  # not flying: it has not left the ground
    assert view.flight(FlightTick(41.0)) == [] and a.report(0.0)["drones"]["d1"]["stage"] == "taking_off"
    view.armed, view.disarmed_at, view.custom_mode = False, 42.0, 3  # disarmed by itself, left in AUTO
    out = view.flight(FlightTick(42.1))
    assert view.mission.stage is Stage.WAITING_READY and view.mission.restarts == 1
    assert _says(out) == ["zdrone gs A: d1 disarmed on the ground before taking off (the autopilot's auto-disarm): "
                          "arming and starting again"]
    out = view.flight(FlightTick(44.5))  # AUTO cannot be armed in: GUIDED first
    assert view.mission.stage is Stage.WAITING_READY and len([x for x in out if isinstance(x, Put)]) == 1
    view.custom_mode = 4
    view.flight(FlightTick(45.6))
    assert view.mission.stage is Stage.ARMING
    view.flight(FlightAck(45.7, mav.MAV_CMD_COMPONENT_ARM_DISARM, True, mav.MAV_RESULT_ACCEPTED))
    view.flight(FlightAck(45.8, mav.MAV_CMD_MISSION_START, True, mav.MAV_RESULT_ACCEPTED))
    view.landed_state = mav.MAV_LANDED_STATE_IN_AIR
    out = view.flight(FlightTick(46.5))
    assert view.mission.stage is Stage.FLYING and _says(out) == ["zdrone gs A: d1 took off"]
    assert [x.fields["restarts"] for x in out if isinstance(x, Emit) and x.kind == "takeoff_confirmed"] == [1]


def test_the_gs_takes_no_position_from_an_autopilot_without_a_fix(fleet_dir):
    """Issue 22: lat = lon = 0 before the fix is no position: no hand-over decision on it."""
    from pymavlink.dialects.v20 import common as mav

    a = paired_a(fleet_dir)
    view = a.sessions["d1"]
    codec = FrameCodec(1, 1)
    view.fix.on_message(codec.decode(codec.encode(mav.MAVLink_global_position_int_message(0, 0, 0, 0, 0, 0, 0, 0, 0))))
    assert view.position is None and a.report(0.0)["drones"]["d1"]["position"] is None
    assert view.release_due(5.0) == []


def _repair(fleet_dir, holds_key: bool):
    a = paired_a(fleet_dir)
    live = a.sessions["d1"].link
    asks = [x for x in a.handle_timer(10.0) if isinstance(x, Ask) and x.kind is AskKind.PAIR]  # silent 10 s: pair again
    assert len(asks) == 1
    m2, _ = respond(ident(fleet_dir, "d1"), "d1", "A", a.fleet.nodes["A"].public_bytes, asks[0].payload, bytes(32),
                    holds_key=holds_key)
    out = a.on_pair_reply("d1", m2, None, 10.1)
    return a, live, out


def test_pairing_again_after_silence_keeps_the_key_the_drone_still_holds(fleet_dir):
    """Out of radio coverage is not a restart: the drone says it still holds our key, and we keep it
    (switching would leave us with a key the drone cannot confirm until it is back in range)."""
    a, live, out = _repair(fleet_dir, holds_key=True)
    assert a.sessions["d1"].link is live and [x.kind for x in out if isinstance(x, Emit)] == ["pair_not_needed"]
    b, live_b, out_b = _repair(fleet_dir, holds_key=False)  # a restarted companion holds nothing
    assert b.sessions["d1"].link is not live_b and any(isinstance(x, Emit) and x.kind == "paired" for x in out_b)


def test_a_drone_that_says_it_still_holds_our_key_is_not_asked_again_before_another_silence(fleet_dir):
    """A slow companion (or a lossy downlink) is silent on the link, yet answers our re-pairing that it
    holds our key: that answer is its word, fresh and authentic. We pair again only after another
    ``SILENT_REPAIR_S`` without a sign of life, not every ``SILENT_RETRY_S`` (each try a handshake the
    late drone computes: the loop that made a saturated host of 300 drones answer 48 000 of them)."""
    from gs.context import SILENT_REPAIR_S, SILENT_RETRY_S

    a, live, out = _repair(fleet_dir, holds_key=True)
    assert [x.kind for x in out if isinstance(x, Emit)] == ["pair_not_needed"]
    t, asked = 10.1, []
    while t < 10.1 + SILENT_REPAIR_S + 0.5:
        t = max(a.get_timer(), t + 0.01)
        asked += [t for x in a.handle_timer(t) if isinstance(x, Ask) and x.kind is AskKind.PAIR]
    assert asked and asked[0] > 10.1 + SILENT_REPAIR_S  # then pairing again, as for any silence
    assert all(y - x >= SILENT_RETRY_S * 0.9 for x, y in zip(asked, asked[1:]))
    b, live_b, _ = _repair(fleet_dir, holds_key=False)  # a restarted companion: the new key, no wait
    assert b.sessions["d1"].link is not live_b and b.sessions["d1"].kept_key_at is None


def test_a_lost_start_answer_never_starts_a_flying_mission_again(fleet_dir):
    """Seen under a lossy radio: MISSION_START's ACK was lost, the GS timed out and, on getting authority
    back later, started the mission again from its first item. A GS whose vehicle flies takes the
    mission as started and never sends MISSION_START to it."""
    from pymavlink.dialects.v20 import common as mav

    from gs.mission import FlightTick

    a = _flying_core(fleet_dir, "px4")
    view = a.sessions["d1"]
    view.mission.stage, view.mission.stage_time, view.prearm_ok, view.armed = Stage.STARTING, 40.0, True, True
    view.landed_state = mav.MAV_LANDED_STATE_IN_AIR  # it took off: the start was obeyed, its ACK lost
    out = view.flight(FlightTick(44.0))
    assert view.mission.stage is Stage.FLYING and not [x for x in out if isinstance(x, Put)]
    # and from the retry stage (the answer timed out before the vehicle left the ground)
    view.mission.stage, view.mission.next_try = Stage.WAITING_READY, 0.0
    out = view.flight(FlightTick(50.0))
    assert view.mission.stage is Stage.FLYING and not [x for x in out if isinstance(x, Put)]


def _flying_mission(a: StationCore) -> None:
    from zdrone.vehicle.modes import custom_mode

    view = a.sessions["d1"]
    view.autopilot, view.armed, view.custom_mode = "px4", True, custom_mode("px4", "MISSION")


def _mode_commands(a: StationCore, out) -> list[str]:
    """The DO_SET_MODE commands among ``out``, by mode name (decoded as the drone would)."""
    from pymavlink.dialects.v20 import common as mav
    from zdrone.core.envelope import SecureLink
    from zdrone.vehicle.modes import mode_name

    names = []
    view = a.sessions["d1"]
    for x in out:
        if not isinstance(x, Put):
            continue
        peer = SecureLink(key=view.link.key, role="drone", tx_keyexpr="", rx_keyexpr=f"zdrone/{x.peer}/up/A", peer_sysid=a.sysid, now=0.0)
        res = peer.open(x.payload, 0.0)
        msg = FrameCodec(1, 1).decode(res.plaintext) if getattr(res, "plaintext", None) else None
        if msg is not None and msg.get_type() == "COMMAND_LONG" and msg.command == mav.MAV_CMD_DO_SET_MODE:
            names.append(mode_name("px4", int(msg.param2) << 16 | int(msg.param3) << 24))
        elif msg is not None and msg.get_type() == "COMMAND_LONG" and msg.command == mav.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            names.append("RTL")
    return names


def _held_for_b(fleet_dir, restarted: bool = True) -> StationCore:
    """A in the overlap nearer B, flying its mission; B's key is asked for and B said ``live_link``;
    ``restarted``: A's own re-pairing showed the companion had lost A's key (authenticated)."""
    a = paired_a(fleet_dir)
    _in_overlap_nearer_b(a, {"A"})
    _flying_mission(a)
    if restarted:
        a.sessions["d1"].linking.lost_key_at = 9.0
    share(a, core(fleet_dir, "B"), 10.0)
    a.on_linkkey_reply("d1", "B", None, b"live_link", 10.1)
    return a


def _set_mode(a: StationCore, name: str) -> None:
    from zdrone.vehicle.modes import custom_mode

    session = a.sessions["d1"]
    session.custom_mode = custom_mode("px4", name)  # as the vehicle's HEARTBEAT says ...
    session.due = 0.0  # ... an input: the session looks at it at once


def _handover_logs(out) -> list[str]:
    return [x.kind for x in out if isinstance(x, Emit) and x.kind.startswith("handover")]


def test_a_key_known_to_be_coming_holds_the_vehicle_then_the_mission_resumes_before_the_release(fleet_dir):
    """Issue 19: B's key still missing on the drone, but known to be coming (B said ``live_link`` and
    A's own pairing showed the companion restarted): A holds the vehicle in the overlap instead of
    bringing it home; the hold is sent again until the vehicle confirms it; once the key is there the
    mission resumes first, and the release goes out only when the vehicle confirms its mission mode."""
    from gs.keyhold import HOLD_RESEND_S

    a = _held_for_b(fleet_dir)
    view = a.sessions["d1"]
    out = a.handle_timer(10.2)
    assert _handover_logs(out) == ["handover_hold"] and _mode_commands(a, out) == ["HOLD"] and a.holds_authority(view)
    assert _mode_commands(a, a.handle_timer(10.2 + HOLD_RESEND_S + 0.01)) == ["HOLD"]  # not confirmed: sent again
    _set_mode(a, "HOLD")  # the vehicle's HEARTBEAT: holding
    assert _mode_commands(a, a.handle_timer(11.5)) == [] and not _handover_logs(a.handle_timer(12.0))
    view.linking.drone_links = {"A", "B"}  # B's key reached the drone and B proved it
    out = a.handle_timer(13.0)
    assert _handover_logs(out) == ["handover_resume"] and _mode_commands(a, out) == ["MISSION"]
    assert _mode_commands(a, a.handle_timer(13.0 + HOLD_RESEND_S + 0.01)) == ["MISSION"]  # not confirmed: sent again
    view.on_mode_ack(True, 13.6)  # COMMAND_ACK accepted
    out = a.handle_timer(13.7)
    assert _handover_logs(out) == ["handover_release"]


def test_a_hold_the_vehicle_never_confirms_ends_in_rtl_past_the_key_wait_radius(fleet_dir):
    """Review 3 H1: the hold's mode command lost (or refused): the vehicle flies on; at 90 % of A's
    radius the hold has failed and A brings it home, as without a hold."""
    from zdrone.core.geometry import offset
    from zdrone.core.reference import HOME

    a = _held_for_b(fleet_dir)
    assert _mode_commands(a, a.handle_timer(10.2)) == ["HOLD"]
    a.sessions["d1"].position = offset(HOME, 0.0, 320.0)  # past 90 % of A's 350 m, still in MISSION
    out = a.handle_timer(10.8)
    assert [x.fields["action"] for x in out if isinstance(x, Emit) and x.kind == "handover_failed"] == ["RTL"]
    assert _mode_commands(a, out) == ["RTL"]


def test_a_hold_that_runs_out_commands_rtl_wherever_the_vehicle_holds(fleet_dir):
    """Review 3 M3: at the end of the hold, RTL whether or not the vehicle is "leaving" (it holds)."""
    from gs.keyhold import HOLD_FOR_KEY_S

    a = _held_for_b(fleet_dir)
    a.handle_timer(10.2)
    _set_mode(a, "HOLD")
    a.handle_timer(11.0)
    out = a.handle_timer(10.2 + HOLD_FOR_KEY_S + 0.1)
    assert "RTL" in _mode_commands(a, out) and a.counters["handover_hold_over:expired"] == 1
    assert not _mode_commands(a, a.handle_timer(10.2 + HOLD_FOR_KEY_S + 3.0))  # once


def test_a_mode_someone_else_chose_during_the_hold_stands(fleet_dir):
    """Review 3 M4: the operator (or the autopilot's own failsafe) changed the mode while A held the
    vehicle: A neither resumes the mission over it nor commands RTL at the end of the hold."""
    from gs.keyhold import HOLD_FOR_KEY_S

    a = _held_for_b(fleet_dir)
    view = a.sessions["d1"]
    a.handle_timer(10.2)
    _set_mode(a, "HOLD")
    a.handle_timer(11.0)
    _set_mode(a, "LAND")
    out = a.handle_timer(11.5)
    assert a.counters["handover_hold_over:mode changed"] == 1 and not _mode_commands(a, out)
    assert not _mode_commands(a, a.handle_timer(10.2 + HOLD_FOR_KEY_S + 0.1))
    view.linking.drone_links = {"A", "B"}
    out = a.handle_timer(10.2 + HOLD_FOR_KEY_S + 3.0)
    assert "MISSION" not in _mode_commands(a, out)


def test_an_unauthenticated_live_link_error_alone_holds_nothing(fleet_dir):
    """Review 3 L5: anyone with B's router password can answer A's query with ``live_link``. Without
    A's own authenticated evidence that the companion restarted, A does not hold: RTL at 90 % of its
    radius, as before; an unanswered query (B unreachable) holds nothing either."""
    from zdrone.core.geometry import offset
    from zdrone.core.reference import HOME

    a = _held_for_b(fleet_dir, restarted=False)
    a.sessions["d1"].position = offset(HOME, 0.0, 320.0)
    out = a.handle_timer(10.2)
    assert [x.fields["action"] for x in out if isinstance(x, Emit) and x.kind == "handover_failed"] == ["RTL"]
    assert "handover_hold" not in _handover_logs(out)
    b = paired_a(fleet_dir)
    _in_overlap_nearer_b(b, {"A"})
    _flying_mission(b)
    b.sessions["d1"].linking.lost_key_at = 9.0
    share(b, core(fleet_dir, "B"), 10.0)  # no answer at all
    b.sessions["d1"].position = offset(HOME, 0.0, 320.0)
    out = b.handle_timer(10.2)
    assert [x.fields["action"] for x in out if isinstance(x, Emit) and x.kind == "handover_failed"] == ["RTL"]


def test_a_silent_drone_is_asked_to_pair_five_times_a_second_at_first_then_once_a_second(fleet_dir):
    """The authority re-pairs a silent drone fast (a restarted companion must have its owner back
    within the loss threshold), and slower once the silence has lasted SILENT_FAST_S (a drone out of
    reach for good is not asked five times a second forever)."""
    from gs.context import SILENT_FAST_S, SILENT_REPAIR_S, SILENT_RETRY_S, SILENT_SLOW_RETRY_S

    a = paired_a(fleet_dir)
    heard = a.sessions["d1"].link.tbm.last_seen or 0.1
    times = []
    for i in range(1, 800):  # 40 s of ticks, not a word from the drone, no answer to any query
        now = 0.1 + i * 0.05
        asks = [x for x in a.handle_timer(now) if isinstance(x, Ask) and x.kind is AskKind.PAIR]
        times += [now for _ in asks]
        for x in asks:  # the companion is down: Zenoh ends the query at once, with no reply
            a.on_pair_done("d1", x.payload, now)
    fast = [t for t in times if t - heard <= SILENT_FAST_S]
    slow = [t for t in times if t - heard > SILENT_FAST_S + SILENT_SLOW_RETRY_S]
    assert fast and fast[0] - heard > SILENT_REPAIR_S
    assert all(0.9 * SILENT_RETRY_S < y - x <= SILENT_RETRY_S + 0.1 for x, y in zip(fast, fast[1:]))
    assert slow and all(0.9 * SILENT_SLOW_RETRY_S < y - x <= SILENT_SLOW_RETRY_S + 0.1 for x, y in zip(slow, slow[1:]))


# ------------------------------------------------------------------ timers and the API by name
def test_the_timer_is_due_at_once_after_an_input_and_else_at_the_next_heartbeat_or_deadline(fleet_dir):
    """As the drone's core: the adapter calls ``handle_timer`` when ``get_timer`` is due and sleeps
    otherwise; an input makes it due at once, for what the input changed may decide something."""
    a = paired_a(fleet_dir)
    assert a.get_timer() <= 0.1  # the pairing reply was an input
    a.sessions["d1"].owner = "B"  # not ours: nothing to re-pair, share or fly
    a.handle_timer(1.0)
    assert a.get_timer() == a._hb_due  # the heartbeat alone: no poll of anything
    a.on_envelope("d1", b"not an envelope", 1.01)
    assert a.get_timer() == 1.01
    a.handle_timer(1.01)
    assert a.get_timer() > 1.01
    hb = a._hb_due
    out = a.handle_timer(hb)
    assert any(isinstance(x, Put) for x in out) and a._hb_due > hb  # the heartbeat went out


def test_a_deadline_shorter_than_the_heartbeat_is_honoured(fleet_dir):
    """An unconfirmed release is sent again after RELEASE_RESEND_S (0.25 s), sooner than the next
    heartbeat: the timer is due then, not at a poll's rhythm."""
    from gs.context import DEADLINE_SLACK_S, RELEASE_RESEND_S

    a = paired_a(fleet_dir)
    _in_overlap_nearer_b(a, {"A", "B"})
    a.handle_timer(10.0)
    out = a.handle_timer(10.2)  # released at 10.0, a heartbeat or not: the release is not due again yet
    assert not [x for x in out if isinstance(x, Emit) and x.kind == "handover_release"]
    assert a.get_timer() == pytest.approx(10.0 + RELEASE_RESEND_S + DEADLINE_SLACK_S)
    sent = [x for x in a.handle_timer(a.get_timer()) if isinstance(x, Put)]
    assert sent  # the release again (no heartbeat was due)
    assert a._hb_due > a.get_timer() - RELEASE_RESEND_S


def test_no_timer_fires_without_work(fleet_dir):
    """Driven by its timer alone for 10 s, a GS whose drone is owned by another wakes for its
    heartbeats only (a 50 ms poll woke it 200 times)."""
    a = paired_a(fleet_dir)
    a.sessions["d1"].owner = "B"
    a.handle_timer(0.2)
    wakes, now = 0, 0.2
    while (now := a.get_timer()) < 10.2:
        out = a.handle_timer(now)
        wakes += 1
        assert any(isinstance(x, Put) for x in out), f"a wake at {now} with nothing to do"
    assert wakes <= 10 * 2 + 1  # 2 Hz heartbeats


def test_adapters_name_a_drone_and_read_its_status(fleet_dir):
    a = paired_a(fleet_dir)
    assert a.drones == tuple(a.sessions)
    st = a.drone_status("d1", 1.0)
    v = a.sessions["d1"]
    assert (st.name, st.sysid, st.linked, st.owner, st.epoch) == ("d1", v.sysid, True, "A", 1)
    assert st.holds_authority == a.holds_authority("d1") == a.holds_authority(v)
    assert st.request is None and not st.takeover
    assert a.send_control("d1", wire.KeyGrantAck("B", 1)) and a.send_frame("d1", FrameCodec(1, 1).encode(
        _heartbeat_msg()))
    assert (a.describe("d1", 1.0) or "").startswith("gs A | d1: nothing heard yet")
    with pytest.raises(KeyError):
        a.drone_status("nobody", 1.0)


def _heartbeat_msg():
    from pymavlink.dialects.v20 import common as mav

    return mav.MAVLink_heartbeat_message(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, mav.MAV_STATE_ACTIVE, 3)


def test_a_bundle_opens_every_envelope_in_it_and_a_malformed_one_is_counted(fleet_dir):
    """The drone publishes a pass's envelopes as one bundle (``zdrone.core.bundle``): the GS opens
    each on its own (one forged among them is dropped by its key, the rest count); bytes that are
    not a bundle are dropped whole and counted, never raised."""
    from zdrone.core import wire
    from zdrone.core.bundle import pack
    from zdrone.core.envelope import SecureLink
    from zdrone.core.keys import LinkKey

    a = paired_a(fleet_dir)
    view = a.sessions["d1"]
    drone = SecureLink(key=view.slot.candidates[0].link.key if view.link is None else view.link.key, role="drone",
                       tx_keyexpr="zdrone/d1/down/A", rx_keyexpr="zdrone/d1/up/A", peer_sysid=None, now=0.0)
    forged = SecureLink(key=LinkKey.from_secret("d1", "A", bytes(32)), role="drone",
                        tx_keyexpr="zdrone/d1/down/A", rx_keyexpr="zdrone/d1/up/A", peer_sysid=None, now=0.0)
    items = [drone.seal_control(wire.SmHeartbeat(1)), forged.seal_control(wire.SmHeartbeat(2)),
             drone.seal_control(wire.SmHeartbeat(3))]
    a.on_bundle("d1", pack(items), 0.2)
    link = view.link if view.link is not None else view.slot.live
    assert link is not None and link.opened == 2
    a.on_bundle("d1", b"\x00\x09short", 0.3)
    assert a.counters["down:bad_bundle"] == 1 and link.opened == 2


def test_heartbeats_keep_their_rhythm_when_the_loop_runs_late(fleet_dir):
    """A loop late by d sends the next heartbeat a period after the last was *due* (a late loop
    does not stretch the period); one late by more than a period starts again from now (no burst)."""
    a = paired_a(fleet_dir)
    period = 1.0 / a.opts.heartbeat_hz
    a.handle_timer(1.0)
    due = a._hb_due
    assert due == 1.0 + period
    a.handle_timer(due + 0.2)  # late by 0.2 s
    assert a._hb_due == due + period
    late = a._hb_due + 3 * period  # late by three periods
    a.handle_timer(late)
    assert a._hb_due == late + period


def test_a_release_refused_because_authority_moved_on_stops_our_commands_until_the_drone_says(fleet_dir):
    """A released d1 to B; the drone completed the hand-over and refused A's repeated release (``not the
    authority``) before A heard its new status. That is no failed hand-over: A commands nothing, and
    retries nothing, until the drone's status says who holds it (a command of A's then would be
    dropped by the drone: one command lost per such race at 300 drones over sites)."""
    from zdrone.core.authority import RELEASE_NOT_AUTHORITY, RELEASE_STALE_EPOCH
    from zdrone.core.authority import State as HaState

    for reason in (RELEASE_NOT_AUTHORITY, f"{RELEASE_STALE_EPOCH}: 1 != 2"):
        a = paired_a(fleet_dir)
        view = a.sessions["d1"]
        _in_overlap_nearer_b(a, {"A", "B"})
        a.opts = CoreOptions(pair=True, command_rate=5.0)
        view.armed = True
        out = a.handle_timer(10.0)
        assert [x.fields["to"] for x in out if isinstance(x, Emit) and x.kind == "handover_release"] == ["B"]
        view.on_control(wire.AuthorityStatus("A", 1, HaState.HANDOVER_PENDING, "B", ["A", "B"]), 10.1)
        out = view.on_control(wire.Reject("release", reason), 10.2)
        assert not [x for x in out if isinstance(x, Emit) and x.kind == "handover_failed"]
        assert not a.holds_authority(view) and a.counters["release_after_authority_moved"] == 1
        for t in (10.3, 10.6, 11.0):  # the command stream and the retries wait
            out = a.handle_timer(t)
            assert not [x for x in out if isinstance(x, Emit) and x.kind in ("handover_release", "handover_failed")]
            assert not [x for x in out if isinstance(x, Put) and len(x.payload) > 60]  # heartbeats only
        view.on_control(wire.AuthorityStatus("B", 2, HaState.LINKED, None, ["A", "B"]), 11.2)
        assert view.owner == "B" and not a.holds_authority(view)


def test_a_silent_drone_slow_to_answer_is_not_asked_again_while_its_query_is_open(fleet_dir):
    """A loaded companion answers a re-pairing in more than SILENT_RETRY_S: the exchange waits for it
    (SILENT_PAIR_TIMEOUT_S) instead of asking again at every retry, each new question costing it a
    handshake whose answer would come late too."""
    from gs.session import SILENT_PAIR_TIMEOUT_S

    a = paired_a(fleet_dir)
    times = []
    for i in range(1, 100):  # 5 s of ticks; the queries stay open (the drone has not answered yet)
        now = 0.1 + i * 0.05
        times += [now for x in a.handle_timer(now) if isinstance(x, Ask) and x.kind is AskKind.PAIR]
    assert times and all(y - x >= SILENT_PAIR_TIMEOUT_S - 0.05 for x, y in zip(times, times[1:]))
