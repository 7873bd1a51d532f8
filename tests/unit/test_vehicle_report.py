"""VehicleReport: each message kind the vehicle reports -> the state it holds and the change it says."""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as apm
from pymavlink.dialects.v20 import common as mav

from zdrone.vehicle.fix import MSG_EKF_STATUS_REPORT
from zdrone.vehicle.report import (READ_MSGIDS, TEXTS_KEPT, AutopilotHeard, PositionReported, TextHeard,
                                   VehicleReport)

_MAV = mav.MAVLink(None, srcSystem=1, srcComponent=1)


def _wire(msg):
    """As the vehicle sends it: encoded and decoded again."""
    return _MAV.decode(bytearray(msg.pack(_MAV)))


def _heartbeat(armed: bool, custom_mode: int = 4, autopilot: int = mav.MAV_AUTOPILOT_ARDUPILOTMEGA,
               status: int = mav.MAV_STATE_STANDBY):
    base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mav.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
    return _wire(mav.MAVLink_heartbeat_message(mav.MAV_TYPE_QUADROTOR, autopilot, base, custom_mode, status, 3))


def _position(lat: float, lon: float, alt_m: float):
    return _wire(mav.MAVLink_global_position_int_message(0, int(lat * 1e7), int(lon * 1e7), 0, int(alt_m * 1000),
                                                         0, 0, 0, 0))


def _text(text: str, severity: int = mav.MAV_SEVERITY_WARNING):
    return _wire(mav.MAVLink_statustext_message(severity, text.encode()))


def _sys_status(present: int, health: int):
    return _wire(mav.MAVLink_sys_status_message(present, present, health, 0, 12000, -1, -1, 0, 0, 0, 0, 0, 0))


def test_nothing_is_known_before_the_vehicle_speaks():
    r = VehicleReport()
    assert r.autopilot is None and r.mav_autopilot is None and r.heartbeat_at is None
    assert not r.armed and r.position is None and r.prearm_ok is None and r.texts == []
    assert r.landed_state == mav.MAV_LANDED_STATE_UNDEFINED and r.landed_at is None


def test_the_first_heartbeat_names_the_autopilot_once():
    r = VehicleReport()
    assert r.on_message(_heartbeat(armed=False), 1.0) == (AutopilotHeard("ardupilot", mav.MAV_TYPE_QUADROTOR),)
    assert (r.autopilot, r.mav_autopilot, r.mav_type) == ("ardupilot", mav.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                                          mav.MAV_TYPE_QUADROTOR)
    assert (r.custom_mode, r.system_status, r.heartbeat_at) == (4, mav.MAV_STATE_STANDBY, 1.0)
    assert r.on_message(_heartbeat(armed=False), 2.0) == () and r.heartbeat_at == 2.0
    assert r.on_message(_heartbeat(False, autopilot=mav.MAV_AUTOPILOT_PX4), 3.0) == ()
    assert r.autopilot == "ardupilot" and r.mav_autopilot == mav.MAV_AUTOPILOT_PX4  # named once; the field as sent


def test_an_autopilot_without_a_name_is_other():
    r = VehicleReport()
    assert r.on_message(_heartbeat(False, autopilot=mav.MAV_AUTOPILOT_GENERIC), 1.0) == (
        AutopilotHeard("other", mav.MAV_TYPE_QUADROTOR),)
    assert r.autopilot == "other" and r.mav_autopilot == mav.MAV_AUTOPILOT_GENERIC


def test_armed_then_disarmed_is_stamped_with_when():
    r = VehicleReport()
    r.on_message(_heartbeat(armed=True, custom_mode=3, status=mav.MAV_STATE_ACTIVE), 1.0)
    assert r.armed and r.custom_mode == 3 and r.disarmed_at is None
    r.on_message(_heartbeat(armed=False, custom_mode=9), 7.5)
    assert not r.armed and r.custom_mode == 9 and r.disarmed_at == 7.5
    r.on_message(_heartbeat(armed=False), 8.0)
    assert r.disarmed_at == 7.5  # staying disarmed is no new disarm


def test_a_position_report_is_a_change_and_a_position_only_with_a_fix():
    r = VehicleReport()
    assert r.on_message(_position(47.1, 8.2, 30.0), 3.0) == (PositionReported(3.0),)
    assert r.position_at == 3.0 and r.position is not None
    assert abs(r.position.lat - 47.1) < 1e-6 and abs(r.position.alt - 30.0) < 1e-3
    assert r.on_message(_wire(mav.MAVLink_gps_raw_int_message(0, 1, 0, 0, 0, 0, 0, 0, 0, 0)), 3.5) == ()
    assert r.position is None and r.fix.unknown_because == "no GPS fix (fix type 1)"  # GPS_RAW_INT: no fix
    assert r.position_at == 3.0  # only GLOBAL_POSITION_INT is a position report
    assert r.on_message(_position(0.0, 0.0, 0.0), 4.0) == (PositionReported(4.0),) and r.position is None


def test_the_ekf_report_is_read_into_the_fix():
    r = VehicleReport()
    r.on_message(_position(47.1, 8.2, 30.0), 1.0)
    ekf = apm.MAVLink_ekf_status_report_message(apm.EKF_ATTITUDE, 0, 0, 0, 0, 0)  # not using GPS
    assert r.on_message(ekf, 2.0) == () and r.fix.ekf_flags == apm.EKF_ATTITUDE
    assert r.position is None and r.fix.unknown_because == "estimate not absolute (EKF not using GPS)"


def test_prearm_health_only_when_the_autopilot_reports_the_check():
    r = VehicleReport()
    assert r.on_message(_sys_status(0, 0), 1.0) == () and r.prearm_ok is None
    check = mav.MAV_SYS_STATUS_PREARM_CHECK
    r.on_message(_sys_status(check, 0), 2.0)
    assert r.prearm_ok is False
    r.on_message(_sys_status(check, check), 3.0)
    assert r.prearm_ok is True


def test_landed_state_and_when():
    r = VehicleReport()
    assert r.on_message(_wire(mav.MAVLink_extended_sys_state_message(0, mav.MAV_LANDED_STATE_IN_AIR)), 5.0) == ()
    assert (r.landed_state, r.landed_at) == (mav.MAV_LANDED_STATE_IN_AIR, 5.0)


def test_texts_are_cleaned_kept_bounded_and_said():
    r = VehicleReport()
    assert r.on_message(_text("PreArm: GPS not healthy\t", mav.MAV_SEVERITY_CRITICAL), 1.0) == (
        TextHeard("PreArm: GPS not healthy", mav.MAV_SEVERITY_CRITICAL),)  # PX4's trailing tab cut
    for i in range(TEXTS_KEPT + 3):
        r.on_message(_text(f"t{i}"), 2.0 + i)
    assert len(r.texts) == TEXTS_KEPT and r.texts[-1] == (2.0 + TEXTS_KEPT + 2, f"t{TEXTS_KEPT + 2}")


def test_restart_forgets_position_and_landed_state_not_the_heartbeat():
    r = VehicleReport()
    r.on_message(_heartbeat(armed=True), 1.0)
    r.on_message(_position(47.1, 8.2, 30.0), 1.0)
    r.on_message(_wire(mav.MAVLink_extended_sys_state_message(0, mav.MAV_LANDED_STATE_IN_AIR)), 1.0)
    r.restart()
    assert r.position is None and r.position_at is None and r.fix.reported is None
    assert (r.landed_state, r.landed_at) == (mav.MAV_LANDED_STATE_UNDEFINED, None)
    assert r.armed and r.autopilot == "ardupilot" and r.heartbeat_at == 1.0


def test_other_messages_change_nothing():
    r = VehicleReport()
    assert r.on_message(_wire(mav.MAVLink_mission_current_message(3)), 1.0) == ()
    assert r.heartbeat_at is None and r.position_at is None and r.landed_at is None and r.texts == []


def test_the_read_msgids_are_the_kinds_read():
    assert READ_MSGIDS == {mav.MAVLINK_MSG_ID_HEARTBEAT, mav.MAVLINK_MSG_ID_SYS_STATUS,
                           mav.MAVLINK_MSG_ID_EXTENDED_SYS_STATE, mav.MAVLINK_MSG_ID_STATUSTEXT,
                           mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, mav.MAVLINK_MSG_ID_GPS_RAW_INT,
                           MSG_EKF_STATUS_REPORT}
