"""Vehicle profiles: the ONE place where thrust in newtons becomes MAVLink's normalized 0..1 thrust.

SET_ATTITUDE_TARGET carries a normalized thrust; what 0.5 means depends on the autopilot and airframe.
A profile states the normalized thrust that holds the vehicle in hover and maps linearly around it:
``norm = hover_thrust_norm · thrust_n / hover_thrust_n`` (clipped to [0, 1]). PX4's MPC_THR_HOVER and
ArduPilot's MOT_THST_HOVER are exactly that hover value (both autopilots linearize thrust internally).

The profile also names the autopilot family's flight modes, the other thing PX4 and ArduPilot disagree on
(MAV_CMD_DO_SET_MODE parameters: base mode flag, custom mode, custom sub mode):

=============  =================================  ==============================  =====================
family         companion in control               hold (abort)                    land
=============  =================================  ==============================  =====================
PX4 (bundled)  OFFBOARD (main 6)                  AUTO.LOITER (main 4, sub 3)     AUTO.LAND (4, 6)
ArduPilot      GUIDED_NOGPS (20; takes attitude)  BRAKE (17)                      LAND (9)
=============  =================================  ==============================  =====================

The ArduPilot row follows ArduCopter's documented mode numbers; it is not exercised against a real
ArduPilot here (no ArduPilot SITL on this machine), only the encoding is tested.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

PROFILE_NAMES = ("bundled", "px4", "ardupilot")


@dataclass(frozen=True)
class VehicleProfile:
    """How one autopilot family interprets normalized thrust.

    name: one of :data:`PROFILE_NAMES`; hover_thrust_norm: normalized thrust (0..1) that holds hover.
    """

    name: str = "bundled"
    hover_thrust_norm: float = 0.4

    def validate(self) -> None:
        """Raise ``ValueError("<key>: ...")`` for an unknown name or a hover thrust outside (0, 1)."""
        if self.name not in PROFILE_NAMES:
            raise ValueError(f"name: must be one of {', '.join(PROFILE_NAMES)}, got {self.name!r}")
        if not (math.isfinite(self.hover_thrust_norm) and 0.0 < self.hover_thrust_norm < 1.0):
            raise ValueError(f"hover_thrust_norm: must be in (0, 1), got {self.hover_thrust_norm}")

    def thrust_to_norm(self, thrust_n: float, hover_thrust_n: float) -> float:
        """Normalized thrust in [0, 1] for ``thrust_n`` newtons, given the hover thrust in newtons."""
        if not hover_thrust_n > 0.0:
            raise ValueError(f"hover_thrust_n: must be > 0, got {hover_thrust_n}")
        v = self.hover_thrust_norm * float(thrust_n) / hover_thrust_n
        if not math.isfinite(v):
            return 0.0
        return min(1.0, max(0.0, v))

    @property
    def autopilot(self) -> str:
        """Mode family: ``"px4"`` (PX4 and the bundled vehicle) or ``"ardupilot"``."""
        return "ardupilot" if self.name == "ardupilot" else "px4"

    def mode_params(self, what: str) -> list[float]:
        """DO_SET_MODE params [base_mode, custom_mode, custom_sub_mode] for ``what`` in offboard/hold/land."""
        try:
            main, sub = _MODES[self.autopilot][what]
        except KeyError:
            raise ValueError(f"mode: unknown mode {what!r} (known: offboard, hold, land)") from None
        return [float(MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(main), float(sub)]

    def is_offboard(self, custom_mode: int) -> bool:
        """Whether a HEARTBEAT custom_mode means the companion is in control."""
        return self.mode_class(custom_mode) == "offboard"

    def mode_class(self, custom_mode: int) -> str:
        """A HEARTBEAT custom_mode in the flight sequence's words: ``offboard`` (the companion flies),
        ``hold``, ``land``, ``takeoff`` or ``other``."""
        if self.autopilot == "ardupilot":
            return _ARDUPILOT_CLASS.get(int(custom_mode), "other")
        main = (int(custom_mode) >> 16) & 0xFF
        sub = (int(custom_mode) >> 24) & 0xFF if main == 4 else 0
        return _PX4_CLASS.get((main, sub), "other")

    @property
    def hover_param(self) -> str:
        """The autopilot parameter that holds the normalized hover thrust."""
        return "MOT_THST_HOVER" if self.autopilot == "ardupilot" else "MPC_THR_HOVER"

    @property
    def takeover_before_arm(self) -> bool:
        """ArduPilot arms in its guided mode; PX4 arms first and then accepts OFFBOARD."""
        return self.autopilot == "ardupilot"

    def norm_to_thrust(self, thrust_norm: float, hover_thrust_n: float) -> float:
        """Inverse of :meth:`thrust_to_norm` (newtons), for logging what a normalized value meant."""
        return float(thrust_norm) * hover_thrust_n / self.hover_thrust_norm


MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MAV_AUTOPILOT_ARDUPILOTMEGA = 3
MAV_AUTOPILOT_PX4 = 12
_MODES = {
    "px4": {"offboard": (6, 0), "hold": (4, 3), "land": (4, 6)},
    "ardupilot": {"offboard": (20, 0), "hold": (17, 0), "land": (9, 0)},
}

_PX4_CLASS = {(6, 0): "offboard", (4, 3): "hold", (4, 6): "land", (4, 2): "takeoff"}
_ARDUPILOT_CLASS = {20: "offboard", 4: "offboard", 17: "hold", 5: "hold", 9: "land"}

_PROFILES = {
    # bundled SITL vehicle: thrust-to-weight 2.5, so hover at 1/2.5 of full thrust
    "bundled": VehicleProfile("bundled", 0.4),
    # PX4 multicopter default MPC_THR_HOVER
    "px4": VehicleProfile("px4", 0.5),
    # ArduPilot default MOT_THST_HOVER
    "ardupilot": VehicleProfile("ardupilot", 0.35),
}


def profile_by_name(name: str, hover_thrust_norm: float | None = None) -> VehicleProfile:
    """The named profile; ``hover_thrust_norm`` overrides its hover value (e.g. read from the autopilot)."""
    try:
        p = _PROFILES[name]
    except KeyError:
        raise ValueError(f"profile: unknown vehicle profile {name!r} (known: {', '.join(PROFILE_NAMES)})") from None
    if hover_thrust_norm is not None:
        p = VehicleProfile(p.name, float(hover_thrust_norm))
        p.validate()
    return p


def profile_for_autopilot(mav_autopilot: int, hover_thrust_norm: float | None = None) -> VehicleProfile:
    """The profile matching HEARTBEAT.autopilot (ArduPilot → "ardupilot", anything else → "px4")."""
    name = "ardupilot" if mav_autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA else "px4"
    return profile_by_name(name, hover_thrust_norm)
