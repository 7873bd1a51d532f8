"""Issue 22 in memory (``tests/coreflight.py``): the reference flight with each autopilot's real
start-up, and a vehicle that disarms itself on the ground after the mission start."""

from __future__ import annotations

import pytest

from gs.mission import Stage
from tests.coreflight import DRONE, CoreFlight
from zdrone.core import records as rec
from zdrone.sil.launcher import delivered_at
from zdrone.vehicle.personality import personality

#: the real start-up of each (simulated seconds): PX4 ready ~10 s, ArduCopter's EKF using GPS at ~40 s
REAL_START = {"px4": 10.0, "ardupilot": 40.0}
WAITS_FOR = {"px4": "pre-arm checks failing", "ardupilot": "EKF to use GPS"}  # what it waits for last
WAITS_ANY = ("pre-arm", "EKF", "position", "SYS_STATUS")  # what a GS may say it waits for


@pytest.fixture(scope="module")
def fleet_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("fleet")


def _delivered(f: CoreFlight, autopilot: str) -> bool:
    return delivered_at([rec.MissionProgress(**x) for _, x in f.gs_logs("B", "mission_progress")], autopilot)


@pytest.mark.parametrize("autopilot", ["px4", "ardupilot"])
def test_the_reference_flight_with_the_autopilots_real_start_up(fleet_dir, autopilot):
    f = CoreFlight(fleet_dir, personality(autopilot))
    f.sim.ready_after = REAL_START[autopilot]
    r = f.sim.p.readiness
    fix_at, position_at = r.gps_fix_at * f.sim.ready_after, r.position_at * f.sim.ready_after
    first_armed = None
    while not f.flown() and f.now < 500:
        f.step()
        if f.now < fix_at - 0.5:
            assert f.drone.position is None and f.gs["A"].core.sessions[DRONE].position is None, f.now  # never (0, 0)
        if first_armed is None and f.sim.armed:
            first_armed = f.now
    assert f.flown(), f"not flown: stage {f.gs['A'].core.sessions[DRONE].mission.stage}"
    assert first_armed is not None and first_armed >= position_at  # armed only once it could fly the mission
    waits = [x["waiting"] for _, x in f.gs_logs("A", "vehicle_waiting")]
    # the first pairing gives authority, so it waits for the vehicle's own position (issue 18: an unknown
    # position is inside no coverage); by then the autopilot may be ready: whatever the GS waited for
    # after that, it said so and ended ready
    refused = [x["reason"] for _, x in f.gs_logs("A", "pair_refused")]
    assert any("position is unknown" in r for r in refused), refused
    assert not waits or (all(w is None or any(k in w for k in WAITS_ANY) for w in waits) and waits[-1] is None), waits
    assert not f.gs_logs("A", "mission_failed") and not f.gs_logs("A", "takeoff_restart")
    assert _delivered(f, autopilot) and f.of(rec.Failsafe) == []


@pytest.mark.parametrize("autopilot", ["px4", "ardupilot"])
def test_a_vehicle_that_disarms_on_the_ground_after_the_start_is_armed_and_started_again(fleet_dir, autopilot):
    """ArduCopter's case: the start accepted, then "Disarming motors" on the ground, left in AUTO; the
    GS used to believe it flew."""
    f = CoreFlight(fleet_dir, personality(autopilot))
    view = f.gs["A"].core.sessions[DRONE]
    assert f.run_until(lambda: view.mission.stage is Stage.TAKING_OFF, 100)
    f.sim.disarm("disarmed_preflight")  # the auto-disarm, before it could climb
    assert view.mission.stage is not Stage.FLYING
    assert f.run_until(f.flown, 400), f"not flown: stage {view.mission.stage}"
    [(_, restart)] = f.gs_logs("A", "takeoff_restart")
    assert restart["restarts"] == 1
    assert [x["restarts"] for _, x in f.gs_logs("A", "takeoff_confirmed")] == [1]
    assert _delivered(f, autopilot) and f.of(rec.Failsafe) == []


@pytest.mark.parametrize("autopilot", ["px4", "ardupilot"])
def test_a_cancelled_mission_upload_is_tried_again_and_flown(fleet_dir, autopilot, monkeypatch):
    """300 drones at scale: GS A stalled in the middle of uploads, the vehicles asked for the next item
    five times, cancelled the upload (MISSION_ACK 15, OPERATION_CANCELLED) and the GS gave the mission
    up: the drones sat disarmed. Here the GS's items of the first upload never reach the vehicle; it
    cancels for real (``MissionProtocol.retry_upload``), the GS tries again after a backoff, and the
    drone takes off with the mission the second upload stored."""
    from pymavlink.dialects.v20 import common as mav

    from gs.mission import UPLOAD_BACKOFF_S
    from zdrone.core.mavlink import read_header

    f = CoreFlight(fleet_dir, personality(autopilot))
    view = f.gs["A"].core.sessions[DRONE]
    receive = f.sim.receive

    def items_lost_until_cancelled(frame: bytes, now: float, link: int = 0) -> None:
        if (not f.sim.counters["mission_operation_cancelled"]
                and read_header(frame).msgid == mav.MAVLINK_MSG_ID_MISSION_ITEM_INT):
            return  # as from a GS that stalled between items
        receive(frame, now, link)

    monkeypatch.setattr(f.sim, "receive", items_lost_until_cancelled)
    assert f.run_until(lambda: view.mission.stage is Stage.UPLOAD_WAIT, 60), view.mission.stage
    assert f.sim.counters["mission_operation_cancelled"] == 1
    [(t_failed, retry)] = f.gs_logs("A", "mission_retry")
    assert retry["what"] == "upload" and retry["result"] == mav.MAV_MISSION_OPERATION_CANCELLED and retry["try"] == 1
    assert UPLOAD_BACKOFF_S / 2 <= retry["after"] <= UPLOAD_BACKOFF_S  # first backoff: half fixed, half drawn
    assert f.gs["A"].core.counters["mission_upload_retry"] == 1
    assert f.run_until(lambda: bool(f.gs_logs("A", "takeoff_confirmed")), 120), view.mission.stage
    uploads = [t for t, _ in f.gs_logs("A", "mission_upload")]
    assert len(uploads) == 2 and uploads[1] >= t_failed + retry["after"]  # not before its backoff
    assert f.sim.armed and not f.gs_logs("A", "mission_failed") and f.gs["A"].core.counters["mission_failed"] == 0
    assert f.run_until(f.flown, 400), f"not flown: stage {view.mission.stage}"
    assert _delivered(f, autopilot) and f.of(rec.Failsafe) == []
