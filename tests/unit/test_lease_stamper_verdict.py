"""``lease-stamper``'s verdict asks, beyond ``revoked-alone``'s, that X stamped all through B's lease and
that the drone refused X's stamps as unauthorized while the lease ran (and counted them at the end)."""

from __future__ import annotations

from zdrone.core.records import AuthorityState, DroneStatus, Drop
from zdrone.sil.fault_verdicts import LEASE_STAMPER_PERIOD_S, check_lease_stamper, check_revoked_alone
from zdrone.sil.testbed_records import StampPut
from zdrone.sil.verdicts import Outcome

CUT = 1795338600.0
LAPSE = CUT + 13.0
REFUSED = "stamp_refused:unauthorized"


def _status(t: float, refused: int) -> DroneStatus:
    return DroneStatus(t=t, node="d1", owner="B", epoch=2, state=AuthorityState.LINKED, pending_to=None, position=None,
                       armed=True, mode="MISSION", landed_state=2, in_region=True, subscribed=("B",), links={}, keys={},
                       ha_drops={}, rejects={}, counters={REFUSED: refused} if refused else {}, forwarded_commands={},
                       out_of_coverage={})


def _stamps(*offsets: float) -> list[StampPut]:
    return [StampPut(t=CUT + dt, node="rogue-lease-stamper", gs="X", number=0, wall=CUT + dt, drones=("d1",))
            for dt in offsets]


def _outcome(stamps: list[StampPut], refused_by_lapse: int, refused_at_end: int) -> Outcome:
    summary = {"faults": [{"t": CUT, "target": "backhaul", "text": "cut", "ends": None}],
               "notes": ["revision revoking B published through A"], "drone_counters": {REFUSED: refused_at_end},
               "failsafe": None, "handovers": [], "regained": [], "final_owner": None}
    drone = [_status(CUT - 1.0, 0), _status(LAPSE - 0.3, refused_by_lapse),
             Drop(t=LAPSE, node="d1", gs="B", reason="lease_lapsed", detail="no stamp")]
    return Outcome(summary, drone, {"A": [], "B": []}, list(stamps))


def _own(o: Outcome) -> list[str]:
    """What ``lease-stamper`` finds wrong beyond ``revoked-alone``."""
    control = check_revoked_alone(o)
    return [why for why in check_lease_stamper(o) if why not in control]


EVERY = [LEASE_STAMPER_PERIOD_S * i for i in range(10)]  # 0 .. 18 s after the cut


def test_x_stamping_through_the_lease_refused_as_unauthorized_passes():
    assert _own(_outcome(_stamps(*EVERY), refused_by_lapse=6, refused_at_end=10)) == []


def test_x_silent_or_stamping_too_little_fails():
    assert any("no stamp" in why for why in _own(_outcome([], 0, 0)))
    late = _own(_outcome(_stamps(14.0, 16.0, 18.0), refused_by_lapse=0, refused_at_end=3))  # all after the lapse
    assert any("between the cut and the lapse" in why for why in late)
    assert any("while B's lease ran" in why for why in late)


def test_x_stamps_never_refused_fail():
    """The hole closed by the fix: X's stamps heard and taken (renewing), never refused."""
    whys = _own(_outcome(_stamps(*EVERY), refused_by_lapse=0, refused_at_end=0))
    assert any("refused none of X's stamps" in why for why in whys)
    assert any("while B's lease ran" in why for why in whys)
