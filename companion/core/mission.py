"""Mission files: where to fly, with which planner and controller, in which wind, around which trunks.

Format (TOML; every table strict: unknown keys, missing required keys and wrong types are refused with
``ConfigError("<file>: [table] key: message")``)::

    [mission]                      # required
    name = "forest"
    start_ned_m = [0.0, 0.0, -2.0] # the vehicle climbs from the ground below start to this altitude
    goal_ned_m = [10.0, 0.0, -2.0]
    planner = "safe"               # traditional | improved | safe | none
    controller = "smc_ff"          # smc_ff | smc | pid
    timeout_s = 40.0
    hold_s = 5.0                   # optional: hover at the goal this long, then phase "done"
    land = true                    # optional: the app lands after the hold
    [wind]                         # optional (default: none)
    model = "paper"
    scale = 1.0
    [vehicle]                      # optional: VehicleParams overrides by field name
    m = 0.25
    [payload]                      # optional: what the companion assumes about the payload (issue 11)
    mass_kg = 0.25                 # optional; measured by the user: used as is, never identified
    cable_length_m = 1.0           # optional; likewise
    identify = false               # optional: identify what is not given above, in flight (hover hop)
    [[obstacles]]                  # optional, any number; Obstacle keys (not "source")
    x_m = 3.0
    y_m = -0.22
    radius_m = 0.3
    height_m = 4.0
    safe_distance_m = 0.1
    [[waypoints]]                  # optional, at most MAX_WAYPOINTS, flown in order between start and goal
    ned_m = [4.0, 2.0, -2.0]       # NED metres, mission frame
    hold_s = 0.0                   # optional: hover here this long first (0: fly through without stopping)
    speed_max_mps = 1.5            # optional: horizontal speed limit of the leg that ends here
    name = "gate"                  # optional, for the report
    [[fence.polygons]]             # optional: a geofence zone (north, east) m, at least three vertices
    vertices_ne_m = [[-5.0, -5.0], [15.0, -5.0], [15.0, 5.0], [-5.0, 5.0]]
    inclusion = true               # required: true = stay inside, false = stay outside
    [[fence.circles]]              # optional
    center_ne_m = [5.0, 3.0]
    radius_m = 1.0
    inclusion = false

``[vehicle]`` is the whole physical vehicle (the bundled simulator flies it; the companion's model uses it too).
``[payload]`` lets the companion's model differ from it: a measured ``mass_kg`` / ``cable_length_m`` overrides
``[vehicle]`` m / l for the companion (and for identification: a given value is never identified);
``identify = true`` asks for :func:`companion.estimation.payload_id.identify_payload` on the values not given;
``drag_n_per_mps2`` is the payload's drag coefficient for the swing estimator and the shaped planner's drag budget
(default 0: negligible drag, or identified in flight); ``airframe_drag_n_per_mps2`` the airframe's, from which the
climb judges the wind before it lifts the payload (:mod:`companion.flight.liftoff`; default 0: a typical
quadrotor's assumed, and a small push read as no wind).
:meth:`Mission.companion_params` is the model the companion should fly with before any identification.

A start, goal or waypoint whose airframe circle (r_uav + L_uav) would overlap an obstacle's safety ring
(radius_m + safe_distance_m) below the obstacle's top is refused too; so are waypoints with NaN or out-of-range
values, more than :data:`MAX_WAYPOINTS` of them, and fence zones with fewer than three vertices or a
non-positive radius (each error names the file, the table and its index, and the key).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from companion.config import dataclass_from_table, read_toml
from companion.core.fence import Fence
from companion.core.mission_zones import check_fenced, fence_toml, parse_fence
from companion.core.obstacles import Obstacle
from companion.core.vehicle_params import VehicleParams, vehicle_params_with
from companion.core.wind import WindConfig
from companion.errors import ConfigError

PLANNERS = ("traditional", "improved", "safe", "shaped", "none")
CONTROLLERS = ("smc_ff", "smc", "pid")
_MAX_COORD_M = 1.0e4
MAX_WAYPOINTS = 1000  # waypoints in one mission file (a mission of 10,000 items is refused, not flown)


@dataclass(frozen=True)
class MissionTable:
    """The ``[mission]`` table as written in the file (positions NED metres, times seconds)."""

    name: str
    start_ned_m: tuple[float, float, float]
    goal_ned_m: tuple[float, float, float]
    planner: str
    controller: str
    timeout_s: float
    hold_s: float = 5.0
    land: bool = True

    def validate(self) -> None:
        """Raise ``ValueError("<key>: ...")`` on unknown planner/controller names or bad numbers."""
        if not self.name:
            raise ValueError("name: must not be empty")
        if self.planner not in PLANNERS:
            raise ValueError(f"planner: must be one of {', '.join(PLANNERS)}, got {self.planner!r}")
        if self.controller not in CONTROLLERS:
            raise ValueError(f"controller: must be one of {', '.join(CONTROLLERS)}, got {self.controller!r}")
        for key in ("start_ned_m", "goal_ned_m"):
            v = getattr(self, key)
            if any(abs(c) > _MAX_COORD_M for c in v):
                raise ValueError(f"{key}: coordinates beyond {_MAX_COORD_M} m")
            if v[2] > 0.0:
                raise ValueError(f"{key}: z = {v[2]} m is below the ground (NED: z <= 0 is above ground)")
        if not 0.0 < self.timeout_s <= 3600.0:
            raise ValueError(f"timeout_s: must be in (0, 3600], got {self.timeout_s}")
        if not 0.0 <= self.hold_s <= 600.0:
            raise ValueError(f"hold_s: must be in [0, 600], got {self.hold_s}")


@dataclass(frozen=True)
class PayloadConfig:
    """The ``[payload]`` table: measured payload mass (kg) and cable length (m), each None when not given,
    whether to identify the ones not given in flight, and the payload's drag coefficient ``drag_n_per_mps2``
    (k in p = −k·|v|·v, N per (m/s)²: ½·ρ·C_d·A, e.g. 0.043 for a 30 cm sphere; 0, the default, for a payload
    whose drag is negligible or unknown), which the swing estimator starts from and refines (docs/swing-estimation.md)
    and the shaped planner's speed-up budgets from take-off (:mod:`companion.control.drag_id`); the airframe's own
    ``airframe_drag_n_per_mps2`` (0: unknown, a typical one assumed), for the wind before the lift-off
    (:mod:`companion.flight.liftoff`)."""

    mass_kg: float | None = None
    cable_length_m: float | None = None
    identify: bool = False
    drag_n_per_mps2: float = 0.0
    airframe_drag_n_per_mps2: float = 0.0

    def validate(self) -> None:
        """Raise ``ValueError("<key>: ...")`` for non-physical values."""
        if self.mass_kg is not None and not (0.0 < self.mass_kg <= 100.0):
            raise ValueError(f"mass_kg: must be in (0, 100], got {self.mass_kg}")
        if self.cable_length_m is not None and not (0.0 < self.cable_length_m <= 20.0):
            raise ValueError(f"cable_length_m: must be in (0, 20] (the model's range), got {self.cable_length_m}")
        for key in ("drag_n_per_mps2", "airframe_drag_n_per_mps2"):
            v = getattr(self, key)
            if not (math.isfinite(v) and 0.0 <= v <= 10.0):
                raise ValueError(f"{key}: must be in [0, 10] N per (m/s)², got {v}")

    @property
    def is_default(self) -> bool:
        """True when the table says nothing (absent or empty)."""
        return self.mass_kg is None and self.cable_length_m is None and not self.identify and \
            self.drag_n_per_mps2 == 0.0 and self.airframe_drag_n_per_mps2 == 0.0


@dataclass(frozen=True)
class Waypoint:
    """A point the mission flies through on its way to the goal: NED metres (3,) in the mission frame;
    ``hold_s`` (s) hovers there first (0: fly through without stopping); ``speed_max_mps`` limits the horizontal
    speed of the leg that ends here (None: the planner's own limit); ``name`` for the report."""

    pos_ned_m: np.ndarray
    hold_s: float = 0.0
    speed_max_mps: float | None = None
    name: str = ""


@dataclass(frozen=True)
class WaypointTable:
    """A ``[[waypoints]]`` table as written: ``ned_m`` NED metres, ``hold_s`` s, ``speed_max_mps`` m/s, ``name``."""

    ned_m: tuple[float, float, float]
    hold_s: float = 0.0
    speed_max_mps: float | None = None
    name: str = ""

    def validate(self) -> None:
        """Raise ``ValueError("<key>: ...")`` on NaN, far-off or below-ground positions and bad numbers."""
        if not all(math.isfinite(c) for c in self.ned_m):
            raise ValueError(f"ned_m: must be finite, got {list(self.ned_m)}")
        if any(abs(c) > _MAX_COORD_M for c in self.ned_m):
            raise ValueError(f"ned_m: coordinates beyond {_MAX_COORD_M} m")
        if self.ned_m[2] > 0.0:
            raise ValueError(f"ned_m: z = {self.ned_m[2]} m is below the ground (NED: z <= 0 is above ground)")
        if not 0.0 <= self.hold_s <= 600.0:
            raise ValueError(f"hold_s: must be in [0, 600], got {self.hold_s}")
        if self.speed_max_mps is not None and not 0.0 < self.speed_max_mps <= 20.0:
            raise ValueError(f"speed_max_mps: must be in (0, 20], got {self.speed_max_mps}")
        if len(self.name) > 64:
            raise ValueError("name: at most 64 characters")


@dataclass(frozen=True)
class Mission:
    """A validated mission (see module docstring for the file format). Arrays are NED metres, (3,)."""

    name: str
    start_ned_m: np.ndarray
    goal_ned_m: np.ndarray
    planner: str
    controller: str
    timeout_s: float
    wind: WindConfig = field(default_factory=lambda: WindConfig("none", 0.0))
    vehicle: VehicleParams = field(default_factory=VehicleParams)
    obstacles: tuple[Obstacle, ...] = ()
    hold_s: float = 5.0
    land: bool = True
    source_path: str = ""
    payload: PayloadConfig = field(default_factory=PayloadConfig)
    #: the points flown through, in order, between the start and the goal (empty: straight to the goal); the
    #: goal (``goal_ned_m``, hovered ``hold_s``) stays the last point of every mission
    waypoints: tuple[Waypoint, ...] = ()
    #: where the flight may and may not go (None: no fence)
    fence: Fence | None = None

    def companion_params(self) -> VehicleParams:
        """The model the companion flies with: ``vehicle`` with ``[payload]``'s measured mass and cable length."""
        from dataclasses import replace

        p = self.payload
        return replace(self.vehicle, m=self.vehicle.m if p.mass_kg is None else p.mass_kg,
                       l=self.vehicle.l if p.cable_length_m is None else p.cable_length_m)

    def with_(self, **changes: Any) -> Mission:
        """A copy with fields replaced (e.g. another planner for a comparison run)."""
        from dataclasses import replace

        return replace(self, **changes)


def _check_clear(where: str, key: str, p: np.ndarray, obstacles: tuple[Obstacle, ...], vp: VehicleParams,
                 table: str = "[mission]") -> None:
    airframe = vp.r_uav + vp.L_uav
    for i, o in enumerate(obstacles):
        if p[2] < -o.height_m:
            continue  # above the trunk's top
        d = math.hypot(p[0] - o.x_m, p[1] - o.y_m)
        need = o.radius_m + o.safe_distance_m + airframe
        if d < need:
            raise ConfigError(
                f"{where}: {table} {key}: ({p[0]:g}, {p[1]:g}) is {d:.3f} m from obstacle {i} "
                f"at ({o.x_m:g}, {o.y_m:g}); needs >= {need:.3f} m (radius + safe distance + airframe)"
            )


def _waypoints(raw: Any, where: str, obs: tuple[Obstacle, ...], vp: VehicleParams) -> tuple[Waypoint, ...]:
    """The ``[[waypoints]]`` tables, validated (see module docstring)."""
    if not isinstance(raw, list):
        raise ConfigError(f"{where}: waypoints: expected an array of tables [[waypoints]]")
    if len(raw) > MAX_WAYPOINTS:
        raise ConfigError(f"{where}: [[waypoints]]: {len(raw)} waypoints, at most {MAX_WAYPOINTS}")
    out = []
    for i, t in enumerate(raw):
        wt = dataclass_from_table(WaypointTable, t, where=f"{where}: [[waypoints]] #{i}")
        pos = np.array(wt.ned_m, dtype=np.float64)
        _check_clear(where, "ned_m", pos, obs, vp, table=f"[[waypoints]] #{i}")
        out.append(Waypoint(pos, float(wt.hold_s), wt.speed_max_mps, wt.name))
    return tuple(out)


def mission_from_dict(data: dict[str, Any], where: str) -> Mission:
    """Build and validate a :class:`Mission` from a parsed TOML document; ``where`` names the file."""
    unknown = sorted(set(data) - {"mission", "wind", "vehicle", "payload", "obstacles", "waypoints", "fence"})
    if unknown:
        raise ConfigError(f"{where}: unknown table or key {unknown[0]!r} "
                          "(known: mission, wind, vehicle, payload, obstacles, waypoints, fence)")
    if "mission" not in data:
        raise ConfigError(f"{where}: missing required table [mission]")
    mt = dataclass_from_table(MissionTable, data["mission"], where=f"{where}: [mission]")
    wind = dataclass_from_table(WindConfig, data.get("wind", {"model": "none", "scale": 0.0}), where=f"{where}: [wind]")
    vp = vehicle_params_with(VehicleParams(), data.get("vehicle", {}), where=f"{where}: [vehicle]")
    payload = dataclass_from_table(PayloadConfig, data.get("payload", {}), where=f"{where}: [payload]")
    if payload.mass_kg is not None and payload.mass_kg > 10.0 * vp.M:
        raise ConfigError(f"{where}: [payload] mass_kg: {payload.mass_kg} kg is more than ten times the vehicle mass")
    raw_obs = data.get("obstacles", [])
    if not isinstance(raw_obs, list):
        raise ConfigError(f"{where}: obstacles: expected an array of tables [[obstacles]]")
    obstacles = []
    for i, t in enumerate(raw_obs):
        w = f"{where}: [[obstacles]] #{i}"
        if isinstance(t, dict) and "source" in t:
            raise ConfigError(f"{w}: unknown key 'source' (set by the program, not the file)")
        obstacles.append(dataclass_from_table(Obstacle, t, where=w))
    obs = tuple(obstacles)
    start = np.array(mt.start_ned_m, dtype=np.float64)
    goal = np.array(mt.goal_ned_m, dtype=np.float64)
    _check_clear(where, "start_ned_m", start, obs, vp)
    _check_clear(where, "goal_ned_m", goal, obs, vp)
    waypoints = _waypoints(data.get("waypoints", []), where, obs, vp)
    fence = parse_fence(data["fence"], where) if "fence" in data else None
    airframe = vp.r_uav + vp.L_uav
    check_fenced(where, "[mission] start_ned_m", start, fence, airframe)
    check_fenced(where, "[mission] goal_ned_m", goal, fence, airframe)
    for i, wp in enumerate(waypoints):
        check_fenced(where, f"[[waypoints]] #{i} ned_m", wp.pos_ned_m, fence, airframe)
    return Mission(
        name=mt.name, start_ned_m=start, goal_ned_m=goal, planner=mt.planner, controller=mt.controller,
        timeout_s=mt.timeout_s, wind=wind, vehicle=vp, obstacles=obs, hold_s=mt.hold_s, land=mt.land,
        source_path=where, payload=payload, waypoints=waypoints, fence=fence,
    )


def load_mission(path: str | Path) -> Mission:
    """Read and validate a mission file; raises :class:`ConfigError` naming the file and the key."""
    return mission_from_dict(read_toml(path), str(path))


def mission_to_toml(mission: Mission) -> str:
    """The mission as a TOML document :func:`load_mission` reads back (used to replay generated forests)."""

    def vec(v: np.ndarray) -> str:
        return "[" + ", ".join(repr(float(c)) for c in v) + "]"

    lines = [
        "[mission]",
        f'name = "{mission.name}"',
        f"start_ned_m = {vec(mission.start_ned_m)}",
        f"goal_ned_m = {vec(mission.goal_ned_m)}",
        f'planner = "{mission.planner}"',
        f'controller = "{mission.controller}"',
        f"timeout_s = {float(mission.timeout_s)!r}",
        f"hold_s = {float(mission.hold_s)!r}",
        f"land = {'true' if mission.land else 'false'}",
        "",
        "[wind]",
        *mission.wind.toml_lines(),
        "",
        "[vehicle]",
    ]
    for k, v in mission.vehicle.as_dict().items():
        lines.append(f"{k} = {float(v)!r}")
    p = mission.payload
    if not p.is_default:
        lines += ["", "[payload]"]
        if p.mass_kg is not None:
            lines.append(f"mass_kg = {float(p.mass_kg)!r}")
        if p.cable_length_m is not None:
            lines.append(f"cable_length_m = {float(p.cable_length_m)!r}")
        lines.append(f"identify = {'true' if p.identify else 'false'}")
        if p.drag_n_per_mps2:
            lines.append(f"drag_n_per_mps2 = {float(p.drag_n_per_mps2)!r}")
        if p.airframe_drag_n_per_mps2:
            lines.append(f"airframe_drag_n_per_mps2 = {float(p.airframe_drag_n_per_mps2)!r}")
    for o in mission.obstacles:
        lines += [
            "",
            "[[obstacles]]",
            f"x_m = {o.x_m!r}",
            f"y_m = {o.y_m!r}",
            f"radius_m = {o.radius_m!r}",
            f"height_m = {o.height_m!r}",
            f"safe_distance_m = {o.safe_distance_m!r}",
        ]
        if o.vx_mps or o.vy_mps:
            lines += [f"vx_mps = {o.vx_mps!r}", f"vy_mps = {o.vy_mps!r}"]
    return "\n".join(lines + _legs_toml(mission)) + "\n"


def _legs_toml(mission: Mission) -> list[str]:
    """The ``[[waypoints]]`` and ``[fence]`` lines of :func:`mission_to_toml`."""
    lines: list[str] = []
    for wp in mission.waypoints:
        lines += ["", "[[waypoints]]", "ned_m = [" + ", ".join(repr(float(c)) for c in wp.pos_ned_m) + "]",
                  f"hold_s = {float(wp.hold_s)!r}"]
        if wp.speed_max_mps is not None:
            lines.append(f"speed_max_mps = {float(wp.speed_max_mps)!r}")
        if wp.name:
            lines.append(f"name = {json.dumps(wp.name)}")
    return lines + fence_toml(mission.fence)

