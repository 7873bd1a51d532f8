"""A vehicle link to a simulator inside the same process (no sockets): for hosting many drones in
one process in ``zdrone bench scale``. Same interface as ``VehicleLink``, read by polling: there is
nothing to wait on, the simulator advances when the node's loop calls ``recv`` (``start_reader``
says so). ``next_due`` says when to call it next: when the simulator's next stream message is due
(``STEP_MAX_S`` at the latest), or at once after a frame was sent to it (its answer is ready)."""

from __future__ import annotations

import time
from typing import Any, Callable

from zdrone.core.geometry import GeoPoint
from zdrone.vehicle.link import VehicleState
from zdrone.vehicle.modes import mode_name
from zdrone.vehicle.px4modes import FlightMode
from zdrone.vehicle.sim import SimAutopilot

#: The longest a node's loop that sleeps until its next deadline leaves the simulator unstepped
#: (wall seconds), whatever its streams: its own timers (readiness, retries, the GCS's loss) run in steps.
STEP_MAX_S = 0.25
#: Vehicle ``seed``'s streams start ``seed`` times this (modulo 1 s) into its first second: spread evenly.
PHASE_STEP = 0.6180339887


class InProcessVehicle:
    """Drives a ``SimAutopilot`` on the wall clock times ``speedup``; frames pass as bytes."""

    def __init__(self, home: GeoPoint, sysid: int, speedup: float = 1.0, seed: int = 0) -> None:
        self.sim = SimAutopilot(home, sysid=sysid, seed=seed)
        self.speedup = speedup
        self.t0 = time.monotonic()
        # its streams' phase (simulated seconds, by ``seed``): hundreds of vehicles made at once do not
        # stream in step, as companions' autopilots that booted apart do not (one burst a period otherwise)
        phase = (seed * PHASE_STEP) % 1.0
        due = self.sim.telemetry.next_due
        for m in due:
            due[m] += phase
        self.sysid = sysid
        self.autopilot: str | None = self.sim.p.name  # "px4"
        self.conn = f"inproc-sim:{sysid}"
        self._sent = False  # a frame was sent to the simulator since its last step: its answer is ready

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
        self._sent = False
        self.sim.step(self._sim_time())
        return self.sim.drain()

    def start_reader(self, deliver: Callable[[Any], None]) -> bool:
        """No reader thread: the simulator is stepped by the caller's ``recv`` (False: keep polling)."""
        return False

    def accept(self, msg: Any, now: float) -> bytes:
        return bytes(msg)

    def next_due(self) -> float:
        """When to step the simulator next (monotonic seconds), for a caller's timer: at once if a frame
        was sent to it; else when its next stream message is due, ``STEP_MAX_S`` from now at the latest."""
        now = time.monotonic()
        if self._sent:
            return now
        tel = self.sim.telemetry
        sim_due = min((tel.next_due.get(m, self.sim.t) for m in tel.streams), default=None)
        soonest = now + STEP_MAX_S if sim_due is None else self.t0 + sim_due / self.speedup
        return min(soonest, now + STEP_MAX_S)

    def send(self, frame: bytes) -> None:
        self._sent = True
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

    # ---------------------------------------------------- a GCS's part, for a bench that flies it bare
    def upload(self, items: list[Any], codec: Any) -> bool:
        """Upload ``items`` (``PlannedItem``) as a GCS does (what the simulator says meanwhile is
        dropped: before the flight). True if it accepted the mission."""
        from pymavlink.dialects.v20 import common as mav

        sim, sysid = self.sim, self.sysid
        sim.drain()
        sim.receive(codec.encode(mav.MAVLink_mission_count_message(sysid, 1, len(items), 0)), sim.t)
        for _ in range(len(items) + 1):
            for f in sim.drain():
                msg = codec.decode(f)
                if msg is None:
                    continue
                if msg.get_type() == "MISSION_ACK":
                    return bool(msg.type == mav.MAV_MISSION_ACCEPTED)
                if msg.get_type() == "MISSION_REQUEST_INT":
                    sim.receive(codec.encode(items[msg.seq].message(msg.seq, (sysid, 1))), sim.t)
                    break
        return False

    def arm_and_start(self, codec: Any) -> None:
        """ARM, then MISSION_START, as the GS that flies it sends them."""
        from pymavlink.dialects.v20 import common as mav

        for cmd, p1 in ((mav.MAV_CMD_COMPONENT_ARM_DISARM, 1.0), (mav.MAV_CMD_MISSION_START, 0.0)):
            self.send(codec.encode(mav.MAVLink_command_long_message(self.sysid, 1, cmd, 0, p1, 0, 0, 0, 0, 0, 0)))

    def wait_vehicle(self, timeout: float) -> bool:
        return True

    def close(self) -> None:
        pass
