"""The vehicle link asks for what it needs: ``VehicleTracker`` driven against the simulator's PX4 and
ArduPilot personalities in memory (explicit simulated time, no sockets)."""

from __future__ import annotations

from collections import Counter
from dataclasses import replace
from typing import Any

from pymavlink.dialects.v20 import common as mav

from zdrone.core.geometry import distance_m
from zdrone.core.mavlink import FrameCodec, read_header
from zdrone.core.reference import HOME
from zdrone.vehicle.modes import set_mode_params
from zdrone.vehicle.personality import ARDUPILOT, PX4, Personality
from zdrone.vehicle.sim import SimAutopilot
from zdrone.vehicle.tracker import DEFAULT_STREAMS, VIEW_STREAMS, StreamWant, Timing, VehicleTracker

COMPANION = (1, mav.MAV_COMP_ID_ONBOARD_COMPUTER)
PX4_NEEDED = ("GLOBAL_POSITION_INT", "EXTENDED_SYS_STATE", "SYS_STATUS", "MISSION_CURRENT", "HOME_POSITION",
              "GPS_RAW_INT")
NEEDED = PX4_NEEDED + ("EKF_STATUS_REPORT",)  # ArduPilot's: its EKF says whether the position is absolute


class Bench:
    """A simulator and a tracker wired together through MAVLink frames, on one simulated clock."""

    def __init__(self, personality: Personality, streams: tuple[StreamWant, ...] = DEFAULT_STREAMS,
                 timing: Timing = Timing(), ready_after: float = 0.0, deaf: bool = False) -> None:
        self.sim = SimAutopilot(HOME, sysid=1, personality=personality, ready_after=ready_after)
        self.tracker = VehicleTracker(*COMPANION, streams=streams, timing=timing)
        self.companion = FrameCodec(*COMPANION)
        self.decoder = FrameCodec(*COMPANION)
        self.now = 0.0
        self.received: Counter[int] = Counter()  # message ids from the vehicle
        self.sent: list[Any] = []  # what the tracker sent the vehicle
        self.deaf = deaf  # the vehicle ignores everything the tracker sends
        self.attached = True

    def run(self, seconds: float, dt: float = 0.05) -> None:
        end = self.now + seconds
        while self.now < end - 1e-9:
            self.now = round(self.now + dt, 6)
            self.sim.step(self.now)
            for f in self.sim.drain():
                self.received[read_header(f).msgid] += 1
                msg = self.decoder.decode(f)
                if msg is not None and self.attached:
                    self.tracker.on_message(msg, self.now)
            if self.attached:
                for m in self.tracker.poll(self.now):
                    self.sent.append(m)
                    if not self.deaf:
                        self.sim.receive(self.companion.encode(m), self.now)

    def command(self, cmd: int, *params: float) -> None:
        m = self.tracker.command(cmd, params, self.now)
        self.sent.append(m)
        if not self.deaf:
            self.sim.receive(self.companion.encode(m), self.now)

    def gcs_command(self, cmd: int, *params: float) -> None:
        """A command from a ground station relayed to the vehicle (sysid 4): not the tracker's."""
        p = list(params) + [0.0] * (7 - len(params))
        self.sim.receive(FrameCodec(4, 190).encode(mav.MAVLink_command_long_message(1, 1, cmd, 0, *p)), self.now)

    def sent_of(self, name: str, command: int | None = None) -> list[Any]:
        return [m for m in self.sent if m.get_type() == name and (command is None or m.command == command)]

    def stream(self, name: str) -> dict[str, Any]:
        return self.tracker.stats()["streams"][name]


def _ids(*names: str) -> set[int]:
    return {193 if n == "EKF_STATUS_REPORT" else getattr(mav, f"MAVLINK_MSG_ID_{n}") for n in names}


# ---------------------------------------------------------------------------- ArduPilot
def test_ardupilot_streams_nothing_until_the_tracker_asks_then_everything_needed_arrives():
    b = Bench(ARDUPILOT)
    b.attached = False
    b.run(5.0)
    assert not set(b.received) & _ids(*NEEDED)  # HEARTBEAT (and texts) only
    assert b.received[mav.MAVLINK_MSG_ID_HEARTBEAT] >= 4
    b.attached = True
    b.received.clear()
    b.run(8.0)  # HOME_POSITION (every 2 s) is asked for after 5 s, the others after 1 s
    t = b.tracker
    assert t.autopilot == "ardupilot" and t.sysid == 1 and t.compid == 1
    for name in NEEDED:
        assert b.stream(name)["state"] == "seen" and b.stream(name)["via"] == "interval", name
    assert _ids(*NEEDED) <= set(b.received)
    assert b.received[mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT] >= 10  # at 4 Hz
    assert t.position is not None and abs(t.position.lat - HOME.lat) < 1e-5
    assert t.mode == "STABILIZE" and t.landed_state(b.now) == mav.MAV_LANDED_STATE_ON_GROUND
    asks = b.sent_of("COMMAND_LONG", mav.MAV_CMD_SET_MESSAGE_INTERVAL)
    assert sorted(int(m.param1) for m in asks) == sorted(_ids(*NEEDED))  # each asked once, nothing else
    assert [m.param2 for m in asks if int(m.param1) == mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT] == [250_000]
    assert not b.sent_of("REQUEST_DATA_STREAM") and not t.counters
    b.sent.clear()
    b.run(10.0)
    assert not b.sent  # nothing more to ask


def test_one_message_unasked_is_not_a_stream():
    b = Bench(ARDUPILOT)
    b.run(0.5)
    b.sim._send_mission_current()  # e.g. after a mission upload: one MISSION_CURRENT, no stream
    b.run(6.0)
    mc = b.stream("MISSION_CURRENT")
    assert mc["state"] == "seen" and mc["via"] == "interval" and mc["interval_asks"] == 1
    assert b.received[mav.MAVLINK_MSG_ID_MISSION_CURRENT] >= 4


def test_ardupilot_refusing_an_interval_falls_back_to_its_stream_group():
    # an ArduPilot that cannot stream GLOBAL_POSITION_INT by interval ("No ap_message for mavlink id (33)")
    refusing = replace(ARDUPILOT, sendable=ARDUPILOT.sendable - {mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT})
    b = Bench(refusing)
    b.run(8.0)
    gpi = b.stream("GLOBAL_POSITION_INT")
    assert gpi["state"] == "seen" and gpi["via"] == "data_stream" and gpi["interval_asks"] == 1
    assert gpi["refusal"] == "FAILED: No ap_message for mavlink id (33)"
    [req] = b.sent_of("REQUEST_DATA_STREAM")
    assert (req.req_stream_id, req.req_message_rate, req.start_stop) == (mav.MAV_DATA_STREAM_POSITION, 4, 1)
    assert b.tracker.counters["interval_refused"] == 1 and b.tracker.position is not None
    assert all(b.stream(n)["state"] == "seen" for n in NEEDED)


def test_ardupilot_mode_names_commands_and_landed_state_from_heartbeat():
    b = Bench(ARDUPILOT, streams=())  # nothing asked: no EXTENDED_SYS_STATE
    b.run(2.0)
    t = b.tracker
    assert t.mode == "STABILIZE" and t.landed_state(b.now) == mav.MAV_LANDED_STATE_ON_GROUND  # STANDBY
    assert mav.MAVLINK_MSG_ID_EXTENDED_SYS_STATE not in b.received
    b.command(mav.MAV_CMD_DO_SET_MODE, *set_mode_params("ardupilot", "GUIDED"))
    b.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    b.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, float("nan"), float("nan"), float("nan"), 20)
    b.run(3.0)
    assert t.mode == "GUIDED" and t.armed
    assert t.landed_state(b.now) == mav.MAV_LANDED_STATE_IN_AIR  # ACTIVE while flying
    b.command(mav.MAV_CMD_DO_SET_MODE, *set_mode_params("ardupilot", "LAND"))
    b.run(1.0)
    assert t.mode == "LAND" and t.custom_mode == 9
    b.run(40.0)
    assert not t.armed and t.landed_state(b.now) == mav.MAV_LANDED_STATE_ON_GROUND
    assert not t.counters  # every command acknowledged at once


# ---------------------------------------------------------------------------- PX4
def test_px4_streams_what_is_needed_unasked_and_the_tracker_leaves_its_rates_alone():
    b = Bench(PX4)
    b.run(6.0)
    t = b.tracker
    assert t.autopilot == "px4" and t.mode == "HOLD"
    assert "EKF_STATUS_REPORT" not in t.stats()["streams"]  # asked of ArduPilot only
    for name in PX4_NEEDED:
        assert b.stream(name) == {"state": "seen", "via": "unasked", "interval_asks": 0, "stream_asks": 0,
                                  "lapses": 0, "refusal": None}, name
    assert not b.sent and t.landed_state(b.now) == mav.MAV_LANDED_STATE_ON_GROUND
    b.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    b.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, float("nan"), float("nan"), float("nan"), float("nan"))
    b.run(2.0)
    assert t.armed and t.mode == "TAKEOFF" and t.landed_state(b.now) == mav.MAV_LANDED_STATE_TAKEOFF
    b.run(10.0)
    assert t.mode == "HOLD" and t.landed_state(b.now) == mav.MAV_LANDED_STATE_IN_AIR
    b.command(mav.MAV_CMD_NAV_RETURN_TO_LAUNCH)
    b.run(1.5)  # the next HEARTBEAT
    assert t.mode == "RTL" and not t.counters


def test_px4_refusing_a_stream_is_bounded_logged_and_counted():
    vfr_hud = next(w for w in VIEW_STREAMS if w.name == "VFR_HUD")  # not a stream this PX4 offers
    b = Bench(PX4, streams=DEFAULT_STREAMS + (vfr_hud,))
    b.run(30.0)
    st = b.stream("VFR_HUD")
    assert st["state"] == "failed" and st["refusal"] == "UNSUPPORTED" and st["interval_asks"] == 1
    assert st["stream_asks"] == 3  # PX4 ignores REQUEST_DATA_STREAM: asked 3 times, then given up
    assert len(b.sent_of("COMMAND_LONG")) == 1 and len(b.sent_of("REQUEST_DATA_STREAM")) == 3
    assert b.tracker.counters["stream_failed"] == 1 and b.tracker.counters["interval_refused"] == 1
    b.sent.clear()
    b.run(20.0)
    assert not b.sent


# ---------------------------------------------------------------------------- bounded retries
def test_a_vehicle_that_answers_nothing_is_asked_a_bounded_number_of_times():
    b = Bench(ARDUPILOT, deaf=True)
    b.run(60.0)
    t = b.tracker
    assert all(b.stream(n)["state"] == "failed" for n in NEEDED)
    intervals = b.sent_of("COMMAND_LONG", mav.MAV_CMD_SET_MESSAGE_INTERVAL)
    assert len(intervals) == 3 * len(NEEDED)
    # the groups: POSITION 3 times; EXTENDED_STATUS for SYS_STATUS, MISSION_CURRENT and GPS_RAW_INT: 3 + 2 + 2
    # (the first asks of the latter two ride on SYS_STATUS's); EXTRA3 (EKF_STATUS_REPORT) 3 times;
    # EXTENDED_SYS_STATE and HOME_POSITION have none
    assert len(b.sent_of("REQUEST_DATA_STREAM")) == 13
    assert t.counters["interval_no_ack"] == 3 * len(NEEDED) and t.counters["stream_failed"] == len(NEEDED)
    b.sent.clear()
    b.run(30.0)
    assert not b.sent
    # with no EXTENDED_SYS_STATE, the landed state comes from HEARTBEAT
    assert t.landed_state(b.now) == mav.MAV_LANDED_STATE_ON_GROUND


def test_commands_are_resent_until_acknowledged_and_then_given_up():
    b = Bench(PX4, deaf=True)
    b.run(1.0)
    b.command(mav.MAV_CMD_NAV_LAND)
    b.run(10.0)
    lands = b.sent_of("COMMAND_LONG", mav.MAV_CMD_NAV_LAND)
    assert [m.confirmation for m in lands] == [0, 1, 2]
    assert b.tracker.counters[f"command_{mav.MAV_CMD_NAV_LAND}_unacknowledged"] == 1
    ok = Bench(PX4)
    ok.run(1.0)
    ok.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    ok.run(5.0)
    assert len(ok.sent_of("COMMAND_LONG", mav.MAV_CMD_COMPONENT_ARM_DISARM)) == 1 and not ok.tracker.counters


def test_acks_to_ground_stations_are_not_taken_for_the_trackers_own():
    b = Bench(ARDUPILOT)
    b.run(1.05)  # the first SET_MESSAGE_INTERVAL is in flight
    b.gcs_command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, 9999, 1e6)  # refused, to sysid 4
    b.run(6.0)
    assert all(b.stream(n)["refusal"] is None for n in NEEDED)
    assert all(b.stream(n)["state"] == "seen" for n in NEEDED)


# ---------------------------------------------------------------------------- reboots
def _reboot(b: Bench, personality: Personality) -> None:
    sim = SimAutopilot(HOME, sysid=1, personality=personality, now=b.now)
    b.sim = sim


def test_after_a_reboot_with_a_heartbeat_gap_the_streams_are_asked_for_again():
    b = Bench(ARDUPILOT)
    b.run(6.0)
    assert all(b.stream(n)["state"] == "seen" for n in NEEDED)
    b.attached = False
    _reboot(b, ARDUPILOT)  # ArduPilot forgets every stream request when it reboots
    b.run(5.0)  # rebooting: the tracker hears nothing
    b.attached = True
    b.sent.clear()
    b.run(8.0)
    t = b.tracker
    assert t.connections == 2 and t.counters["reconnects"] == 1
    assert all(b.stream(n)["state"] == "seen" and b.stream(n)["via"] == "interval" for n in NEEDED)
    assert len(b.sent_of("COMMAND_LONG", mav.MAV_CMD_SET_MESSAGE_INTERVAL)) == len(NEEDED)


def test_boot_time_going_back_is_a_reboot_too():
    b = Bench(PX4)
    b.run(10.0)
    _reboot(b, PX4)  # no gap at all; its GLOBAL_POSITION_INT restarts from time_boot_ms 0
    b.run(1.0)
    assert b.tracker.connections == 2 and b.tracker.counters["reconnects"] == 1


def test_a_stream_that_stops_while_heartbeats_go_on_is_asked_for_again():
    b = Bench(ARDUPILOT)
    b.run(6.0)
    _reboot(b, ARDUPILOT)  # a quick reboot: no heartbeat gap and no boot time to see (nothing streams)
    b.sent.clear()
    b.run(26.0)  # HOME_POSITION (every 2 s) counts as stopped after 20 s, the others after 5 s
    t = b.tracker
    assert t.connections == 1 and t.counters["stream_lapsed"] == len(NEEDED)
    assert all(b.stream(n)["state"] == "seen" and b.stream(n)["lapses"] == 1 for n in NEEDED)


# ---------------------------------------------------------------------------- position only after a fix
def _feed(t: VehicleTracker, *msgs: Any, now: float = 1.0) -> None:
    codec = FrameCodec(1, 1)
    for m in msgs:
        t.on_message(codec.decode(codec.encode(m)), now)


def _gpi(lat: float, lon: float) -> Any:
    return mav.MAVLink_global_position_int_message(1000, int(lat * 1e7), int(lon * 1e7), 488_000, 0, 0, 0, 0, 0)


def _gps(fix: int) -> Any:
    return mav.MAVLink_gps_raw_int_message(0, fix, 0, 0, 0, 65535, 65535, 0, 65535, 0)


def test_no_position_while_the_autopilot_has_no_fix_and_the_status_says_why():
    """Issue 22: ArduCopter sends lat = lon = 0 before its GPS fix, and its EKF uses GPS only later;
    the tracker used to take (0, 0) for the vehicle's position."""
    from pymavlink.dialects.v20 import ardupilotmega as apm

    t = VehicleTracker(*COMPANION)
    _feed(t, mav.MAVLink_heartbeat_message(mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 3, 3))
    assert t.position is None and t.stats()["position"]["why"] == "no position report"
    _feed(t, _gpi(0.0, 0.0))
    assert t.position is None and t.stats()["position"] == {"known": False, "why": "position 0, 0 (no fix)",
                                                            "fix_type": None, "ekf_flags": None}
    _feed(t, _gps(1), _gpi(HOME.lat, HOME.lon))  # a position, but GPS_RAW_INT says no fix
    assert t.position is None and t.stats()["position"]["why"] == "no GPS fix (fix type 1)"
    attitude_only = apm.EKF_ATTITUDE | apm.EKF_VELOCITY_HORIZ | apm.EKF_POS_HORIZ_REL | apm.EKF_CONST_POS_MODE
    _feed(t, _gps(6), apm.MAVLink_ekf_status_report_message(attitude_only, 0, 0, 0, 0, 0, 0))
    assert t.position is None and t.stats()["position"]["why"] == "estimate not absolute (EKF not using GPS)"
    _feed(t, apm.MAVLink_ekf_status_report_message(attitude_only | apm.EKF_POS_HORIZ_ABS, 0, 0, 0, 0, 0, 0))
    assert t.position is not None and abs(t.position.lat - HOME.lat) < 1e-6 and t.stats()["position"]["known"]
    _feed(t, _gpi(0.0, 0.0))  # zeros again (a GPS glitch): unknown again, never (0, 0)
    assert t.position is None


def test_px4_position_is_known_from_its_global_position_alone():
    t = VehicleTracker(*COMPANION)
    _feed(t, mav.MAVLink_heartbeat_message(mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_PX4, 0, 0, 3, 3))
    _feed(t, _gps(3), _gpi(HOME.lat, HOME.lon))  # no EKF_STATUS_REPORT from PX4: not held against it
    assert t.position is not None and t.stats()["position"]["why"] is None


def test_against_the_ardupilot_personality_the_position_comes_only_once_its_ekf_uses_gps():
    b = Bench(ARDUPILOT, ready_after=12.0)  # fix at 3 s, EKF origin at 5.7 s, EKF using GPS at 12 s
    b.run(2.8)
    t = b.tracker
    assert t.position is None and t.stats()["position"]["why"] in ("position 0, 0 (no fix)", "no GPS fix (fix type 1)")
    b.run(5.0)
    assert t.position is None and t.stats()["position"]["why"] == "estimate not absolute (EKF not using GPS)"
    b.run(5.0)
    assert t.position is not None and distance_m(HOME, t.position) < 1.0 and t.stats()["position"]["known"]


def test_only_the_autopilot_component_says_where_the_vehicle_is_or_whether_it_is_on_the_ground():
    """A local process that takes the drone's system id with another component id (a camera, a
    script beside the companion) is not the autopilot: its EXTENDED_SYS_STATE "on the ground" (what
    confirms a failsafe) and its texts are not the vehicle's."""
    b = Bench(PX4)
    b.run(3.0)
    assert b.tracker.landed_state(b.now) == mav.MAV_LANDED_STATE_ON_GROUND
    other = FrameCodec(1, mav.MAV_COMP_ID_CAMERA)
    for m in (mav.MAVLink_extended_sys_state_message(0, mav.MAV_LANDED_STATE_IN_AIR),
              mav.MAVLink_statustext_message(mav.MAV_SEVERITY_CRITICAL, b"not the autopilot")):
        b.tracker.on_message(b.decoder.decode(other.encode(m)), b.now)
    assert b.tracker.landed_state(b.now) == mav.MAV_LANDED_STATE_ON_GROUND
    assert all("not the autopilot" not in t for _, t in b.tracker.vehicle.texts)
