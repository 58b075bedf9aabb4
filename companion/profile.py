"""Vehicle profiles: the ONE place where thrust in newtons becomes MAVLink's normalized 0..1 thrust.

SET_ATTITUDE_TARGET carries a normalized thrust; what 0.5 means depends on the autopilot and airframe.
A profile states the normalized thrust that holds the vehicle in hover and maps linearly around it:
``norm = hover_thrust_norm · thrust_n / hover_thrust_n`` (clipped to [0, 1]). PX4's MPC_THR_HOVER and
ArduPilot's MOT_THST_HOVER are exactly that hover value (both autopilots linearize thrust internally).
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

    def norm_to_thrust(self, thrust_norm: float, hover_thrust_n: float) -> float:
        """Inverse of :meth:`thrust_to_norm` (newtons), for logging what a normalized value meant."""
        return float(thrust_norm) * hover_thrust_n / self.hover_thrust_norm


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
