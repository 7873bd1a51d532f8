"""The simulated vehicle's own state: where it is and how it moves, its battery, armed or not, on the
ground or not.

Theory of operation
-------------------
``VehicleState`` is what the autopilot (``autopilot.SimAutopilot``) changes as it flies: the
kinematic state (``kinematics.Kinematics``: position from home, velocity), the battery, whether it is
armed (and since when), whether it has lifted off since arming, whether it is on the ground (and
since when it touched down), and whether its gripper released the payload. The autopilot's parts
(``commands``, ``mission``, ``telemetry``, ``gcslink``) read it as ``ap.vehicle`` and never write
it: arming, disarming, the gripper and the physics are the autopilot's.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from zdrone.vehicle.sim.kinematics import Kinematics


@dataclass(slots=True)
class VehicleState:
    """The simulated vehicle (see the module docstring)."""

    k: Kinematics = field(default_factory=Kinematics)
    battery: float = 100.0  # %
    armed: bool = False
    armed_at: float | None = None
    taken_off: bool = False  # lifted off since arming
    landed: bool = True
    touchdown_at: float | None = None
    payload_released: bool = False
