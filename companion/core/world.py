"""World files: the trunks that really stand where the bundled vehicle flies (``sitl --world``, ``fly --sitl --world``).

Pure data, shared by the vehicle (:mod:`sim_bridge.world` casts its LiDAR against them) and the companion (the
report of a flight in a world scores clearance against them: the truth).

Format (TOML; strict: unknown keys, missing required keys and wrong types are refused with
``ConfigError("<file>: [[obstacles]] #i key: message")``)::

    [world]                        # optional
    name = "forest"
    [[obstacles]]                  # any number; the mission file's obstacle keys (not "source")
    x_m = 3.0                      # NED north (m) of the trunk's axis at time 0
    y_m = -0.22                    # NED east (m)
    radius_m = 0.3
    height_m = 4.0                 # standing on the ground z = 0 up to z = -height_m
    safe_distance_m = 0.1          # kept for the mission schema; the world itself does not use it
    vx_mps = 0.0                   # optional: a moving trunk (m/s, NED)
    vy_mps = 0.0

Clock of moving trunks: a world trunk is at ``(x_m, y_m)`` at the vehicle's boot (its clock's zero: the
``time_boot_ms`` / ``time_usec`` of its telemetry) and moves at constant velocity from there:
``x(t) = x_m + vx_mps * t``. The world knows nothing of missions; a *mission's* moving trunk, in contrast, is at
its file position at the mission clock's zero (the first setpoint; :mod:`companion.report.scoring`). The report
of a flight in a world scores the world's trunks on the vehicle's clock (``source == "world"``).

``NAME`` (no ``/``, no ``.toml`` needed) names a shipped world in ``config/worlds/``; anything else is a path.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from companion.config import dataclass_from_table, read_toml, resolve_shipped, shipped_files
from companion.core.obstacles import Obstacle
from companion.errors import ConfigError

WORLD_SOURCE = "world"  #: the ``source`` of every obstacle loaded from a world file
MAX_TRUNKS = 10_000


@dataclass(frozen=True)
class World:
    """A world: its name, its trunks (``source == "world"``, positions at the vehicle's t = 0) and where it was
    read from."""

    name: str
    trunks: tuple[Obstacle, ...]
    source_path: str = ""


def shipped_worlds() -> dict[str, Path]:
    """The worlds that ship with slungpilot, by name (file stem): ``{"forest": Path, ...}``."""
    return shipped_files("worlds")


def resolve_world(arg: str | Path) -> Path:
    """A ``--world`` argument as a file: an existing path wins, else a shipped world by name (``forest``,
    ``forest_crossing.toml``); :class:`ConfigError` naming the shipped worlds otherwise."""
    return resolve_shipped(arg, "worlds", "world")


def world_from_dict(data: dict[str, Any], where: str) -> World:
    """Build and validate a :class:`World` from a parsed TOML document; ``where`` names the file."""
    unknown = sorted(set(data) - {"world", "obstacles"})
    if unknown:
        raise ConfigError(f"{where}: unknown table or key {unknown[0]!r} (known: world, obstacles)")
    head = data.get("world", {})
    if not isinstance(head, dict):
        raise ConfigError(f"{where}: world: expected a table [world]")
    extra = sorted(set(head) - {"name"})
    if extra:
        raise ConfigError(f"{where}: [world] unknown key {extra[0]!r} (known keys: name)")
    name = head.get("name", Path(where).stem)
    if not isinstance(name, str) or not name:
        raise ConfigError(f"{where}: [world] name: expected a non-empty string, got {name!r}")
    raw = data.get("obstacles", [])
    if not isinstance(raw, list):
        raise ConfigError(f"{where}: obstacles: expected an array of tables [[obstacles]]")
    if len(raw) > MAX_TRUNKS:
        raise ConfigError(f"{where}: obstacles: {len(raw)} trunks, more than {MAX_TRUNKS}")
    trunks = []
    for i, t in enumerate(raw):
        w = f"{where}: [[obstacles]] #{i}"
        if isinstance(t, dict) and "source" in t:
            raise ConfigError(f"{w}: unknown key 'source' (set by the program, not the file)")
        o = dataclass_from_table(Obstacle, t, where=w)
        trunks.append(dataclasses.replace(o, source=WORLD_SOURCE))
    return World(name=name, trunks=tuple(trunks), source_path=where)


def load_world(arg: str | Path) -> World:
    """Read and validate a world file or shipped world (see :func:`resolve_world`); raises :class:`ConfigError`
    naming the file and the key."""
    path = resolve_world(arg)
    return world_from_dict(read_toml(path), str(path))


def world_to_toml(name: str, trunks: tuple[Obstacle, ...] | list[Obstacle]) -> str:
    """A world document :func:`load_world` reads back (e.g. the trunks of a generated forest, for ``--world``)."""
    lines = ["[world]", f"name = {json.dumps(name)}"]
    for o in trunks:
        lines += ["", "[[obstacles]]", f"x_m = {o.x_m!r}", f"y_m = {o.y_m!r}", f"radius_m = {o.radius_m!r}",
                  f"height_m = {o.height_m!r}", f"safe_distance_m = {o.safe_distance_m!r}"]
        if o.vx_mps or o.vy_mps:
            lines += [f"vx_mps = {o.vx_mps!r}", f"vy_mps = {o.vy_mps!r}"]
    return "\n".join(lines) + "\n"
