"""The simulated multicopter's physics: where it is, how it moves toward a target, its battery.

Theory of operation: ``Kinematics`` is one instant of the vehicle (north/east/up metres from home,
velocities, yaw), a frozen value. ``advance(k, target, limits, dt)`` is the next instant after ``dt``
seconds of flying toward ``target`` (north, east, altitude) within ``Limits``: the vertical speed is
proportional to the altitude error up to the climb and descent rates (at most 1 m/s below 5 m on
the way down), the horizontal speed is the cruise speed, slowed so that the vehicle can stop at the
target, and none at all while it is still below 2 m and climbing; both change by at most ``acc`` per
second. The yaw follows the track above 0.5 m/s; the ground stops the vehicle at altitude 0.

The battery is a percentage that drains at a rate per minute while the motors run; its voltage is
a 4S LiPo's, linear between empty and full. Nothing here knows MAVLink, modes or the autopilot:
``zdrone.vehicle.sim.autopilot`` decides the target and reads the result.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["Kinematics", "Limits", "advance", "battery_after", "battery_millivolts", "wrap_pi"]

SUBSTEP_S = 0.05  # the longest step the autopilot integrates at once: stable at any speed-up
EMPTY_MV, FULL_MV = 13200, 16800  # 4S LiPo


@dataclass(frozen=True, slots=True)
class Kinematics:
    """The vehicle at one instant: position from home, velocity, heading."""

    north: float = 0.0
    east: float = 0.0
    alt: float = 0.0  # metres above home
    vn: float = 0.0
    ve: float = 0.0
    vz: float = 0.0  # up positive
    yaw: float = 0.0  # radians, 0 north

    def halted(self) -> Kinematics:
        """The same place and heading, standing still."""
        return Kinematics(self.north, self.east, self.alt, 0.0, 0.0, 0.0, self.yaw)

    def touched_down(self) -> Kinematics:
        """On the ground: no horizontal speed left."""
        return Kinematics(self.north, self.east, self.alt, 0.0, 0.0, self.vz, self.yaw)

    def tilt(self) -> tuple[float, float]:
        """Roll and pitch (radians) of a multicopter flying at this velocity."""
        pitch = -math.atan2(self.vn * math.cos(self.yaw) + self.ve * math.sin(self.yaw), 40.0)
        roll = math.atan2(-self.vn * math.sin(self.yaw) + self.ve * math.cos(self.yaw), 40.0)
        return roll, pitch


@dataclass(frozen=True, slots=True)
class Limits:
    """How fast the vehicle may move: m/s up and down, m/s² of any speed change, m/s horizontally."""

    up: float
    down: float
    acc: float
    speed: float


def advance(k: Kinematics, target: tuple[float, float, float], limits: Limits, dt: float) -> Kinematics:
    """``k`` after ``dt`` seconds of flying toward ``target`` (north, east, altitude) within ``limits``."""
    tn, te, talt = target
    # vertical
    up_max, dn_max = limits.up, limits.down
    if k.alt < 5.0 and talt < k.alt:
        dn_max = min(dn_max, 1.0)  # gentle final descent
    dz = talt - k.alt
    want_vz = max(-dn_max, min(up_max, dz * 1.5))
    # horizontal: no lateral motion until clear of the ground
    dn_, de_ = tn - k.north, te - k.east
    dist = math.hypot(dn_, de_)
    acc = limits.acc
    speed = limits.speed
    if k.alt < 2.0 and dz > 0.5:
        speed = 0.0
    want = min(speed, math.sqrt(2 * acc * dist) * 0.9, dist / max(dt, 1e-3))
    want_vn, want_ve = (dn_ / dist * want, de_ / dist * want) if dist > 1e-6 else (0.0, 0.0)
    dvn, dve = want_vn - k.vn, want_ve - k.ve
    dv = math.hypot(dvn, dve)
    if dv > acc * dt:
        dvn, dve = dvn / dv * acc * dt, dve / dv * acc * dt
    vn = k.vn + dvn
    ve = k.ve + dve
    vz = k.vz + max(-acc * dt, min(acc * dt, want_vz - k.vz))
    north = k.north + vn * dt
    east = k.east + ve * dt
    alt = k.alt + vz * dt
    yaw = math.atan2(ve, vn) if math.hypot(vn, ve) > 0.5 else k.yaw
    if alt <= 0.0:  # the ground
        alt = 0.0
        vz = max(0.0, vz)
    return Kinematics(north, east, alt, vn, ve, vz, yaw)


def battery_after(percent: float, drain_per_minute: float, dt: float) -> float:
    """The charge left (%) after ``dt`` seconds with the motors running."""
    return max(0.0, percent - drain_per_minute / 60.0 * dt)


def battery_millivolts(percent: float) -> int:
    """The pack voltage at this charge."""
    return int(EMPTY_MV + (FULL_MV - EMPTY_MV) * percent / 100.0)


def wrap_pi(a: float) -> float:
    """An angle in [-pi, pi)."""
    return (a + math.pi) % (2 * math.pi) - math.pi
