"""A scenario whose point is the failsafe passes only if the autopilot showed it (``failsafe_confirmed``):
a LAND commanded into a port someone else had bound (a hijack) was absorbed, the vehicle flew on, and
``link-loss`` still said OK."""

from __future__ import annotations

from zdrone.core.records import Failsafe, FailsafeConfirmed, FailsafeUnconfirmed
from zdrone.sil.fault_verdicts import check_failsafe_recover, check_link_loss, check_site_router_down_alone
from zdrone.sil.verdicts import Outcome

T0 = 1795338600.0
FS = Failsafe(t=T0 + 10, node="d1", action="LAND", reason="authority link to A lost", detect_to_command_ms=1.5,
              position=(47.4, 8.5, 30.0))


def _outcome(*records) -> Outcome:
    summary = {"failsafe": {"action": "LAND", "detect_to_command_ms": 1.5}, "notes": ["router restarted"],
               "handovers": [], "regained": [], "final_owner": None}
    return Outcome(summary, [FS, *records], {"A": [], "B": []}, {})


def test_link_loss_fails_unless_the_autopilot_showed_the_failsafe():
    absorbed = _outcome(FailsafeUnconfirmed(t=T0 + 20, node="d1", action="LAND", attempts=5, after_s=8.0,
                                            seen="mode MISSION"))
    assert any("failsafe_confirmed" in why for why in check_link_loss(absorbed))
    assert any("failsafe_confirmed" in why for why in check_site_router_down_alone(absorbed))
    assert any("failsafe_confirmed" in why for why in check_failsafe_recover(absorbed))
    shown = _outcome(FailsafeConfirmed(t=T0 + 11, node="d1", action="LAND", attempts=1, after_s=0.5, seen="mode LAND"))
    assert check_link_loss(shown) == [] and check_site_router_down_alone(shown) == []
