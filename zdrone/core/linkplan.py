"""Links that follow the drone: which ground stations a drone holds live links with, sans-IO.

Theory of operation
-------------------
A drone authorized for more GSs than the fleet's ``links_max`` (``Fleet.links_follow``; 3 by default)
does not keep a link with each for the whole flight, as a beyond-line-of-sight corridor of twenty GSs
would need: it holds links only with the GSs that cover it and the next one (or two) on its course,
prepared ahead, and closes a link it has left behind. A drone authorized for ``links_max`` GSs or
fewer keeps a link with each, as before (each is within the bound).

Each end decides only from what it knows first-hand:

* **The owner prepares** (``plan_links``). From the drone's position and course as the drone's own
  telemetry reports them, under the owner's link, it wants links for the GSs whose coverage holds the
  drone (every heir is one) and then for the GSs whose coverage the course enters within ``ahead_m``
  (the course's ground speed times ``AHEAD_S``, at least ``AHEAD_MIN_M``), nearest entry first, up to
  ``links_max`` counting itself. Only for those does it share keys (key sharing, unchanged: the other
  GS makes its key, the drone proves it); a GS it no longer wants is not asked again.
* **The drone closes** (``LinkGrace``). A link the authority machine allows to close
  (``AuthorityMachine.may_close``: not the owner's, not a pending recipient's, a consent window's or a
  first claim's, not a GS whose coverage holds the drone by its own GPS, never in FAILSAFE) is closed
  once it has stayed closable ``GRACE_S`` (a GS left behind, or a prepared one the drone never
  reached), or at once, oldest closable first, when a new link needs room under ``links_max``. The
  drone tells the GS (``wire.LinkClosed``, under that link's key, its last frame on it) and wipes its
  key; the GS wipes its end and stops its heartbeats. A grant or a pairing that would pass
  ``links_max`` with nothing closable is refused (``links_full``): the owner's own plan never asks for
  more, so only a plan gone stale or someone else's pairing meets it.

Whose word counts. The owner's plan rests on the drone's position and course, which reach it sealed
by the drone: a GS cannot make another prepare or close a link by claiming where the drone is. The
close rule rests on the drone's own GPS and its authority machine: what a GS says cannot make the
drone close an heir's link. A GS off the course is simply not prepared; it may still pair on its
operator's request, within the pairing rules and ``links_max``.

Pure: no I/O, no clock (``now`` comes in).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from zdrone.core.geometry import Circle, GeoPoint, distance_m, offset
from zdrone.core.routecheck import Leg, coverage_along

#: The owner prepares the GSs whose coverage the drone's course enters within this many seconds at its
#: ground speed ...
AHEAD_S = 60.0
#: ... and at least this far ahead (a slow or hovering drone still prepares the GS about to cover it).
AHEAD_MIN_M = 300.0
#: Below this ground speed (m/s) the drone has no course to look along: only the covering GSs.
COURSE_MIN_MS = 0.5
#: A closable link is closed after this long (drone's seconds): long enough that a GS prepared ahead at
#: ``AHEAD_S`` is reached before its link is let go at speed-up 1; a link needed for room goes at once.
GRACE_S = 90.0


@dataclass(frozen=True, slots=True)
class LinkPlan:
    """The owner's plan for one drone: the GSs covering it (nearest centre first), those its course
    enters next (nearest entry first), and the links it wants (itself first), at most ``links_max``."""

    covering: tuple[str, ...]
    ahead: tuple[str, ...]
    wanted: tuple[str, ...]


def plan_links(me: str, others: list[str], circles: dict[str, Circle], here: GeoPoint,
               course: tuple[float, float] | None, links_max: int, ahead_s: float = AHEAD_S,
               ahead_min_m: float = AHEAD_MIN_M) -> LinkPlan:
    """The links owner ``me`` wants for a drone at ``here`` moving at ``course`` (north, east m/s; None:
    unknown), among ``others`` (the other GSs authorized for it) whose coverage ``circles`` gives."""
    cands = [g for g in others if g != me and g in circles]
    covering = sorted((g for g in cands if circles[g].contains(here)), key=lambda g: (distance_m(circles[g].centre, here), g))
    ahead: list[str] = []
    speed = math.hypot(*course) if course is not None else 0.0
    if course is not None and speed >= COURSE_MIN_MS:
        reach = max(ahead_min_m, speed * ahead_s)
        end = offset(here, course[0] / speed * reach, course[1] / speed * reach)
        spans = coverage_along([Leg(0, here, end, 0.0, reach, speed)],
                               {g: circles[g] for g in cands if g not in covering})
        ahead = [g for _, g in sorted((s[0][0], g) for g, s in spans.items())]
    wanted = [me, *covering, *ahead][:max(1, links_max)]
    return LinkPlan(tuple(covering), tuple(ahead), tuple(wanted))


@dataclass
class LinkGrace:
    """The drone's clock on its closable links: since when each has been closable (``update`` with the
    set ``AuthorityMachine.may_close`` allows), which are due to close (``due``), which goes first when
    room is needed (``oldest``)."""

    grace_s: float = GRACE_S
    since: dict[str, float] = field(default_factory=dict)

    def update(self, closable: set[str] | frozenset[str], now: float) -> None:
        for g in [g for g in self.since if g not in closable]:
            del self.since[g]
        for g in closable:
            self.since.setdefault(g, now)

    def due(self, now: float) -> list[str]:
        """The links closable for ``grace_s`` at ``now``, longest first."""
        return [g for g, t in sorted(self.since.items(), key=lambda kv: (kv[1], kv[0])) if now - t >= self.grace_s]

    def oldest(self, besides: str | None = None) -> str | None:
        """The link closable longest (not ``besides``), None if none is."""
        found = sorted((t, g) for g, t in self.since.items() if g != besides)
        return found[0][1] if found else None

    def next_due(self) -> float | None:
        return min(self.since.values()) + self.grace_s if self.since else None

    def forget(self, gs: str) -> None:
        self.since.pop(gs, None)
