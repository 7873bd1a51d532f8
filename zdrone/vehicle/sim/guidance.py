"""Where the simulated vehicle flies to and how fast: the one object the autopilot's parts steer by.

Theory of operation
-------------------
The autopilot (``autopilot.SimAutopilot``) moves the vehicle toward ``target`` (north, east, altitude
in metres from home; None: nowhere, it holds still) at ``cruise_speed`` (None: the personality's
cruise speed); a take-off climbs to ``takeoff_alt``. The flight mode, the commands (``commands``)
and the mission (``mission``) set these through the methods here (``fly_to``, ``stop``,
``set_speed``, ``set_takeoff_alt``) and read them back; none of them writes the autopilot's own
attributes. Nothing here moves the vehicle: the kinematics do, in the autopilot's step.
"""

from __future__ import annotations

from dataclasses import dataclass

Target = tuple[float, float, float]  # north, east, altitude (m, from home)


@dataclass(slots=True)
class Guidance:
    """The vehicle's target, cruise speed and take-off altitude (see the module docstring)."""

    takeoff_alt: float
    target: Target | None = None
    cruise_speed: float | None = None  # set by a command or the mission; None: the personality's

    def fly_to(self, north: float, east: float, alt: float) -> None:
        self.target = (north, east, alt)

    def stop(self) -> None:
        """No target: the vehicle holds where it is."""
        self.target = None

    def set_speed(self, speed: float | None) -> None:
        self.cruise_speed = speed

    def set_takeoff_alt(self, alt: float) -> None:
        self.takeoff_alt = alt
