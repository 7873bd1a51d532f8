"""One way to write a state machine: a table, its lookup, the check of every move, one log line per move.

Theory of operation
-------------------
The protocol's machines (the drone's handover authority, ``zdrone.core.authority``; the ground
station's hand-over, key hold, linking and mission, ``gs.handover``, ``gs.keyhold``, ``gs.linking``,
``gs.mission``) are each an object holding a state (a member of its enum), fed frozen events that
carry the time, and a table::

    (state, event type) -> (handler, allowed)

``allowed`` is the set of states the handler may leave the machine in (a ``frozenset``); a row may
name one state alone instead: the state the machine goes to once its handler has run. The machines
are pure (no clock, no IO): what a step decides is its return value.

One step, as a machine built on ``Machine`` takes it:

1. **Lookup** (``_row``): the row of (current state, type of the event). A pair missing from the table
   has no handler, and what that means is the machine's to say, never the engine's: "nothing to do"
   (``Handover.handle`` returns False, ``KeyHold.handle`` None, ``Mission.handle`` an empty list), a
   ``Reject`` answered to the peer that sent it, or ``IllegalTransition`` raised for an event of our
   own that no row covers (``AuthorityMachine.handle``).
2. **The handler** runs. It moves the machine in one of two ways, each checked against the row:

   * it calls ``_set_state(new, reason)`` (the GS's machines): each move must be to a state of the
     row; staying where the machine is is no move, neither checked nor logged;
   * it returns the state it chooses with its outputs, ``(state, outputs)`` (the authority machine),
     and ``_step`` enters it through ``_move``: the choice must be a state of the row, *staying
     included*: such a row lists every state its step may end in.

   A move outside the row raises ``IllegalTransition``: a programming error of ours, one class for
   every machine (what a peer sends is never raised: a machine drops it, counted, or answers it).
3. **Settle rules** (``_settle``, optional): rules that follow from the state and the time alone,
   looked at once after the handler, whatever the event was (as h11's state-triggered transitions:
   a hand-over completes when its recipient is proven, whichever event proved it). Each is a row
   ``(states it applies in, rule, allowed)``; the first rule that fires (returns ``(state, outputs)``
   rather than None) applies, its choice checked as a handler's.
4. **Effects** (optional): what follows from the state change is computed once, from what ``_before()``
   saw before the step and the machine after it (``_effects(before)``), never appended by handlers.

Steps 3 and 4 are ``_step``'s, for machines whose handlers return their choice; the others compose
steps 1 and 2 in their own ``handle``.

A move outside any row (a restart restoring the state it had, an exchange whose deadline passed
before the lookup) names the states its own rule allows: ``_set_state(new, allowed=...)``, or
``_move(rule, state, allowed, now)`` for a choosing machine.

Every move is logged once, by the machine's own logger (``_log``) at its own level (``_log_level``),
as ``<name>: <old> -> <new>`` and `` (<reason>)`` when the caller gives a reason or the machine has
a note for every move (``_state_note``). ``_machine_name`` says which machine (and which drone) it is.

Where the state lives: the attribute ``_state_attr``; a machine whose table applies to several parts
at once (``gs.linking``: one key-sharing exchange per other GS, next to its pairing exchange) names
the part with ``key`` and says where each part's state is (``_get_state`` / ``_put_state``).
``_put_state`` is also where a machine keeps what goes with a move (``gs.mission``: when the stage
began, the ``now`` of the move).
"""

from __future__ import annotations

import enum
import logging
from typing import Any, Callable, ClassVar, Hashable, Iterable, Mapping, TypeVar, Union

from zdrone.core.errors import ProtocolError

log = logging.getLogger(__name__)

S = TypeVar("S", bound=enum.Enum)

Handler = Callable[..., Any]
#: (handler, the states it may leave the machine in); one state alone: where the machine goes
Row = tuple[Handler, Union[frozenset[S], S]]
#: (state, event type) -> row
Table = Mapping[tuple[S, type], Row[S]]
#: (states the rule applies in, rule(machine, now) -> (state, outputs) or None, the states it may choose)
SettleRow = tuple[frozenset[S], Callable[..., Any], frozenset[S]]


class IllegalTransition(ProtocolError, AssertionError):
    """A move no table row allows, or an event of our own that no row covers: a programming error,
    raised. (Also an ``AssertionError``: the GS machines' checks are assertions of the code's own
    consistency.)"""


def allowed_states(allowed: Any) -> frozenset[Any]:
    """A row's allowed states as a set (a row naming one state allows that one)."""
    return allowed if isinstance(allowed, frozenset) else frozenset((allowed,))


class Machine:
    """The engine of a table-driven machine, as a base class: the machine keeps its own constructor,
    state attribute and ``handle`` (see the module docstring)."""

    #: the attribute that holds the state
    _state_attr: ClassVar[str] = "state"
    #: where and how loud a move is logged (a machine sets its own module's logger)
    _log: ClassVar[logging.Logger] = log
    _log_level: ClassVar[int] = logging.INFO
    #: the states the row being applied allows (a class default: a copy made without ``__init__`` has it)
    _allowed: frozenset[Any] = frozenset()

    # ------------------------------------------------------------------ the machine's to say
    def _machine_name(self, key: Hashable | None = None) -> str:
        """Which machine (and part, ``key``) a log line or an error is about."""
        return type(self).__name__

    def _state_note(self) -> str | None:
        """What a move's log line says in parentheses when its caller gives no reason (None: nothing)."""
        return None

    def _get_state(self, key: Hashable | None = None) -> Any:
        return getattr(self, self._state_attr)

    def _put_state(self, new: Any, key: Hashable | None = None, now: float | None = None) -> None:
        setattr(self, self._state_attr, new)

    def _before(self) -> Any:
        """What the effects of a step are computed from, seen before its handler runs (``_step``)."""
        return None

    def _effects(self, before: Any) -> list[Any]:
        """The outputs that follow from the step's change, from ``before`` and the machine now (``_step``)."""
        return []

    # ------------------------------------------------------------------ the engine
    def _row(self, table: Mapping[tuple[Any, type], Row[Any]], event: object,
             key: Hashable | None = None) -> Row[Any] | None:
        """The row of (state, type of ``event``), its allowed states kept for ``_set_state``; None: the
        pair is not in the table (what that means is the caller's to say)."""
        row = table.get((self._get_state(key), type(event)))
        if row is not None:
            self._allowed = allowed_states(row[1])
        return row

    def _set_state(self, new: Any, reason: str | None = None, *, key: Hashable | None = None,
                   allowed: frozenset[Any] | None = None, now: float | None = None) -> bool:
        """Move to ``new`` (the part ``key``'s state), at ``now`` if the machine keeps when it moved. It
        must be one of the states the row being applied allows, or ``allowed`` for a move outside any
        row; staying where it is is no move (False). Logged ``old -> new (reason)``."""
        old = self._get_state(key)
        if new is old:
            return False
        if new not in (self._allowed if allowed is None else allowed):
            raise IllegalTransition(f"{self._machine_name(key)}: {old.value} -> {new.value} is not in the table")
        if self._log.isEnabledFor(self._log_level):
            note = self._state_note() if reason is None else reason
            if note is None:
                self._log.log(self._log_level, "%s: %s -> %s", self._machine_name(key), old.value, new.value)
            else:
                self._log.log(self._log_level, "%s: %s -> %s (%s)", self._machine_name(key), old.value, new.value,
                              note)
        self._put_state(new, key, now)
        return True

    def _move(self, rule: str, new: Any, allowed: frozenset[Any], now: float) -> None:
        """Enter the state a handler or a settle rule (``rule``, by name) chose at ``now``: one its row
        lists, staying included (a machine extends this with what it keeps after every step)."""
        if new not in allowed:
            raise IllegalTransition(f"{self._machine_name()}: {rule} chose {new.value} in "
                                    f"{self._get_state().value}: not in its row")
        self._set_state(new, allowed=allowed, now=now)

    def _settle(self, rules: Iterable[SettleRow[Any]], now: float) -> list[Any]:
        """The first of ``rules`` that applies in the state and fires: its choice entered, its outputs."""
        for states, rule, allowed in rules:
            if self._get_state() not in states:
                continue
            fired = rule(self, now)
            if fired is not None:
                new, outputs = fired
                self._move(rule.__name__, new, allowed, now)
                return outputs
        return []

    def _step(self, row: Row[Any], event: Any, settle: Iterable[SettleRow[Any]] = ()) -> list[Any]:
        """One step of a machine whose handlers return ``(state, outputs)`` for an event carrying
        ``now``: the handler, its choice entered (``_move``), the settle rules, the effects."""
        before = self._before()
        handler, allowed = row
        new, outputs = handler(self, event)
        self._move(handler.__name__, new, allowed_states(allowed), event.now)
        outputs += self._settle(settle, event.now)
        return outputs + self._effects(before)
