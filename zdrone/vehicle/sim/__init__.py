"""The built-in multicopter simulator, sans-IO: ``SimAutopilot`` (``autopilot``) is the autopilot and
the façade; beside it its kinematics (``kinematics``), what it sends (``outbox``) and its MAVLink
protocols: commands as a table (``commands``), the mission (``mission``), parameters (``params``),
telemetry streams (``telemetry``) and the GCS link (``gcslink``). The socket adapter is
``zdrone.vehicle.simserver``; the autopilot's facts per PX4 / ArduPilot are
``zdrone.vehicle.personality``.
"""

from zdrone.vehicle.personality import Param
from zdrone.vehicle.sim.autopilot import SimAutopilot
from zdrone.vehicle.sim.kinematics import Kinematics
from zdrone.vehicle.sim.mission import MissionItem

__all__ = ["SimAutopilot", "MissionItem", "Param", "Kinematics"]
