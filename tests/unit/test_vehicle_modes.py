"""Mode names and landed state per autopilot (``zdrone.vehicle.modes``), shared by the drone node and the GS."""

from __future__ import annotations

import pytest
from pymavlink.dialects.v20 import common as mav

from zdrone.vehicle.modes import (ARDUCOPTER_MODE_NAMES, MODE_ROLES, autopilot_name, custom_mode, landed_from_heartbeat,
                                  mode_name, set_mode_params)
from zdrone.vehicle.personality import ARDUCOPTER_MODES, PX4_MODES
from zdrone.vehicle.px4modes import FlightMode


def test_autopilot_names():
    assert autopilot_name(mav.MAV_AUTOPILOT_PX4) == "px4"
    assert autopilot_name(mav.MAV_AUTOPILOT_ARDUPILOTMEGA) == "ardupilot"
    assert autopilot_name(mav.MAV_AUTOPILOT_GENERIC) is None and autopilot_name(None) is None


def test_px4_modes_decode_as_today():
    for mode in FlightMode:
        assert mode_name("px4", mode.custom_mode) == mode.name == mode_name(mav.MAV_AUTOPILOT_PX4, mode.custom_mode)
    assert mode_name("px4", 1 << 16) == "POSCTL"  # manual main modes fly as position control here
    assert mode_name("px4", 6 << 16) == "custom:0x60000"  # offboard: not one of ours
    assert {r.name for r in PX4_MODES.rows} == {m.name for m in FlightMode}


def test_arducopter_modes_by_their_own_numbers_and_names():
    assert [mode_name("ardupilot", n) for n in (0, 3, 4, 5, 6, 9, 16)] == \
        ["STABILIZE", "AUTO", "GUIDED", "LOITER", "RTL", "LAND", "POSHOLD"]
    for row in ARDUCOPTER_MODES.rows:  # the simulator's rows agree with the real numbering
        assert ARDUCOPTER_MODE_NAMES[row.custom_mode] == row.name
    assert mode_name("ardupilot", 99) == "custom:99"
    # the same number means different modes on the two autopilots; unknown autopilots get the number
    assert mode_name("ardupilot", FlightMode.MISSION.custom_mode).startswith("custom:")
    assert mode_name(None, 3) == "custom:3" and mode_name(mav.MAV_AUTOPILOT_GENERIC, 3) == "custom:3"


@pytest.mark.parametrize("autopilot", ["px4", "ardupilot"])
def test_roles_name_real_modes_and_round_trip(autopilot: str):
    for role, name in MODE_ROLES[autopilot].items():
        number = custom_mode(autopilot, name)
        assert number is not None and mode_name(autopilot, number) == name, role
    assert custom_mode(autopilot, "NO_SUCH_MODE") is None and set_mode_params(autopilot, "NO_SUCH_MODE") is None


def test_set_mode_params_per_autopilot():
    flag = float(mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED)
    assert set_mode_params("ardupilot", "LAND") == (flag, 9.0, 0.0)
    assert set_mode_params("ardupilot", "RTL") == (flag, 6.0, 0.0)
    assert set_mode_params("px4", "LAND") == (flag, 4.0, 6.0)  # AUTO.LAND: main 4, sub 6
    assert PX4_MODES.from_command(4.0, 6.0).name == "LAND"
    assert ARDUCOPTER_MODES.from_command(9.0, 0.0).name == "LAND"
    assert set_mode_params(None, "LAND") is None


def test_landed_state_from_heartbeat():
    on, air, undef = mav.MAV_LANDED_STATE_ON_GROUND, mav.MAV_LANDED_STATE_IN_AIR, mav.MAV_LANDED_STATE_UNDEFINED
    assert landed_from_heartbeat("ardupilot", mav.MAV_STATE_STANDBY, armed=True) == on  # armed, not yet flying
    assert landed_from_heartbeat("ardupilot", mav.MAV_STATE_ACTIVE, armed=True) == air
    assert landed_from_heartbeat("ardupilot", mav.MAV_STATE_CRITICAL, armed=True) == undef  # a failsafe says nothing
    assert landed_from_heartbeat("px4", mav.MAV_STATE_ACTIVE, armed=True) == undef  # PX4 is ACTIVE when armed
    assert landed_from_heartbeat("px4", mav.MAV_STATE_STANDBY, armed=False) == on
    assert landed_from_heartbeat(None, mav.MAV_STATE_CRITICAL, armed=False) == on
