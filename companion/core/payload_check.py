"""The thrust-margin check before take-off: a payload the vehicle cannot lift with margin is refused (pure).

Hovering the vehicle and its payload takes (M + m)·g of thrust; the rotors give at most ``max_thrust_n``
(``[vehicle] max_thrust_n``, N). The flight is refused before take-off when the hover takes more than
:data:`HOVER_FRACTION_LIMIT` (0.75) of it. Why 0.75 (docs/companion.md, "Thrust margin"):

* multirotor design guidance asks for a thrust-to-weight ratio of about 2:1 at take-off weight (hover at
  ~50 % throttle; ArduPilot's wiki: the learnt hover throttle MOT_THST_HOVER "is usually between 0.2 and 0.6").
  0.75 (thrust-to-weight 1.33) is the far edge of that;
* what the remaining 25 % must pay for: the companion's controller tilts up to 0.6 rad
  (``LimitGains.tilt_max_rad``), which at constant altitude takes 1/cos 0.6 = 1.21× the hover thrust: 0.91 of
  the maximum at a hover fraction of 0.75, leaving ~9 % for the attitude loop's differential thrust (a rotor at
  its limit has no authority) and nothing for a climb; above 0.83 it cannot even hold altitude at full tilt.

The check uses what the companion is told (the mission's vehicle with ``[payload]``'s declared mass); a payload
heavier than declared is the vehicle's to discover in flight.

The ground check: a payload on a cable of length l hangs l below the airframe. Flown lower than l plus a margin,
it touches the ground: in the bundled vehicle (and in a real field) it then drags and snags, and each snag throws
it into a swing the controller cannot damp (issue 28: 0.25 kg on 2.5 m at 2 m altitude swung to 0.74 rad and hit
two trunks). No controller fixes that, so such a mission is refused before take-off too, naming the point and
the altitude that would fit (positions NED metres in the mission frame; the ground is z = 0).
"""

from __future__ import annotations

from dataclasses import dataclass

from companion.core.mission import Mission
from companion.core.vehicle_params import VehicleParams
from companion.errors import ConfigError

#: Largest hover thrust, as a fraction of the maximum thrust, that the companion takes off with.
HOVER_FRACTION_LIMIT = 0.75


@dataclass(frozen=True)
class ThrustMargin:
    """Hover thrust ``hover_n`` and maximum thrust ``max_n`` (N); ``fraction`` = hover / max; ``limit``."""

    payload_kg: float
    vehicle_kg: float
    hover_n: float
    max_n: float
    limit: float = HOVER_FRACTION_LIMIT

    @property
    def fraction(self) -> float:
        """Hover thrust over maximum thrust (dimensionless)."""
        return self.hover_n / self.max_n

    @property
    def ok(self) -> bool:
        """True when the vehicle lifts the payload with margin."""
        return self.fraction <= self.limit

    def detail(self) -> str:
        """The numbers in one sentence, e.g. for the report's ``outcome_detail``."""
        verdict = "" if self.ok else "refused before take-off: "
        return (f"{verdict}hover needs {self.fraction:.2f} of maximum thrust (limit {self.limit:.2f}): payload "
                f"{self.payload_kg:g} kg + vehicle {self.vehicle_kg:g} kg = {self.hover_n:.1f} N of "
                f"{self.max_n:.1f} N")

    def as_dict(self) -> dict[str, float | bool]:
        """For the report: masses (kg), thrusts (N), fraction, limit, ok."""
        return {"payload_kg": self.payload_kg, "vehicle_kg": self.vehicle_kg, "hover_thrust_n": self.hover_n,
                "max_thrust_n": self.max_n, "hover_fraction": self.fraction, "limit": self.limit, "ok": self.ok}


def thrust_margin(params: VehicleParams, limit: float = HOVER_FRACTION_LIMIT) -> ThrustMargin:
    """The hover thrust (M + m)·g of ``params`` against its ``max_thrust_n``."""
    return ThrustMargin(params.m, params.M, params.hover_thrust_n, params.max_thrust_n, limit)


#: the least height (m) of the hanging payload above the ground anywhere on the route: room for a swing's rise
#: and the altitude loop's error (the climb overshoots by ~0.1 m), with margin
GROUND_CLEARANCE_M = 0.3


def check_payload_clears_ground(mission: Mission, clearance_m: float = GROUND_CLEARANCE_M) -> None:
    """Raise :class:`ConfigError` if the payload (the companion's belief of its cable length) would hang less than
    ``clearance_m`` above the ground at the start (unless the start is on the ground), a waypoint or the goal."""
    cable = mission.companion_params().l
    # a start on the ground (z = 0, the paper's group 1) is a take-off point: the payload lifts off in the climb
    points = [("start_ned_m", mission.start_ned_m)] if float(mission.start_ned_m[2]) < 0.0 else []
    points += [(f"waypoint {i} ({w.name})" if w.name else f"waypoint {i}", w.pos_ned_m)
               for i, w in enumerate(mission.waypoints)]
    points.append(("goal_ned_m", mission.goal_ned_m))
    for where, p in points:
        height = -float(p[2])
        if height - cable < clearance_m:
            raise ConfigError(
                f"{mission.source_path or mission.name}: {where}: the payload would hang "
                f"{height - cable:+.2f} m above the ground (altitude {height:.2f} m, cable {cable:.2f} m); fly at "
                f"least {cable + clearance_m:.2f} m high (cable + {clearance_m:g} m) or shorten the cable")
