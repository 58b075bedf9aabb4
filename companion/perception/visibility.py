"""What one scan saw: where it saw free space, how far it saw free along a heading, and which trunks it could have
seen (within range, not occluded, at the height they were seen). Pure: numpy only; positions in the mission frame
(north, east; m), bearings and headings from north, clockwise (rad).

:class:`~companion.perception.local_map.LocalMap` asks it which unseen tracks were missed (and which occluded);
the planner's stop cap asks it how far the last scan saw free (:func:`free_distance_m`).
"""

from __future__ import annotations

import math

import numpy as np

from companion.perception.points import ScanPoints

FREE_STEP_M = 0.05  # the free-distance march's step (m)
VIEW_BAND_M = 0.5  # a ray this close (m, vertically) to where a trunk was seen would have seen it again


def _nearest_ray(pts: ScanPoints, bearing: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per bearing (rad): the index of the nearest ray and the angle to it (rad)."""
    b = pts.bearing_rad
    diff = (bearing[:, None] - b[None, :] + math.pi) % (2.0 * math.pi) - math.pi
    k = np.argmin(np.abs(diff), axis=1)
    return k, np.abs(diff[np.arange(len(bearing)), k])


def seen_free(pts: ScanPoints, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Per point (mission frame, m): did the scan see it free (a ray towards it, within 1.5 increments, passed
    beyond it)?"""
    dx, dy = x - pts.origin_m[0], y - pts.origin_m[1]
    d = np.hypot(dx, dy)
    k, off = _nearest_ray(pts, np.arctan2(dy, dx))
    return (d <= pts.free_m[k]) & ((off <= 1.5 * pts.increment_rad) | (d < 1e-6))


def in_view_many(pts: ScanPoints, x: np.ndarray, y: np.ndarray, radius_m: np.ndarray,
                 z_m: np.ndarray | None = None) -> np.ndarray:
    """Per trunk at (x, y) (m) of ``radius_m``: could the scan have seen it? Within range, the ray towards it saw
    free space beyond its near side (nothing in front of it: not occluded), and, when ``z_m`` (the NED height (m)
    the trunk was seen at) is given, the ray passes the trunk within :data:`VIEW_BAND_M` of that height (a tilted
    scan passing over its top or under it at the ground says nothing about it)."""
    dx, dy = x - pts.origin_m[0], y - pts.origin_m[1]
    d = np.hypot(dx, dy)
    k, off = _nearest_ray(pts, np.arctan2(dy, dx))
    near = d - radius_m
    ok = (near <= pts.range_max_m) & (d > 1e-6) & (off <= 1.5 * pts.increment_rad) & (pts.free_m[k] > near + 0.05)
    if z_m is not None and pts.slope is not None:
        with np.errstate(invalid="ignore"):
            ok &= np.abs(pts.origin_z_m + pts.slope[k] * near - z_m) <= VIEW_BAND_M
    return ok


def in_view(pts: ScanPoints, x: float, y: float, radius_m: float) -> bool:
    """:func:`in_view_many` for one trunk."""
    return bool(in_view_many(pts, np.array([x]), np.array([y]), np.array([radius_m]))[0])


def free_distance_m(pts: ScanPoints, from_xy: tuple[float, float], heading_rad: float,
                    max_m: float | None = None) -> float:
    """How far (m) from ``from_xy`` along ``heading_rad`` the scan ``pts`` saw free: the march (steps of
    :data:`FREE_STEP_M`, up to ``max_m``, default the sensor's range) stops at the first point no ray saw free."""
    limit = pts.range_max_m if max_m is None else max_m
    s = np.arange(0.0, limit + FREE_STEP_M, FREE_STEP_M)
    x = from_xy[0] + s * math.cos(heading_rad)
    y = from_xy[1] + s * math.sin(heading_rad)
    ok = seen_free(pts, x, y)
    bad = np.flatnonzero(~ok)
    return float(s[bad[0] - 1]) if len(bad) and bad[0] > 0 else (0.0 if len(bad) else float(s[-1]))
