"""When a bench host steps each of its drones (testbed): at the drone's own next deadline, or when an
input comes, as a drone's loop does on its own companion computer, not every drone on every pass.

A host process that steps hundreds of drones in turn used to step each one every pass (a pass every
``scalehosts.PASS_S`` at most): a drone with nothing due was stepped anyway, so its fixed cost (the
simulator's step, the node's polls) was paid a hundred times a second at one drone, and the CPU per
drone fell as the fleet grew, since a pass over more drones comes round less often. Now each drone
says when it next has something to do (``DroneNode.next_deadline``: its vehicle's next frame, its
core's timer, its status; the bare half's drone: its vehicle's next frame, its take-off) and is
stepped then; an input (a GS's frame, handed over between steps as before) brings it forward. Both
halves of ``bench overhead`` step their drones by this rule.

``StepSchedule`` is pure: a heap of (due, drone); ``now`` is passed in.
"""

from __future__ import annotations

import heapq
import math

#: A drone is stepped again this long after its last step at the soonest, whatever it says is due
#: (a deadline already past, e.g. a core timer the step did not move, must not spin the host).
MIN_STEP_GAP_S = 0.002


class StepSchedule:
    """Which drones (by index) are due now; each has one deadline, moved by ``set`` or ``bring_forward``."""

    def __init__(self, n: int, now: float = 0.0) -> None:
        self.due = [now] * n
        self._heap = [(now, i) for i in range(n)]
        heapq.heapify(self._heap)
        self.steps = 0  # drones taken, in all

    def set(self, i: int, due: float) -> None:
        """Drone ``i``'s next deadline (after its step)."""
        self.due[i] = due
        heapq.heappush(self._heap, (due, i))

    def bring_forward(self, i: int, due: float) -> None:
        """An input came for drone ``i``: its deadline moves to ``due`` if that is sooner."""
        if due < self.due[i]:
            self.set(i, due)

    def take(self, now: float) -> list[int]:
        """The drones due at ``now``, soonest first; each is not due again until ``set``."""
        out = []
        heap, due = self._heap, self.due
        while heap and heap[0][0] <= now:
            t, i = heapq.heappop(heap)
            if t == due[i]:  # else a deadline since moved: its entry is stale
                due[i] = math.inf
                out.append(i)
        self.steps += len(out)
        return out

    def next_due(self) -> float:
        """The soonest deadline (inf if none)."""
        heap, due = self._heap, self.due
        while heap and heap[0][0] != due[heap[0][1]]:
            heapq.heappop(heap)
        return heap[0][0] if heap else math.inf
