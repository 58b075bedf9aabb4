"""The geofence as the planners see it: keep-out discs (obstacles of ``source`` :data:`FENCE_SOURCE`), and how far a
point is inside the fence (for the report). Pure; mission-frame (north, east) metres.

Every planner already keeps its swing envelope clear of obstacles, so the fence becomes obstacles (vertical
cylinders of :data:`WALL_HEIGHT_M`: a fence has no altitude limit here) and the plan never leaves it, envelope
included:

* an exclusion circle is one obstacle of its radius;
* an exclusion polygon is covered along its boundary by discs of radius :data:`WALL_R_M` centred on the boundary
  at most 2·WALL_R_M·cos(30°) apart: every boundary point is within WALL_R_M of a centre, so a vehicle whose
  envelope clears every disc never reaches the boundary, nor the inside (which only a crossing reaches);
* an inclusion polygon or circle is walled from outside: discs of radius :data:`WALL_R_M` whose centres lie
  :data:`WALL_OUT_M` beyond the boundary, :data:`WALL_STEP_M` apart, so that every boundary point is within
  WALL_R_M of a centre (sqrt((step/2)² + out²) <= WALL_R_M); they reach WALL_R_M − WALL_OUT_M = 0.54 m into the
  zone (the plan stays that much further inside than it must).

Each disc carries ``safe_distance_m`` :data:`FENCE_SAFE_M` like a trunk. Weak: for a non-convex inclusion
polygon a disc outside one edge may reach further into the zone near a reflex vertex (more conservative, never
less); the route search's cost grows with the number of discs (a 40 m × 20 m inclusion rectangle is 30 discs).
"""

from __future__ import annotations

import math

import numpy as np

from companion.core.fence import Fence
from companion.core.obstacles import Obstacle

FENCE_SOURCE = "fence"
WALL_R_M = 4.0
WALL_STEP_M = 4.0
WALL_OUT_M = math.sqrt(WALL_R_M**2 - (0.5 * WALL_STEP_M) ** 2) - 0.01
WALL_HEIGHT_M = 1000.0
FENCE_SAFE_M = 0.1
_EDGE_STEP_M = 2.0 * WALL_R_M * math.cos(math.radians(30.0))


def _disc(x: float, y: float, r: float) -> Obstacle:
    return Obstacle(float(x), float(y), float(r), WALL_HEIGHT_M, FENCE_SAFE_M, source=FENCE_SOURCE)


def _ccw(verts: np.ndarray) -> np.ndarray:
    """The polygon's vertices (n, 2) counter-clockwise in (north, east) (shoelace sign)."""
    x, y = verts[:, 0], verts[:, 1]
    area2 = float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))
    return verts if area2 > 0.0 else verts[::-1]


def _along(a: np.ndarray, b: np.ndarray, step: float) -> np.ndarray:
    """Points from a towards b (b excluded) at most ``step`` apart, (k, 2)."""
    n = max(1, math.ceil(float(np.hypot(*(b - a))) / step))
    return a[None, :] + (b - a)[None, :] * (np.arange(n) / n)[:, None]


def _outside_wall(verts: np.ndarray) -> list[Obstacle]:
    """Discs beyond each edge of an inclusion polygon (and one beyond each vertex)."""
    v = _ccw(verts)
    out: list[Obstacle] = []
    n = len(v)
    for k in range(n):
        a, b = v[k], v[(k + 1) % n]
        d = b - a
        length = float(np.hypot(*d))
        if length < 1e-9:
            continue
        nrm = np.array((d[1], -d[0])) / length  # outward for a counter-clockwise polygon in (x, y)
        for p in _along(a, b, WALL_STEP_M):
            c = p + WALL_OUT_M * nrm
            out.append(_disc(c[0], c[1], WALL_R_M))
        c = b + WALL_OUT_M * nrm
        out.append(_disc(c[0], c[1], WALL_R_M))
    return out


def fence_obstacles(fence: Fence | None) -> tuple[Obstacle, ...]:
    """The fence as keep-out discs (see module docstring); empty without a fence."""
    if fence is None:
        return ()
    out: list[Obstacle] = []
    for z in fence.polygons:
        verts = np.asarray(z.vertices_ne_m, dtype=np.float64)
        if z.inclusion:
            out += _outside_wall(verts)
            continue
        for k in range(len(verts)):
            for p in _along(verts[k], verts[(k + 1) % len(verts)], _EDGE_STEP_M):
                out.append(_disc(p[0], p[1], WALL_R_M))
    for c in fence.circles:
        cx, cy = c.center_ne_m
        if not c.inclusion:
            out.append(_disc(cx, cy, c.radius_m))
            continue
        ring = c.radius_m + WALL_OUT_M
        n = max(8, math.ceil(2.0 * math.pi * c.radius_m / WALL_STEP_M))
        for k in range(n):
            a = 2.0 * math.pi * k / n
            out.append(_disc(cx + ring * math.cos(a), cy + ring * math.sin(a), WALL_R_M))
    return tuple(out)


def _polygon_signed(xy: np.ndarray, verts: np.ndarray) -> np.ndarray:
    """Signed distance (m) of points (N, 2) to the polygon's boundary: positive inside."""
    dmin = np.full(len(xy), np.inf)
    inside = np.zeros(len(xy), dtype=bool)
    n = len(verts)
    for k in range(n):
        a, b = verts[k], verts[(k + 1) % n]
        d = b - a
        dd = float(d @ d)
        t = np.clip(((xy - a) @ d) / dd, 0.0, 1.0) if dd > 0.0 else np.zeros(len(xy))
        dmin = np.minimum(dmin, np.hypot(*(xy - a - t[:, None] * d).T))
        cross = (a[1] > xy[:, 1]) != (b[1] > xy[:, 1])
        with np.errstate(divide="ignore", invalid="ignore"):
            xi = a[0] + (xy[:, 1] - a[1]) * d[0] / d[1]
        inside ^= cross & (xy[:, 0] < xi)
    return np.where(inside, dmin, -dmin)


def fence_margin_m(fence: Fence | None, xy: np.ndarray) -> np.ndarray:
    """Per point (N, 2) (north, east) m, how far (m) it is on the allowed side of the nearest zone boundary
    (negative: outside an inclusion zone or inside an exclusion zone); +inf without a fence."""
    pts = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    out = np.full(len(pts), np.inf)
    if fence is None:
        return out
    for z in fence.polygons:
        s = _polygon_signed(pts, np.asarray(z.vertices_ne_m, dtype=np.float64))
        out = np.minimum(out, s if z.inclusion else -s)
    for c in fence.circles:
        s = c.radius_m - np.hypot(pts[:, 0] - c.center_ne_m[0], pts[:, 1] - c.center_ne_m[1])
        out = np.minimum(out, s if c.inclusion else -s)
    return out
