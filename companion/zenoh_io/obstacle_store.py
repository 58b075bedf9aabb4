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
import re
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

from companion.core.obstacles import Obstacle
from companion.zenoh_io.schema import OBSTACLES_IN, SCHEMA_VERSION

log = logging.getLogger(__name__)

MAX_SAMPLE_BYTES = 256 * 1024
MAX_OBSTACLES_PER_SAMPLE = 256
MAX_ITEM_CHARS = 1024  # one obstacle object's JSON text (a full one with long numbers is ~250)
MAX_SOURCES = 64
MAX_EXPIRES_S = 3600.0
_TOP_KEYS = frozenset({"obstacles", "expires_s", "schema", "version"})
_OBSTACLE_KEYS = ("x_m", "y_m", "radius_m", "height_m", "safe_distance_m", "vx_mps", "vy_mps")
_REQUIRED_KEYS = ("x_m", "y_m", "radius_m")


def _reject_constant(name: str) -> Any:
    raise ValueError(f"obstacles: {name} is not allowed")


def _is_number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


_DECODER = json.JSONDecoder(parse_constant=_reject_constant)
MAX_WHITESPACE_RUN = 4096  # JSON whitespace in a row (a longer run is refused: keeps every scan step short)
MAX_SCALAR_CHARS = 256  # a top-level key or value, or a non-object item, as JSON text
_WS = re.compile(f"[ \\t\\n\\r]{{0,{MAX_WHITESPACE_RUN}}}")
_TYPE_OF_OPENER = {"{": "dict", "[": "list"}


def _short(v: Any) -> str:
    """``repr(v)`` cut to 60 characters (error messages quote what a publisher sent, which can be 256 kB)."""
    r = repr(v)
    return r if len(r) <= 60 else r[:57] + "..."


def _not_json(exc: json.JSONDecodeError | str) -> ValueError:
    return ValueError(f"sample: not JSON ({exc})")


def _scalar(s: str, i: int, what: str, want: str) -> tuple[Any, int]:
    """The JSON string, number, true, false or null at ``s[i]`` and the index after it. An object or array there
    is refused as ``what: expected <want>, got dict|list`` without being read (bounded time, no recursion)."""
    opener = s[i:i + 1]
    if opener in _TYPE_OF_OPENER:
        raise ValueError(f"{what}: expected {want}, got {_TYPE_OF_OPENER[opener]}")
    try:
        v, n = _DECODER.raw_decode(s[i:i + MAX_SCALAR_CHARS])
    except json.JSONDecodeError as exc:
        why = f"{exc.msg} (char {i + exc.pos}), or a value longer than {MAX_SCALAR_CHARS} characters"
        raise _not_json(why) from None
    return v, i + n


def _skip_ws(s: str, i: int) -> int:
    """The index of the first non-whitespace character at or after ``s[i]``."""
    j = _WS.match(s, i).end()
    if j - i == MAX_WHITESPACE_RUN and s[j:j + 1] in (" ", "\t", "\n", "\r"):
        raise _not_json(f"more than {MAX_WHITESPACE_RUN} whitespace characters in a row at char {i}")
    return j


def _after_member(s: str, i: int, closer: str) -> tuple[int, bool]:
    """After an object member or array item ending before ``s[i]``: the index of what follows the ``,`` or the
    ``closer``, and whether it was the closer."""
    i = _skip_ws(s, i)
    sep = s[i:i + 1]
    if sep != "," and sep != closer:
        raise _not_json(f"expected ',' or '{closer}' at char {i}")
    return _skip_ws(s, i + 1), sep == closer


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
    p = SampleParser(source, raw)
    p.work(math.inf)
    if p.error is not None:
        raise ValueError(p.error)
    return p.obstacles, p.expires_s


class SampleParser:
    """One sample parsed a slice at a time: :meth:`work` stops at a deadline and goes on at the next call, so no
    sample — a list of hundreds of obstacles, or 256 kB built to be slow — costs one control tick more than its
    budget (plus one slice: at most ``ITEMS_PER_SLICE`` items of at most ``MAX_ITEM_CHARS`` characters).

    The sample is read by a scanner for exactly the schema's shape (an object whose ``obstacles`` array holds
    flat objects), never by one ``json.loads`` of the whole text: that took 15 ms for 256 kB of numbers and
    raised ``RecursionError`` on deeply nested arrays. Each obstacle object is decoded on its own.

    After :meth:`work` returned True, ``error`` is None and ``obstacles``/``expires_s`` hold the result, or
    ``error`` says why the sample was refused as a whole.
    """

    ITEMS_PER_SLICE = 4

    def __init__(self, key: str, raw: bytes | str) -> None:
        self.key = key
        self.raw = raw  # the sample as received
        self.obstacles: tuple[Obstacle, ...] = ()
        self.expires_s: float | None = None
        self.error: str | None = None
        self._steps = self._scan()

    def work(self, deadline_s: float, clock: Callable[[], float] = time.perf_counter) -> bool:
        """Parse until done (True) or until ``clock()`` passes ``deadline_s`` (False: call again)."""
        try:
            for _ in self._steps:
                if clock() > deadline_s:
                    return False
        except ValueError as exc:  # JSONDecodeError and UnicodeDecodeError are ValueErrors too
            self.error = str(exc)
            self._steps = iter(())
        except Exception as exc:  # a bug here must refuse this sample, never wedge the input behind it
            log.exception("obstacles: parsing a sample from %s failed", self.key)
            self.error = f"sample: could not be parsed ({type(exc).__name__})"
            self._steps = iter(())
        return True

    def _scan(self) -> Iterator[None]:
        """Generator: the whole parse, yielding after every ``ITEMS_PER_SLICE`` obstacles."""
        raw = self.raw
        if len(raw) > MAX_SAMPLE_BYTES:
            raise ValueError(f"sample: {len(raw)} bytes is above {MAX_SAMPLE_BYTES}")
        if isinstance(raw, bytes):
            try:
                raw = raw.decode("utf-8")
            except UnicodeDecodeError as exc:
                raise ValueError(f"sample: not UTF-8 ({exc})") from None
        s: str = raw
        i = _skip_ws(s, 0)
        if s[i:i + 1] != "{":
            v, i = _scalar(s, i, "sample", "a JSON object")
            raise ValueError(f"sample: expected a JSON object, got {type(v).__name__}")
        top: dict[str, Any] = {}
        out: list[Obstacle] = []
        i = _skip_ws(s, i + 1)
        if s[i:i + 1] == "}":
            i += 1
        else:
            while True:
                if s[i:i + 1] != '"':
                    raise _not_json(f"expected a key in double quotes at char {i}")
                name, i = _scalar(s, i, "sample", "a key")
                i = _skip_ws(s, i)
                if s[i:i + 1] != ":":
                    raise _not_json(f"expected ':' at char {i}")
                i = _skip_ws(s, i + 1)
                if name not in _TOP_KEYS:
                    raise ValueError(f"{_short(name)}: unknown key (known: {', '.join(sorted(_TOP_KEYS))})")
                if name in top:
                    raise ValueError(f"{name}: given twice")
                if name == "obstacles" and s[i:i + 1] == "[":
                    top[name] = out
                    i = yield from self._scan_items(s, i + 1, out)
                else:
                    top[name], i = _scalar(s, i, name, "a list" if name == "obstacles" else "a scalar")
                i, closed = _after_member(s, i, "}")
                if closed:
                    break
        if _skip_ws(s, i) != len(s):
            raise _not_json(f"extra data at char {i}")
        self.expires_s = _check_top(top)
        self.obstacles = tuple(out)

    def _scan_items(self, s: str, i: int, out: list[Obstacle]) -> Iterator[None]:
        """Generator: the obstacle objects from ``s[i]`` (just after the ``[``) into ``out``; returns the index
        after the ``]``."""
        i = _skip_ws(s, i)
        if s[i:i + 1] == "]":
            return i + 1
        while True:
            n = len(out)
            if n >= MAX_OBSTACLES_PER_SAMPLE:
                raise ValueError(f"obstacles: more than {MAX_OBSTACLES_PER_SAMPLE} obstacles")
            if s[i:i + 1] != "{":
                v, i = _scalar(s, i, f"obstacles[{n}]", "an object")
                raise ValueError(f"obstacles[{n}]: expected an object, got {type(v).__name__}")
            j = s.find("}", i, i + MAX_ITEM_CHARS)
            if j < 0:
                raise ValueError(f"obstacles[{n}]: not a flat object of at most {MAX_ITEM_CHARS} characters")
            text = s[i:j + 1]
            if "{" in text[1:] or "[" in text:
                raise ValueError(f"obstacles[{n}]: values must be numbers, not objects or arrays")
            try:
                item = _DECODER.decode(text)
            except json.JSONDecodeError as exc:
                raise ValueError(f"obstacles[{n}]: not JSON ({exc})") from None
            out.append(_obstacle_of(n, item, self.key))
            i, closed = _after_member(s, j + 1, "]")
            if closed:
                return i
            if len(out) % self.ITEMS_PER_SLICE == 0:
                yield


def _check_top(top: dict[str, Any]) -> float | None:
    """The sample's top-level members checked (``obstacles`` already read); returns expires_s or None."""
    if "schema" in top and top["schema"] != OBSTACLES_IN:
        raise ValueError(f"schema: expected {OBSTACLES_IN!r}, got {_short(top['schema'])}")
    if "version" in top and (not _is_number(top["version"]) or top["version"] != SCHEMA_VERSION):
        raise ValueError(f"version: expected {SCHEMA_VERSION}, got {_short(top['version'])}")
    if "obstacles" not in top:
        raise ValueError("obstacles: missing required key")
    expires = top.get("expires_s")
    if expires is not None and (not _is_number(expires) or not 0.0 < expires <= MAX_EXPIRES_S):
        raise ValueError(f"expires_s: must be a number in (0, {MAX_EXPIRES_S}] s or null, got {_short(expires)}")
    return None if expires is None else float(expires)


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
