"""PX4's flight-mode encoding in HEARTBEAT.custom_mode and MAV_CMD_DO_SET_MODE.

PX4 packs its mode as ``custom_mode = main_mode << 16 | sub_mode << 24`` (px4_custom_mode.h). The bundled
vehicle flies a subset: OFFBOARD, POSCTL (a position hold: there is no RC), AUTO.LOITER, AUTO.TAKEOFF and
AUTO.LAND. The other PX4 modes are known by name (so a request for them is denied with a clear reason).
"""

from __future__ import annotations

from dataclasses import dataclass

# main modes
MAIN_MANUAL = 1
MAIN_ALTCTL = 2
MAIN_POSCTL = 3
MAIN_AUTO = 4
MAIN_ACRO = 5
MAIN_OFFBOARD = 6
MAIN_STABILIZED = 7
MAIN_RATTITUDE = 8

# AUTO sub modes
SUB_AUTO_READY = 1
SUB_AUTO_TAKEOFF = 2
SUB_AUTO_LOITER = 3
SUB_AUTO_MISSION = 4
SUB_AUTO_RTL = 5
SUB_AUTO_LAND = 6
SUB_AUTO_FOLLOW_TARGET = 8
SUB_AUTO_PRECLAND = 9


@dataclass(frozen=True)
class Px4Mode:
    """A PX4 flight mode: main mode and (for AUTO) sub mode."""

    main: int
    sub: int = 0

    @property
    def custom_mode(self) -> int:
        """The HEARTBEAT.custom_mode value."""
        return (self.main << 16) | (self.sub << 24)

    @property
    def name(self) -> str:
        """PX4's name, e.g. ``"AUTO.LOITER"``; ``"UNKNOWN(main,sub)"`` for codes PX4 does not have."""
        return _NAMES.get((self.main, self.sub if self.main == MAIN_AUTO else 0), f"UNKNOWN({self.main},{self.sub})")

    @staticmethod
    def from_custom_mode(custom_mode: int) -> Px4Mode:
        """Decode a HEARTBEAT/SET_MODE custom_mode value."""
        main = (int(custom_mode) >> 16) & 0xFF
        sub = (int(custom_mode) >> 24) & 0xFF
        return Px4Mode(main, sub if main == MAIN_AUTO else 0)


MANUAL = Px4Mode(MAIN_MANUAL)
ALTCTL = Px4Mode(MAIN_ALTCTL)
POSCTL = Px4Mode(MAIN_POSCTL)
OFFBOARD = Px4Mode(MAIN_OFFBOARD)
STABILIZED = Px4Mode(MAIN_STABILIZED)
ACRO = Px4Mode(MAIN_ACRO)
AUTO_TAKEOFF = Px4Mode(MAIN_AUTO, SUB_AUTO_TAKEOFF)
AUTO_LOITER = Px4Mode(MAIN_AUTO, SUB_AUTO_LOITER)
AUTO_MISSION = Px4Mode(MAIN_AUTO, SUB_AUTO_MISSION)
AUTO_RTL = Px4Mode(MAIN_AUTO, SUB_AUTO_RTL)
AUTO_LAND = Px4Mode(MAIN_AUTO, SUB_AUTO_LAND)

_NAMES = {
    (MAIN_MANUAL, 0): "MANUAL",
    (MAIN_ALTCTL, 0): "ALTCTL",
    (MAIN_POSCTL, 0): "POSCTL",
    (MAIN_ACRO, 0): "ACRO",
    (MAIN_OFFBOARD, 0): "OFFBOARD",
    (MAIN_STABILIZED, 0): "STABILIZED",
    (MAIN_RATTITUDE, 0): "RATTITUDE",
    (MAIN_AUTO, SUB_AUTO_READY): "AUTO.READY",
    (MAIN_AUTO, SUB_AUTO_TAKEOFF): "AUTO.TAKEOFF",
    (MAIN_AUTO, SUB_AUTO_LOITER): "AUTO.LOITER",
    (MAIN_AUTO, SUB_AUTO_MISSION): "AUTO.MISSION",
    (MAIN_AUTO, SUB_AUTO_RTL): "AUTO.RTL",
    (MAIN_AUTO, SUB_AUTO_LAND): "AUTO.LAND",
    (MAIN_AUTO, SUB_AUTO_FOLLOW_TARGET): "AUTO.FOLLOW_TARGET",
    (MAIN_AUTO, SUB_AUTO_PRECLAND): "AUTO.PRECLAND",
}

#: Modes the bundled vehicle can fly.
SUPPORTED_MODES = frozenset({POSCTL, OFFBOARD, AUTO_TAKEOFF, AUTO_LOITER, AUTO_LAND})

#: Modes flown by the internal position controller (everything but OFFBOARD).
INTERNAL_MODES = frozenset({POSCTL, AUTO_TAKEOFF, AUTO_LOITER, AUTO_LAND})
