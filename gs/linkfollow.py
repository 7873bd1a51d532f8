"""A session's part in links that follow the drone (``zdrone.core.linkplan``): what the owner prepares,
when a GS pairs of its own accord, and its end of a link the drone closed. A mixin of
``gs.session.DroneSession``, which holds the state it reads (the link, the slot, the drone's word).
"""

from __future__ import annotations

import logging

from zdrone.core import records as rec
from zdrone.core import wire
from zdrone.core.authority import State as HaState
from zdrone.core.linkplan import GRACE_S, plan_links
from zdrone.core.linkslot import LinkSlot

from gs.actions import Action, Emit

log = logging.getLogger(__name__)

#: An operator's request for control of a drone we hold no link with starts pairing for this long (the
#: application repeats its request meanwhile: answered TEMPORARILY_REJECTED until the link is made).
PAIR_ON_DEMAND_S = 10.0
#: A link whose drone's links follow it, silent this long while the drone is not ours, is closed on the
#: drone's end (``linkplan.GRACE_S`` after it left our coverage): we wipe ours (the drone's notice, sent
#: out of our radio's reach, rarely gets here).
WIPE_SILENT_S = GRACE_S + 15.0


class LinkFollow:
    """The link-following rules of one drone's session (its attributes are ``DroneSession``'s)."""

    closed_by_drone: bool
    pair_on_demand_until: float | None

    def _pairs(self, now: float) -> bool:
        """Whether we pair with the drone while we hold no link: the station pairs (``--pair``) and the
        drone never closed our link (its links follow it: the owner prepares ours), or our operator asked
        for control within ``PAIR_ON_DEMAND_S``."""
        if self.pair_on_demand_until is not None and now >= self.pair_on_demand_until:
            self.pair_on_demand_until = None
        pairs = self.st.opts.pair and (self.st.opts.pair_drones is None or self.name in self.st.opts.pair_drones)
        return pairs and not self.closed_by_drone or self.pair_on_demand_until is not None

    def links_wanted(self) -> set[str] | None:
        """As the owner, the GSs whose links we prepare for the drone (``zdrone.core.linkplan``): those
        covering it and the next on its course, by its own reports; None: every authorized GS (its
        links do not follow it)."""
        fleet = self.st.fleet
        if not fleet.links_follow(self.name):
            return None
        if self.position is None:
            return set()  # where the drone is, it has not said yet: nothing to prepare
        circles = {g: n.coverage.circle() for g, n in fleet.nodes.items() if n.role == "gs" and n.coverage is not None}
        plan = plan_links(self.st.name, self.linking.others(), circles, self.position, self.fix.course,
                          fleet.links_max)
        return set(plan.wanted) - {self.st.name}

    def _on_link_closed(self, msg: wire.LinkClosed, now: float) -> list[Action]:
        """The drone closed our link (it needed the room, or it left us behind while our radio still
        reached it): our end is wiped (``_wipe_link``)."""
        if self.st.name in (self.owner, self.pending_to) or self.ha_state is HaState.FAILSAFE:
            # the drone never closes its owner's, a pending recipient's or any link in its failsafe
            # (``may_close``): such a notice was sealed by someone else holding the key (the GS that granted it)
            self.st.counters["link_closed_refused"] += 1
            return []
        self.st.counters["link_closed_by_drone"] += 1
        return self._wipe_link(msg.reason)

    def _left_behind(self, now: float) -> bool:
        """The drone's links follow it and ours has been silent ``WIPE_SILENT_S``, with the drone not ours
        nor in its failsafe by its last word: it has closed its end (``linkplan.GRACE_S`` after it left our
        coverage, which is when our radio lost it), and its notice could not reach us."""
        link = self.link
        return (link is not None and self.st.fleet.links_follow(self.name) and self.owner != self.st.name
                and self.ha_state is not HaState.FAILSAFE and link.tbm.last_seen is not None
                and link.tbm.since_last(now) >= WIPE_SILENT_S)

    def _wipe_link(self, reason: str) -> list[Action]:
        """Our end of a link the drone closed: the key wiped (live, the one replaced, a fallback; a candidate
        we made since for the owner's grant stays, to be proven when the drone comes back), the heartbeats stopped (they need a link), and no pairing of our own again (the owner prepares our link
        when the drone comes our way; our operator may still ask for control)."""
        fresh = self.slot.candidates  # keys made since for the owner's grant (the drone coming back our way)
        self.slot = LinkSlot(hybrid_only=self.st.fleet.pairing_pq)
        self.slot.candidates = fresh
        self.link = None
        self.switching = False
        self.closed_by_drone = True
        self.st.counters["link_wiped"] += 1
        log.info("link to %s closed (%s): key wiped", self.name, reason)
        return [Emit(rec.GsLinkClosed(drone=self.name, reason=reason[:120]))]

