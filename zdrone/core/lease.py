"""The owner's lease: how long a drone's owner keeps authority without word from the rest of the fleet.

Theory of operation
-------------------
From its first pairing, a drone's owner keeps authority only while the drone hears, within the
fleet's lease (``Fleet.revision_lease``), a signed revision stamp (``zdrone.core.revision``) from a GS
*authorized for the drone, other than the owner*. ``OwnerLease.stamp`` judges one stamp: signed by a
GS of the fleet under its key in force (no other name signs one), heard on that GS's own revision key
(not relayed on another's; a query's reply carries none: the adapter drops it), naming the revision
in force (a newer one renews nothing until the drone holds it), naming the drone, from a GS
authorized for the drone in the revision in force that is neither the owner nor one whose lease
lapsed, not dated ahead of the drone's clock. A renewal runs from the stamp's own time, signed by its
issuer (a replayed old stamp buys nothing past it). So the lease lapses at the silence of every
*other GS authorized for the drone*: the owner's stamps, those of a GS authorized for other drones
only, of a revoked or a lapsed GS never renew it. Each owner's lease runs from when it took authority
(``owner_is``) or from the newest renewing stamp, whichever is later (``due``); at ``due`` the owner
``lapse``s: the drone's core takes it off the authorized list (a covered heir, else the failsafe),
and its stamps renew nothing until another GS's do (``Renewed.restores``).

Pure: time comes in as ``now``; the results are values; the caller counts and logs them.
"""

from __future__ import annotations

from dataclasses import dataclass

from zdrone.core.fleet import Fleet
from zdrone.core.revision import STAMP_AHEAD_S, check_stamp


@dataclass(frozen=True, slots=True)
class StampRefused:
    reason: str  # signature, relayed, newer_revision, stale_revision, unnamed, unauthorized, owner, ahead


@dataclass(frozen=True, slots=True)
class Renewed:
    gs: str
    restores: frozenset[str]  # GSs whose lapse this renewal ends (empty: nothing lapsed, or the stamp too old)


@dataclass(frozen=True, slots=True)
class NotNewer:
    """A valid stamp no newer than the last renewal: nothing changes."""


StampResult = StampRefused | Renewed | NotNewer


class OwnerLease:
    """One drone's owner lease: the newest renewal, the owner in force and since when, who lapsed."""

    def __init__(self) -> None:
        self.synced: float | None = None  # the time of the newest stamp that renewed the lease
        self.armed: float | None = None  # when the owner in force took authority
        self.owner: str | None = None  # ... that owner
        self.lapsed: set[str] = set()  # GSs whose lease lapsed

    def owner_is(self, owner: str | None, now: float) -> None:
        """The owner in force at ``now``: a new one's lease runs from now (the first pairing included)."""
        if owner != self.owner:
            self.owner, self.armed = owner, (now if owner is not None else None)

    def due(self, lease_s: float) -> float | None:
        """When the owner's lease lapses if no stamp renews it (None: no lease, or no owner)."""
        if lease_s <= 0 or self.armed is None or self.owner is None:
            return None
        return max(self.armed, self.synced if self.synced is not None else self.armed) + lease_s

    def lapse_due(self, now: float, lease_s: float) -> str | None:
        """The owner whose lease lapses at ``now`` (marked lapsed), or None."""
        due = self.due(lease_s)
        if due is None or now < due or self.owner is None or self.owner in self.lapsed:
            return None
        self.lapsed.add(self.owner)
        return self.owner

    def stamp(self, data: bytes, fleet: Fleet, drone: str, carrier: str, now: float, wall_offset: float,
              lease_s: float) -> StampResult:
        """Judge one stamp heard by ``drone`` (``fleet``: the revision in force there) on ``carrier``'s
        revision key (the GS of the key it was published on: always known)."""
        stamp = check_stamp(data, fleet)
        if stamp is None:
            return StampRefused("signature")
        if stamp.gs != carrier:
            return StampRefused("relayed")
        if stamp.number != fleet.revision:
            return StampRefused("newer_revision" if stamp.number > fleet.revision else "stale_revision")
        if not stamp.names(drone):
            return StampRefused("unnamed")
        if not fleet.is_authorized(drone, stamp.gs):
            return StampRefused("unauthorized")
        if stamp.gs == self.owner or stamp.gs in self.lapsed:
            return StampRefused("owner")
        if stamp.wall > now + wall_offset + STAMP_AHEAD_S:
            return StampRefused("ahead")
        at = min(now, stamp.wall - wall_offset)
        if self.synced is not None and at <= self.synced:
            return NotNewer()
        self.synced = at
        restores = frozenset(self.lapsed) if now < at + lease_s else frozenset()
        self.lapsed -= restores
        return Renewed(stamp.gs, restores)


__all__ = ["NotNewer", "OwnerLease", "Renewed", "StampRefused", "StampResult"]
