"""Vertical cylindrical obstacles (tree trunks), shared by missions, planners and the Zenoh input."""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Obstacle:
    """A vertical cylinder standing on the ground (NED: from z = 0 up to z = −height_m).

    Keys are the mission file's obstacle keys. ``source`` names where it came from: ``"mission"`` or the
    Zenoh key of a live publisher. Velocity (for moving obstacles) defaults to zero.
    """

    x_m: float
    y_m: float
    radius_m: float
    height_m: float = 4.0
    safe_distance_m: float = 0.1
    vx_mps: float = 0.0
    vy_mps: float = 0.0
    source: str = "mission"

    MAX_RADIUS_M = 50.0
    MAX_HEIGHT_M = 1000.0
    MAX_COORD_M = 1.0e5
    MAX_SPEED_MPS = 50.0

    def validate(self) -> None:
        """Raise ``ValueError("<key>: ...")`` for non-finite, negative or absurd values."""
        for key in ("x_m", "y_m", "radius_m", "height_m", "safe_distance_m", "vx_mps", "vy_mps"):
            v = getattr(self, key)
            if not isinstance(v, int | float) or isinstance(v, bool) or not math.isfinite(v):
                raise ValueError(f"{key}: must be a finite number, got {v!r}")
        if not 0.0 < self.radius_m <= self.MAX_RADIUS_M:
            raise ValueError(f"radius_m: must be in (0, {self.MAX_RADIUS_M}] m, got {self.radius_m}")
        if not 0.0 < self.height_m <= self.MAX_HEIGHT_M:
            raise ValueError(f"height_m: must be in (0, {self.MAX_HEIGHT_M}] m, got {self.height_m}")
        if not 0.0 <= self.safe_distance_m <= self.MAX_RADIUS_M:
            raise ValueError(f"safe_distance_m: must be in [0, {self.MAX_RADIUS_M}] m, got {self.safe_distance_m}")
        for key in ("x_m", "y_m"):
            if abs(getattr(self, key)) > self.MAX_COORD_M:
                raise ValueError(f"{key}: |{getattr(self, key)}| m is beyond {self.MAX_COORD_M} m")
        if math.hypot(self.vx_mps, self.vy_mps) > self.MAX_SPEED_MPS:
            raise ValueError(f"vx_mps: obstacle speed above {self.MAX_SPEED_MPS} m/s")

    def at_time(self, dt_s: float) -> Obstacle:
        """The obstacle moved by its velocity over ``dt_s`` seconds."""
        if self.vx_mps == 0.0 and self.vy_mps == 0.0:
            return self
        return Obstacle(
            self.x_m + self.vx_mps * dt_s, self.y_m + self.vy_mps * dt_s, self.radius_m, self.height_m,
            self.safe_distance_m, self.vx_mps, self.vy_mps, self.source,
        )

    def as_dict(self) -> dict:
        """JSON-ready dict with the mission-file keys plus ``source``."""
        return {
            "x_m": self.x_m, "y_m": self.y_m, "radius_m": self.radius_m, "height_m": self.height_m,
            "safe_distance_m": self.safe_distance_m, "vx_mps": self.vx_mps, "vy_mps": self.vy_mps,
            "source": self.source,
        }
