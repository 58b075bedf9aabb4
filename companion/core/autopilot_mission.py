"""The autopilot's own mission (what the operator uploaded with a ground station) as a :class:`Mission`.

``fly --mission autopilot`` downloads the autopilot's MAV_MISSION_TYPE_MISSION and _FENCE items
(:mod:`companion.mavlink_io.mission_client`); this module turns them into the mission the pilot flies. The flight's
mission file still gives the planner, controller, vehicle, payload, wind and obstacles; the autopilot's mission gives
the route (start altitude, waypoints with holds, the goal, whether to land) and the fence (the flight core turns
it into keep-out discs for every planner: :mod:`companion.planning.fence_guard`).

Items (each with ``item_seq``, ``frame``, ``command``, ``params`` (4 floats), ``x``, ``y``, ``z`` as
MISSION_ITEM_INT carries them):

* frames: MAV_FRAME_GLOBAL(_INT) (altitude above mean sea level), MAV_FRAME_GLOBAL_RELATIVE_ALT(_INT) (altitude
  above home), MAV_FRAME_LOCAL_NED (x, y: m × 1e4 and z: m down, in the autopilot's local frame);
  MAV_FRAME_MISSION only for a return to launch (no position);
* commands: NAV_TAKEOFF (first item only: its altitude is the start's; the vehicle climbs where it stands),
  NAV_WAYPOINT (param1: hold time, s), NAV_LAND (last: land there, or where the previous point was when its latitude
  and longitude are 0), NAV_RETURN_TO_LAUNCH (last: fly back above the start at take-off altitude, then land).
  Anything else is refused before take-off naming the item and the command.

Positions are in the mission frame: NED metres from home (:mod:`companion.flight.mission_frame`). Latitude and
longitude become north and east about home with an equirectangular (flat-earth) formula: north = Δφ·R_N,
east = Δλ·R_E·cos φ_home, with the radii the autopilot itself uses for its local frame (:data:`EARTH_MODELS`: PX4 a
6371 km sphere, ArduPilot 6378.1 km, the bundled vehicle WGS-84's local radii). Against PX4's own azimuthal
equidistant projection the difference is of second order, about d²·tan φ / (2R) for a point d east of home:
0.8 mm at 100 m, 8 cm at 1 km, 8 m at 10 km at 45° latitude; points farther than 10 km from home are refused.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from itertools import pairwise
from typing import Any

import numpy as np

from companion.core.fence import Fence, check_point, fence_from_items, segment_clear
from companion.core.mission import Mission, Waypoint

MAV_FRAME_GLOBAL, MAV_FRAME_LOCAL_NED, MAV_FRAME_MISSION, MAV_FRAME_GLOBAL_RELATIVE_ALT = 0, 1, 2, 3
MAV_FRAME_GLOBAL_INT, MAV_FRAME_GLOBAL_RELATIVE_ALT_INT = 5, 6
FRAME_NAMES = {0: "MAV_FRAME_GLOBAL", 1: "MAV_FRAME_LOCAL_NED", 2: "MAV_FRAME_MISSION",
               3: "MAV_FRAME_GLOBAL_RELATIVE_ALT", 5: "MAV_FRAME_GLOBAL_INT", 6: "MAV_FRAME_GLOBAL_RELATIVE_ALT_INT"}
_AMSL_FRAMES = (MAV_FRAME_GLOBAL, MAV_FRAME_GLOBAL_INT)
_RELATIVE_FRAMES = (MAV_FRAME_GLOBAL_RELATIVE_ALT, MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)
MAV_CMD_NAV_WAYPOINT, MAV_CMD_NAV_RETURN_TO_LAUNCH, MAV_CMD_NAV_LAND, MAV_CMD_NAV_TAKEOFF = 16, 20, 21, 22
SUPPORTED_COMMANDS = {16: "MAV_CMD_NAV_WAYPOINT", 20: "MAV_CMD_NAV_RETURN_TO_LAUNCH", 21: "MAV_CMD_NAV_LAND",
                      22: "MAV_CMD_NAV_TAKEOFF"}
#: a few commands' names for the refusal messages (others are named by number)
OTHER_COMMAND_NAMES = {17: "MAV_CMD_NAV_LOITER_UNLIM", 18: "MAV_CMD_NAV_LOITER_TURNS", 19: "MAV_CMD_NAV_LOITER_TIME",
                       82: "MAV_CMD_NAV_SPLINE_WAYPOINT", 93: "MAV_CMD_NAV_DELAY", 112: "MAV_CMD_CONDITION_DELAY",
                       177: "MAV_CMD_DO_JUMP", 178: "MAV_CMD_DO_CHANGE_SPEED", 183: "MAV_CMD_DO_SET_SERVO",
                       201: "MAV_CMD_DO_SET_ROI", 206: "MAV_CMD_DO_SET_CAM_TRIGG_DIST",
                       2000: "MAV_CMD_IMAGE_START_CAPTURE", 5000: "MAV_CMD_NAV_FENCE_RETURN_POINT"}
#: (north radius m, east radius m) of the earth as each autopilot family makes its local frame, or "wgs84"
EARTH_MODELS: dict[str, tuple[float, float] | str] = {
    "px4": (6_371_000.0, 6_371_000.0),  # PX4's map_projection: a sphere
    "ardupilot": (6_378_100.0, 6_378_100.0),  # ArduPilot's LOCATION_SCALING_FACTOR (m per 1e-7 degree)
    "wgs84": "wgs84",  # the bundled vehicle: WGS-84's meridian and prime-vertical radii at home
}
LAND_HERE_M = 0.5  # a landing this close (m) to the previous point lands there (no leg of its own)
MAX_DISTANCE_M = 1.0e4  # from home: farther is refused (the flat-earth formula's range)
_WGS84_A, _WGS84_E2 = 6_378_137.0, 6.69437999014e-3


@dataclass(frozen=True)
class Home:
    """The autopilot's home: in its local NED frame (m) and as WGS-84 latitude, longitude (deg) and altitude above
    mean sea level (m) (HOME_POSITION)."""

    pos_ned_m: tuple[float, float, float]
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float


def earth_radii_m(model: str, lat_deg: float, alt_m: float = 0.0) -> tuple[float, float]:
    """(north radius, east radius) m that a latitude and a longitude difference (rad) are multiplied by (the east
    one before cos φ) for ``model`` (:data:`EARTH_MODELS`) at ``lat_deg``; WGS-84's grow by ``alt_m``."""
    radii = EARTH_MODELS[model]
    if radii != "wgs84":
        return radii  # type: ignore[return-value]
    s2 = math.sin(math.radians(lat_deg)) ** 2
    return (_WGS84_A * (1.0 - _WGS84_E2) / (1.0 - _WGS84_E2 * s2) ** 1.5 + alt_m,
            _WGS84_A / math.sqrt(1.0 - _WGS84_E2 * s2) + alt_m)


class Placement:
    """Where an item's position is in the mission frame (NED m from home), or why it cannot be placed."""

    def __init__(self, home: Home, earth_model: str = "px4") -> None:
        self.home = home
        self.r_n, r_e = earth_radii_m(earth_model, home.lat_deg, home.alt_amsl_m)
        self.r_e_cos = r_e * math.cos(math.radians(home.lat_deg))

    def ned(self, it: Any, horizontal: bool = True) -> np.ndarray:
        """The item's (north, east, down) m in the mission frame (north and east 0 when not ``horizontal``: a
        take-off's altitude only); ValueError naming the item otherwise."""
        w = f"item {it.item_seq}"
        if it.frame in _AMSL_FRAMES or it.frame in _RELATIVE_FRAMES:
            h = self.home
            n = math.radians(it.x * 1e-7 - h.lat_deg) * self.r_n if horizontal else 0.0
            e = math.radians(it.y * 1e-7 - h.lon_deg) * self.r_e_cos if horizontal else 0.0
            d = -(it.z - h.alt_amsl_m) if it.frame in _AMSL_FRAMES else -it.z
        elif it.frame == MAV_FRAME_LOCAL_NED:
            h = self.home.pos_ned_m
            n, e = (it.x * 1e-4 - h[0], it.y * 1e-4 - h[1]) if horizontal else (0.0, 0.0)
            d = it.z - h[2]
        else:
            raise ValueError(f"{w}: frame {FRAME_NAMES.get(it.frame, it.frame)} ({it.frame}) is not supported; "
                             f"supported: {', '.join(f'{FRAME_NAMES[f]} ({f})' for f in (0, 1, 3, 5, 6))}")
        if not all(math.isfinite(c) for c in (n, e, d)):
            raise ValueError(f"{w}: a coordinate is not a number (x={it.x}, y={it.y}, z={it.z})")
        dist = math.hypot(n, e)
        if dist > MAX_DISTANCE_M:
            raise ValueError(f"{w}: {dist / 1000.0:.1f} km from home, beyond {MAX_DISTANCE_M / 1000.0:g} km")
        return np.array([n, e, d])

    def ne(self, it: Any) -> tuple[float, float]:
        """The item's (north, east) m in the mission frame (a fence vertex or centre)."""
        p = self.ned(it)
        return float(p[0]), float(p[1])


def command_name(cmd: int) -> str:
    """``MAV_CMD_...`` of a command number when known, else ``MAV_CMD <n>``."""
    return SUPPORTED_COMMANDS.get(cmd) or OTHER_COMMAND_NAMES.get(cmd) or f"MAV_CMD {cmd}"


@dataclass
class _Route:
    """What the items say, in order: the take-off altitude, the points (seq, NED m, hold s), how it ends."""

    takeoff_alt_m: float | None = None
    points: list[tuple[int, np.ndarray, float]] | None = None
    end: str = ""  # "", "land" or "rtl"
    end_seq: int = -1


def _altitude_ok(w: str, p: np.ndarray) -> None:
    if p[2] >= 0.0:
        raise ValueError(f"{w}: altitude {-p[2]:.2f} m above home is at or below the ground")


def _route(items: Sequence[Any], place: Placement) -> _Route:
    """The route the items describe (see the module docstring); ValueError naming the first item not understood."""
    r = _Route(points=[])
    assert r.points is not None
    for k, it in enumerate(items):
        cmd, w = it.command, f"item {it.item_seq}"
        if r.end:
            raise ValueError(f"{w}: {command_name(cmd)} after {command_name(items[k - 1].command)} (item "
                             f"{r.end_seq}): nothing after the landing is flown")
        if cmd not in SUPPORTED_COMMANDS:
            raise ValueError(f"{w}: {command_name(cmd)} ({cmd}) is not supported; supported: "
                             + ", ".join(f"{n} ({c})" for c, n in SUPPORTED_COMMANDS.items()))
        if cmd == MAV_CMD_NAV_TAKEOFF:
            if k != 0:
                raise ValueError(f"{w}: MAV_CMD_NAV_TAKEOFF must be the first item")
            p = place.ned(it, horizontal=False)  # it climbs where it stands: its latitude and longitude unused
            _altitude_ok(w, p)
            r.takeoff_alt_m = float(-p[2])
        elif cmd == MAV_CMD_NAV_WAYPOINT:
            p = place.ned(it)
            _altitude_ok(w, p)
            hold = it.params[0]
            if not (math.isfinite(hold) and 0.0 <= hold <= 600.0):
                raise ValueError(f"{w}: MAV_CMD_NAV_WAYPOINT hold time (param1) {hold} s is not in [0, 600]")
            r.points.append((it.item_seq, p, float(hold)))
        else:
            r.end, r.end_seq = ("land" if cmd == MAV_CMD_NAV_LAND else "rtl"), it.item_seq
            if cmd == MAV_CMD_NAV_LAND and (it.x != 0 or it.y != 0):
                p = place.ned(it)
                prev = r.points[-1][1] if r.points else np.array([0.0, 0.0, -(r.takeoff_alt_m or 0.0)])
                if math.hypot(p[0] - prev[0], p[1] - prev[1]) > LAND_HERE_M:  # else: where the previous point is
                    r.points.append((it.item_seq, np.array([p[0], p[1], prev[2]]), 0.0))
    return r


def mission_from_items(items: Sequence[Any], fence_items: Sequence[Any], home: Home, base: Mission, *,
                       earth_model: str = "px4", skip_home_item: bool = False) -> tuple[Mission, list[str]]:
    """The mission to fly: ``base`` (the flight's mission file: planner, controller, vehicle, payload, wind,
    obstacles, timeout) with the route of the autopilot's ``items`` and the fence of its ``fence_items``; and notes
    for the report. It lands when the route ends with a landing or a return and ``base.land`` (False with
    ``--no-land``) allows it. ``skip_home_item``: item 0 is home (ArduPilot), not part of the route. Raises
    ValueError naming the item (or point) that cannot be flown: nothing is flown half-understood."""
    notes: list[str] = []
    place = Placement(home, earth_model)
    if skip_home_item and items:
        notes.append("item 0 is the autopilot's home (ArduPilot), not flown")
        items = items[1:]
    elif items and _is_home_item(items[0], place):
        notes.append("item 0 is a waypoint on the ground at home (a WPL file's home line, as MAVProxy uploads it): "
                     "not flown")
        items = items[1:]
    route = _route(items, place)
    points = route.points or []
    if not points:
        raise ValueError("no waypoint to fly to (upload a mission with a ground station first)"
                         if items else "no items (upload a mission with a ground station first)")
    if route.takeoff_alt_m is None:
        route.takeoff_alt_m = float(-points[0][1][2])
        notes.append(f"no MAV_CMD_NAV_TAKEOFF: the start altitude is the first waypoint's "
                     f"({route.takeoff_alt_m:.2f} m)")
    start = np.array([0.0, 0.0, -route.takeoff_alt_m])
    if route.end == "rtl":
        points.append((route.end_seq, start.copy(), 0.0))
    fence, fence_notes = fence_from_items(fence_items, place.ne)
    notes += fence_notes
    named = [("the start (home at take-off altitude)", start)] + [(f"item {s}", p) for s, p, _ in points]
    _check_points(named, fence, base)
    notes += _legs_near_the_fence(named, fence, base.vehicle.r_uav + base.vehicle.L_uav)
    if not route.end:
        notes.append("the mission ends without MAV_CMD_NAV_LAND or RETURN_TO_LAUNCH: the vehicle holds at the end")
    elif not base.land:
        notes.append(f"the mission ends with {command_name(items[-1].command)}, but the flight is not to land "
                     "(--no-land or the base mission's land = false): the vehicle holds at the end")
    wps = tuple(Waypoint(p, hold_s=h, name=f"item {s}") for s, p, h in points[:-1])
    path_m = sum(float(np.linalg.norm(b[1] - a[1])) for a, b in zip([(0, start, 0.0), *points], points,
                                                                      strict=False))
    timeout = min(3600.0, max(base.timeout_s, 30.0 + path_m / 0.5 + sum(h for _, _, h in points)))
    mission = base.with_(name="autopilot", start_ned_m=start, goal_ned_m=points[-1][1].copy(),
                         hold_s=points[-1][2] if not route.end else 1.0, land=bool(route.end) and base.land,
                         waypoints=wps,
                         fence=None if fence.empty else fence, timeout_s=timeout,
                         source_path=f"autopilot ({len(items)} items, {len(fence_items)} fence items)")
    return mission, notes


def _is_home_item(it: Any, place: Placement) -> bool:
    """Whether ``it`` is a NAV_WAYPOINT within 1 m of home and at most 0.5 m above it: the home line of a QGC WPL
    file (ArduPilot's item 0), which MAVProxy uploads to any autopilot as item 0."""
    if it.command != MAV_CMD_NAV_WAYPOINT:
        return False
    try:
        p = place.ned(it)
    except ValueError:
        return False
    return math.hypot(p[0], p[1]) <= 1.0 and p[2] >= -0.5


def _legs_near_the_fence(named: list[tuple[str, np.ndarray]], fence: Fence, margin_m: float) -> list[str]:
    """Notes for the straight legs that would not keep ``margin_m`` (m, the airframe) inside the fence: the planners
    route around its keep-out discs, so such a leg is flown bent (or ends no_route), not refused."""
    if fence.empty:
        return []
    out = []
    for (wa, a), (wb, b) in pairwise(named):
        if not segment_clear(fence, (float(a[0]), float(a[1])), (float(b[0]), float(b[1])), margin_m):
            out.append(f"the straight leg from {wa} to {wb} would come within {margin_m:.2f} m of the fence's "
                       "boundary (or cross it): the planner must route around it")
    return out


def _check_points(named: list[tuple[str, np.ndarray]], fence: Fence, base: Mission) -> None:
    """ValueError naming the first point outside the fence or inside an obstacle's ring (airframe included)."""
    vp = base.vehicle
    airframe = vp.r_uav + vp.L_uav
    for what, p in named:
        if not fence.empty:
            check_point(fence, what, (float(p[0]), float(p[1])), margin_m=airframe)
        for i, o in enumerate(base.obstacles):
            if p[2] < -o.height_m:
                continue  # above the trunk's top
            d = math.hypot(p[0] - o.x_m, p[1] - o.y_m)
            need = o.radius_m + o.safe_distance_m + airframe
            if d < need:
                raise ValueError(f"{what} ({p[0]:.2f}, {p[1]:.2f}) m is {d:.2f} m from obstacle {i} at "
                                 f"({o.x_m:g}, {o.y_m:g}); needs >= {need:.2f} m (radius + safe distance + airframe)")
