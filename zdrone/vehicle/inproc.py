"""A vehicle link to a simulator inside the same process (no sockets): for hosting many drones in
one process in ``zdrone bench scale``. Same interface as ``VehicleLink``, read by polling: there is
nothing to wait on, the simulator advances when the node's loop calls ``recv`` (``start_reader``
says so, and ``next_due`` asks for a look every ``STEP_S``)."""

from __future__ import annotations

import time
from typing import Any, Callable

from zdrone.core.geometry import GeoPoint
from zdrone.vehicle.link import VehicleState
from zdrone.vehicle.modes import mode_name
from zdrone.vehicle.px4modes import FlightMode
from zdrone.vehicle.sim import SimAutopilot

#: How often a node's loop that sleeps until its next deadline steps the simulator.
STEP_S = 0.02


class InProcessVehicle:
    """Drives a ``SimAutopilot`` on the wall clock times ``speedup``; frames pass as bytes."""

    def __init__(self, home: GeoPoint, sysid: int, speedup: float = 1.0, seed: int = 0) -> None:
        self.sim = SimAutopilot(home, sysid=sysid, seed=seed)
        self.speedup = speedup
        self.t0 = time.monotonic()
        self.sysid = sysid
        self.autopilot: str | None = self.sim.p.name  # "px4"
        self.conn = f"inproc-sim:{sysid}"

    def _sim_time(self) -> float:
        return (time.monotonic() - self.t0) * self.speedup

    @property
    def position(self) -> GeoPoint:
        p = self.sim.position
        return GeoPoint(p.lat, p.lon, self.sim.k.alt)

    @property
    def armed(self) -> bool:
        return self.sim.armed

    @property
    def landed_state(self) -> int:
        return self.sim.landed_state()

    def heartbeat(self, now: float | None = None) -> None:
        pass

    def recv(self, timeout: float = 0.0) -> list[bytes]:
        self.sim.step(self._sim_time())
        return self.sim.drain()

    def start_reader(self, deliver: Callable[[Any], None]) -> bool:
        """No reader thread: the simulator is stepped by the caller's ``recv`` (False: keep polling)."""
        return False

    def accept(self, msg: Any, now: float) -> bytes:
        return bytes(msg)

    def next_due(self) -> float:
        """The next step of the simulator, for a caller's timer."""
        return time.monotonic() + STEP_S

    def send(self, frame: bytes) -> None:
        self.sim.receive(frame, self.sim.t)

    def state(self) -> VehicleState:
        return VehicleState(self.sysid, self.position, self.armed,
                            mode_name(self.autopilot, self.sim.mode_row.custom_mode), self.landed_state, self.autopilot)

    def stream_stats(self) -> dict[str, Any]:
        """The simulator in this process streams what it streams: nothing is asked of it."""
        return {"autopilot": self.autopilot, "connections": 1, "streams": {}, "counters": {}}

    @property
    def position_signed(self) -> bool:
        """The simulator in this process is the autopilot: its position is its own, no wire between."""
        return True

    def failsafe_outcomes(self) -> list[Any]:
        """A mode asked of the simulator in this process is taken at once: nothing to follow."""
        return []

    def command_land(self) -> None:
        self.sim.request_mode(FlightMode.LAND)

    def command_rtl(self) -> None:
        self.sim.request_mode(FlightMode.RTL)

    def wait_vehicle(self, timeout: float) -> bool:
        return True

    def close(self) -> None:
        pass
