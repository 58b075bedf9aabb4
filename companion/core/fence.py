"""Geofences: where the flight may go (inclusion zones) and may not (exclusion zones), in the mission frame.

A fence is what the autopilot holds as MAV_MISSION_TYPE_FENCE (polygons and circles, each an inclusion or an
exclusion zone) or what a mission file's ``[fence]`` table lists. Coordinates are horizontal NED (north, east)
metres in the mission frame; a fence has no altitude limits here. The plan must never leave it, swing envelope
included: every inclusion zone contains the whole envelope, no exclusion zone touches it.
"""

from __future__ import annotations

from dataclasses import dataclass


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
