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

How late a host steps its drones is measured, in both halves alike: ``started(i, now)`` notes, as a
drone's step begins, how long after its deadline (or the input that brought it forward) that is. A
saturated host steps late; the figure shows by how much (``StepLateness``: p50, p99, max).

``StepSchedule`` is pure: a heap of (due, drone); ``now`` is passed in.
"""

from __future__ import annotations

import heapq
import math

#: A drone is stepped again this long after its last step at the soonest, whatever it says is due
#: (a deadline already past, e.g. a core timer the step did not move, must not spin the host).
MIN_STEP_GAP_S = 0.002


#: At most this many lateness samples are kept; past it every other one is dropped and only every
#: second one taken from then on (a uniform sample of the whole flight in bounded memory).
LATENESS_SAMPLES = 50_000


class StepLateness:
    """How late the steps began after they were due, in seconds: a bounded uniform sample."""

    def __init__(self) -> None:
        self.samples: list[float] = []
        self.n = 0  # steps noted, in all
        self._stride = 1
        self.worst = 0.0

    def add(self, late: float) -> None:
        late = max(0.0, late)
        self.worst = max(self.worst, late)
        if self.n % self._stride == 0:
            self.samples.append(late)
            if len(self.samples) >= LATENESS_SAMPLES:
                self.samples = self.samples[::2]
                self._stride *= 2
        self.n += 1

    def report(self) -> dict[str, float | int | None]:
        """p50, p99 and max in ms (None: nothing noted)."""
        xs = sorted(self.samples)
        if not xs:
            return {"n": 0, "p50_ms": None, "p99_ms": None, "max_ms": None}
        pick = lambda q: round(1000.0 * xs[min(len(xs) - 1, int(q * len(xs)))], 2)  # noqa: E731
        return {"n": self.n, "p50_ms": pick(0.50), "p99_ms": pick(0.99), "max_ms": round(1000.0 * self.worst, 2)}


def worst_lateness(parts: list[dict | None]) -> dict | None:
    """Of several drones hosts' step lateness (``StepLateness.report``), the latest host's (by p99)."""
    known = [x for x in parts if x and x.get("p99_ms") is not None]
    return max(known, key=lambda x: x["p99_ms"]) if known else None


class StepSchedule:
    """Which drones (by index) are due now; each has one deadline, moved by ``set`` or ``bring_forward``."""

    def __init__(self, n: int, now: float = 0.0) -> None:
        self.due = [now] * n
        self._heap = [(now, i) for i in range(n)]
        heapq.heapify(self._heap)
        self.steps = 0  # drones taken, in all
        self._taken_due = [now] * n  # the deadline each drone was taken at
        self.lateness = StepLateness()

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
                self._taken_due[i] = t
                out.append(i)
        self.steps += len(out)
        return out

    def started(self, i: int, now: float) -> None:
        """Drone ``i``'s step (taken by ``take``) begins at ``now``: how late that is, noted."""
        self.lateness.add(now - self._taken_due[i])

    def next_due(self) -> float:
        """The soonest deadline (inf if none)."""
        heap, due = self._heap, self.due
        while heap and heap[0][0] != due[heap[0][1]]:
            heapq.heappop(heap)
        return heap[0][0] if heap else math.inf
