"""The GS's operations picture goes out at once after an authority event: how the page follows a
hand-over within a tenth of a second of the GS hearing it (the figure itself is ``zdrone bench
view``'s), instead of at the next period."""

from __future__ import annotations

from zdrone.core.opspicture import OPS_MIN_GAP_S, OPS_PERIOD_S, DroneOps
from zdrone.core.records.base import UntypedRecord
from zdrone.net.opspublish import OpsPublisher


class _Source:
    drones: tuple[str, ...] = ()

    def drone_ops(self, drone: str, now: float) -> DroneOps:  # pragma: no cover - no drones
        raise AssertionError(drone)


class _Sealer:
    def seal(self, part: bytes) -> bytes:
        return part


class _Station:
    """A publisher and the moments its parts went out."""

    def __init__(self) -> None:
        self.sent: list[float] = []
        self.now = 0.0
        self.pub = OpsPublisher("A", _Source(), _Sealer(), lambda key, payload: self.sent.append(self.now))  # type: ignore[arg-type]

    def publish(self, now: float) -> None:
        self.now = now
        self.pub.publish(now, 1000.0 + now)


def test_an_authority_event_makes_the_next_picture_go_after_the_short_gap_not_the_period():
    st = _Station()
    pub, sent = st.pub, st.sent
    st.publish(10.0)
    assert sent == [10.0] and pub.next_due() == 10.0 + OPS_PERIOD_S
    pub.on_record(UntypedRecord(10.02, "A", "authority_status", {"drone": "d1", "owner": "B"}), 1010.02)
    assert pub.next_due() == 10.0 + OPS_MIN_GAP_S
    st.publish(10.0 + OPS_MIN_GAP_S / 2)  # not yet: the short gap bounds a burst of events
    assert sent == [10.0]
    st.publish(10.0 + OPS_MIN_GAP_S)
    assert sent == [10.0, 10.0 + OPS_MIN_GAP_S]
    assert pub.next_due() == 10.0 + OPS_MIN_GAP_S + OPS_PERIOD_S  # the event went: back to the period


def test_a_record_that_is_no_authority_event_waits_for_the_period():
    st = _Station()
    pub, sent = st.pub, st.sent
    st.publish(10.0)
    pub.on_record(UntypedRecord(10.02, "A", "position", {"drone": "d1"}), 1010.02)
    assert pub.next_due() == 10.0 + OPS_PERIOD_S and pub.events == []
