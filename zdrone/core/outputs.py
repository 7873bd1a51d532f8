"""What a pure core asks its adapter to do: the outputs both protocol cores share, and the one loop
that carries a list of outputs out.

Theory of operation
-------------------
The drone's core (``zdrone.nodes.drone_core``) and the ground station's (``gs.core``) are sans-IO:
inputs come in as ``on_*`` calls and ``handle_timer(now)`` at ``get_timer()``, and what must happen
in the world comes out as a list of values. The ideas both cores have are spelled once, here:

* ``Put(peer, payload)``: publish a sealed envelope on the link to ``peer`` (a GS's ``up/<gs>`` key
  of drone ``peer``, a drone's ``down/<peer>`` key); the adapter knows the key expression;
* ``Emit(record)``: write one typed event-log record (``zdrone.core.records``).

Each core adds the outputs only it has (the drone: ``ToVehicle``, ``CommandVehicle``, ``Listen``,
``Persist``; the GS: ``Ask``, ``FrameUp``, ``ToOperator``, in ``gs.actions``). Both cores name their status
for the adapter ``report(now)``.

An adapter carries outputs out with ``dispatch(outputs, handlers)``: ``handlers`` maps each output
type to what the adapter does with it; an output of a type without a handler is a programming
error (``UnhandledOutput``), never silently dropped.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Iterable, Mapping

from zdrone.core import records as rec


@dataclass(frozen=True, slots=True)
class Put:
    """Publish ``payload`` (a sealed envelope) on the link to ``peer``."""

    peer: str
    payload: bytes


@dataclass(frozen=True, slots=True)
class Emit:
    """Write ``record`` to the event log (``AuthorityMoved.time`` 0: the adapter stamps the time of day)."""

    record: rec.Record

    @property
    def kind(self) -> str:
        """The record's event type (its tag)."""
        return rec.record_type(self.record)

    @property
    def fields(self) -> dict[str, Any]:
        """The record's own fields as logged (JSON values)."""
        return rec.fields_of(self.record)


class UnhandledOutput(TypeError):
    """An adapter was handed an output it has no handler for: a programming error."""


Handlers = Mapping[type, Callable[[Any], None]]


def dispatch(outputs: Iterable[object], handlers: Handlers) -> None:
    """Carry out ``outputs`` in order, each by the handler of its type."""
    for o in outputs:
        handler = handlers.get(type(o))
        if handler is None:
            raise UnhandledOutput(f"no handler for output {o!r}")
        handler(o)
