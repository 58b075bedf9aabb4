"""The companion's Zenoh shell: session flags, telemetry publishers, live obstacle input, config queryable.

Streams (``<prefix>/<id>/...``, prefix default ``slungpilot``, id the vehicle id):
``swing`` (every call, the control rate), ``state`` (50 Hz by sim time), ``setpoint`` (50 Hz), ``status``
(1 Hz), ``obstacles`` (on change, at most 20 Hz, at least 1 Hz), liveliness token ``alive``, queryable
``config``. Input: ``<prefix>/<id>/obstacles/in/**`` and ``<prefix>/world/obstacles/**``.

Threading: obstacle samples never run Python on Zenoh's threads. Each obstacle subscriber has a Zenoh ring
channel (``INBOX_RING``, newest samples kept, oldest dropped inside Zenoh) that :meth:`ingest` drains on the app's
thread, so a flood never competes with the control thread for the GIL (a callback per sample took it a thousand
times a second under a 1 kHz flood, ~1 s of CPU per flooded flight). Drained samples replace
their publisher's previous unread one (newest wins; superseded ones are counted, never parsed). Config queries
are handled by a callback that hands them to the asyncio loop with ``loop.call_soon_threadsafe``.
Obstacle samples are parsed by :meth:`ingest` on the app's thread right after
each control tick (outside it: the tick only reads the adopted set, :meth:`obstacles_current`), within a time
budget (``ingest_budget_s``, 0.3 ms): a list too long for one budget is parsed over several
(:class:`~companion.zenoh_io.obstacle_store.SampleParser`). So a flood — any rate, any size — costs each control
period at most the budget (plus one slice of a few obstacles), never the tick itself, and the newest list of
every publisher still gets through.

Keys and rates: :mod:`companion.zenoh_io.telemetry_options`; the flight's sink over it:
:mod:`companion.zenoh_io.telemetry_sink`.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import queue
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import zenoh

from companion.core.obstacles import Obstacle
from companion.errors import ConfigError
from companion.zenoh_io import schema as ts
from companion.zenoh_io.obstacle_store import ObstacleStore, SampleParser
from companion.zenoh_io.session import open_session
from companion.zenoh_io.telemetry_options import TelemetryOptions, _Every

log = logging.getLogger(__name__)

MAX_PUBLISHERS_WAITING = 256  # distinct publishers with an unread sample; beyond this samples are dropped
# samples each obstacle subscriber holds between two drains (one control period); a flood beyond this many samples
# per period loses its oldest inside Zenoh (uncounted), so another publisher's sample survives a flood of up to
# INBOX_RING samples per period (16 kHz at 250 Hz); worst-case memory INBOX_RING x 256 kB per subscriber
INBOX_RING = 64
INGEST_BUDGET_S = 0.3e-3  # parsing time one control tick may spend on live obstacle input
MAX_QUEUE = 2000
Vec = Sequence[float] | np.ndarray


def _tup(v: Vec) -> tuple[float, ...]:
    return tuple(map(float, v))


def _body(payload: Mapping[str, Any]) -> dict[str, Any]:
    """Shallow copy with top-level numpy arrays copied out (the app may reuse its arrays)."""
    body = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in payload.items()}
    if not ts.HEADER_KEYS_SET.isdisjoint(body):
        raise ValueError(f"{sorted(ts.HEADER_KEYS_SET & set(body))[0]}: is a header key, not a body field")
    return body


def _encode_obstacles(seq: int, vid: str, t_s: float, wall_s: float, obstacles: Sequence[Obstacle],
                      rejected: int, version: int) -> bytes:
    return ts.encode_dict(seq, vid, t_s, wall_s, ts.obstacles_body(obstacles, rejected, version), ts.OBSTACLES)


class ZenohTelemetry:
    """Publishers, obstacle input, liveliness token and config queryable of one vehicle.

    Use ``async with ZenohTelemetry(cfg, opts) as zt:`` in the app (or ``with`` / :meth:`open` +
    :meth:`close` without asyncio). Every ``publish_*`` returns True when a sample went out; after
    :meth:`close` they do nothing. Call them from one thread (the app's loop).
    """

    def __init__(self, config: zenoh.Config, options: TelemetryOptions | None = None,
                 *, store: ObstacleStore | None = None) -> None:
        self.options = options or TelemetryOptions()
        try:
            self.options.validate()
        except ValueError as exc:
            raise ConfigError(f"zenoh telemetry: {exc}") from None
        self._config = config
        self.store = store if store is not None else ObstacleStore()
        self._vid = self.options.vehicle_id
        base = f"{self.options.prefix}/{self._vid}"
        self.keys = {name: f"{base}/{name}" for name in ts.STREAMS}
        self.keys["alive"] = f"{base}/alive"
        self.keys["obstacles_in"] = f"{base}/obstacles/in/**"
        self.keys["world_obstacles"] = f"{self.options.prefix}/world/obstacles/**"
        self.seq = dict.fromkeys(ts.STREAMS, 0)
        self.inbox_dropped = 0  # samples dropped: too many publishers waiting
        self.superseded = 0  # samples replaced by a newer one from the same publisher before they were parsed
        self.ring_full = 0  # drains that found a ring full: older samples may have been dropped inside Zenoh
        self.ingest_budget_s = INGEST_BUDGET_S
        self.dropped_local = 0
        self.worker_errors = 0
        self._queue: queue.SimpleQueue | None = None
        self._thread: threading.Thread | None = None
        self._stack: contextlib.ExitStack | None = None
        self._session: zenoh.Session | None = None
        self._pubs: dict[str, zenoh.Publisher] = {}
        self._loop: asyncio.AbstractEventLoop | None = None
        self._subs: list[zenoh.Subscriber] = []  # obstacle input, each with a ring channel drained by ingest
        self._waiting: dict[str, bytes] = {}  # publisher key → newest drained sample not yet parsed
        self._parser: SampleParser | None = None
        # per publisher: the raw bytes of its last adopted sample and what they parsed to; a sample with the same
        # bytes (a static map re-sent, a flood) is adopted again without parsing
        self._adopted: dict[str, tuple[bytes, tuple[Obstacle, ...], float | None]] = {}
        self.unchanged = 0  # samples adopted again without parsing (same bytes as the publisher's last)
        self._provider: Callable[[], Mapping[str, Any]] | None = None
        self._swing_every = _Every(self.options.swing_hz)
        self._state_every = _Every(self.options.state_hz)
        self._setpoint_every = _Every(self.options.setpoint_hz)
        self._status_every = _Every(self.options.status_hz)
        self._obs_heartbeat = _Every(self.options.obstacles_min_hz)
        self._obs_cap = _Every(self.options.obstacles_max_hz)
        self._obs_last: tuple[Obstacle, ...] | None = None
        self._obs_dirty = False
        self._last_t_s = math.nan
        self.last_obstacles: tuple[Obstacle, ...] | None = None

    # -- lifecycle -------------------------------------------------------------------------------------
    def open(self) -> ZenohTelemetry:
        """Open the session and declare everything; raises :class:`LinkError` if Zenoh cannot start."""
        if self._session is not None:
            return self
        stack = contextlib.ExitStack()
        try:
            session = stack.enter_context(open_session(self._config))
            for name, schema in ts.STREAMS.items():
                if name == "config":
                    continue
                self._pubs[name] = session.declare_publisher(
                    self.keys[name], encoding=zenoh.Encoding.APPLICATION_JSON.with_schema(ts.encoding_schema(schema)),
                    congestion_control=zenoh.CongestionControl.DROP, express=self.options.express,
                )
            self._subs = []
            if self.options.subscribe_obstacles:
                for k in ("obstacles_in", "world_obstacles"):
                    self._subs.append(session.declare_subscriber(self.keys[k],
                                                                 zenoh.handlers.RingChannel(INBOX_RING)))
            self._queryable = session.declare_queryable(self.keys["config"], self._on_query)
            self._token = session.liveliness().declare_token(self.keys["alive"])
        except Exception:
            self._pubs = {}
            stack.close()
            raise
        self._stack, self._session = stack, session
        if self.options.background:
            self._queue = queue.SimpleQueue()
            self._thread = threading.Thread(target=self._worker, args=(self._queue, dict(self._pubs)),
                                            name=f"zenoh-pub-{self._vid}", daemon=True)
            self._thread.start()
        log.info("zenoh: publishing under %s/%s", self.options.prefix, self._vid)
        return self

    def close(self) -> None:
        """Undeclare the token (subscribers see the vehicle go) and close the session. Idempotent."""
        stack, self._stack = self._stack, None
        self._session = None
        self._pubs = {}
        self._subs = []
        q, th, self._queue, self._thread = self._queue, self._thread, None, None
        if q is not None and th is not None:
            q.put(None)
            th.join(timeout=2.0)
        if stack is not None:
            with contextlib.suppress(Exception):
                self._token.undeclare()
            stack.close()

    @property
    def is_open(self) -> bool:
        return self._session is not None

    @property
    def session(self) -> zenoh.Session | None:
        """The open session (None when closed): for other inputs of the same vehicle (the scan input)."""
        return self._session

    def __enter__(self) -> ZenohTelemetry:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    async def __aenter__(self) -> ZenohTelemetry:
        self._loop = asyncio.get_running_loop()
        return self.open()

    async def __aexit__(self, *exc: object) -> None:
        self.close()
        self._loop = None

    # -- streams out -----------------------------------------------------------------------------------
    def _emit(self, name: str, encode: Callable[..., bytes], *args: Any) -> bool:
        """Number the sample and send it: encoded and put by the worker thread (``background``), else here."""
        if not self._pubs:
            return False
        seq = self.seq[name]
        self.seq[name] = seq + 1
        q = self._queue
        if q is not None:
            if q.qsize() >= MAX_QUEUE:
                self.dropped_local += 1
                return False
            q.put((name, encode, (seq, self._vid, *args)))
            return True
        self._pubs[name].put(encode(seq, self._vid, *args))
        return True

    def _worker(self, q: queue.SimpleQueue, pubs: dict[str, zenoh.Publisher]) -> None:
        """Background thread: encode and put queued samples in order until the ``None`` sentinel."""
        last_log = -math.inf
        while True:
            item = q.get()
            if item is None:
                return
            name, encode, args = item
            try:
                pubs[name].put(encode(*args))
            except Exception as exc:
                self.worker_errors += 1
                if time.monotonic() - last_log >= 1.0:
                    last_log = time.monotonic()
                    log.warning("zenoh: %s sample not published: %s (%d so far)", name, exc, self.worker_errors)

    def publish_swing(self, t_s: float, swing4: Vec | None, r_max_m: float, envelope_mode: str,
                      source: str | None = None, truth4: Vec | None = None, sigma_rad: float | None = None,
                      fade: float | None = None) -> bool:
        """Swing (α, β rad; α̇, β̇ rad/s; None = no estimate), envelope radius (m) and mode; where known its
        source, the vehicle's own measurement beside an estimate, its 1σ and fade; every call (or ``swing_hz``)."""
        self._last_t_s = t_s
        if not self._swing_every.due(t_s):
            return False
        sw = None if swing4 is None else tuple(map(float, swing4))
        tr = None if truth4 is None else tuple(map(float, truth4))
        return self._emit("swing", ts.encode_swing, t_s, time.time(), sw, r_max_m, envelope_mode, source, tr,
                          sigma_rad, fade)

    def publish_state(self, t_s: float, pos_ned_m: Vec, vel_ned_mps: Vec, euler_rad: Vec,
                      payload_pos_ned_m: Vec | None) -> bool:
        """Vehicle position (m), velocity (m/s), roll/pitch/yaw (rad), payload position (m); NED; 50 Hz."""
        if not self._pubs or not self._state_every.due(t_s):
            return False
        return self._emit("state", ts.encode_state, t_s, time.time(), _tup(pos_ned_m), _tup(vel_ned_mps),
                          _tup(euler_rad), None if payload_pos_ned_m is None else _tup(payload_pos_ned_m))

    def publish_setpoint(self, t_s: float, payload: Mapping[str, Any]) -> bool:
        """The app's setpoint dict (attitude, thrust, reference, forces; JSON-able values, numpy arrays
        allowed; nested containers must not be mutated afterwards); 50 Hz."""
        if not self._pubs or not self._setpoint_every.due(t_s):
            return False
        return self._emit("setpoint", ts.encode_dict, t_s, time.time(), _body(payload), ts.SETPOINT)

    def publish_status(self, t_s: float, payload: Mapping[str, Any], *, force: bool = False) -> bool:
        """The app's status dict (mode, armed, link health, progress, counters), plus ``obstacles_in``
        counters of this object; 1 Hz unless ``force``."""
        if not self._pubs or not (self._status_every.due(t_s) or force):
            return False
        body = _body(payload)
        body.setdefault("obstacles_in", {
            "accepted": self.store.accepted_count, "rejected": self.store.rejected_count,
            "inbox_dropped": self.inbox_dropped, "superseded": self.superseded, "unchanged": self.unchanged,
            "ring_full": self.ring_full,
            "pending": len(self._waiting) + (self._parser is not None),
            "sources": list(self.store.sources()),
        })
        body.setdefault("zenoh", {"dropped_local": self.dropped_local, "worker_errors": self.worker_errors})
        return self._emit("status", ts.encode_dict, t_s, time.time(), body, ts.STATUS)

    def publish_obstacles(self, t_s: float, obstacles: Sequence[Obstacle]) -> bool:
        """The obstacle set in use: sent when it changed (at most ``obstacles_max_hz``) and at least every
        ``1/obstacles_min_hz`` s of sim time."""
        if not self._pubs:
            return False
        if obstacles is not self._obs_last:
            obs = tuple(obstacles)
            if obs != self._obs_last:
                self._obs_dirty = True
            self._obs_last = obs
        heartbeat = self._obs_heartbeat.due(t_s)
        if not heartbeat and not (self._obs_dirty and self._obs_cap.due(t_s)):
            return False
        if heartbeat:
            self._obs_cap.due(t_s)
        self._obs_dirty = False
        return self._emit("obstacles", _encode_obstacles, t_s, time.time(), self._obs_last or (),
                          self.store.rejected_count, self.store.version)

    # -- obstacles in ----------------------------------------------------------------------------------
    def _drain(self) -> None:
        """Move every sample waiting in the subscribers' rings to ``_waiting`` (newest per publisher wins)."""
        waiting = self._waiting
        parsing = self._parser.key if self._parser is not None else None
        for sub in self._subs:
            n = 0
            while (sample := sub.try_recv()) is not None:
                n += 1
                if n == INBOX_RING:
                    self.ring_full += 1
                key = str(sample.key_expr)
                if key in waiting or key == parsing:
                    self.superseded += 1
                elif len(waiting) >= MAX_PUBLISHERS_WAITING:
                    self.inbox_dropped += 1
                    continue
                waiting[key] = sample.payload.to_bytes()

    def obstacles_now(self, now_s: float, mission_obstacles: Sequence[Obstacle] = ()) -> tuple[Obstacle, ...]:
        """:meth:`ingest` then :meth:`obstacles_current`: parse what waits (within the budget), then the merged
        set to plan with now."""
        self.ingest(now_s)
        return self.obstacles_current(now_s, mission_obstacles)

    def obstacles_current(self, now_s: float, mission_obstacles: Sequence[Obstacle] = ()) -> tuple[Obstacle, ...]:
        """The mission's obstacles and every live publisher's adopted, unexpired ones at app time ``now_s`` (s);
        parses nothing (cheap: cached until the set changes)."""
        self.last_obstacles = self.store.current(now_s, mission_obstacles)
        return self.last_obstacles

    def ingest(self, now_s: float) -> None:
        """Parse waiting live samples for at most ``ingest_budget_s`` and adopt the finished ones at app time
        ``now_s`` (s). The app calls this after each tick."""
        self._drain()
        if self._parser is not None or self._waiting:
            deadline = time.perf_counter() + self.ingest_budget_s
            while True:
                if self._parser is None:
                    if not self._waiting:
                        break
                    key = next(iter(self._waiting))
                    raw = self._waiting.pop(key)
                    prev = self._adopted.get(key)
                    if prev is not None and prev[0] == raw:
                        self.unchanged += 1
                        self.store.adopt(key, prev[1], prev[2], now_s)  # refreshes its age and expiry
                        continue
                    self._parser = SampleParser(key, raw)
                p = self._parser
                if not p.work(deadline):
                    break
                self._parser = None
                if p.error is not None:
                    self.store.reject(p.key, p.error)
                    self._adopted.pop(p.key, None)
                elif self.store.adopt(p.key, p.obstacles, p.expires_s, now_s):
                    self._adopted[p.key] = (p.raw, p.obstacles, p.expires_s)
                if time.perf_counter() > deadline:
                    break

    def obstacle_source(self, mission_obstacles: Sequence[Obstacle]) -> Callable[[float], tuple[Obstacle, ...]]:
        """``t_s -> obstacles`` for a runner's obstacle source (no parsing: pair it with :meth:`ingest` as its
        obstacle ingest, ``Runner.use_obstacle_input``)."""
        return lambda t_s: self.obstacles_current(t_s, mission_obstacles)

    # -- config queryable ------------------------------------------------------------------------------
    def set_config_provider(self, provider: Callable[[], Mapping[str, Any]]) -> None:
        """``provider()`` returns the effective mission / vehicle / controller parameters as a dict; it is
        called on the app's loop thread (or a Zenoh thread when not entered with ``async with``)."""
        self._provider = provider

    def _on_query(self, query: zenoh.Query) -> None:
        loop = self._loop
        if loop is None:
            self._answer(query)
            return
        try:
            loop.call_soon_threadsafe(self._answer, query)
        except RuntimeError:
            query.drop()

    def _answer(self, query: zenoh.Query) -> None:
        try:
            if self._provider is None:
                query.reply_err(b"no config provider set")
                return
            body = {"config": self._provider()}
            seq = self.seq["config"]
            self.seq["config"] += 1
            payload = ts.encode_dict(seq, self._vid, self._last_t_s, time.time(), body, ts.CONFIG)
            query.reply(self.keys["config"], payload,
                        encoding=zenoh.Encoding.APPLICATION_JSON.with_schema(ts.encoding_schema(ts.CONFIG)))
        except Exception as exc:
            log.warning("zenoh: config query failed: %s", exc)
            with contextlib.suppress(Exception):
                query.reply_err(f"config provider failed: {exc}".encode())
        finally:
            query.drop()
