"""TESTBED ONLY: radio coverage emulation for software-in-the-loop flights.

Frames between the drone and a GS pass only while the vehicle is inside that GS's coverage circle
(from fleet.json5), judged from the vehicle's reported position (the built-in simulator reports its
true position unless ``--gps-noise`` is set). The drone node applies the gate to what it receives
and what it sends when started with ``--sil-coverage``; frames it stops are counted as
``out_of_coverage``, never lost silently. A real deployment has real radios and no such gate.
"""

from __future__ import annotations

from collections import Counter

from zdrone.core.fleet import Fleet
from zdrone.core.geometry import Circle, GeoPoint


class CoverageGate:
    """Decides whether the emulated radio link between the vehicle and a GS exists right now."""

    def __init__(self, fleet: Fleet) -> None:
        self.circles: dict[str, Circle] = {
            name: node.coverage.circle() for name, node in fleet.nodes.items() if node.role == "gs" and node.coverage
        }
        self.position: GeoPoint | None = None
        self._reach: dict[str, bool] = {}  # GS -> in reach of ``position``
        self.blocked: Counter[str] = Counter()
        self.jammed = False  # the radio cut whatever the position (``zdrone bench revoke``'s drone out of reach)

    def update(self, position: GeoPoint | None) -> None:
        if position != self.position:
            self.position = position
            self._reach.clear()  # each GS's answer computed again on first use

    def reaches(self, gs: str) -> bool:
        if self.jammed:
            return False
        got = self._reach.get(gs)
        if got is None:
            circle = self.circles.get(gs)
            # nothing known yet: do not invent an outage
            got = self._reach[gs] = circle is None or self.position is None or circle.contains(self.position)
        return got

    def allow(self, gs: str, direction: str) -> bool:
        if self.reaches(gs):
            return True
        self.blocked[f"{direction}:{gs}"] += 1
        return False
