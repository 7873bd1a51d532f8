"""Flat-earth geometry around a reference point: good to centimetres over a few kilometres."""

from __future__ import annotations

import math
from dataclasses import dataclass

EARTH_RADIUS_M = 6_371_000.0


@dataclass(frozen=True, slots=True)
class GeoPoint:
    lat: float
    lon: float
    alt: float = 0.0  # metres above home


def offset(origin: GeoPoint, north_m: float, east_m: float, up_m: float = 0.0) -> GeoPoint:
    """The point ``north_m``/``east_m``/``up_m`` metres from ``origin``."""
    dlat = math.degrees(north_m / EARTH_RADIUS_M)
    dlon = math.degrees(east_m / (EARTH_RADIUS_M * math.cos(math.radians(origin.lat))))
    return GeoPoint(origin.lat + dlat, origin.lon + dlon, origin.alt + up_m)


def ne_of(origin: GeoPoint, p: GeoPoint) -> tuple[float, float]:
    """(north, east) metres of ``p`` relative to ``origin``."""
    north = math.radians(p.lat - origin.lat) * EARTH_RADIUS_M
    east = math.radians(p.lon - origin.lon) * EARTH_RADIUS_M * math.cos(math.radians(origin.lat))
    return north, east


def distance_m(a: GeoPoint, b: GeoPoint) -> float:
    """Horizontal distance between two points (metres)."""
    n, e = ne_of(a, b)
    return math.hypot(n, e)


@dataclass(frozen=True, slots=True)
class Circle:
    """A coverage circle on the ground."""

    centre: GeoPoint
    radius_m: float

    def contains(self, p: GeoPoint) -> bool:
        return distance_m(self.centre, p) <= self.radius_m
