"""What the drone's pure core (``zdrone.nodes.drone_core``) asks its adapter to do: the drone's output
vocabulary. ``Put`` and ``Emit`` are the outputs the ground station's core has too
(``zdrone.core.outputs``); the drone adds ``ToVehicle`` (a frame for the flight controller),
``CommandVehicle`` (the failsafe), ``Listen`` (the uplinks to subscribe) and ``Persist`` (the
authority to keep across a restart). ``Out`` is any one of them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Union

from zdrone.core import wire
from zdrone.core.outputs import Emit, Put


@dataclass(frozen=True, slots=True)
class ToVehicle:
    """Send ``frame`` (MAVLink, as a GS sent it) to the flight controller."""

    frame: bytes


@dataclass(frozen=True, slots=True)
class CommandVehicle:
    """The failsafe: command the vehicle to ``command`` (LAND, RTL)."""

    command: str
    reason: str
    detect_to_command_ms: float | None  # from the loss threshold to this decision


@dataclass(frozen=True, slots=True)
class Listen:
    """Subscribe to the uplinks of exactly these GSs from now on."""

    gss: frozenset[str]


@dataclass(frozen=True, slots=True)
class Countersign:
    """GS ``gs``'s authority-record checkpoint, from its authentic ``wire.AuditOffer``: for the drone
    to countersign in its own record (``zdrone.core.audit``)."""

    gs: str
    head: wire.AuditHead


@dataclass(frozen=True, slots=True)
class Persist:
    """Keep this authority across a restart (``owner`` None: forget what was kept)."""

    owner: str | None
    epoch: int
    state: str


Out = Union[Put, ToVehicle, CommandVehicle, Listen, Emit, Persist, Countersign]

OutHandler = Callable[[Out], None]
