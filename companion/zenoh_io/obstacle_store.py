"""Live obstacles from outside publishers, merged with the mission's own (pure: no Zenoh, no asyncio).

A publisher (a perception node, ``slungpilot obstacles publish``) sends its *current* obstacle list as one
JSON object (schema ``slungpilot.obstacles_in`` v1)::

    {"obstacles": [{"x_m": 6.0, "y_m": 0.1, "radius_m": 0.3, "height_m": 4.0, "safe_distance_m": 0.1,
                    "vx_mps": 0.0, "vy_mps": 0.0}],
     "expires_s": 2.0}

Per obstacle ``x_m``, ``y_m`` (NED, m) and ``radius_m`` (m) are required; ``height_m`` defaults to 4.0 m,
``safe_distance_m`` to 0.1 m, ``vx_mps``/``vy_mps`` to 0 (the obstacle moves with that NED velocity from
the moment its sample is ingested). ``expires_s`` is optional: absent or null means the list stays until
the same publisher sends another one; otherwise the list is dropped ``expires_s`` seconds (app clock) after
it was ingested. Optional ``"schema": "slungpilot.obstacles_in"`` and ``"version": 1`` are checked when
present. Each publisher is identified by its source key (the Zenoh key expression of its samples); a new
sample replaces that publisher's list, an empty list clears it.

Bad samples (not JSON, not an object, unknown keys, NaN/Infinity, wrong types, values that fail
:meth:`Obstacle.validate`, too many obstacles, too large) are rejected as a whole and counted; a warning is
logged at most once per ``log_interval_s`` of wall time.
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from companion.core.obstacles import Obstacle
from companion.zenoh_io.schema import OBSTACLES_IN, SCHEMA_VERSION

log = logging.getLogger(__name__)

MAX_SAMPLE_BYTES = 256 * 1024
MAX_OBSTACLES_PER_SAMPLE = 256
MAX_SOURCES = 64
MAX_EXPIRES_S = 3600.0
_TOP_KEYS = frozenset({"obstacles", "expires_s", "schema", "version"})
_OBSTACLE_KEYS = ("x_m", "y_m", "radius_m", "height_m", "safe_distance_m", "vx_mps", "vy_mps")
_REQUIRED_KEYS = ("x_m", "y_m", "radius_m")


def _reject_constant(name: str) -> Any:
    raise ValueError(f"obstacles: {name} is not allowed")


def _is_number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _decode_sample(raw: bytes | str) -> tuple[list, float | None]:
    """The sample's JSON object checked at its top level: (the raw obstacle items, expires_s or None)."""
    if len(raw) > MAX_SAMPLE_BYTES:
        raise ValueError(f"sample: {len(raw)} bytes is above {MAX_SAMPLE_BYTES}")
    try:
        d = json.loads(raw, parse_constant=_reject_constant)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"sample: not JSON ({exc})") from None
    if not isinstance(d, dict):
        raise ValueError(f"sample: expected a JSON object, got {type(d).__name__}")
    unknown = sorted(set(d) - _TOP_KEYS)
    if unknown:
        raise ValueError(f"{unknown[0]}: unknown key (known: {', '.join(sorted(_TOP_KEYS))})")
    if "schema" in d and d["schema"] != OBSTACLES_IN:
        raise ValueError(f"schema: expected {OBSTACLES_IN!r}, got {d['schema']!r}")
    if "version" in d and d["version"] != SCHEMA_VERSION:
        raise ValueError(f"version: expected {SCHEMA_VERSION}, got {d['version']!r}")
    if "obstacles" not in d:
        raise ValueError("obstacles: missing required key")
    items = d["obstacles"]
    if not isinstance(items, list):
        raise ValueError(f"obstacles: expected a list, got {type(items).__name__}")
    if len(items) > MAX_OBSTACLES_PER_SAMPLE:
        raise ValueError(f"obstacles: {len(items)} obstacles is above {MAX_OBSTACLES_PER_SAMPLE}")
    expires = d.get("expires_s")
    if expires is not None and (not _is_number(expires) or not 0.0 < expires <= MAX_EXPIRES_S):
        raise ValueError(f"expires_s: must be a number in (0, {MAX_EXPIRES_S}] s or null, got {expires!r}")
    return items, (None if expires is None else float(expires))


def _obstacle_of(i: int, it: Any, source: str) -> Obstacle:
    """Item ``i`` of a sample's obstacle list as a validated :class:`Obstacle`."""
    if not isinstance(it, dict):
        raise ValueError(f"obstacles[{i}]: expected an object, got {type(it).__name__}")
    bad = sorted(set(it) - set(_OBSTACLE_KEYS))
    if bad:
        raise ValueError(f"obstacles[{i}].{bad[0]}: unknown key (known: {', '.join(_OBSTACLE_KEYS)})")
    for k in _REQUIRED_KEYS:
        if k not in it:
            raise ValueError(f"obstacles[{i}].{k}: missing required key")
    for k, v in it.items():
        if not _is_number(v):
            raise ValueError(f"obstacles[{i}].{k}: expected a number, got {v!r}")
    ob = Obstacle(**{k: float(v) for k, v in it.items()}, source=source)
    try:
        ob.validate()
    except ValueError as exc:
        raise ValueError(f"obstacles[{i}].{exc}") from None
    return ob


def parse_obstacles_in(raw: bytes | str, source: str) -> tuple[tuple[Obstacle, ...], float | None]:
    """Parse and validate one input sample; returns (obstacles with ``source`` set, expires_s or None).

    Raises ``ValueError("<key>: message")`` on any problem (the whole sample is refused).
    """
    items, expires = _decode_sample(raw)
    return tuple(_obstacle_of(i, it, source) for i, it in enumerate(items)), expires


class SampleParser:
    """One sample parsed a slice at a time: :meth:`work` stops at a deadline and goes on at the next call, so a
    list of hundreds of obstacles never costs one control tick more than its budget.

    After :meth:`work` returned True, ``error`` is None and ``obstacles``/``expires_s`` hold the result, or
    ``error`` says why the sample was refused as a whole.
    """

    def __init__(self, key: str, raw: bytes | str) -> None:
        self.key = key
        self.raw = raw  # the sample as received
        self._items: list | None = None
        self._out: list[Obstacle] = []
        self.obstacles: tuple[Obstacle, ...] = ()
        self.expires_s: float | None = None
        self.error: str | None = None

    def work(self, deadline_s: float, clock: Callable[[], float] = time.perf_counter) -> bool:
        """Parse until done (True) or until ``clock()`` passes ``deadline_s`` (False: call again)."""
        try:
            if self._items is None:
                self._items, self.expires_s = _decode_sample(self.raw)
            items, out, key = self._items, self._out, self.key
            while len(out) < len(items):
                out.append(_obstacle_of(len(out), items[len(out)], key))
                if len(out) % 8 == 0 and clock() > deadline_s:
                    return len(out) == len(items) and self._finish()
        except ValueError as exc:
            self.error = str(exc)
            return True
        return self._finish()

    def _finish(self) -> bool:
        self.obstacles = tuple(self._out)
        return True


@dataclass(frozen=True, slots=True)
class _Entry:
    obstacles: tuple[Obstacle, ...]
    ingested_s: float
    expires_at_s: float
    moving: bool


class ObstacleStore:
    """The live obstacle lists of every publisher, merged on demand with the mission's.

    Times are the app's clock in seconds (sim time in lockstep). Not thread-safe: call from one thread
    (the app's event loop).
    """

    def __init__(self, *, log_interval_s: float = 1.0, clock: Callable[[], float] = time.monotonic) -> None:
        self._entries: dict[str, _Entry] = {}
        self._next_expiry_s = math.inf
        self.rejected_count = 0
        self.accepted_count = 0
        self.version = 0
        self.last_error: str | None = None
        self._log_interval_s = log_interval_s
        self._clock = clock
        self._last_log = -math.inf
        self._unlogged = 0
        self._cache_version = -1
        self._cache_mission: Sequence[Obstacle] | None = None
        self._cache: tuple[Obstacle, ...] = ()

    def ingest(self, source_key: str, raw_bytes: bytes | str, now_s: float) -> bool:
        """Take one sample from publisher ``source_key`` at app time ``now_s``; False if rejected."""
        try:
            obstacles, expires_s = parse_obstacles_in(raw_bytes, source_key)
        except ValueError as exc:
            self._reject(source_key, str(exc))
            return False
        return self.adopt(source_key, obstacles, expires_s, now_s)

    def reject(self, source_key: str, why: str) -> None:
        """Count a sample that failed parsing elsewhere (e.g. in a :class:`SampleParser`)."""
        self._reject(source_key, why)

    def adopt(self, source_key: str, obstacles: tuple[Obstacle, ...], expires_s: float | None, now_s: float) -> bool:
        """Take publisher ``source_key``'s parsed list at app time ``now_s``; False if refused."""
        try:
            if not math.isfinite(now_s):
                raise ValueError(f"now_s: must be finite, got {now_s!r}")
            if source_key not in self._entries and obstacles and len(self._entries) >= MAX_SOURCES:
                raise ValueError(f"source: {MAX_SOURCES} live publishers already, refusing {source_key!r}")
        except ValueError as exc:
            self._reject(source_key, str(exc))
            return False
        self.accepted_count += 1
        old = self._entries.get(source_key)
        if not obstacles:
            if old is not None:
                del self._entries[source_key]
                self._changed()
            return True
        moving = any(o.vx_mps != 0.0 or o.vy_mps != 0.0 for o in obstacles)
        expires_at = math.inf if expires_s is None else now_s + expires_s
        self._entries[source_key] = _Entry(obstacles, now_s, expires_at, moving)
        self._next_expiry_s = min(self._next_expiry_s, expires_at)
        if old is None or old.obstacles != obstacles or moving:
            self._changed()
        return True

    def current(self, now_s: float, mission_obstacles: Sequence[Obstacle] = ()) -> tuple[Obstacle, ...]:
        """Mission obstacles (unchanged) followed by every live publisher's unexpired ones, moving ones
        advanced to ``now_s``. Cheap when nothing changed (cached)."""
        if now_s >= self._next_expiry_s:
            self._expire(now_s)
        if (
            self.version == self._cache_version and mission_obstacles is self._cache_mission
            and not self._any_moving()
        ):
            return self._cache
        merged: list[Obstacle] = list(mission_obstacles)
        for e in self._entries.values():
            if e.moving:
                dt = max(0.0, now_s - e.ingested_s)
                merged.extend(o.at_time(dt) for o in e.obstacles)
            else:
                merged.extend(e.obstacles)
        self._cache = tuple(merged)
        self._cache_version = self.version
        self._cache_mission = mission_obstacles
        return self._cache

    def sources(self) -> tuple[str, ...]:
        """Keys of the publishers whose obstacles are held now (expired ones go at the next ``current``)."""
        return tuple(self._entries)

    def _any_moving(self) -> bool:
        return any(e.moving for e in self._entries.values())

    def _expire(self, now_s: float) -> None:
        gone = [k for k, e in self._entries.items() if now_s >= e.expires_at_s]
        for k in gone:
            log.info("live obstacles from %s expired at t=%.3f s", k, now_s)
            del self._entries[k]
        self._next_expiry_s = min((e.expires_at_s for e in self._entries.values()), default=math.inf)
        if gone:
            self._changed()

    def _changed(self) -> None:
        self.version += 1

    def _reject(self, source_key: str, msg: str) -> None:
        self.rejected_count += 1
        self.last_error = f"{source_key}: {msg}"
        now = self._clock()
        if now - self._last_log >= self._log_interval_s:
            extra = f" (+{self._unlogged} more since last report)" if self._unlogged else ""
            log.warning(
                "rejected obstacle sample from %s: %s; %d rejected in total%s",
                source_key, msg[:300], self.rejected_count, extra,
            )
            self._last_log = now
            self._unlogged = 0
        else:
            self._unlogged += 1
