"""A route checked before take-off: does a mission stay inside the authorized GSs' coverage, and does
every crossing from one GS's coverage to the next leave time for a make-before-break hand-over?

Theory of operation
-------------------
The route is the mission's path on the ground: from home, through every navigation item that has a
position, in order (a return to launch goes home); its speed is the mission's cruise speed (its last
``DO_CHANGE_SPEED`` before the leg, else the default). Along it, each authorized GS covers a set of
stretches (its coverage circle cut by each straight leg, found exactly, not sampled). The drone is with
one GS at a time; it stays with it as long as it covers the drone and then must already be inside the
next one's coverage, with the two covering the route together for at least ``HANDOVER_OVERLAP_S`` at
the cruise speed (the hand-over, started on entering the overlap, is proven and done in it, or times
out and leaves authority where it was: ``zdrone.core.authority``'s hand-over timeout). The next GS is
the one that overlaps long enough and reaches furthest (greedy: it is optimal for covering a line by
intervals). The first place where no GS covers the route, or where the next GS's overlap is too short,
is the route's first bad segment (where along the route, which leg, between which GSs, how short).

Pure: no I/O, no clock; ``check_route`` takes the route and the circles and returns a ``RouteReport``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from zdrone.core.geometry import Circle, GeoPoint, ne_of, offset

#: A crossing from one GS to the next needs the two coverages to overlap this long at cruise speed:
#: the hand-over's own timeout (``authority.DEFAULT_HANDOVER_TIMEOUT``), so it completes inside.
HANDOVER_OVERLAP_S = 5.0
#: MAVLink commands that move the vehicle to a position (their lat/lon are a point of the route).
NAV_WITH_POSITION = frozenset({16, 17, 18, 19, 21, 22, 31, 82, 84, 85})  # WAYPOINT, LOITER_*, LAND, TAKEOFF, ...
RETURN_TO_LAUNCH = 20
CHANGE_SPEED = 178
#: Two stretches this close are one (the numerics of a circle cut at a shared waypoint).
EPS_M = 0.01


@dataclass(frozen=True, slots=True)
class Leg:
    """One straight leg of the route: from ``a`` to ``b``, ``start_m`` metres along the route."""

    index: int
    a: GeoPoint
    b: GeoPoint
    start_m: float
    length_m: float
    speed_ms: float


@dataclass(frozen=True, slots=True)
class RouteProblem:
    """The first bad segment: ``kind`` is ``uncovered`` (no authorized GS covers the route from
    ``at_m``) or ``short_overlap`` (from ``from_gs`` to ``to_gs`` the coverages overlap ``overlap_m``,
    a hand-over needs ``need_m``)."""

    kind: str
    at_m: float
    leg: int
    where: GeoPoint
    from_gs: str | None = None
    to_gs: str | None = None
    overlap_m: float = 0.0
    need_m: float = 0.0
    until_m: float | None = None  # uncovered: where coverage comes back (None: never)

    def describe(self) -> str:
        place = (f"leg {self.leg + 1} (waypoint {self.leg} -> {self.leg + 1}), {self.at_m / 1000:.3f} km along the "
                 f"route ({self.where.lat:.6f},{self.where.lon:.6f})")
        if self.kind == "uncovered":
            gap = f"for {self.until_m - self.at_m:.0f} m" if self.until_m is not None else "to its end"
            after = f" after {self.from_gs}" if self.from_gs else ""
            return f"{place}: leaves every authorized GS's coverage{after} {gap}"
        return (f"{place}: from {self.from_gs} to {self.to_gs} the coverages overlap {self.overlap_m:.0f} m, a "
                f"hand-over needs {self.need_m:.0f} m ({HANDOVER_OVERLAP_S:g} s at cruise speed)")


@dataclass(frozen=True, slots=True)
class RouteReport:
    """The route's length, the GSs in the order the drone is with them and where each hand-over's
    overlap lies, or the first problem."""

    length_m: float
    chain: tuple[tuple[str, float, float], ...]  # (GS, from m, to m) the drone is with it
    problem: RouteProblem | None

    @property
    def ok(self) -> bool:
        return self.problem is None


def route_of(items: list, home: GeoPoint | None, default_speed: float) -> list[Leg]:
    """The legs of a mission (``gs.planner.PlannedItem``-like: command, params, lat, lon) from ``home``
    (None: from its first item with a position, where it takes off; a return to launch goes there)."""
    points: list[tuple[GeoPoint, float]] = []
    speed = default_speed
    for it in items:
        if it.command == CHANGE_SPEED and len(it.params) > 1 and it.params[1] > 0:
            speed = float(it.params[1])
        elif it.command == RETURN_TO_LAUNCH:
            points.append((home, speed))  # type: ignore[arg-type]  # None: the first point, set below
        elif it.command in NAV_WITH_POSITION and not (math.isnan(it.lat) or math.isnan(it.lon)) \
                and (it.lat, it.lon) != (0.0, 0.0):
            points.append((GeoPoint(it.lat, it.lon), speed))
    if home is None:
        if not points:
            return []
        home = points[0][0]
        points = [(home if p is None else p, v) for p, v in points]
    legs: list[Leg] = []
    here, along = home, 0.0
    for p, v in points:
        n, e = ne_of(here, p)
        length = math.hypot(n, e)
        if length > EPS_M:
            legs.append(Leg(len(legs), here, p, along, length, v))
            along += length
            here = p
    return legs


def _cut(leg: Leg, c: Circle) -> tuple[float, float] | None:
    """The stretch of ``leg`` inside ``c`` (metres along the route), or None."""
    n0, e0 = ne_of(c.centre, leg.a)
    n1, e1 = ne_of(c.centre, leg.b)
    dn, de = (n1 - n0) / leg.length_m, (e1 - e0) / leg.length_m  # unit direction
    # |p0 + t d|^2 = r^2  ->  t^2 + 2 t (p0.d) + |p0|^2 - r^2 = 0
    b = n0 * dn + e0 * de
    cc = n0 * n0 + e0 * e0 - c.radius_m * c.radius_m
    disc = b * b - cc
    if disc < 0:
        return None
    root = math.sqrt(disc)
    t0, t1 = max(-b - root, 0.0), min(-b + root, leg.length_m)
    if t1 < t0:
        return None
    return leg.start_m + t0, leg.start_m + t1


def coverage_along(legs: list[Leg], circles: dict[str, Circle]) -> dict[str, list[tuple[float, float]]]:
    """Each GS's stretches of the route (merged where they touch), in order."""
    out: dict[str, list[tuple[float, float]]] = {}
    for g, c in sorted(circles.items()):
        spans = sorted(s for leg in legs if (s := _cut(leg, c)) is not None)
        merged: list[tuple[float, float]] = []
        for a, b in spans:
            if merged and a <= merged[-1][1] + EPS_M:
                merged[-1] = (merged[-1][0], max(merged[-1][1], b))
            else:
                merged.append((a, b))
        if merged:
            out[g] = merged
    return out


def _at(legs: list[Leg], m: float) -> tuple[int, GeoPoint, float]:
    """The leg, the point and the cruise speed ``m`` metres along the route."""
    for leg in legs:
        if m <= leg.start_m + leg.length_m + EPS_M or leg is legs[-1]:
            t = min(max(m - leg.start_m, 0.0), leg.length_m) / leg.length_m
            n, e = ne_of(leg.a, leg.b)
            return leg.index, offset(leg.a, n * t, e * t), leg.speed_ms
    raise ValueError("a route without legs")


def check_route(legs: list[Leg], circles: dict[str, Circle], overlap_s: float = HANDOVER_OVERLAP_S) -> RouteReport:
    """The route's first bad segment, if any (see the module's theory of operation)."""
    if not legs:
        return RouteReport(0.0, (), None)
    total = legs[-1].start_m + legs[-1].length_m
    spans = coverage_along(legs, circles)

    def uncovered(at: float, after: str | None) -> RouteReport:
        back = min((a for ss in spans.values() for a, _ in ss if a > at + EPS_M), default=None)
        leg, where, _ = _at(legs, at)
        return RouteReport(total, tuple(chain), RouteProblem("uncovered", at, leg, where, from_gs=after, until_m=back))

    chain: list[tuple[str, float, float]] = []
    # the GS the drone starts with: one covering home that reaches furthest
    first = [(b, g) for g, ss in spans.items() for a, b in ss if a <= EPS_M]
    if not first:
        return uncovered(0.0, None)
    end, gs = max(first)
    start = 0.0
    while end < total - EPS_M:
        _, _, speed = _at(legs, end)
        need = speed * overlap_s
        best: tuple[float, str, float] | None = None  # (reaches, GS, overlap)
        shortest: tuple[float, str] | None = None
        for g, ss in spans.items():
            if g == gs:
                continue
            for a, b in ss:
                if a <= end + EPS_M and b > end + EPS_M:  # it covers the route where ours ends, and beyond
                    overlap = end - max(a, start)
                    if overlap + EPS_M >= need:
                        if best is None or b > best[0]:
                            best = (b, g, overlap)
                    elif shortest is None or overlap > shortest[0]:
                        shortest = (overlap, g)
        if best is None:
            if shortest is None:
                chain.append((gs, start, end))
                return uncovered(end, gs)
            overlap, g = shortest
            leg, where, _ = _at(legs, end - overlap)
            chain.append((gs, start, end))
            return RouteReport(total, tuple(chain), RouteProblem("short_overlap", end - overlap, leg, where, gs, g,
                                                                 overlap, need))
        reach, nxt, overlap = best
        chain.append((gs, start, end))
        start, end, gs = end - overlap, reach, nxt
    chain.append((gs, start, total))
    return RouteReport(total, tuple(chain), None)


def check_mission(items: list, fleet: object, drone: str, home: GeoPoint | None, default_speed: float,
                  overlap_s: float = HANDOVER_OVERLAP_S) -> RouteReport:
    """``check_route`` of a mission for ``drone`` over the coverages of the GSs authorized for it in
    ``fleet`` (a ``zdrone.core.fleet.Fleet``; revoked GSs cover nothing)."""
    circles = {g: fleet.nodes[g].coverage.circle()  # type: ignore[attr-defined]
               for g in fleet.nodes[drone].authorized_gs  # type: ignore[attr-defined]
               if fleet.is_authorized(drone, g) and fleet.nodes[g].coverage is not None}  # type: ignore[attr-defined]
    return check_route(route_of(items, home, default_speed), circles, overlap_s)
