"""The ``[fence]`` table of a mission file: parsing, the check that a point lies inside the fence, TOML back.

Format (see :mod:`companion.core.mission`): ``[[fence.polygons]]`` with ``vertices_ne_m = [[n, e], ...]`` (at
least three, mission-frame (north, east) metres, not closed) and ``[[fence.circles]]`` with ``center_ne_m`` and
``radius_m``; each zone says ``inclusion = true`` (stay inside) or ``false`` (stay outside). Errors are
``ConfigError("<file>: [[fence.polygons]] #i key: message")``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from companion.core.fence import Fence, FenceCircle, FencePolygon, check_point, polygon_problem
from companion.errors import ConfigError

_MAX_COORD_M = 1.0e4
MAX_FENCE_VERTICES = 1000  # vertices of one fence polygon


def _ne(v: Any, w: str, key: str) -> tuple[float, float]:
    """A finite (north, east) pair (m) within the coordinate range, or ConfigError naming ``w`` and ``key``."""
    ok = isinstance(v, list) and len(v) == 2 and all(isinstance(c, int | float) and not isinstance(c, bool)
                                                     for c in v)
    if not ok or not all(math.isfinite(c) and abs(c) <= _MAX_COORD_M for c in v):
        raise ConfigError(f"{w} {key}: expected a finite [north, east] pair within {_MAX_COORD_M:g} m, got {v!r}")
    return float(v[0]), float(v[1])


def _zones(raw: Any, w: str, keys: set[str]) -> list[dict[str, Any]]:
    """An array of tables whose keys are all among ``keys`` and which say ``inclusion`` (true or false)."""
    if not isinstance(raw, list) or not all(isinstance(t, dict) for t in raw):
        raise ConfigError(f"{w}: expected an array of tables")
    for i, t in enumerate(raw):
        unknown = sorted(set(t) - keys)
        if unknown:
            raise ConfigError(f"{w} #{i}: unknown key {unknown[0]!r} (known keys: {', '.join(sorted(keys))})")
        if not isinstance(t.get("inclusion"), bool):
            raise ConfigError(f"{w} #{i} inclusion: required, true (stay inside) or false (stay outside)")
    return raw


def parse_fence(raw: Any, where: str) -> Fence | None:
    """The ``[fence]`` table: ``[[fence.polygons]]`` and ``[[fence.circles]]`` (see module docstring)."""
    if not isinstance(raw, dict):
        raise ConfigError(f"{where}: fence: expected a table [fence]")
    unknown = sorted(set(raw) - {"polygons", "circles"})
    if unknown:
        raise ConfigError(f"{where}: [fence]: unknown key {unknown[0]!r} (known: circles, polygons)")
    polys, circles = [], []
    for i, t in enumerate(_zones(raw.get("polygons", []), f"{where}: [[fence.polygons]]",
                                 {"vertices_ne_m", "inclusion"})):
        w = f"{where}: [[fence.polygons]] #{i}"
        verts = t.get("vertices_ne_m")
        if not isinstance(verts, list) or not 3 <= len(verts) <= MAX_FENCE_VERTICES:
            raise ConfigError(f"{w} vertices_ne_m: expected 3 to {MAX_FENCE_VERTICES} [north, east] pairs")
        poly = FencePolygon(tuple(_ne(v, w, "vertices_ne_m") for v in verts), t["inclusion"])
        problem = polygon_problem(poly)
        if problem is not None:
            raise ConfigError(f"{w} vertices_ne_m: {problem}")
        polys.append(poly)
    for i, t in enumerate(_zones(raw.get("circles", []), f"{where}: [[fence.circles]]",
                                 {"center_ne_m", "radius_m", "inclusion"})):
        w = f"{where}: [[fence.circles]] #{i}"
        r = t.get("radius_m")
        if not isinstance(r, int | float) or isinstance(r, bool) or not 0.0 < r <= _MAX_COORD_M:
            raise ConfigError(f"{w} radius_m: expected a number in (0, {_MAX_COORD_M:g}] m, got {r!r}")
        circles.append(FenceCircle(_ne(t.get("center_ne_m"), w, "center_ne_m"), float(r), t["inclusion"]))
    fence = Fence(tuple(polys), tuple(circles))
    return None if fence.empty else fence


def check_fenced(where: str, what: str, p: np.ndarray, fence: Fence | None, margin_m: float = 0.0) -> None:
    """ConfigError unless the point's horizontal part (m) is inside every inclusion and outside every exclusion
    zone by ``margin_m`` (m; the airframe's circle: the planners keep the swing envelope clear in flight, see
    :mod:`companion.planning.fence_guard`)."""
    if fence is None:
        return
    try:
        check_point(fence, what, (float(p[0]), float(p[1])), margin_m)
    except ValueError as exc:
        raise ConfigError(f"{where}: {exc}") from None


def fence_toml(fence: Fence | None) -> list[str]:
    """The ``[[fence.polygons]]`` / ``[[fence.circles]]`` lines of a fence (none for None)."""
    lines: list[str] = []
    for z in () if fence is None else fence.polygons:
        verts = ", ".join(f"[{float(n)!r}, {float(e)!r}]" for n, e in z.vertices_ne_m)
        lines += ["", "[[fence.polygons]]", f"vertices_ne_m = [{verts}]",
                  f"inclusion = {'true' if z.inclusion else 'false'}"]
    for c in () if fence is None else fence.circles:
        lines += ["", "[[fence.circles]]",
                  f"center_ne_m = [{float(c.center_ne_m[0])!r}, {float(c.center_ne_m[1])!r}]",
                  f"radius_m = {float(c.radius_m)!r}", f"inclusion = {'true' if c.inclusion else 'false'}"]
    return lines
