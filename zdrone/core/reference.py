"""The reference geography and fleet of the testbed (defaults of ``zdrone fleet init``).

GS A sits at the take-off point; GS B 500 m east; both cover 350 m, so the hand-over region is the
band 150..350 m east of A. The delivery point is at B. The rogue GS X is in the fleet but not on
d1's authorized list. V is the viewer: it reads the GSs' operations pictures, nothing else.
"""

from __future__ import annotations

from zdrone.core.geometry import GeoPoint, offset

HOME = GeoPoint(47.397742, 8.545594, 0.0)
COVERAGE_RADIUS_M = 350.0
GS_A = HOME
GS_B = offset(HOME, 0.0, 500.0)
DELIVERY = GS_B
CRUISE_ALT_M = 30.0
CRUISE_SPEED_MS = 12.0

#: (name, role, sysid, coverage centre or None, authorized list)
DEFAULT_NODES: list[tuple[str, str, int, GeoPoint | None, list[str]]] = [
    ("d1", "drone", 1, None, ["A", "B"]),
    ("A", "gs", 4, GS_A, []),
    ("B", "gs", 3, GS_B, []),
    ("X", "gs", 7, HOME, []),
    ("V", "viewer", 250, None, []),  # the fleet's viewer (``zdrone view``): reads only
]
