"""Does the mission fit its payload? The hanging payload must clear the ground wherever the mission flies.

A payload on a cable of length l hangs l below the airframe. Flown lower than l plus a margin, it touches the
ground: in the bundled vehicle (and in a real field) it then drags and snags, and each snag throws it into a
swing the controller cannot damp (the issue-28 table: 0.25 kg on 2.5 m at 2 m altitude swung to 0.74 rad and hit
two trunks). No controller fixes that, so such a mission is refused before take-off, naming the point and the
altitude that would fit. Positions are NED metres in the mission frame; the ground is z = 0.
"""

from __future__ import annotations

from companion.core.mission import Mission
from companion.errors import ConfigError

#: the least height (m) of the hanging payload above the ground anywhere on the route: room for a swing's rise
#: and the altitude loop's error (the climb overshoots by ~0.1 m), with margin
GROUND_CLEARANCE_M = 0.3


def check_payload_clears_ground(mission: Mission, clearance_m: float = GROUND_CLEARANCE_M) -> None:
    """Raise :class:`ConfigError` if the payload (the companion's belief of its cable length) would hang less than
    ``clearance_m`` above the ground at the start, a waypoint or the goal."""
    cable = mission.companion_params().l
    points = [("start_ned_m", mission.start_ned_m)]
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
