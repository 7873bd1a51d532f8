"""How the drone's core follows the fleet's revisions: a signed revision applied (a revoked GS's link and
keys dropped at once, a rotated GS re-pairing under its new key make-before-break), the owner's lease
(renewed only by a revision stamp naming the drone from a GS authorized for it other than the owner;
when it lapses, the owner's authority goes as if its link were LOST), and the drone's own keys
rotated. Pure, as ``zdrone.nodes.drone_core``.
"""

from __future__ import annotations

import logging
from collections import Counter
from typing import Any, Callable

from zdrone.core import authority as ha
from zdrone.core import records as rec
from zdrone.core.attestation import Attester
from zdrone.core.envelope import SecureLink
from zdrone.core.fleet import Fleet
from zdrone.core.geometry import Circle
from zdrone.core.keys import Identity, SigningKey
from zdrone.core.lease import OwnerLease, Renewed, StampRefused
from zdrone.core.linkslot import LinkSlot
from zdrone.core.outputs import Emit
from zdrone.core.pairing import PairingResponder
from zdrone.core.uplink import UplinkPolicy
from zdrone.nodes.drone_actions import Out

#: the drone core's own logger: what it says of a revision or the lease is the core's word
log = logging.getLogger("zdrone.nodes.drone_core")


class DroneRevisions:
    """``DroneCore``'s part in the fleet's revisions. A mixin: the core holds the state (named here) and
    decides what a revised authorized list means (``_handle`` of ``ha.Revised``, then ``_effects``)."""

    name: str
    fleet: Fleet
    opts: Any  # the core's ``DroneCoreOptions``
    machine: ha.AuthorityMachine
    responder: PairingResponder
    uplink: UplinkPolicy
    slots: dict[str, LinkSlot]
    links: dict[str, SecureLink]
    probation: dict[str, float]
    counters: Counter[str]
    gs_sysids: dict[str, int]
    coverage: dict[str, Circle]
    rekey: set[str]
    lease: OwnerLease
    wall_offset: float
    attester: Attester | None
    _handle: Callable[..., list[Out]]
    _effects: Callable[..., list[Out]]

    def on_revision(self, fleet: Fleet, now: float) -> list[Out]:
        """A fleet revision the adapter checked (signature, number) and applied (``fleet``, the new
        effective fleet). A GS off the drone's authorized list (revoked, or no longer authorized)
        loses its link at once: its keys and candidates erased, its uplink no longer heard, its
        requests refused; if it held authority, an heir takes over, else the failsafe
        (``AuthorityMachine._on_revised``). A rotated GS pairs from now on under its new key only;
        its live link goes on until its new pairing's key is proven (no gap). ``pairing_pq``: every classical
        key not yet proven is dropped at once (``LinkSlot.require_hybrid``); a live one waits for its hybrid re-pairing."""
        old, self.fleet = self.fleet, fleet
        node = fleet.nodes[self.name]
        authorized = frozenset() if fleet.is_revoked(self.name) else frozenset(
            g for g in node.authorized_gs if not fleet.is_revoked(g))
        gone = sorted(g for g in {*self.slots, *self.probation} if g not in authorized)
        for gs in gone:  # keys erased: the slot (live key, candidates) and its link dropped
            self.slots.pop(gs, None)
            self.links.pop(gs, None)
            self.probation.pop(gs, None)
            self.counters["revoked_links"] += 1
        r = self.responder
        r.ground_stations = {g: fleet.nodes[g].public_bytes for g in fleet.ground_stations()}
        r.authorized = authorized
        r.require_hybrid = fleet.pairing_pq
        classical: list[Out] = []
        for gs, slot in sorted(self.slots.items()):
            dropped = slot.require_hybrid(fleet.pairing_pq)
            for what in dropped:
                self.counters[f"classical_dropped:{what}"] += 1
            if not dropped:
                continue
            if not any(c.origin == "pair" for c in slot.candidates):
                self.probation.pop(gs, None)  # no pairing key of its left to prove
            classical.append(Emit(rec.Drop(gs=gs, reason="classical_key", detail=(
                f"{', '.join(dropped)} dropped: revision {fleet.revision} requires the hybrid pairing"))))
            log.warning("revision %d requires the hybrid pairing: %s's classical %s dropped", fleet.revision, gs,
                        ", ".join(dropped))
        self.uplink = node.uplink
        self.gs_sysids = {n: fleet.nodes[n].sysid for n in fleet.ground_stations()}
        self.coverage = {n: fleet.nodes[n].coverage.circle() for n in fleet.ground_stations()  # type: ignore[union-attr]
                         if fleet.nodes[n].coverage is not None}
        rotated = sorted(n for n, v in fleet.nodes.items() if n in old.nodes and v.public_key != old.nodes[n].public_key)
        self.rekey = (self.rekey | {g for g in rotated if g in self.links}) & authorized
        authorized -= self.lapsed  # a revision is no renewal (whoever relayed it): a lapsed owner stays out
        out: list[Out] = [Emit(rec.RevisionApplied(number=fleet.revision, revoked=tuple(sorted(fleet.revoked)), rotated=tuple(rotated),
                                                   pairing_pq=fleet.pairing_pq)), *classical]
        out += self._handle(ha.Revised(now, authorized, fleet.revision), now)
        return out + self._effects(now)

    @property
    def lease_s(self) -> float:
        """The owner's lease (s; 0: none): the fleet's signed value, else the node's option."""
        return self.fleet.revision_lease or self.opts.revision_lease

    @property
    def revision_synced(self) -> float | None:
        """The time of the newest stamp that renewed the owner's lease."""
        return self.lease.synced

    @property
    def lapsed(self) -> set[str]:
        """The GSs whose lease lapsed: their stamps renew nothing, they regain nothing."""
        return self.lease.lapsed

    def on_revision_stamp(self, data: bytes, now: float, carrier: str) -> list[Out]:
        """A GS's revision stamp published on ``carrier``'s revision key (never a query's reply), judged
        by the owner's lease (``zdrone.core.lease``). A renewal that ends a lapse makes the authorized
        list whole again: the GSs take control back by the usual rules."""
        got = self.lease.stamp(data, self.fleet, self.name, carrier, now, self.wall_offset, self.lease_s)
        if isinstance(got, StampRefused):
            self.counters[f"stamp_refused:{got.reason}"] += 1
            return []
        if not isinstance(got, Renewed):
            return []
        self.counters["stamp_renewed"] += 1
        if not got.restores:
            return []
        log.warning("revision stamp from %s: the lease is renewed (%s may take control again)", got.gs,
                    ", ".join(sorted(got.restores)))
        node = self.fleet.nodes[self.name]
        authorized = frozenset() if self.fleet.is_revoked(self.name) else frozenset(
            g for g in node.authorized_gs if not self.fleet.is_revoked(g))
        return self._handle(ha.Revised(now, authorized, self.fleet.revision), now) + self._effects(now)

    def lease_due(self) -> float | None:
        """When the owner's lease lapses if no stamp renews it (None: no lease, or no owner)."""
        return self.lease.due(self.lease_s) if self.machine.owner is not None else None

    def _lease(self, now: float) -> list[Out]:
        owner = self.lease.lapse_due(now, self.lease_s)
        if owner is None:
            return []
        self.counters["revision_lease_lapsed"] += 1
        log.warning("no revision stamp from a GS authorized for this drone other than %s for %.0f s: its authority "
                    "lapses", owner, self.lease_s)
        out: list[Out] = [Emit(rec.Drop(gs=owner, reason="lease_lapsed",
                                        detail=f"no stamp from another authorized GS for {self.lease_s:.0f} s"))]
        authorized = frozenset(self.machine.config.authorized) - self.lapsed
        why = f"lease lapsed (no revision stamp from another authorized GS for {self.lease_s:g} s)"
        return out + self._handle(ha.Revised(now, authorized, self.fleet.revision, why), now)

    def adopt_own_keys(self, identity: Identity | None, signing: SigningKey | None) -> None:
        """The fleet rotated this drone's keys (``identity``, ``signing``: the new ones from its bundle;
        None where the bundle does not hold them yet): pairing answers under the new static key, and
        the drone's word on its authority is signed with the new key, or not at all (never with a
        retired key: the viewer shows the drone stale until the new key is here). Live links go on."""
        if identity is not None:
            self.responder.me = identity
        self.attester = Attester(self.name, signing) if signing is not None else None
