"""Link health, measured without I/O: frame loss and reordering from MAVLink sequence numbers, telemetry age
and staleness per control tick. The app feeds it; the status stream and the report read :meth:`summary`.

Loss: MAVLink numbers every frame per (system, component) modulo 256. The numbers a source went through
(every step of 1..127 ahead of the highest seen) minus the frames that arrived is the loss; a frame behind the
highest seen arrived out of order (counted as reordered, and no longer as lost).
Staleness: a tick is *stale* when the older of position and attitude is more than three control periods
older than its usual interval (learned from the stream itself, so an autopilot that sends 50 Hz instead
of the 250 Hz asked for is not stale for it).
Deaf spells: while the companion's own loop is stalled (its process stopped, swapped out, or the VM paused), the
vehicle's datagrams wait unread in the socket, so the silence is ours. :class:`DeafSpells` keeps those spells
and moves a "last heard" time forward by the deaf time since, so a lost link is declared only for silence the
companion was there to hear.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

_AGE_RING = 4096  # recent telemetry ages kept for the percentiles


@dataclass
class _Stream:
    last_t_s: float | None = None
    interval_s: float | None = None  # exponential average of the sample interval (vehicle time)

    def sample(self, t_s: float) -> None:
        if self.last_t_s is not None and t_s > self.last_t_s:
            dt = t_s - self.last_t_s
            self.interval_s = dt if self.interval_s is None else 0.95 * self.interval_s + 0.05 * dt
        self.last_t_s = t_s


@dataclass
class LinkHealth:
    """Counters and recent ages; ``period_s`` is the control period."""

    period_s: float = 0.004
    frames: int = 0
    reordered: int = 0
    stale_ticks: int = 0
    _span: int = 0  # sequence numbers gone through, all sources
    _last_seq: dict[tuple[int, int], int] = field(default_factory=dict)
    _ages: np.ndarray = field(default_factory=lambda: np.full(_AGE_RING, np.nan))
    _n_ages: int = 0
    _streams: dict[str, _Stream] = field(default_factory=dict)

    def on_frame(self, sysid: int, compid: int, seq: int) -> None:
        """One frame from (sysid, compid) with sequence number ``seq`` (0..255)."""
        self.frames += 1
        key = (sysid, compid)
        last = self._last_seq.get(key)
        if last is None:
            self._last_seq[key] = seq
            self._span += 1
            return
        ahead = (seq - last) & 0xFF
        if 0 < ahead < 128:
            self._span += ahead
            self._last_seq[key] = seq
        else:
            self.reordered += 1

    @property
    def lost(self) -> int:
        """Frames the sources numbered that never arrived (so far)."""
        return max(0, self._span - self.frames)

    def on_sample(self, kind: str, t_s: float) -> None:
        """A telemetry sample of ``kind`` (``position``, ``attitude``) stamped ``t_s`` (vehicle time)."""
        st = self._streams.get(kind)
        if st is None:
            st = self._streams[kind] = _Stream()
        st.sample(t_s)

    def on_tick(self, now_vehicle_s: float, age_wall_s: float | None) -> bool:
        """Record one tick's telemetry age (wall, s); returns True when the tick counts as stale."""
        if age_wall_s is not None and math.isfinite(age_wall_s):
            self._ages[self._n_ages % _AGE_RING] = age_wall_s
            self._n_ages += 1
        stale = False
        for st in self._streams.values():
            if st.last_t_s is None or st.interval_s is None:
                continue
            if now_vehicle_s - st.last_t_s > st.interval_s + 3.0 * self.period_s:
                stale = True
        if stale:
            self.stale_ticks += 1
        return stale

    def summary(self) -> dict[str, float | int | None]:
        """frames, lost, loss fraction, reordered, stale ticks, telemetry age p50/p99 (ms, wall)."""
        ages = self._ages[np.isfinite(self._ages)]
        return {
            "frames": self.frames,
            "lost": self.lost,
            "loss": (self.lost / self._span) if self._span else 0.0,
            "reordered": self.reordered,
            "stale_ticks": self.stale_ticks,
            "telemetry_age_ms_p50": float(np.percentile(ages, 50) * 1e3) if ages.size else None,
            "telemetry_age_ms_p99": float(np.percentile(ages, 99) * 1e3) if ages.size else None,
        }


def lockstep_telemetry_wall_s(wall_s: float, telemetry_wall_s: float | None, last_answer_wall_s: float,
                              vehicle_t_s: float, pos_t_s: float, att_t_s: float) -> float | None:
    """The wall time (s) telemetry counts as received at, in lockstep.

    While the vehicle has not had our answer to its last step it waits on us, so a quiet socket is not staleness:
    its telemetry is as current as the vehicle's own clock says, i.e. as old as the vehicle time ``vehicle_t_s``
    is past the older of the last *accepted* position and attitude (``pos_t_s``, ``att_t_s``). Samples the vehicle
    keeps sending but we reject (an attitude out of range) therefore age on vehicle time. Once it has our answer
    (``last_answer_wall_s`` after ``telemetry_wall_s``), the wall clock rules as in real time.
    """
    if telemetry_wall_s is None or last_answer_wall_s > telemetry_wall_s:
        return telemetry_wall_s
    return wall_s - max(0.0, vehicle_t_s - min(pos_t_s, att_t_s))


@dataclass
class DeafSpells:
    """Spells (wall clock, s) when the companion's loop could not listen: stalls of at least ``min_s``."""

    min_s: float = 0.1  # shorter waits are ordinary jitter; silence through them counts
    count: int = 0
    longest_s: float = 0.0
    _spells: deque[tuple[float, float]] = field(default_factory=lambda: deque(maxlen=64))

    def add(self, start_s: float, end_s: float) -> None:
        """A loop should have run at ``start_s`` and ran at ``end_s``; kept when it is a stall (>= ``min_s``).
        The tick loop and the watchdog both report the same stall: one overlapping the last spell extends it."""
        if end_s - start_s < self.min_s:
            return
        if self._spells and start_s <= self._spells[-1][1] and end_s >= self._spells[-1][0]:
            s0, e0 = self._spells[-1]
            start_s, end_s = min(s0, start_s), max(e0, end_s)
            self._spells[-1] = (start_s, end_s)
        else:
            self._spells.append((start_s, end_s))
            self.count += 1
        self.longest_s = max(self.longest_s, end_s - start_s)

    def heard_at(self, wall_s: float | None, now_s: float) -> float | None:
        """``wall_s`` (when something was last heard) moved forward by the deaf time between it and ``now_s``, so
        ``now_s - heard_at(...)`` counts only time the loop was listening; None stays None."""
        if wall_s is None:
            return None
        deaf = sum(max(0.0, min(end, now_s) - max(start, wall_s)) for start, end in self._spells)
        return wall_s + deaf

    def summary(self) -> dict[str, float | int]:
        """How many deaf spells and the longest (s)."""
        return {"deaf_spells": self.count, "deaf_s_max": self.longest_s}


class RealtimeClock:
    """The sequence's clock in real time: ``now_s`` is the wall clock, and silence while the companion's own loop
    stalled (:class:`DeafSpells`, filled by the real-time runner) is not the vehicle's."""

    lockstep = False

    def __init__(self) -> None:
        self.deaf = DeafSpells()

    def times(self, heartbeat_wall_s: float | None, telemetry_wall_s: float | None, vehicle_t_s: float,
              pos_t_s: float, att_t_s: float, wall_s: float) -> tuple[float, float | None, float | None]:
        """(now_s, heartbeat wall time, telemetry wall time) as the sequence should see them."""
        return wall_s, self.deaf.heard_at(heartbeat_wall_s, wall_s), self.deaf.heard_at(telemetry_wall_s, wall_s)


class LockstepClock:
    """The sequence's clock in lockstep: ``now_s`` is the vehicle's time (a flight repeats bit for bit); telemetry
    ages as :func:`lockstep_telemetry_wall_s` says; any datagram from the vehicle shows it alive (its HEARTBEAT runs on
    simulated time, which may run slower than the wall clock on a loaded machine). The lockstep runner sets
    ``last_answer_wall_s`` (when it last answered a step) and ``last_rx_wall_s`` (when the vehicle last sent)."""

    lockstep = True

    def __init__(self) -> None:
        self.last_answer_wall_s = 0.0
        self.last_rx_wall_s = 0.0

    def times(self, heartbeat_wall_s: float | None, telemetry_wall_s: float | None, vehicle_t_s: float,
              pos_t_s: float, att_t_s: float, wall_s: float) -> tuple[float, float | None, float | None]:
        """(now_s, heartbeat wall time, telemetry wall time) as the sequence should see them."""
        tel = lockstep_telemetry_wall_s(wall_s, telemetry_wall_s, self.last_answer_wall_s, vehicle_t_s, pos_t_s,
                                        att_t_s)
        hb = None if heartbeat_wall_s is None else max(heartbeat_wall_s, self.last_rx_wall_s)
        return vehicle_t_s, hb, tel
