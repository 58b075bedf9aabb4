"""Random forests (and traps) from a seed, as missions the companion can fly. Pure: numpy only, no I/O.

Geometry (NED metres, flown at ``altitude_m`` above ground):

* The corridor runs north from the start ``(0, 0)`` to the goal ``(length_m, 0)``; trunks stand in the
  rectangle ``0 <= x <= length_m``, ``|y| <= width_m / 2``. The default width of 6 m leaves the vehicle with
  a 1 m cable about one envelope on each side of the widest detour it should need; the vehicle may fly
  outside the rectangle (there are no walls), so a forest is never closed.
* Trunk count: ``round(density_per_100m2 * length_m * width_m / 100)`` (plus the trap trunks, if any).
  Positions uniform in the rectangle, radii uniform in ``[r_min_m, r_max_m]`` (0.15–0.35 m), rejection
  sampled so trunks do not overlap (surfaces at least ``min_gap_m`` apart) and no trunk surface comes
  closer than ``clear_radius_m`` to the start or the goal (so the mission file validator always accepts it).
* Variations (``vary=True``): wind scale U(0, 1.3) (eq. 49 beyond 1.34 exceeds the airframe's yaw authority: the
  bundled vehicle refuses it, :func:`sim_bridge.inner_loop.eq49_torque_problem`), payload mass U(0.1, 0.5) kg,
  cable length U(0.5, 1.5) m;
  otherwise the fixed ``wind_scale``, ``payload_kg`` and ``cable_m`` (default: Table 1, wind 1).
* Traps (``trap="pair" | "cluster" | "mixed"``), placed across the path at ``x`` in the middle third:
  ``pair`` is two trunks side by side with a surface gap of 0.15–0.35 m (narrower than the airframe circle
  2 (r_uav + L_uav) = 0.56 m), centred on the path within ±0.1 m; ``cluster`` is 5–7 trunks on a half circle of
  radius 1.0–1.4 m whose open side faces the start (a cup the attractive force pushes the vehicle into).
  ``mixed`` picks one of the two per seed. ``fence`` rings the goal with trunks (radius 0.25 m on a circle of
  1.3 m, surface gaps 0.15–0.35 m, narrower than the airframe circle): no route to the goal exists, the
  mission's correct outcome is ``no_route``.
* Moving trunks (``movers`` > 0): each crosses the straight path at a point uniform in the middle of the
  corridor (25–85 % of its length), within ±30° of square to it, at U(``mover_speed_min_mps``,
  ``mover_speed_max_mps``), radius U(r_min, r_max). Its file position is where it is at the mission clock's
  zero (the first setpoint, on the ground), timed so that it reaches the path when a vehicle that climbs for
  ``climb_s`` and then accelerates at 1.5 m/s² to ``cruise_mps`` would be there, ± U(0, ``mover_jitter_s``):
  pedestrians or vehicles crossing in front of, onto and behind the vehicle. Its track keeps at least
  ``clear_radius_m`` from the start and the goal, so it never runs over the vehicle climbing or holding
  there. Trunks move through one another (they are not simulated, only flown around).

Everything is drawn from ``numpy.random.default_rng(seed)`` in a fixed order: the same (spec, seed) always
gives the same mission.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from companion.core.mission import Mission
from companion.core.obstacles import Obstacle
from companion.core.vehicle_params import VehicleParams
from companion.core.wind import WindConfig

TRAP_KINDS = ("none", "pair", "cluster", "mixed", "fence")
MAX_EQ49_SCALE = 1.3  # the largest eq. 49 scale the Table 1 airframe holds (yaw authority at hover, with margin)


@dataclass(frozen=True)
class ForestSpec:
    """How to generate a forest (lengths m, density trunks per 100 m², mass kg)."""

    density_per_100m2: float = 3.0
    length_m: float = 20.0
    width_m: float = 6.0
    altitude_m: float = 2.0
    r_min_m: float = 0.15
    r_max_m: float = 0.35
    trunk_height_m: float = 4.0
    safe_distance_m: float = 0.1
    clear_radius_m: float = 1.5
    min_gap_m: float = 0.1
    vary: bool = False
    wind_scale: float = 1.0
    payload_kg: float = 0.25
    cable_m: float = 1.0
    trap: str = "none"
    planner: str = "safe"
    controller: str = "smc_ff"
    timeout_s: float = 60.0
    hold_s: float = 1.0
    land: bool = False
    movers: int = 0
    mover_speed_min_mps: float = 0.5
    mover_speed_max_mps: float = 1.5
    mover_jitter_s: float = 1.5
    climb_s: float = 2.2
    cruise_mps: float = 3.0

    def validate(self) -> None:
        """Raise ``ValueError("<key>: ...")`` for values the generator cannot honour."""
        if not 0.0 <= self.density_per_100m2 <= 30.0:
            raise ValueError(f"density_per_100m2: must be in [0, 30], got {self.density_per_100m2}")
        if not 2.0 * self.clear_radius_m < self.length_m <= 1000.0:
            raise ValueError(f"length_m: must be in (2 clear_radius_m, 1000], got {self.length_m}")
        if not 0.0 < self.width_m <= 100.0:
            raise ValueError(f"width_m: must be in (0, 100], got {self.width_m}")
        if not 0.0 < self.r_min_m <= self.r_max_m:
            raise ValueError(f"r_max_m: need 0 < r_min_m <= r_max_m, got {self.r_min_m}, {self.r_max_m}")
        if not 0.0 < self.altitude_m < self.trunk_height_m:
            raise ValueError(f"altitude_m: must be in (0, trunk_height_m), got {self.altitude_m}")
        airframe = VehicleParams().r_uav + VehicleParams().L_uav
        if self.clear_radius_m < self.safe_distance_m + airframe:
            raise ValueError(f"clear_radius_m: must be >= safe distance + airframe = {self.safe_distance_m + airframe}")
        if not 0.0 <= self.wind_scale <= MAX_EQ49_SCALE:
            raise ValueError(f"wind_scale: must be in [0, {MAX_EQ49_SCALE}] (eq. 49's yaw torque beyond it exceeds the "
                             f"airframe's authority), got {self.wind_scale}")
        if not 0.1 <= self.payload_kg <= 0.5:
            raise ValueError(f"payload_kg: must be in [0.1, 0.5], got {self.payload_kg}")
        if not 0.5 <= self.cable_m <= 1.5:
            raise ValueError(f"cable_m: must be in [0.5, 1.5], got {self.cable_m}")
        if self.trap not in TRAP_KINDS:
            raise ValueError(f"trap: must be one of {', '.join(TRAP_KINDS)}, got {self.trap!r}")
        if self.timeout_s <= 0.0:
            raise ValueError(f"timeout_s: must be > 0, got {self.timeout_s}")
        if not 0 <= self.movers <= 20:
            raise ValueError(f"movers: must be in 0..20, got {self.movers}")
        if not 0.0 < self.mover_speed_min_mps <= self.mover_speed_max_mps <= 10.0:
            raise ValueError(f"mover_speed_max_mps: need 0 < min <= max <= 10 m/s, got "
                             f"{self.mover_speed_min_mps}, {self.mover_speed_max_mps}")
        if self.mover_jitter_s < 0.0 or self.climb_s < 0.0 or self.cruise_mps <= 0.0:
            raise ValueError("mover_jitter_s: jitter and climb time must be >= 0, cruise speed > 0")

    def with_(self, **changes: object) -> ForestSpec:
        """A validated copy with fields replaced."""
        out = replace(self, **changes)
        out.validate()
        return out

    @property
    def n_trunks(self) -> int:
        """Random trunks (traps not counted) for this density and corridor."""
        return round(self.density_per_100m2 * self.length_m * self.width_m / 100.0)


def _fits(x: float, y: float, r: float, placed: list[tuple[float, float, float]], spec: ForestSpec,
          goal_x: float) -> bool:
    for px, py in ((0.0, 0.0), (goal_x, 0.0)):
        if math.hypot(x - px, y - py) - r < spec.clear_radius_m:
            return False
    return all(math.hypot(x - ox, y - oy) - r - orr >= spec.min_gap_m for ox, oy, orr in placed)


def _trap_trunks(rng: np.random.Generator, spec: ForestSpec, kind: str) -> list[tuple[float, float, float]]:
    """Trunks (x, y, r) of one trap across the path, centred in the middle third of the corridor."""
    x_c = float(rng.uniform(spec.length_m / 3.0, 2.0 * spec.length_m / 3.0))
    if kind == "pair":
        r = float(rng.uniform(0.25, spec.r_max_m))
        gap = float(rng.uniform(0.15, 0.35))
        y_c = float(rng.uniform(-0.1, 0.1))
        half = r + gap / 2.0
        return [(x_c, y_c - half, r), (x_c, y_c + half, r)]
    # cluster: a cup, open towards the start, bottom towards the goal
    radius = float(rng.uniform(1.0, 1.4))
    n = int(rng.integers(5, 8))
    r = float(rng.uniform(0.2, spec.r_max_m))
    angles = np.linspace(-0.5 * math.pi, 0.5 * math.pi, n)
    x0 = x_c - radius / 2.0
    return [(x0 + radius * math.cos(a), radius * math.sin(a), r) for a in angles]


def _fence_trunks(spec: ForestSpec, rng: np.random.Generator) -> list[tuple[float, float, float]]:
    """Trunks (x, y, r) on a circle around the goal with gaps narrower than the airframe circle."""
    radius, r = 1.3, 0.25
    gap = float(rng.uniform(0.15, 0.35))
    n = math.ceil(2.0 * math.pi * radius / (2.0 * r + gap))
    phase = float(rng.uniform(0.0, 2.0 * math.pi / n))
    return [(spec.length_m + radius * math.cos(phase + 2.0 * math.pi * k / n),
             radius * math.sin(phase + 2.0 * math.pi * k / n), r) for k in range(n)]


def _movers(rng: np.random.Generator, spec: ForestSpec) -> list[Obstacle]:
    """Trunks crossing the straight path (see module docstring)."""
    out = []
    a_nom = 1.5
    for _ in range(spec.movers):
        x_c = float(rng.uniform(0.25, 0.85)) * spec.length_m
        ang = float(rng.uniform(-math.pi / 6.0, math.pi / 6.0))
        side = 1.0 if rng.uniform() < 0.5 else -1.0
        speed = float(rng.uniform(spec.mover_speed_min_mps, spec.mover_speed_max_mps))
        r = float(rng.uniform(spec.r_min_m, spec.r_max_m))
        jitter = float(rng.uniform(-spec.mover_jitter_s, spec.mover_jitter_s))
        d_acc = spec.cruise_mps**2 / (2.0 * a_nom)
        t_at = (math.sqrt(2.0 * x_c / a_nom) if x_c < d_acc
                else spec.cruise_mps / a_nom + (x_c - d_acc) / spec.cruise_mps)
        t_c = max(0.0, spec.climb_s + t_at + jitter)
        # moving across the path (+y or −y), tilted by ang from square
        vx, vy = speed * math.sin(ang), side * speed * math.cos(ang)
        out.append(Obstacle(x_m=round(x_c - vx * t_c, 4), y_m=round(-vy * t_c, 4), radius_m=round(r, 4),
                            height_m=spec.trunk_height_m, safe_distance_m=spec.safe_distance_m,
                            vx_mps=round(vx, 4), vy_mps=round(vy, 4)))
    return out


def _track_clear(o: Obstacle, points: tuple[tuple[float, float], ...], clear_m: float) -> bool:
    """Does the moving obstacle's straight track keep ``clear_m`` (surface) from each point?"""
    sp = math.hypot(o.vx_mps, o.vy_mps)
    ux, uy = o.vx_mps / sp, o.vy_mps / sp
    for px, py in points:
        dx, dy = px - o.x_m, py - o.y_m
        if abs(dx * uy - dy * ux) - o.radius_m < clear_m:
            return False
    return True


def _fill_random(placed: list[tuple[float, float, float]], spec: ForestSpec, rng: np.random.Generator,
                 goal_x: float) -> None:
    """Add ``spec.n_trunks`` random trunks (x, y, r; m) to ``placed`` where they fit (200 tries a trunk at most)."""
    half_w = spec.width_m / 2.0
    target = len(placed) + spec.n_trunks
    attempts = 0
    while len(placed) < target and attempts < 200 * max(1, spec.n_trunks):
        attempts += 1
        x = float(rng.uniform(0.0, spec.length_m))
        y = float(rng.uniform(-half_w, half_w))
        r = float(rng.uniform(spec.r_min_m, spec.r_max_m))
        if _fits(x, y, r, placed, spec, goal_x):
            placed.append((x, y, r))


def _clear_movers(spec: ForestSpec, rng: np.random.Generator, goal_x: float) -> tuple[Obstacle, ...]:
    """``spec.movers`` crossing trunks whose tracks keep clear of the start and the goal (100 tries each)."""
    movers: list[Obstacle] = []
    ends = ((0.0, 0.0), (goal_x, 0.0))
    attempts = 0
    while len(movers) < spec.movers and attempts < 100 * spec.movers:
        attempts += 1
        o = _movers(rng, spec.with_(movers=1))[0]
        if _track_clear(o, ends, spec.clear_radius_m):
            movers.append(o)
    return tuple(movers)


def generate_forest(seed: int, spec: ForestSpec | None = None) -> Mission:
    """The mission for ``seed``: a random forest (and trap) in the corridor, start and goal at its ends."""
    spec = spec or ForestSpec()
    spec.validate()
    rng = np.random.default_rng(seed)
    if spec.vary:
        wind_scale = float(rng.uniform(0.0, MAX_EQ49_SCALE))
        payload = float(rng.uniform(0.1, 0.5))
        cable = float(rng.uniform(0.5, 1.5))
    else:
        wind_scale, payload, cable = spec.wind_scale, spec.payload_kg, spec.cable_m
    kind = spec.trap
    if kind == "mixed":
        kind = ("pair", "cluster")[int(rng.integers(0, 2))]
    placed: list[tuple[float, float, float]] = []
    if kind == "fence":
        placed += _fence_trunks(spec, rng)
    elif kind != "none":
        placed += _trap_trunks(rng, spec, kind)
    goal_x = spec.length_m
    _fill_random(placed, spec, rng, goal_x)
    obstacles = tuple(
        Obstacle(x_m=round(x, 4), y_m=round(y, 4), radius_m=round(r, 4), height_m=spec.trunk_height_m,
                 safe_distance_m=spec.safe_distance_m)
        for x, y, r in placed
    )
    if spec.movers:
        obstacles = obstacles + _clear_movers(spec, rng, goal_x)
    vehicle = replace(VehicleParams(), m=round(payload, 4), l=round(cable, 4))
    vehicle.validate()
    tag = (f"-{kind}" if kind != "none" else "") + (f"-m{spec.movers}" if spec.movers else "")
    z = -spec.altitude_m
    return Mission(
        name=f"forest-s{seed}-d{spec.density_per_100m2:g}{tag}",
        start_ned_m=np.array([0.0, 0.0, z]),
        goal_ned_m=np.array([spec.length_m, 0.0, z]),
        planner=spec.planner,
        controller=spec.controller,
        timeout_s=spec.timeout_s,
        wind=WindConfig("paper" if wind_scale > 0.0 else "none", round(wind_scale, 4)),
        vehicle=vehicle,
        obstacles=obstacles,
        hold_s=spec.hold_s,
        land=spec.land,
        source_path=f"lab.forests seed={seed}",
    )

