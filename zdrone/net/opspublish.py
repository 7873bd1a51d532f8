"""A GS's operations picture, published for the fleet's viewer (the GS's side of ``zdrone view``).

The station calls ``on_record`` with every record its core logs and ``publish(now, wall)`` once per
loop pass (and wakes by ``next_due``). The picture (``StationCore.drone_ops`` of every drone it
serves, the drone's signed word on its authority among them, and the authority events logged since
the last one) goes out every ``OPS_PERIOD_S``; after an authority event a short picture goes at once (at
most every ``OPS_MIN_GAP_S``): the events and the drones they name only, so the viewer shows a hand-over
within a few tens of milliseconds of the GS hearing it, and a GS whose drones hand over all the time
(300 of them) does not build its whole picture ten times a second. The viewer takes each drone's entry
on its own (``FleetPicture.on_report``): the others keep the last whole picture's. It is cut into parts under
``OPS_MAX_BYTES`` and each is sealed for the viewer (``zdrone.core.opspicture``), on ``zdrone-ops/<gs>/<lane>``
(the only key the router lets this GS put its picture on; only the viewer receives it).

One viewer per fleet (the first of ``Fleet.viewers``): a fleet without one publishes nothing.
"""

from __future__ import annotations

import os
from typing import Any, Callable, Iterable, Protocol

from zdrone.core.fleet import Fleet
from zdrone.core.keys import Identity
from zdrone.core.opspicture import (OPS_MAX_EVENTS, OPS_MIN_GAP_S, OPS_PERIOD_S, DroneOps, OpsEvent, OpsSealer, SALT_LEN,
                               report_parts)
from zdrone.core.records import AnyRecord, fields_of, record_type
from zdrone.fleet import keyexprs

#: The records a GS logs that the viewer's authority feed shows (by type).
AUTHORITY_KINDS = frozenset({
    "authority_status", "failsafe_notice", "control_requested", "handover_release", "handover_failed",
    "handover_hold", "handover_resume", "operator_control_requested", "operator_control_asked",
    "operator_request", "operator_request_granted", "operator_request_declined", "operator_request_expired",
    "operator_request_timed_out", "operator_request_withdrawn", "operator_control_taken",
    "operator_control_let_go", "operator_consent_refused", "takeover_window_opened", "takeover_window_closed",
    "operator_takeover_setting"})


class PictureSource(Protocol):
    """What the publisher reads of the GS core."""

    @property
    def drones(self) -> tuple[str, ...]: ...

    def drone_ops(self, drone: str, now: float) -> DroneOps: ...


def event_text(record: AnyRecord) -> str:
    """One short line for the feed: the record's fields but the drone."""
    fields = fields_of(record)
    return ", ".join(f"{k.rstrip('_')} {v}" for k, v in fields.items() if k != "drone" and v not in (None, "", [], {}))


class OpsPublisher:
    """Publishes one GS's operations picture (see the module docstring)."""

    def __init__(self, gs: str, source: PictureSource, sealer: OpsSealer, put: Callable[[str, bytes], None]) -> None:
        self.gs, self.source, self.sealer, self._put = gs, source, sealer, put
        self.events: list[OpsEvent] = []
        self.events_dropped = 0
        self.urgent = False
        self.last: float | None = None
        self.last_whole: float | None = None  # when the last picture of every drone went
        self.parts_sent = 0
        self.lane_overflow = 0  # parts beyond the lanes (on the last lane: the router may drop them)

    @staticmethod
    def sealer_for(gs: str, fleet: Fleet, identity: Identity) -> OpsSealer | None:
        """A fresh start's sealer (a new salt) for the fleet's viewer, None: the fleet has none."""
        viewers = fleet.viewers()
        if not viewers:
            return None
        viewer = viewers[0]
        return OpsSealer(identity, gs, viewer, fleet.nodes[viewer].public_bytes, keyexprs.ops(gs), os.urandom(SALT_LEN))

    @classmethod
    def for_station(cls, gs: str, fleet: Fleet, identity: Identity, source: PictureSource,
                    put: Callable[[str, bytes], None]) -> "OpsPublisher | None":
        sealer = cls.sealer_for(gs, fleet, identity)
        return None if sealer is None else cls(gs, source, sealer, put)

    def reseal(self, fleet: Fleet, identity: Identity) -> bool:
        """A fleet revision in force: if it rotated this GS's key or the viewer's (or gave the fleet
        another viewer), the picture is sealed anew from now on (a new start); True if it was. A
        fleet left without a viewer keeps the last sealer (the router lets nobody read it)."""
        sealer = self.sealer_for(self.gs, fleet, identity)
        if sealer is None:
            return False
        old = self.sealer
        if (sealer.viewer, sealer.viewer_public, sealer.public) == (old.viewer, old.viewer_public, old.public):
            return False
        self.sealer = sealer
        return True

    def on_record(self, record: AnyRecord, wall: float) -> None:
        """A record the GS logged: an authority event goes in the next picture, which goes soon."""
        kind = record_type(record)
        if kind not in AUTHORITY_KINDS:
            return
        drone = getattr(record, "drone", "")
        self.events.append(OpsEvent(round(wall, 3), str(drone), kind, event_text(record)))
        if len(self.events) > OPS_MAX_EVENTS:
            self.events_dropped += len(self.events) - OPS_MAX_EVENTS
            del self.events[:-OPS_MAX_EVENTS]
        self.urgent = True

    def _whole_due(self) -> float:
        return 0.0 if self.last_whole is None else self.last_whole + OPS_PERIOD_S

    def next_due(self) -> float:
        if self.last is None:
            return 0.0
        return min(self._whole_due(), self.last + OPS_MIN_GAP_S) if self.urgent else self._whole_due()

    def publish(self, now: float, wall: float) -> None:
        """Publish the picture if it is due: every drone's at the period, the events' drones' in between."""
        if now < self.next_due():
            return
        whole = now >= self._whole_due()
        if whole:
            names: Iterable[str] = self.source.drones
        else:
            served = set(self.source.drones)
            names = [d for d in dict.fromkeys(ev.drone for ev in self.events) if d in served]
        drones = [self.source.drone_ops(d, now) for d in names]
        for i, part in enumerate(report_parts(self.gs, round(wall, 3), drones, self.events)):
            # part i on lane i (the router's budget per lane); more parts than lanes share the last one
            self._put(keyexprs.ops_lane(self.gs, min(i, keyexprs.OPS_LANES - 1)), self.sealer.seal(part))
            self.parts_sent += 1
            self.lane_overflow += i >= keyexprs.OPS_LANES
        self.events, self.urgent, self.last = [], False, now
        if whole:
            self.last_whole = now

    def stats(self) -> dict[str, Any]:
        return {"parts_sent": self.parts_sent, "events_dropped": self.events_dropped, "lane_overflow": self.lane_overflow}
