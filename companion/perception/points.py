"""A scan's returns as points in the mission frame, with the pose at the scan's time (pure: numpy only).

Each ray leaves the sensor (at the vehicle's position: the lever arm is neglected) along its direction in the
airframe's x-y plane, rotated into NED by the full attitude: a tilted airframe tilts the scan, so rays may strike
the ground. Filtered, and counted by reason in :class:`PointFilter` ``dropped``:

- ``ground``: the return's end point is within :data:`GROUND_MARGIN_M` of the ground (z = 0 NED) or below it;
- ``below_band``: the end point lies more than :data:`BELOW_BAND_M` below the airframe (the payload, low brush);
- ``phantom``: an isolated return (rain, dust): neither neighbouring ray returns within :data:`PHANTOM_GAP_M`
  of it. A trunk seen by one ray only (thin and far) is dropped too; it is seen by several rays when nearer;
- ``unknown``: rays without a valid reading (NaN: a dropout, a NaN in a LaserScan, below the minimum range).

Also kept per ray: its horizontal bearing in the mission frame (rad, from north, clockwise) and the horizontal
distance it saw free (m): to its return, to its ground strike, to its range limit when nothing returned; 0 when
unknown. That is the free space the planner may count on.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np

from companion.perception.pose_history import Pose
from companion.perception.scan import Scan

GROUND_MARGIN_M = 0.15  # a return this close above the ground (m) is the ground
BELOW_BAND_M = 1.5  # a return this far below the airframe (m) is not a trunk at flight height
PHANTOM_GAP_M = 0.3  # a return with no neighbour within this range difference (m) is a phantom


@dataclass(frozen=True, slots=True)
class ScanPoints:
    """One scan placed: ``xy_m`` (N, 2) mission-frame north/east of the returns kept (m), ``z_m`` (N,) their
    NED height (m), ``ray`` (N,) their ray index, ``range_m`` (N,) their range (m), sorted by ray; per ray of the
    scan ``bearing_rad`` (from north, clockwise, rad) and ``free_m`` (horizontal free distance, m); ``origin_m``
    the sensor's mission-frame (north, east) (m), ``range_max_m`` the sensor's limit (m), ``t_s`` the scan's time
    (s), ``increment_rad`` the rays' spacing; ``origin_z_m`` the sensor's NED height (m) and ``slope`` per ray the
    NED height it gains per metre of horizontal travel (a tilted scan climbs or dips)."""

    xy_m: np.ndarray
    z_m: np.ndarray
    ray: np.ndarray
    range_m: np.ndarray
    bearing_rad: np.ndarray
    free_m: np.ndarray
    origin_m: tuple[float, float]
    range_max_m: float
    t_s: float
    increment_rad: float
    origin_z_m: float = 0.0
    slope: np.ndarray | None = None


def ray_directions(scan: Scan, pose: Pose) -> np.ndarray:
    """(N, 3) unit NED directions of the scan's rays: body FRD (cos a, sin a, 0) rotated by the attitude, or for
    a north-aligned scan level rays at angle a from north."""
    a = scan.angles_rad
    if scan.frame == "north":
        return np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=1)
    body = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=1)
    return body @ pose.r_body_to_ned.T


class PointFilter:
    """Scans → :class:`ScanPoints`, counting what it drops in ``dropped`` (``ground``, ``below_band``,
    ``phantom``, ``unknown``)."""

    def __init__(self, ground_margin_m: float = GROUND_MARGIN_M, below_band_m: float = BELOW_BAND_M,
                 phantom_gap_m: float = PHANTOM_GAP_M) -> None:
        self.ground_margin_m = ground_margin_m
        self.below_band_m = below_band_m
        self.phantom_gap_m = phantom_gap_m
        self.dropped: Counter[str] = Counter()

    def place(self, scan: Scan, pose: Pose) -> ScanPoints:
        """The scan's returns in the mission frame with ``pose`` (the pose at the scan's time)."""
        d = ray_directions(scan, pose)
        r = scan.ranges_m
        hit = np.isfinite(r)
        horiz = np.hypot(d[:, 0], d[:, 1])
        reach = np.where(hit, r, np.where(np.isnan(r), 0.0, scan.range_max_m))
        end = pose.pos_m[None, :] + d * reach[:, None]
        # a ray that dips reaches the ground before its range: free only that far
        with np.errstate(divide="ignore", invalid="ignore"):
            to_ground = np.where(d[:, 2] > 1e-9, (-pose.pos_m[2]) / d[:, 2], np.inf)
        reach_free = np.minimum(reach, np.maximum(to_ground, 0.0))
        free = reach_free * horiz
        ground = hit & (end[:, 2] > -self.ground_margin_m)
        below = hit & ~ground & (end[:, 2] > pose.pos_m[2] + self.below_band_m)
        keep = hit & ~ground & ~below
        phantom = keep & self._isolated(r, keep)
        keep &= ~phantom
        self.dropped["unknown"] += int(np.isnan(r).sum())  # NaN: no data, a dropout, below the minimum range
        self.dropped["ground"] += int(ground.sum())
        self.dropped["below_band"] += int(below.sum())
        self.dropped["phantom"] += int(phantom.sum())
        idx = np.flatnonzero(keep)
        with np.errstate(divide="ignore", invalid="ignore"):
            slope = np.where(horiz > 1e-9, d[:, 2] / horiz, np.inf)
        return ScanPoints(end[idx, :2], end[idx, 2], idx, r[idx], np.arctan2(d[:, 1], d[:, 0]), free,
                          (float(pose.pos_m[0]), float(pose.pos_m[1])), scan.range_max_m, scan.t_s,
                          scan.increment_rad, float(pose.pos_m[2]), slope)

    def _isolated(self, r: np.ndarray, keep: np.ndarray) -> np.ndarray:
        """Returns with no kept neighbour (previous or next ray, wrapping around) within the phantom gap."""
        rk = np.where(keep, r, np.nan)
        gap = self.phantom_gap_m
        with np.errstate(invalid="ignore"):
            prev_ok = np.abs(rk - np.roll(rk, 1)) <= gap + 0.02 * rk
            next_ok = np.abs(rk - np.roll(rk, -1)) <= gap + 0.02 * rk
        return ~(prev_ok | next_ok)
