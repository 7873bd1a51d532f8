"""The demo's verdict from what both autopilots send (issue 22): the delivery at B from the mission's
progress, and an autopilot already running flown in real time."""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mav

from gs.planner import reference_mission
from zdrone.core.geometry import offset
from zdrone.core.records import MissionProgress, VehicleText
from zdrone.core.reference import DELIVERY, HOME
from zdrone.sil.launcher import delivered_at

ON_GROUND, IN_AIR = mav.MAV_LANDED_STATE_ON_GROUND, mav.MAV_LANDED_STATE_IN_AIR


def _gripper(autopilot: str) -> int:
    return next(i for i, it in enumerate(reference_mission(autopilot=autopilot)) if it.command == mav.MAV_CMD_DO_GRIPPER)


def _at(p, alt: float = 0.0):
    return (p.lat, p.lon, alt)


def test_the_delivery_is_the_mission_past_its_gripper_item_on_the_ground_at_b():
    for autopilot in ("px4", "ardupilot"):
        g = _gripper(autopilot)
        past = MissionProgress(drone="d1", seq=g + 1, reached=False, landed_state=ON_GROUND, position=_at(DELIVERY))
        assert delivered_at([past], autopilot)
        reached = MissionProgress(drone="d1", seq=g, reached=True, landed_state=ON_GROUND,
                                  position=_at(offset(DELIVERY, 3.0, 0.0)))
        assert delivered_at([reached], autopilot)  # a few metres off: still at B
        not_yet = MissionProgress(drone="d1", seq=g, reached=False, landed_state=ON_GROUND, position=_at(DELIVERY))
        flying = MissionProgress(drone="d1", seq=g + 1, reached=False, landed_state=IN_AIR, position=_at(DELIVERY, 12.0))
        elsewhere = MissionProgress(drone="d1", seq=g + 1, reached=False, landed_state=ON_GROUND, position=_at(HOME))
        unknown = MissionProgress(drone="d1", seq=g + 1, reached=False, landed_state=ON_GROUND, position=None)
        assert not delivered_at([not_yet, flying, elsewhere, unknown], autopilot)
    # a text alone is no delivery (PX4 says nothing, ArduCopter "Gripper Released")
    assert not delivered_at([VehicleText(drone="d1", text="payload released", severity=6)], "px4")


def test_demo_with_an_autopilot_already_running_flies_in_real_time(monkeypatch):
    import zdrone.sil.launcher as launcher
    from zdrone.cli import build_parser

    seen = []
    monkeypatch.setattr(launcher, "run_demo", lambda opts: seen.append(opts) or 0)
    for argv, speedup in ((["demo", "--vehicle", "tcp:127.0.0.1:5760"], 1.0), (["demo"], 2.0),
                          (["demo", "--vehicle", "udpin:127.0.0.1:14540", "--speedup", "3"], 3.0)):
        args = build_parser().parse_args(argv)
        assert args.func(args) == 0
        assert seen[-1].speedup == speedup, argv


def test_demo_passes_the_simulators_start_up_and_refuses_it_with_an_external_autopilot(monkeypatch):
    import pytest

    import zdrone.sil.launcher as launcher
    from zdrone.cli import build_parser
    from zdrone.core.errors import UsageError

    seen = []
    monkeypatch.setattr(launcher, "run_demo", lambda opts: seen.append(opts) or 0)
    args = build_parser().parse_args(["demo", "--autopilot", "ardupilot", "--ready-after", "40"])
    assert args.func(args) == 0 and seen[-1].ready_after == 40.0
    for argv in (["demo", "--vehicle", "tcp:127.0.0.1:5760", "--ready-after", "40"], ["demo", "--ready-after", "-1"]):
        args = build_parser().parse_args(argv)
        with pytest.raises(UsageError):
            args.func(args)
