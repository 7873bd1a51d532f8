"""The GS's mission stages (gs.mission): the whole table, and random walks through it."""

from dataclasses import dataclass, field

from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mav

from gs.actions import Emit, ToOperator
from gs.mission import (TABLE, FlightAck, FlightParam, FlightTick, Mission, PendingRefusal, Stage)
from gs.planner import MissionUploader, encode_mission, reference_plan
from zdrone.core.geometry import GeoPoint
from zdrone.vehicle.fix import PositionFix


@dataclass
class Vehicle:
    autopilot: str | None = None
    armed: bool = False
    disarmed_at: float | None = None
    custom_mode: int = 0
    landed_state: int = 0
    prearm_ok: bool | None = None
    texts: list = field(default_factory=list)
    fix: PositionFix = field(default_factory=PositionFix)


def _fix(alt: float | None) -> PositionFix:
    fix = PositionFix()
    if alt is not None:
        fix.reported = GeoPoint(47.0, 8.0, alt)
    return fix


VEHICLES = st.builds(
    Vehicle, autopilot=st.sampled_from([None, "px4", "ardupilot", "other"]), armed=st.booleans(),
    disarmed_at=st.one_of(st.none(), st.floats(0, 100)), custom_mode=st.sampled_from([0, 3, 4, 6, 9]),
    landed_state=st.sampled_from([0, 1, 2, 3, 4]), prearm_ok=st.sampled_from([None, True, False]),
    texts=st.lists(st.tuples(st.floats(0, 100), st.sampled_from(["PreArm: GPS", "mission rejected", "ok"])),
                   max_size=3),
    fix=st.builds(_fix, st.one_of(st.none(), st.floats(-1, 50))))
COMMANDS = st.sampled_from([mav.MAV_CMD_COMPONENT_ARM_DISARM, mav.MAV_CMD_MISSION_START, 400, 176])
EVENTS = st.one_of(
    st.builds(FlightTick, st.floats(0, 100)),
    st.builds(FlightAck, st.floats(0, 100), COMMANDS, st.booleans(), st.sampled_from([0, 1, 4])),
    st.builds(FlightParam, st.floats(0, 100), st.sampled_from(["MIS_OPTIONS", "OTHER"]), st.sampled_from([0.0, 4.0])))


def _send(msg):
    return [msg]  # the message itself stands for its sealed frame


def _mission(stage: Stage, at: float = 0.0) -> Mission:
    m = Mission("A", "d1", 1, reference_plan())
    m.stage, m.stage_time = stage, at
    if stage is Stage.UPLOADING:
        m.uploader = MissionUploader(encode_mission(m.plan, "px4"))
        m.uploader.start(at)
    if stage is Stage.REFUSED:
        m.refusal = PendingRefusal("arm", 1, at)
    return m


@settings(max_examples=600, deadline=None)
@given(st.sampled_from(list(Stage)), EVENTS, VEHICLES)
def test_every_stage_and_event_follows_the_table(stage, ev, vehicle):
    """A pair not in the table changes nothing and says nothing; a listed one moves only to a stage its
    row allows (``_set_state`` raises otherwise)."""
    m = _mission(stage)
    row = TABLE.get((stage, type(ev)))
    out = m.handle(ev, vehicle, _send)
    if row is None:
        assert out == [] and m.stage is stage
    else:
        assert m.stage is stage or m.stage in row[1]
    assert all(isinstance(x, (Emit, ToOperator, mav.MAVLink_message)) for x in out)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(EVENTS, VEHICLES), max_size=30))
def test_random_walks_stay_in_the_table(steps):
    m = _mission(Stage.IDLE)
    for ev, vehicle in sorted(steps, key=lambda s: s[0].now):
        before = m.stage
        m.handle(ev, vehicle, _send)
        assert m.stage is before or m.stage in TABLE[(before, type(ev))][1]


def test_no_plan_no_mission():
    m = Mission("A", "d1", 1, None)
    assert m.handle(FlightTick(1.0), Vehicle(autopilot="px4"), _send) == [] and m.stage is Stage.IDLE
    assert m.deadline(1.0, Vehicle()) is None


def test_every_stage_but_the_last_two_has_a_row():
    assert {s for s, _ in TABLE} == set(Stage) - {Stage.FLYING, Stage.FAILED}


def _upload_ends(m: Mission, now: float, result: int, v: Vehicle) -> list:
    """The vehicle answers ``m``'s upload with MISSION_ACK ``result`` at ``now``; the next tick reads it."""
    assert m.stage is Stage.UPLOADING and m.uploader is not None
    ack = mav.MAVLink_mission_ack_message(255, 190, result, 0)
    ack._header = mav.MAVLink_header(ack.id, srcSystem=1, srcComponent=1)
    m.on_message(ack, now, 255, _send)
    return m.handle(FlightTick(now), v, _send)


def test_a_cancelled_upload_is_retried_with_backoff_and_jitter_until_its_deadline():
    from collections import Counter

    from gs.mission import UPLOAD_BACKOFF_MAX_S, UPLOAD_DEADLINE_S, backoff, jitter

    # jitter: the adapter's seed decides it, the same seed replays it, drones differ
    assert jitter(b"s", "d1", "upload", 1) == jitter(b"s", "d1", "upload", 1)
    draws = {jitter(b"s", f"d{i}", "upload", 1) for i in range(300)}
    assert len(draws) == 300 and all(0 <= u < 1 for u in draws) and min(draws) < 0.1 and max(draws) > 0.9
    assert [backoff(n, 0.0) for n in (1, 2, 3, 6)] == [1.0, 2.0, 4.0, UPLOAD_BACKOFF_MAX_S / 2]
    assert backoff(1, 0.999) < 2.0 and backoff(40, 0.5) <= UPLOAD_BACKOFF_MAX_S

    counters: Counter[str] = Counter()
    v = Vehicle(autopilot="px4")
    m = Mission("A", "d1", 1, reference_plan(), seed=b"seed", counters=counters)
    m.handle(FlightTick(0.0), v, _send)
    out = _upload_ends(m, 1.0, mav.MAV_MISSION_OPERATION_CANCELLED, v)
    assert m.stage is Stage.UPLOAD_WAIT and m.uploader is None and counters["mission_upload_retry"] == 1
    [retry] = [x.record for x in out if isinstance(x, Emit)]
    assert retry.result == 15 and retry.try_ == 1 and 1.0 <= retry.after < 2.0
    assert m.deadline(1.0, v) == m.next_try and abs(m.next_try - (1.0 + retry.after)) < 1e-3
    assert m.handle(FlightTick(m.next_try - 0.01), v, _send) == []  # its backoff first
    out = m.handle(FlightTick(m.next_try), v, _send)
    assert m.stage is Stage.UPLOADING and isinstance(out[0], mav.MAVLink_mission_count_message)
    # a refusal a new try cannot fix fails at once, said and counted
    m2 = Mission("A", "d2", 2, reference_plan(), seed=b"seed", counters=counters)
    m2.handle(FlightTick(0.0), v, _send)
    out = _upload_ends(m2, 1.0, mav.MAV_MISSION_INVALID_PARAM7, v)
    assert m2.stage is Stage.FAILED and counters["mission_upload_failed"] == 1 and counters["mission_failed"] == 1
    # cancelled again and again: tried until the deadline, then given up with why
    now = 1.0
    while m.stage is not Stage.FAILED:
        assert now < UPLOAD_DEADLINE_S + UPLOAD_BACKOFF_MAX_S
        out = _upload_ends(m, now, mav.MAV_MISSION_OPERATION_CANCELLED, v)
        now = m.next_try
        m.handle(FlightTick(now), v, _send)
    [failed] = [x.record for x in out if isinstance(x, Emit) and x.kind == "mission_failed"]
    assert "OPERATION_CANCELLED" in failed.reason and counters["mission_failed"] == 2
