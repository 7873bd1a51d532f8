"""The GS's operations picture: every drone's at the period, and after an authority event a short one
at once with the events and the drones they name (how the page follows a hand-over within a tenth of a
second of the GS hearing it; the figure itself is ``zdrone bench view``'s) without building every
drone's entry ten times a second when hand-overs never stop."""

from __future__ import annotations

import msgspec

from zdrone.core.opspicture import OPS_MIN_GAP_S, OPS_PERIOD_S, DroneOps, OpsReport
from zdrone.core.records.base import UntypedRecord
from zdrone.core.records.station import FailsafeNoticed
from zdrone.net.opspublish import OpsPublisher


class _Source:
    drones: tuple[str, ...] = ("d1", "d2", "d3")

    def drone_ops(self, drone: str, now: float) -> DroneOps:
        return DroneOps(drone, True, "A", 1, "linked")


class _Sealer:
    def seal(self, part: bytes) -> bytes:
        return part


class _Station:
    """A publisher, and the pictures it sent: (when, the drones in it, the events' kinds)."""

    def __init__(self) -> None:
        self.sent: list[tuple[float, list[str], list[str]]] = []
        self.now = 0.0
        self.pub = OpsPublisher("A", _Source(), _Sealer(), self._put)  # type: ignore[arg-type]

    def _put(self, key: str, payload: bytes) -> None:
        r = msgspec.msgpack.decode(payload, type=OpsReport)
        self.sent.append((self.now, [d.drone for d in r.drones], [e.kind for e in r.events]))

    def publish(self, now: float) -> None:
        self.now = now
        self.pub.publish(now, 1000.0 + now)

    def event(self, drone: str) -> None:
        self.pub.on_record(FailsafeNoticed(drone=drone, action="LAND", reason="link"), 1000.0 + self.now)


def test_an_authority_event_sends_its_drone_after_the_short_gap_and_the_whole_picture_keeps_its_period():
    st = _Station()
    st.publish(10.0)
    assert st.sent == [(10.0, ["d1", "d2", "d3"], [])] and st.pub.next_due() == 10.0 + OPS_PERIOD_S
    st.now = 10.02
    st.event("d2")
    assert st.pub.next_due() == 10.0 + OPS_MIN_GAP_S
    st.publish(10.0 + OPS_MIN_GAP_S / 2)  # not yet: the short gap bounds a burst of events
    assert len(st.sent) == 1
    st.event("d9")  # a drone this GS does not serve: its event goes, no entry for it
    st.publish(10.0 + OPS_MIN_GAP_S)
    assert st.sent[-1] == (10.0 + OPS_MIN_GAP_S, ["d2"], ["failsafe_notice", "failsafe_notice"])
    assert st.pub.next_due() == 10.0 + OPS_PERIOD_S  # the whole picture at its period, not pushed back
    st.publish(10.0 + OPS_PERIOD_S)
    assert st.sent[-1] == (10.0 + OPS_PERIOD_S, ["d1", "d2", "d3"], [])


def test_an_event_when_the_whole_picture_is_due_anyway_goes_in_it():
    st = _Station()
    st.publish(10.0)
    st.now = 10.45
    st.event("d1")
    st.publish(10.0 + OPS_PERIOD_S)
    assert st.sent[-1] == (10.0 + OPS_PERIOD_S, ["d1", "d2", "d3"], ["failsafe_notice"])


def test_a_record_that_is_no_authority_event_waits_for_the_period():
    st = _Station()
    st.publish(10.0)
    st.pub.on_record(UntypedRecord(10.0, "A", "position", {"drone": "d1"}), 1010.0)
    assert st.pub.next_due() == 10.0 + OPS_PERIOD_S and st.pub.events == []
