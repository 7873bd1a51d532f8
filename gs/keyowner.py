"""Key sharing as the owner of our links: answering other GSs' key-sharing queries about link
(drone, us), one ``KeyOwner`` per GS (``gs.linking`` has the asking side).

Refusals cost no crypto where they can: malformed, unknown asker, not authorized for the drone, our own
link alive (a secret handed out then could only serve whoever asked: key escrow), then the cheap tag, a
repeated message 1, the asker's rate limit (charged only for authentic queries), and the handshake
(``zdrone.core.keyshare.KeyShareResponder``). The secret handed out is a candidate of our link until the
drone speaks under it (``gs.core``).
"""

from __future__ import annotations

import logging
from collections import Counter

from zdrone.core import records as rec
from zdrone.core.fleet import Fleet
from zdrone.core.keys import Identity
from zdrone.core.keyshare import KeyShareResponder, Refused, ShareRefusal, decode_query

from gs.actions import Action, Emit, QueryAnswer

log = logging.getLogger("gs.linking")

#: Key-sharing handshakes per asker per second (bursts of ``LINKKEY_BURST``, or more: below): a hostile
#: asker spends a few ms of CPU a second.
LINKKEY_RATE, LINKKEY_BURST = 5.0, 10.0
#: An asker's bucket holds one handshake per drone both GSs are authorized for (the fleet in force), if
#: that is more than ``LINKKEY_BURST``: the first share of a whole fleet on the ground is one burst (300
#: drones: seconds, not a minute); the rate it refills at stays ``LINKKEY_RATE`` (a GS's key in hostile
#: hands still gets that much sustained, after one burst of at most one handshake per shared drone,
#: answered ``LINKKEY_PER_TURN`` a loop turn: ``gs.station``).
LINKKEY_BURST_PER_SHARED_DRONE = 1.0
#: A secret handed out over the backhaul waits this long for the drone to prove it (the drone first
#: speaks under it when it reaches this GS's coverage).
LINKKEY_CANDIDATE_TTL = 900.0
#: The first few of each refusal or bad reply go to the event log; all of them to the counters.
LOGGED = 5


class KeyOwner:
    """Key sharing as the owner of our links: answering other GSs' queries (one per GS)."""

    def __init__(self, identity: Identity, gs: str, fleet: Fleet, counters: Counter[str]) -> None:
        self.gs, self._fleet, self.counters = gs, fleet, counters
        self.adopt(identity)

    def _burst(self) -> float:
        """The asker's bucket: ``LINKKEY_BURST``, or one handshake per drone we and another GS are
        both authorized for, if the fleet has more (the largest over the other GSs)."""
        f, shared = self._fleet, 0
        mine = [d for d in f.drones() if f.is_authorized(d, self.gs)]
        for g in f.ground_stations():
            if g != self.gs:
                shared = max(shared, sum(1 for d in mine if f.is_authorized(d, g)))
        return max(LINKKEY_BURST, LINKKEY_BURST_PER_SHARED_DRONE * shared)

    @property
    def fleet(self) -> Fleet:
        return self._fleet

    @fleet.setter
    def fleet(self, fleet: Fleet) -> None:
        """A fleet revision took effect: the next query is answered by it (``pairing_pq`` on: a
        classical query is refused as a downgrade)."""
        self._fleet = fleet
        self.responder.require_hybrid = fleet.pairing_pq
        self.responder.limiter.set_burst(self._burst())  # no bucket is refilled by it

    def adopt(self, identity: Identity) -> None:
        """Answer under ``identity`` from now on (our static key was rotated)."""
        self.responder = KeyShareResponder(identity, self.gs, LINKKEY_RATE, self._burst(),
                                           require_hybrid=self._fleet.pairing_pq)

    def refused(self, logs: list[Action], reason: ShareRefusal, drone: str, asker: str, detail: str = "") -> QueryAnswer:
        key = f"linkkey_refused:{reason.value}"
        self.counters[key] += 1
        if self.counters[key] <= LOGGED:  # the first few in the log; all of them in the counters
            logs.append(Emit(rec.LinkkeyRefused(drone=drone, asker=asker, reason=reason.value, detail=detail)))
        crypto = reason is ShareRefusal.AUTH_FAILED
        if reason in (ShareRefusal.RATE_LIMITED, ShareRefusal.BAD_MAC, ShareRefusal.STALE):
            return QueryAnswer(crypto=crypto)  # no answer at all: the cheapest refusal
        return QueryAnswer(error=reason.value.encode(), crypto=crypto)

    def answer(self, drone: str, payload: bytes, now: float, secret: bytes, wall: float | None, serves: bool,
               live: bool) -> tuple[QueryAnswer, list[Action], str | None]:
        """One query for link (``drone``, us): the answer, the logs, and the asker whose candidate key
        ``secret`` now is (None: nothing handed out). ``serves``: we serve the drone; ``live``: our
        own link with it is not LOST.

        Refusals before any crypto: malformed, unknown asker, not authorized for the drone, our link
        alive; then the cheap tag, a repeated message 1 (its first answer again), the asker's rate
        limit (charged only for authentic queries), and the handshake (``KeyShareResponder``)."""
        logs: list[Action] = []
        req = decode_query(payload)
        if isinstance(req, Refused):
            return self.refused(logs, req.reason, drone, "?", req.detail), logs, None
        asker = self.fleet.nodes.get(req.asker)
        if asker is None or asker.role != "gs" or req.asker == self.gs:
            return self.refused(logs, ShareRefusal.UNKNOWN_ASKER, drone, req.asker), logs, None
        if not serves or not self.fleet.is_authorized(drone, req.asker) or not self.fleet.is_authorized(drone, self.gs):
            return self.refused(logs, ShareRefusal.UNAUTHORIZED, drone, req.asker), logs, None
        if live:
            # our own link is alive (we may even hold authority): nobody needs a new key for it, and a
            # secret handed out now could only serve whoever asked (issue 18: key escrow)
            return self.refused(logs, ShareRefusal.LIVE_LINK, drone, req.asker), logs, None
        out = self.responder.answer(drone, req.asker, asker.public_bytes, req.m1, now, secret, wall)
        if isinstance(out, Refused):  # forged, over the rate limit, or claimed without the key
            return self.refused(logs, out.reason, drone, req.asker, out.detail), logs, None
        reply, fresh = out
        if not fresh:
            self.counters["linkkey_repeated"] += 1  # a replay or a retransmission: same answer, nothing new
            return QueryAnswer(reply=reply), logs, None
        self.counters["linkkey_shared"] += 1
        logs.append(Emit(rec.LinkkeyShared(drone=drone, asker=req.asker)))
        log.info("link key for (%s, %s) shared with %s (pending the drone's proof)", drone, self.gs, req.asker)
        return QueryAnswer(reply=reply, crypto=True), logs, req.asker
