"""PX4 custom-mode encoding (main mode << 16 | sub mode << 24), as GCS software expects it."""

from __future__ import annotations

import enum

MAIN_MANUAL, MAIN_ALTCTL, MAIN_POSCTL, MAIN_AUTO, MAIN_ACRO, MAIN_OFFBOARD, MAIN_STABILIZED = 1, 2, 3, 4, 5, 6, 7
SUB_READY, SUB_TAKEOFF, SUB_LOITER, SUB_MISSION, SUB_RTL, SUB_LAND = 1, 2, 3, 4, 5, 6


class FlightMode(enum.Enum):
    """The flight modes the simulator flies, with their PX4 (main, sub) mode numbers."""

    POSCTL = (MAIN_POSCTL, 0)
    HOLD = (MAIN_AUTO, SUB_LOITER)
    TAKEOFF = (MAIN_AUTO, SUB_TAKEOFF)
    MISSION = (MAIN_AUTO, SUB_MISSION)
    RTL = (MAIN_AUTO, SUB_RTL)
    LAND = (MAIN_AUTO, SUB_LAND)

    @property
    def custom_mode(self) -> int:
        main, sub = self.value
        return (main << 16) | (sub << 24)

    @classmethod
    def from_custom(cls, custom_mode: int) -> "FlightMode | None":
        return cls.from_main_sub((custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF)

    @classmethod
    def from_main_sub(cls, main: int, sub: int) -> "FlightMode | None":
        if main in (MAIN_POSCTL, MAIN_ALTCTL, MAIN_MANUAL, MAIN_STABILIZED):
            return cls.POSCTL
        for mode in cls:
            if mode.value == (main, sub):
                return mode
        return None


def mode_name(custom_mode: int) -> str:
    mode = FlightMode.from_custom(custom_mode)
    return mode.name if mode else f"custom:{custom_mode:#x}"
