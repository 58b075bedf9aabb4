"""The simulated world as the bundled vehicle's sensors see it: the trunks of a world file
(:mod:`companion.core.world`: format, shipped worlds, loading) as arrays, moved to the vehicle's time.

A world trunk is at its file position at the vehicle's boot (t = 0 of its clock) and moves at constant velocity
from there (docs/sitl.md, *A world and its LiDAR*).
"""

from __future__ import annotations

import numpy as np

from companion.core.world import WORLD_SOURCE, World, load_world, resolve_world, shipped_worlds, world_to_toml

__all__ = ["WORLD_SOURCE", "World", "WorldArrays", "load_world", "resolve_world", "shipped_worlds", "world_to_toml"]


class WorldArrays:
    """A :class:`World`'s trunks as numpy arrays, for casting rays against them many times a second."""

    def __init__(self, world: World) -> None:
        self.world = world

        def arr(key: str) -> np.ndarray:
            return np.array([getattr(o, key) for o in world.trunks], dtype=np.float64)

        self._x0, self._y0, self._vx, self._vy = arr("x_m"), arr("y_m"), arr("vx_mps"), arr("vy_mps")
        self._r, self._h = arr("radius_m"), arr("height_m")
        self._moving = bool(np.any(self._vx != 0.0) or np.any(self._vy != 0.0))

    def at(self, t_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The trunks at vehicle time ``t_s`` (s) as arrays (m,): centre x, y (NED, m), radius (m), height (m)."""
        if not self._moving:
            return self._x0, self._y0, self._r, self._h
        return self._x0 + self._vx * t_s, self._y0 + self._vy * t_s, self._r, self._h
