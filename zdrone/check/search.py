"""The model checker's search: breadth-first exploration of every interleaving of an explorer's
moves from a start state, with the first violation's shortest trace (``Violation``). Each world
(``abstract``, ``consent``, ``cores``) brings its own state, moves and invariants."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Any, Callable


@dataclass(frozen=True)
class Violation:
    invariant: str
    detail: str
    trace: tuple[str, ...]


class _Broken(Exception):
    def __init__(self, invariant: str, detail: str) -> None:
        super().__init__(detail)
        self.invariant, self.detail = invariant, detail


def breadth_first(explorer: Any, start: Any, check: Callable[[Any, Any], None] | None = None) -> Violation | None:
    """Every interleaving of ``explorer.moves`` from ``start``, breadth-first up to ``explorer.depth``
    moves, states told apart by their ``key()``: the first violation (a move or ``check(after, before)``
    raising ``_Broken``) with its trace, the shortest there is, or None. Counts states, transitions and
    the depth reached on the explorer."""
    seen = {start.key()}
    frontier: deque[tuple[Any, tuple[str, ...]]] = deque([(start, ())])
    while frontier:
        w, trace = frontier.popleft()
        if len(trace) >= explorer.depth:
            continue
        for label, move in explorer.moves(w):
            nxt = w.clone()
            explorer.transitions += 1
            try:
                move(nxt)
                if check is not None:
                    check(nxt, w)
            except _Broken as b:
                explorer.states = len(seen)
                return Violation(b.invariant, b.detail, trace + (label,))
            k = nxt.key()
            if k in seen:
                continue
            seen.add(k)
            explorer.max_depth_reached = max(explorer.max_depth_reached, len(trace) + 1)
            frontier.append((nxt, trace + (label,)))
            if explorer.max_states is not None and len(seen) >= explorer.max_states:
                explorer.states = len(seen)
                return None
    explorer.states = len(seen)
    return None
