"""One peer's link with key confirmation: the live key, candidate keys, and the key just replaced.

Theory of operation
-------------------
No new key replaces a live one until its holder proves it. A new key (from pairing, from a key
grant, from answering a key-sharing query) enters the slot as a *candidate* with an expiry; a
newer candidate of the same origin (the same GS's pairing, the same asker) replaces the older. An
incoming envelope is tried under the live key first; if that fails before authentication, under
each candidate, then under the key that was replaced last (for a short grace period, so frames
already in flight under it are not lost). The first candidate that opens an authentic frame is
*proven*: it becomes the live key, the old live key becomes the previous one, the other candidates
are forgotten, and the new link's liveness monitor continues the old one's reporting (so a state
change is never lost across a key change). Candidates that nobody proves expire.

A candidate that came from someone else's action never replaces a live key whose link is alive
(``replaces_live``): a key grant from the authority replaces no live key at all, and a secret this
end handed out over the backhaul replaces its live key only once that link is LOST. Only the peer itself replacing
its own key (``SELF_ORIGINS``: a pairing, which only the holder of the peer's static key completes)
may replace a live key at any time. So nothing any third party sends changes a live link: a
malicious GS that obtained a candidate's secret (by asking for it over the backhaul) and forges a
frame under it is counted as ``live_protected`` and changes nothing.

A third party's key that replaced a LOST live key (a backhaul secret, once the drone restarted and
lost the old key) keeps the old key as a *fallback*: whoever proved the new key also knew it (the
asker of the key-sharing query), so if the peer speaks under the old key again, the slot takes it
back at once (``Promoted("revert")``) — a secret escrowed while the link was LOST cannot cut a
GS off for good.

With ``require_hybrid`` (the fleet's ``pairing_pq``) the slot holds no classical key but its live one
(make-before-break until a hybrid key replaces it): no classical key not yet proven ever becomes live.

Failures are counted once, on the live link (or, when the slot has none yet, in ``unlinked``):
trying a candidate never inflates the drop counters. Work per envelope is bounded by
``MAX_CANDIDATES`` + 2 AEAD attempts.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

from zdrone.core.envelope import Dropped, DropReason, Opened, SecureLink
from zdrone.core.tbm import LinkState

MAX_CANDIDATES = 3
#: Origins of keys that only the peer itself can prove (its own re-pairing): they may replace a live
#: key that is still alive. Every other origin waits for the live link to be LOST.
SELF_ORIGINS = frozenset({"pair"})
CANDIDATE_TTL = 30.0
PREVIOUS_GRACE = 3.0


def replaces_live(origin: str, live: LinkState | None) -> bool:
    """The key-confirmation rule: may a proven candidate of ``origin`` become live, the live link
    being in state ``live`` (None: no live key)? Always with no live key or for the peer's own
    re-pairing (``SELF_ORIGINS``). A key the authority granted (``grant``, on the drone) never
    replaces a live key: the authority grants only keys the drone lacks, so a grant over a live key
    can only be someone using the authority's position against another GS. A secret this GS handed
    out over the backhaul (``linkkey:<asker>``) replaces its live key only once that link is LOST (the
    drone restarted and lost the old key; the GS answers no query while its link is alive)."""
    if live is None or origin in SELF_ORIGINS:
        return True
    return origin != "grant" and live is LinkState.LOST


@dataclass(slots=True)
class _Candidate:
    link: SecureLink
    expires: float
    origin: str


@dataclass(frozen=True, slots=True)
class Promoted:
    """The envelope just opened proved a candidate key; it is now the live one."""

    origin: str
    replaced: bool  # a live key existed and was replaced


@dataclass
class LinkSlot:
    """The keys of one (drone, gs) link at one end."""

    live: SecureLink | None = None
    candidates: list[_Candidate] = field(default_factory=list)
    previous: SecureLink | None = None
    previous_until: float = 0.0
    unlinked: Counter = field(default_factory=Counter)  # drops while no live key exists
    expired: int = 0
    live_protected: int = 0  # authentic frames under a third party's candidate refused: the live link is alive
    fallback: SecureLink | None = None  # a LOST live key a third party's key replaced: the peer may still use it
    hybrid_only: bool = False  # the fleet requires hybrid keys: no classical key becomes live (``require_hybrid``)
    classical_refused: int = 0  # classical keys offered while ``hybrid_only``: refused

    def may_replace_live(self, origin: str, now: float) -> bool:
        """Whether a candidate of ``origin`` may replace the live key now (``replaces_live``)."""
        return replaces_live(origin, None if self.live is None else self.live.tbm.state(now))

    def install(self, link: SecureLink, now: float) -> None:
        """Make ``link`` live at once (a key this end chose and the peer proved, or the first key
        of a link that has none); the replaced key stays readable for a grace period."""
        if self.live is not None:
            link.tbm.carry_over(self.live.tbm)
            self.previous, self.previous_until = self.live, now + PREVIOUS_GRACE
        self.live = link
        self.candidates.clear()
        self.fallback = None  # a key this end installed or the peer proved: nothing to go back to

    def require_hybrid(self, on: bool) -> list[str]:
        """The fleet requires hybrid keys (``on``) or no longer does. On: every classical key that is
        not live is dropped at once, and what was dropped is said (``"candidate"`` once per key,
        ``"fallback"``); the live key stays until a hybrid one replaces it."""
        self.hybrid_only = on
        if not on:
            return []
        dropped = ["candidate" for c in self.candidates if not c.link.hybrid]
        self.candidates = [c for c in self.candidates if c.link.hybrid]
        if self.fallback is not None and not self.fallback.hybrid:
            self.fallback = None
            dropped.append("fallback")
        return dropped

    def offer(self, link: SecureLink, now: float, origin: str, ttl: float = CANDIDATE_TTL) -> bool:
        """Add a candidate key. It replaces an earlier candidate of the same origin (each origin
        only ever means its newest key); the oldest is forgotten beyond ``MAX_CANDIDATES``. A
        classical key is refused (False) while the slot requires hybrid keys."""
        if self.hybrid_only and not link.hybrid:
            self.classical_refused += 1
            return False
        self.expire(now)
        replaced = [c for c in self.candidates if c.origin == origin]
        if replaced:
            self.candidates = [c for c in self.candidates if c.origin != origin]
            self.expired += len(replaced)
        self.candidates.append(_Candidate(link, now + ttl, origin))
        if len(self.candidates) > MAX_CANDIDATES:
            self.candidates.pop(0)
            self.expired += 1
        return True

    def expire(self, now: float) -> None:
        before = len(self.candidates)
        self.candidates = [c for c in self.candidates if c.expires > now]
        self.expired += before - len(self.candidates)
        self.end_grace(now)

    def end_grace(self, now: float) -> None:
        """The key replaced last is wiped once its grace is over."""
        if self.previous is not None and now >= self.previous_until:
            self.previous = None

    def open(self, data: bytes, now: float) -> tuple[Opened | Dropped, Promoted | None]:
        """Open one envelope from the peer; say whether it proved (and promoted) a candidate."""
        first: Dropped | None = None
        self.end_grace(now)  # even while the live key opens everything
        if self.live is not None:
            res = self.live.open(data, now, count=False)
            if isinstance(res, Opened):
                return res, None
            if res.reason not in _BEFORE_AUTH:  # authentic key, failed a later check: ``open`` counted it
                return res, None
            first = res
        if self.candidates or self.previous is not None:
            self.expire(now)
        for cand in self.candidates:
            res = cand.link.open(data, now, count=False)
            if isinstance(res, Opened):
                if not self.may_replace_live(cand.origin, now):
                    self.live_protected += 1  # authentic under a third party's key while ours is alive
                    dropped = Dropped(DropReason.AUTH_FAILED, "candidate refused: the live link is alive")
                    assert self.live is not None
                    self.live.count_drop(dropped)
                    return dropped, None
                replaced = self.live is not None
                keep = self.fallback or self.live  # the key before any third party's: the peer's own
                self.install(cand.link, now)
                if keep is not None and cand.origin not in SELF_ORIGINS:
                    # a third party's key replaced a LOST live key: whoever proved it also knew it (the
                    # asker of a key-sharing query does), so the key before it stays a fallback — the
                    # first authentic frame of the peer under it takes it back (``revert``)
                    self.fallback, self.previous = keep, None
                return res, Promoted(cand.origin, replaced)
            if res.reason not in _BEFORE_AUTH:  # counted by ``open`` on the candidate's link
                return res, None
            first = first or res
        if self.previous is not None:
            res = self.previous.open(data, now, count=False)
            if isinstance(res, Opened):
                return res, None
        if self.fallback is not None:
            res = self.fallback.open(data, now, count=False)
            if isinstance(res, Opened):  # the peer still speaks under the key a third party's replaced
                back, self.fallback = self.fallback, None
                self.install(back, now)
                return res, Promoted("revert", True)
        dropped = first or Dropped(DropReason.AUTH_FAILED, "no key for this link")
        if self.live is not None:
            self.live.count_drop(dropped)
        else:
            self.unlinked[dropped.reason] += 1
        return dropped, None


_BEFORE_AUTH = frozenset({DropReason.MALFORMED, DropReason.UNKNOWN_EPOCH, DropReason.AUTH_FAILED})
