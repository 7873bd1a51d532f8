"""MAVLink operator control bound to fleet keys, end to end: ``zdrone demo --scenario operator-consent``
(real router, simulator, drone and both GSs as processes; two pymavlink applications, one on each GS's
GCS gateway, as the operators)."""

from __future__ import annotations

import pytest
from pymavlink.dialects.v20 import common as mav

from tests.integration.test_flight_e2e import run_demo
from zdrone.net.eventlog import read_events


@pytest.mark.slow
def test_operator_consent_no_consent_moves_nothing_consent_and_takeover_move_control(tmp_path):
    s, out = run_demo(tmp_path, "operator-consent")
    assert s["_rc"] == 0 and s["ok"], s["why_not_ok"]
    op = s["operator"]
    assert op["operator_done"]["ok"] is True
    assert op["no_consent"]["answer"] == mav.MAV_RESULT_FAILED and op["no_consent"]["shown_p4"] == 3  # B's sysid
    assert op["consent"]["within_window"] and op["consent"]["to_control_s"] < 10.0
    # "allow takeover" answers the request the owner's operator read, both ways (no standing setting)
    assert op["takeover"]["b_first_answer"] == mav.MAV_RESULT_FAILED and op["takeover"]["b_to_control_s"] < 3.0
    assert op["takeover"]["allow_answers"] == [mav.MAV_RESULT_ACCEPTED] * 2
    moves = [(h["from"], h["to"], h["kind"]) for h in s["handovers"]]
    assert moves[:4] == [("A", "B", "handover"), ("B", "A", "handover"), ("A", "B", "handover"), ("B", "A", "handover")]
    assert s["failsafe"] is None and s["distance_from_home_m"] < 5.0
    # every step went through sealed messages between fleet identities: the drone passed B's requests on
    drone = read_events(out / "drone.jsonl")
    asked = [e for e in drone if e["type"] == "handover_requested"]
    assert any("B asks for B" in e["detail"] for e in asked) and any("A asks for A" in e["detail"] for e in asked)
    a = read_events(out / "A.jsonl")
    assert [e["requester"] for e in a if e["type"] == "operator_request_shown"][:2] == ["B", "B"]
    assert any(e["type"] == "operator_request_expired" for e in a)  # the first, never consented to


@pytest.mark.slow
# on ArduPilot: the same rules on PX4 are flown by the operator-consent test above and the in-memory
# tests of gs/opcontrol.py (the suite's 10 minutes)
@pytest.mark.parametrize("autopilot", ["ardupilot"])
def test_consent_bound_goes_to_the_named_requester_in_its_epoch_and_a_decline_holds(tmp_path, autopilot):
    """``consent-bound``: three authorized GSs, an application on each gateway (``zdrone.sil.consent_ops``)."""
    s, out = run_demo(tmp_path, "consent-bound", autopilot=autopilot)
    assert s["_rc"] == 0 and s["ok"], s["why_not_ok"]
    op = s["operator"]
    step = op["consent_to_b_while_x_asks"]
    assert step["wrong_named_answer"] == mav.MAV_RESULT_DENIED and step["consent_answer"] == mav.MAV_RESULT_ACCEPTED
    # the race: A's operator answers as B's request ends and X's appears: refused, X never gets the drone
    assert op["consent_race"]["answer"] == mav.MAV_RESULT_DENIED
    assert op["window_across_epochs"]["late_allow_answer"] == mav.MAV_RESULT_DENIED
    assert op["window_across_epochs"]["later_epoch_answer"] == mav.MAV_RESULT_FAILED
    assert all("X" not in (h["from"], h["to"]) for h in s["handovers"])
    a = read_events(out / "A.jsonl")
    assert [e["requester"] for e in a if e["type"] == "operator_request_shown"][0] == "B"
    assert any(e["type"] == "operator_request_busy" and e["requester"] == "X" and e["pending"] == "B" for e in a)
    refused = [e for e in a if e["type"] == "operator_consent_refused"]
    assert refused and refused[0]["named"] == "X" and refused[0]["requester"] == "B"
    assert any(e["requester"] == "X" and e["named"] is None and "shown" in e["reason"] for e in refused)
    b = read_events(out / "B.jsonl")
    assert any(e["type"] == "operator_request_declined" and e["requester"] == "X" for e in b)
    assert any(e["type"] == "operator_request_held_off" and e["requester"] == "X" for e in b)
