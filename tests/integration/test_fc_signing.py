"""``fc-rogue-radio`` end to end: a radio on the autopilot's TELEM2 sends arm, a mode change and a
mission clear in flight. One flight per personality: PX4 with the link signed (nothing obeyed, the
flight completes) and ArduPilot with ``--fc-signing off`` (the control: the autopilot obeys, the
flight does not complete). The other two cases are the in-process tests of the simulator and the
link (``tests/unit/test_fc_signing.py``)."""

from __future__ import annotations

import pytest

from tests.integration.test_flight_e2e import _clean_shutdown, run_demo
from zdrone.net.eventlog import read_events


@pytest.mark.slow
def test_fc_rogue_radio_px4_signed_nothing_obeyed_and_the_flight_completes(tmp_path):
    s, out = run_demo(tmp_path, "fc-rogue-radio")
    assert s["_rc"] == 0 and s["ok"], s["why_not_ok"]
    assert s["fc_signing"]["mode"] == "prefer" and s["fc_signing"]["state"] == "signed"
    done = s["attacks"]["fc-radio"]
    assert min(done["sent"].values()) >= 1 and done["answered"] == 0 and done["obeyed"] == 0
    assert s["vehicle"]["counters"]["signing_refused"] >= sum(done["sent"].values())
    assert s["flight_problems"] == [] and s["delivered_at_b"]
    # every GS heard from the drone that its autopilot link is signed
    for gs in ("A", "B"):
        heard = [e for e in read_events(out / f"{gs}.jsonl") if e["type"] == "fc_signing"]
        assert heard and heard[-1]["signed"] is True, gs
    _clean_shutdown(s, out)


@pytest.mark.slow
def test_fc_rogue_radio_ardupilot_unsigned_control_shows_the_takeover(tmp_path):
    s, out = run_demo(tmp_path, "fc-rogue-radio", autopilot="ardupilot", extra=("--fc-signing", "off"))
    assert s["_rc"] == 0 and s["ok"], s["why_not_ok"]
    assert s["fc_signing"]["state"] == "off"
    done = s["attacks"]["fc-radio"]
    assert done["answers"].get("mode_land:accepted", 0) >= 1 and done["autopilot"] == 3
    assert "no delivery at B" in s["flight_problems"]
    _clean_shutdown(s, out)
