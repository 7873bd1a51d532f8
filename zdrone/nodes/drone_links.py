"""How the drone's core lets a link go: links that follow the drone (at most the fleet's ``links_max``,
the one left behind longest closed to make room, ``zdrone.core.linkplan``), and a GS's key replaced on
its own signed word that it restarted (``zdrone.core.keyslost``: the owner's grant carries the notice;
the drone takes it only if the GS signed it, it is fresh, and the key it replaces is older than the
restart). Pure, as ``zdrone.nodes.drone_core``.
"""

from __future__ import annotations

import logging
from collections import Counter
from typing import Callable

from zdrone.core import authority as ha
from zdrone.core import keyslost, wire
from zdrone.core.envelope import SecureLink
from zdrone.core.fleet import Fleet
from zdrone.core.linkplan import LinkGrace
from zdrone.core.linkslot import LinkSlot
from zdrone.core.pairing import PairRefusal, PairRefused
from zdrone.core.standby import StandbyStream
from zdrone.core.wire import KeyGrant
from zdrone.nodes.drone_actions import Out

#: the drone core's own logger: what it says of its links is the core's word
log = logging.getLogger("zdrone.nodes.drone_core")


class DroneLinks:
    """``DroneCore``'s rules for letting a link go. A mixin: the core holds the state (named here)."""

    name: str
    fleet: Fleet
    machine: ha.AuthorityMachine
    links: dict[str, SecureLink]
    slots: dict[str, LinkSlot]
    probation: dict[str, float]
    rekey: set[str]
    counters: Counter[str]
    grace: LinkGrace
    standby: StandbyStream
    wall_offset: float

    _control: Callable[..., list[Out]]
    _handle: Callable[..., list[Out]]

    def _lost_notice_holds(self, msg: KeyGrant, live: SecureLink, now: float) -> bool:
        """Whether the grant's keys-lost notice lets its key replace ``live`` (``keyslost.judge``); one
        that does not hold is counted and changes nothing (the grant is a candidate to prove, as without)."""
        v = msg.lost and keyslost.judge(msg.lost, self.fleet, self.name, msg.gs, now + self.wall_offset,
                                        live.made + self.wall_offset)
        if isinstance(v, keyslost.NoticeRefused):
            self.counters[f"keys_lost_refused:{v.reason}"] += 1
        return isinstance(v, keyslost.KeysLostNotice)

    def _wipe_key(self, gs: str) -> None:
        """``gs``'s keys are gone here: the live key, candidates and the one replaced (a closed link, a restart)."""
        self.links.pop(gs, None)
        self.slots.pop(gs, None)
        self.probation.pop(gs, None)
        self.rekey.discard(gs)

    # ---------------------------------------------------- links that follow the drone
    def _follows(self) -> bool:
        """The drone's links follow it (more authorized GSs than the fleet's ``links_max``: ``linkplan``)."""
        return self.fleet.links_follow(self.name)

    def _links_full(self, gs: str) -> PairRefused | None:
        """A pairing of ``gs`` would pass ``links_max``: refused unless ``gs`` covers the drone (a possible
        heir) and a closable link makes room."""
        if not self._follows() or gs in self.links or len(self.links) < self.fleet.links_max:
            return None
        if gs in self.machine.inside and self.grace.oldest(besides=gs) is not None:
            return None
        return PairRefused(PairRefusal.LINKS_FULL, f"the drone holds {len(self.links)} links "
                                                   f"(the fleet's most) and none may close")

    def _make_room(self, newcomer: str, now: float) -> list[Out]:
        """Close the link closable longest while a new link for ``newcomer`` would pass ``links_max``."""
        out: list[Out] = []
        while len(self.links) >= self.fleet.links_max:
            victim = self.grace.oldest(besides=newcomer)
            if victim is None:
                break
            out += self._close(victim, now, f"room for {newcomer}")
        return out

    def _close(self, gs: str, now: float, why: str) -> list[Out]:
        """Close ``gs``'s link: tell it (``LinkClosed``, its last frame under the link's key), then wipe the
        key (live, candidates, the one replaced) and forget the link in the machine."""
        self.grace.forget(gs)
        if not self.machine.may_close(gs):
            return []
        out = self._control(gs, wire.LinkClosed(why), now)
        out += self._handle(ha.LinkClosed(now, gs, why), now)
        self._wipe_key(gs)
        self.standby.forget(gs)
        self.counters["link_closed"] += 1
        log.info("link to %s closed (%s): key wiped", gs, why)
        return out
