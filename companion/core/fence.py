"""Geofences: where the flight may go (inclusion zones) and may not (exclusion zones), in the mission frame.

A fence is what the autopilot holds as MAV_MISSION_TYPE_FENCE (polygons and circles, each an inclusion or an
exclusion zone) or what a mission file's ``[fence]`` table lists. Coordinates are horizontal NED (north, east)
metres in the mission frame; a fence has no altitude limits here. The plan must never leave it, swing envelope
included: every inclusion zone contains the whole envelope, no exclusion zone touches it.

Here also (pure, plain floats): the autopilot's fence items as a :class:`Fence` (:func:`fence_from_items`); the
geometry the checks and the planners use — inside a polygon / circle, the signed distance to a zone's boundary
(:func:`zone_margin_m`, :func:`fence_margin_m`: positive on the side the zone wants), whether a straight leg keeps
a margin (:func:`segment_clear`); what makes a zone unusable (:func:`polygon_problem`: fewer than 3 vertices,
non-finite, no area, self-intersecting); a point's check naming it (:func:`check_point`); and exclusion zones as
covering circles / obstacles of source ``"fence"`` (:func:`covering_circles`, :func:`exclusion_obstacles`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from companion.core.obstacles import Obstacle


@dataclass(frozen=True, slots=True)
class FencePolygon:
    """A simple polygon: vertices (north, east) m in order (either winding), at least three, not closed
    (the last vertex is joined to the first). ``inclusion``: the flight stays inside; else it stays outside."""

    vertices_ne_m: tuple[tuple[float, float], ...]
    inclusion: bool


@dataclass(frozen=True, slots=True)
class FenceCircle:
    """A circle of ``radius_m`` around ``center_ne_m`` (north, east) m; ``inclusion`` as for polygons."""

    center_ne_m: tuple[float, float]
    radius_m: float
    inclusion: bool


@dataclass(frozen=True, slots=True)
class Fence:
    """Every zone of a geofence. With several inclusion zones the flight must be inside all of them (PX4's
    and ArduPilot's reading) and outside every exclusion zone."""

    polygons: tuple[FencePolygon, ...] = ()
    circles: tuple[FenceCircle, ...] = ()

    @property
    def empty(self) -> bool:
        """True when the fence has no zone at all."""
        return not self.polygons and not self.circles

    def margin_m(self, p_ne_m: Sequence[float]) -> float:
        """:func:`fence_margin_m` of this fence at (north, east) ``p_ne_m`` m."""
        return fence_margin_m(self, p_ne_m)

    def segment_clear(self, p_ne_m: Sequence[float], q_ne_m: Sequence[float], margin_m: float = 0.0) -> bool:
        """:func:`segment_clear` of this fence."""
        return segment_clear(self, p_ne_m, q_ne_m, margin_m)


# ------------------------------------------------------------------------------------------------ geometry
# Plain floats and tuples (a fence has tens of edges; the checks run before take-off and per planned leg).
def _seg_point_dist(a: Sequence[float], b: Sequence[float], p: Sequence[float]) -> float:
    """Distance (m) from point ``p`` to the segment ``a``-``b`` (all (north, east) m)."""
    ax, ay = a[0], a[1]
    dx, dy = b[0] - ax, b[1] - ay
    L2 = dx * dx + dy * dy
    t = 0.0 if L2 == 0.0 else max(0.0, min(1.0, ((p[0] - ax) * dx + (p[1] - ay) * dy) / L2))
    return math.hypot(p[0] - ax - t * dx, p[1] - ay - t * dy)


def _orient(a: Sequence[float], b: Sequence[float], c: Sequence[float]) -> float:
    return (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])


def segments_intersect(a: Sequence[float], b: Sequence[float], c: Sequence[float], d: Sequence[float]) -> bool:
    """Whether the closed segments ``a``-``b`` and ``c``-``d`` share a point (touching counts)."""
    d1, d2, d3, d4 = _orient(c, d, a), _orient(c, d, b), _orient(a, b, c), _orient(a, b, d)
    if ((d1 > 0.0) != (d2 > 0.0) and d1 != 0.0 and d2 != 0.0) and \
            ((d3 > 0.0) != (d4 > 0.0) and d3 != 0.0 and d4 != 0.0):
        return True
    return (d1 == 0.0 and _seg_point_dist(c, d, a) == 0.0) or (d2 == 0.0 and _seg_point_dist(c, d, b) == 0.0) or \
        (d3 == 0.0 and _seg_point_dist(a, b, c) == 0.0) or (d4 == 0.0 and _seg_point_dist(a, b, d) == 0.0)


def _seg_seg_dist(a: Sequence[float], b: Sequence[float], c: Sequence[float], d: Sequence[float]) -> float:
    """Distance (m) between the segments ``a``-``b`` and ``c``-``d`` (0 when they cross)."""
    if segments_intersect(a, b, c, d):
        return 0.0
    return min(_seg_point_dist(c, d, a), _seg_point_dist(c, d, b), _seg_point_dist(a, b, c), _seg_point_dist(a, b, d))


def _edges(poly: FencePolygon) -> list[tuple[tuple[float, float], tuple[float, float]]]:
    v = poly.vertices_ne_m
    return [(v[k], v[(k + 1) % len(v)]) for k in range(len(v))]


def inside_polygon(poly: FencePolygon, p_ne_m: Sequence[float]) -> bool:
    """Whether (north, east) ``p_ne_m`` m lies inside ``poly`` (even-odd rule; a point on an edge may go either
    way: use :func:`zone_margin_m` for a margin)."""
    x, y = p_ne_m[0], p_ne_m[1]
    inside = False
    for (x1, y1), (x2, y2) in _edges(poly):
        if (y1 > y) != (y2 > y) and x < x1 + (y - y1) * (x2 - x1) / (y2 - y1):
            inside = not inside
    return inside


def inside_circle(circle: FenceCircle, p_ne_m: Sequence[float]) -> bool:
    """Whether (north, east) ``p_ne_m`` m lies inside ``circle`` (strictly)."""
    return math.hypot(p_ne_m[0] - circle.center_ne_m[0], p_ne_m[1] - circle.center_ne_m[1]) < circle.radius_m


def zone_margin_m(zone: FencePolygon | FenceCircle, p_ne_m: Sequence[float]) -> float:
    """Signed distance (m) from (north, east) ``p_ne_m`` m to the zone's boundary: positive on the side the zone
    wants the flight (inside an inclusion zone, outside an exclusion zone), negative on the other."""
    if isinstance(zone, FenceCircle):
        d = zone.radius_m - math.hypot(p_ne_m[0] - zone.center_ne_m[0], p_ne_m[1] - zone.center_ne_m[1])
        inside = d > 0.0
        dist = abs(d)
    else:
        dist = min(_seg_point_dist(a, b, p_ne_m) for a, b in _edges(zone))
        inside = inside_polygon(zone, p_ne_m)
    return dist if inside == zone.inclusion else -dist


def fence_margin_m(fence: Fence, p_ne_m: Sequence[float]) -> float:
    """The smallest :func:`zone_margin_m` over every zone of ``fence`` (m; +inf without zones): negative when
    ``p_ne_m`` is outside an inclusion zone or inside an exclusion zone."""
    return min((zone_margin_m(z, p_ne_m) for z in (*fence.polygons, *fence.circles)), default=math.inf)


def _segment_clear_of(zone: FencePolygon | FenceCircle, p: Sequence[float], q: Sequence[float], m: float) -> bool:
    if isinstance(zone, FenceCircle):
        c, r = zone.center_ne_m, zone.radius_m
        if zone.inclusion:  # the farthest point of a segment from the centre is one of its ends
            return max(math.hypot(p[0] - c[0], p[1] - c[1]), math.hypot(q[0] - c[0], q[1] - c[1])) <= r - m
        return _seg_point_dist(p, q, c) >= r + m
    if zone_margin_m(zone, p) < m or zone_margin_m(zone, q) < m:
        return False
    # both ends on the wanted side, at least m from the boundary: the segment stays there unless it comes
    # closer than m to an edge (crossing one included)
    return all(not segments_intersect(p, q, a, b) and _seg_seg_dist(p, q, a, b) >= m for a, b in _edges(zone))


def segment_clear(fence: Fence, p_ne_m: Sequence[float], q_ne_m: Sequence[float], margin_m: float = 0.0) -> bool:
    """Whether the straight leg from ``p_ne_m`` to ``q_ne_m`` ((north, east) m) keeps ``margin_m`` (m: the swing
    envelope plus the airframe) inside every inclusion zone and away from every exclusion zone."""
    return all(_segment_clear_of(z, p_ne_m, q_ne_m, margin_m) for z in (*fence.polygons, *fence.circles))


# ------------------------------------------------------------------------------------------------ validity
def polygon_problem(poly: FencePolygon) -> str | None:
    """Why ``poly`` is not a usable zone (fewer than 3 vertices, a non-finite coordinate, no area, two edges that
    cross), or None when it is."""
    v = poly.vertices_ne_m
    if len(v) < 3:
        return f"{len(v)} vertices (at least 3 needed)"
    if not all(math.isfinite(c) for p in v for c in p):
        return "a vertex is not a finite number"
    area2 = sum(v[k][0] * v[(k + 1) % len(v)][1] - v[(k + 1) % len(v)][0] * v[k][1] for k in range(len(v)))
    if abs(area2) < 1e-9 and all(_orient(v[0], v[1], p) == 0.0 for p in v[2:]):
        return "no area (its vertices are on one line or coincide)"
    edges = _edges(poly)
    n = len(edges)
    for i in range(n):
        for j in range(i + 2, n):
            if i == 0 and j == n - 1:
                continue  # neighbours through the closing edge
            if segments_intersect(*edges[i], *edges[j]):
                return f"self-intersecting (edge {i} crosses edge {j})"
    if abs(area2) < 1e-9:
        return "no area"
    return None


def circle_problem(circle: FenceCircle) -> str | None:
    """Why ``circle`` is not a usable zone (non-finite centre or radius, radius <= 0), or None."""
    if not all(math.isfinite(c) for c in (*circle.center_ne_m, circle.radius_m)):
        return "centre or radius is not a finite number"
    if circle.radius_m <= 0.0:
        return f"radius {circle.radius_m:g} m (must be > 0)"
    return None


def check_point(fence: Fence, what: str, p_ne_m: Sequence[float], margin_m: float = 0.0) -> None:
    """ValueError naming ``what`` and the zone when (north, east) ``p_ne_m`` m is outside an inclusion zone or
    inside an exclusion zone, or nearer its boundary than ``margin_m`` (m)."""
    for kind, zones in (("polygon", fence.polygons), ("circle", fence.circles)):
        for i, z in enumerate(zones):
            m = zone_margin_m(z, p_ne_m)
            if m < margin_m:
                where = ("outside" if m < 0.0 else "within the margin of") if z.inclusion else \
                    ("inside" if m < 0.0 else "within the margin of")
                zone = f"{'inclusion' if z.inclusion else 'exclusion'} {kind} {i}"
                raise ValueError(f"{what} ({p_ne_m[0]:.2f}, {p_ne_m[1]:.2f}) m is {where} the fence's {zone} "
                                 f"({m:+.2f} m from its boundary; needs >= {margin_m:.2f} m)")


# ------------------------------------------------------------------------------------------------ obstacles
MAX_COVER_CIRCLES = 200  # circles per exclusion zone at most (the grid's spacing grows to stay below it)


def covering_circles(zone: FencePolygon | FenceCircle, spacing_m: float = 1.0) -> list[tuple[float, float, float]]:
    """Circles ((north, east) centre m, radius m) whose union contains the zone: the circle itself when it is no
    larger than an obstacle may be, else the circumscribed circles of the grid squares (side ``spacing_m``, more
    when the zone would need over :data:`MAX_COVER_CIRCLES`) that come within half a diagonal of the zone. They
    overreach the zone by at most a square's diagonal (√2·spacing)."""
    if isinstance(zone, FenceCircle):
        if zone.radius_m <= Obstacle.MAX_RADIUS_M:
            return [(zone.center_ne_m[0], zone.center_ne_m[1], zone.radius_m)]
        cn, ce, r = zone.center_ne_m[0], zone.center_ne_m[1], zone.radius_m
        k = 64  # the circumscribed 64-gon contains the circle
        rr = r / math.cos(math.pi / k)
        zone = FencePolygon(tuple((cn + rr * math.cos(2 * math.pi * i / k), ce + rr * math.sin(2 * math.pi * i / k))
                                  for i in range(k)), inclusion=False)
    ns = [v[0] for v in zone.vertices_ne_m]
    es = [v[1] for v in zone.vertices_ne_m]
    s = max(spacing_m, math.sqrt((max(ns) - min(ns)) * (max(es) - min(es)) / MAX_COVER_CIRCLES))
    half_diag = s / math.sqrt(2.0)
    out = []
    n_cells, e_cells = math.ceil((max(ns) - min(ns)) / s) + 1, math.ceil((max(es) - min(es)) / s) + 1
    for i in range(n_cells):
        for j in range(e_cells):
            c = (min(ns) + i * s, min(es) + j * s)  # the centre of a square of side s
            d = min(_seg_point_dist(a, b, c) for a, b in _edges(zone))
            if inside_polygon(zone, c) or d <= half_diag:
                out.append((c[0], c[1], half_diag))
    return out


def exclusion_obstacles(fence: Fence, spacing_m: float = 1.0, height_m: float = Obstacle.MAX_HEIGHT_M,
                        safe_distance_m: float = 0.1) -> tuple[Obstacle, ...]:
    """Every exclusion zone of ``fence`` as :class:`~companion.core.obstacles.Obstacle` cylinders (source
    ``"fence"``, as tall as an obstacle may be: a fence has no ceiling here) covering it (:func:`covering_circles`),
    so that every planner avoids it as it avoids trunks."""
    zones = [z for z in (*fence.polygons, *fence.circles) if not z.inclusion]
    return tuple(Obstacle(n, e, r, height_m, safe_distance_m, source="fence")
                 for z in zones for n, e, r in covering_circles(z, spacing_m))


# ------------------------------------------------------------------------------------------------ from the autopilot
MAV_CMD_NAV_FENCE_RETURN_POINT = 5000
MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION = 5001
MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION = 5002
MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION = 5003
MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION = 5004
FENCE_COMMANDS = {5000: "MAV_CMD_NAV_FENCE_RETURN_POINT", 5001: "MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION",
                  5002: "MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION", 5003: "MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION",
                  5004: "MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION"}


def fence_from_items(items: Sequence[Any], to_ne: Callable[[Any], tuple[float, float]]) -> tuple[Fence, list[str]]:
    """The fence the autopilot holds (its MAV_MISSION_TYPE_FENCE items, in order) and notes for the report.

    Each item has ``item_seq``, ``command``, ``params`` (4 floats) and whatever ``to_ne(item)`` needs to place it
    ((north, east) m in the mission frame; it raises ValueError for a position it cannot place). Polygon vertices:
    ``param1`` vertices in a row with the same command form one polygon; circles: ``param1`` is the radius (m);
    a return point is ignored (noted: the companion lands or holds, it does not fly to it). Anything else, a
    polygon cut short, a bad radius, fewer than 3 vertices, a self-intersecting or non-finite polygon: ValueError
    naming the item (``fence item <seq>: ...``)."""
    polys: list[FencePolygon] = []
    circles: list[FenceCircle] = []
    notes: list[str] = []
    k = 0
    while k < len(items):
        it = items[k]
        cmd, w = it.command, f"fence item {it.item_seq}"
        if cmd in (MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION):
            poly = _polygon_at(items, k, to_ne)
            polys.append(poly)
            k += len(poly.vertices_ne_m)
            continue
        if cmd in (MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION):
            circle = FenceCircle(to_ne(it), float(it.params[0]), cmd == MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION)
            problem = circle_problem(circle)
            if problem:
                raise ValueError(f"{w}: {FENCE_COMMANDS[cmd]}: {problem}")
            circles.append(circle)
        elif cmd == MAV_CMD_NAV_FENCE_RETURN_POINT:
            notes.append(f"{w}: the fence's return point is ignored (the companion holds or lands instead)")
        else:
            raise ValueError(f"{w}: command {cmd} is not a fence item; supported: "
                             + ", ".join(f"{n} ({c})" for c, n in FENCE_COMMANDS.items()))
        k += 1
    return Fence(tuple(polys), tuple(circles)), notes


def _polygon_at(items: Sequence[Any], k: int, to_ne: Callable[[Any], tuple[float, float]]) -> FencePolygon:
    """The polygon whose first vertex is ``items[k]`` (see :func:`fence_from_items`)."""
    first = items[k]
    cmd, w = first.command, f"fence item {first.item_seq}"
    count = first.params[0]
    if not (math.isfinite(count) and count == int(count) and count >= 3):
        raise ValueError(f"{w}: {FENCE_COMMANDS[cmd]}: a polygon needs at least 3 vertices, param1 says {count:g}")
    n = int(count)
    if k + n > len(items) or any(it.command != cmd or it.params[0] != count for it in items[k:k + n]):
        raise ValueError(f"{w}: {FENCE_COMMANDS[cmd]}: a polygon of {n} vertices must be {n} such items in a row "
                         "with the same param1")
    poly = FencePolygon(tuple(to_ne(it) for it in items[k:k + n]), cmd == MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION)
    problem = polygon_problem(poly)
    if problem:
        raise ValueError(f"{w}: {FENCE_COMMANDS[cmd]} polygon of items {first.item_seq}..{first.item_seq + n - 1}: "
                         f"{problem}")
    return poly
