"""Vehicle profiles: the ONE place where thrust in newtons becomes MAVLink's normalized 0..1 thrust, tied to the
autopilot family whose modes and set-up the vehicle speaks.

SET_ATTITUDE_TARGET carries a normalized thrust; what 0.5 means depends on the autopilot and airframe.
A profile states the normalized thrust that holds the vehicle in hover and maps linearly around it:
``norm = hover_thrust_norm · thrust_n / hover_thrust_n`` (clipped to [0, 1]). PX4's MPC_THR_HOVER and
ArduPilot's MOT_THST_HOVER are exactly that hover value (both autopilots linearize thrust internally;
ArduCopter only with GUID_OPTIONS bit 3, which the set-up sees to).

=============  ============================  =============================  ====================  ==========
profile        family                        companion in control           hold (abort)          land
=============  ============================  =============================  ====================  ==========
``bundled``    PX4 (hover 0.4)               OFFBOARD (main 6)              AUTO.LOITER (4, 3)    AUTO.LAND
``px4``        PX4 (hover 0.5)               OFFBOARD                       AUTO.LOITER           AUTO.LAND
``ardupilot``  ArduPilot (hover 0.35)        GUIDED_NOGPS (20)              BRAKE (17)            LAND (9)
=============  ============================  =============================  ====================  ==========

Both families' tables are flown against the real autopilots (tests/test_real_autopilots.py, when built).

Each profile also states the loop lag the companion measures against it on a clean loopback link
(:mod:`companion.estimation.loop_lag`: commanded attitude to the attitude that comes back, forest flights):
bundled 68–84 ms, PX4 v1.15.2 SIH 164–188 ms, ArduCopter SITL 180–292 ms. The anti-swing feed-forward fades
when the measured lag grows beyond it (a slow or jittery link), :attr:`VehicleProfile.nominal_loop_lag_s`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from companion.autopilots.ardupilot import ARDUPILOT
from companion.autopilots.family import AutopilotFamily
from companion.autopilots.px4 import PX4

PROFILE_NAMES = ("bundled", "px4", "ardupilot")
MAV_AUTOPILOT_ARDUPILOTMEGA = 3
MAV_AUTOPILOT_PX4 = 12
_FAMILIES = {"bundled": PX4, "px4": PX4, "ardupilot": ARDUPILOT}
_HOVER = {"bundled": 0.4, "px4": PX4.default_hover_thrust, "ardupilot": ARDUPILOT.default_hover_thrust}
_LOOP_LAG_S = {"bundled": 0.08, "px4": 0.17, "ardupilot": 0.28}  # measured on clean links, see the module docstring


@dataclass(frozen=True)
class VehicleProfile:
    """How one vehicle interprets normalized thrust, and which autopilot family it speaks.

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

    @property
    def family(self) -> AutopilotFamily:
        """The autopilot family's tables."""
        return _FAMILIES.get(self.name, PX4)

    @property
    def nominal_loop_lag_s(self) -> float:
        """The loop lag (s) this profile's autopilot shows on a clean link (measured, see the module docstring)."""
        return _LOOP_LAG_S.get(self.name, _LOOP_LAG_S["bundled"])

    @property
    def autopilot(self) -> str:
        """Mode family: ``"px4"`` (PX4 and the bundled vehicle) or ``"ardupilot"``."""
        return self.family.name

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

    def mode_params(self, what: str) -> list[float]:
        """DO_SET_MODE params [base_mode, custom_mode, custom_sub_mode] for ``what`` in offboard/hold/land."""
        return self.family.mode_params(what)

    def mode_class(self, custom_mode: int) -> str:
        """A HEARTBEAT custom_mode in the flight sequence's words (see :class:`AutopilotFamily`)."""
        return self.family.mode_class(custom_mode)

    def is_offboard(self, custom_mode: int) -> bool:
        """Whether a HEARTBEAT custom_mode means the companion is in control."""
        return self.mode_class(custom_mode) == "offboard"

    @property
    def hover_param(self) -> str:
        """The autopilot parameter that holds the normalized hover thrust."""
        return self.family.hover_param

    @property
    def takeover_before_arm(self) -> bool:
        """ArduPilot arms in its guided mode; PX4 arms first and then accepts OFFBOARD."""
        return self.family.takeover_before_arm


def profile_by_name(name: str, hover_thrust_norm: float | None = None) -> VehicleProfile:
    """The named profile; ``hover_thrust_norm`` overrides its hover value (e.g. read from the autopilot)."""
    if name not in _FAMILIES:
        raise ValueError(f"profile: unknown vehicle profile {name!r} (known: {', '.join(PROFILE_NAMES)})")
    p = VehicleProfile(name, _HOVER[name] if hover_thrust_norm is None else float(hover_thrust_norm))
    p.validate()
    return p


def profile_for_autopilot(mav_autopilot: int, hover_thrust_norm: float | None = None) -> VehicleProfile:
    """The profile matching HEARTBEAT.autopilot (ArduPilot → "ardupilot", anything else → "px4")."""
    name = "ardupilot" if mav_autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA else "px4"
    return profile_by_name(name, hover_thrust_norm)
