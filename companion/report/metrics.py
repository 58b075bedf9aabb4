"""Flight logs (one row per control tick) and the report metrics computed from them.

The same :class:`FlightLog` is filled by the in-process runner (``lab.inprocess``) and can be filled
by the MAVLink app, so both report identical keys (issue 4's report):

reached_goal, time_to_goal_s (first time within 0.1 m of the goal horizontally, or the flight's wider arrival
tolerance where the autopilot reports a coarser position accuracy, counted from the start of
the cruise phase, i.e. once the vehicle is at mission altitude; ``time_to_goal_from_start_s`` counts from
the first log row), path_length_m (airframe, horizontal, until the goal), payload_path_length_m (same
interval), max_swing_rad (max of |α|, |β|), swing_settle_s (time from cruise start after which both stay
below 0.05 rad; ``swing_settle_after_arrival_s`` the same counted from the goal time), min_clearance_m
(minimum over time and obstacles of airframe clearance = horizontal distance − r_obs − (r_uav + L_uav) and
payload clearance = payload horizontal distance − r_obs, each counted only while that point is below the
obstacle's top; moving obstacles where they are at each row's time, see :mod:`companion.report.scoring`),
collisions (obstacles with clearance < 0; ``collisions_moving`` those of them with a velocity),
``obstacle_clock_t0_s`` (the mission clock's zero the moving obstacles were placed by, None if the log had none),
planner, controller, sim_time_s.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import numpy as np

from companion.core.obstacles import Obstacle
from companion.report.scoring import obstacle_clearances, score

GOAL_TOL_M = 0.1
SETTLE_RAD = 0.05


class Column:
    """One per-tick numeric column of ``width`` floats, kept in float64 chunks of :attr:`CHUNK` rows (no Python
    object per value: 8 bytes a number, against ~100 for a small numpy array per row). Reads like the list it
    replaces: ``len``, ``col[i]`` (a float, or a copy of the row), ``col[a:b]`` and ``np.asarray(col)`` (arrays of
    shape (n,) or (n, width)), iteration, truthiness."""

    CHUNK = 4096
    __slots__ = ("_chunks", "_n", "width")

    def __init__(self, width: int = 1, values=()) -> None:
        self.width = int(width)
        self._chunks: list[np.ndarray] = []
        self._n = 0
        if len(values):
            self._fill(np.asarray(values, dtype=np.float64))

    def _fill(self, rows: np.ndarray) -> None:
        """Set the (empty) column to ``rows``, shape (n,) or (n, width)."""
        n = len(rows)
        for k in range(0, n, self.CHUNK):
            c = self._new_chunk()
            c[: min(self.CHUNK, n - k)] = rows[k : k + self.CHUNK]
            self._chunks.append(c)
        self._n = n

    def _new_chunk(self) -> np.ndarray:
        return np.empty(self.CHUNK if self.width == 1 else (self.CHUNK, self.width), dtype=np.float64)

    def append(self, value) -> None:
        i = self._n % self.CHUNK
        if i == 0:
            self._chunks.append(self._new_chunk())
        self._chunks[-1][i] = value
        self._n += 1

    def __len__(self) -> int:
        return self._n

    def _range(self, start: int, stop: int) -> np.ndarray:
        shape = (stop - start,) if self.width == 1 else (stop - start, self.width)
        out = np.empty(shape, dtype=np.float64)
        k = start
        while k < stop:
            c, i = divmod(k, self.CHUNK)
            take = min(self.CHUNK - i, stop - k)
            out[k - start : k - start + take] = self._chunks[c][i : i + take]
            k += take
        return out

    def __getitem__(self, key):
        if isinstance(key, slice):
            start, stop, step = key.indices(self._n)
            if step != 1:
                return self._range(0, self._n)[key]
            return self._range(start, max(start, stop))
        i = int(key)
        if i < 0:
            i += self._n
        if not 0 <= i < self._n:
            raise IndexError(f"row {key} of {self._n}")
        c, j = divmod(i, self.CHUNK)
        v = self._chunks[c][j]
        return float(v) if self.width == 1 else v.copy()

    def __iter__(self):
        for i in range(self._n):
            yield self[i]

    def array(self) -> np.ndarray:
        """Every row as one new array, (n,) or (n, width)."""
        return self._range(0, self._n)

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        a = self.array()
        return a if dtype is None else a.astype(dtype, copy=False)

    def take(self, idx: np.ndarray) -> Column:
        """A new column of the rows ``idx``."""
        return Column(self.width, self.array()[idx])


@dataclass
class FlightLog:
    """Append-per-tick recorder: numeric columns are :class:`Column` s (float64 chunks), the two label columns lists
    of shared strings; :meth:`arr` gives a column as a numpy array (N,) or (N, k)."""

    planner: str = ""
    controller: str = ""
    mission: str = ""
    obstacles: tuple[Obstacle, ...] = ()
    goal_tol_m: float = GOAL_TOL_M  # "at the goal" horizontally (the flight's arrival tolerance, m)
    #: the mission clock's zero (vehicle time, s): the first setpoint (``FlightCore.t0_s``), when the mission's
    #: moving obstacles are at their file positions. The flight's runner sets it; None (a log or run folder
    #: without it) scores moving obstacles at their file positions (:mod:`companion.report.scoring`).
    obstacle_clock_t0_s: float | None = None
    t: Column = field(default_factory=partial(Column, 1))
    pos: Column = field(default_factory=partial(Column, 3))
    vel: Column = field(default_factory=partial(Column, 3))
    euler: Column = field(default_factory=partial(Column, 3))
    swing: Column = field(default_factory=partial(Column, 4))  # [α, β, α̇, β̇], NaN when unknown (the best measurement)
    swing_used: Column = field(default_factory=partial(Column, 4))  # the estimate the controller flew on, NaN if none
    payload_pos: Column = field(default_factory=partial(Column, 3))
    ref_pos: Column = field(default_factory=partial(Column, 3))
    ref_vel: Column = field(default_factory=partial(Column, 3))
    ref_acc: Column = field(default_factory=partial(Column, 3))
    euler_cmd: Column = field(default_factory=partial(Column, 3))
    thrust_n: Column = field(default_factory=partial(Column, 1))
    ff_accel: Column = field(default_factory=partial(Column, 3))
    force_att: Column = field(default_factory=partial(Column, 2))
    force_rep: Column = field(default_factory=partial(Column, 2))
    r_max_m: Column = field(default_factory=partial(Column, 1))
    phase: list[str] = field(default_factory=list)
    envelope_mode: list[str] = field(default_factory=list)
    wall_time_s: float | None = None
    outcome: str | None = None  # the flight core's verdict (completed, timeout, no_route) where the runner set it
    planning: dict | None = None  # the planner's facts (``Planner.facts``) where the runner set them

    def append(self, t_s: float, pos, vel, euler, swing, payload_pos, cmd: Any | None = None,
               swing_used=None) -> None:
        """Record one tick; ``cmd`` is a :class:`companion.flight.core.Command` (or None: zeros); ``swing_used``
        the swing estimate the controller flew on (None when it flew on the measurement or on nothing)."""
        self.t.append(float(t_s))
        self.swing_used.append(math.nan if swing_used is None else swing_used)
        self.pos.append(pos)
        self.vel.append(vel)
        self.euler.append(euler)
        self.swing.append(math.nan if swing is None else swing)
        self.payload_pos.append(math.nan if payload_pos is None else payload_pos)
        if cmd is None:
            self.ref_pos.append(0.0)
            self.ref_vel.append(0.0)
            self.ref_acc.append(0.0)
            self.euler_cmd.append(0.0)
            self.thrust_n.append(0.0)
            self.ff_accel.append(0.0)
            self.force_att.append(0.0)
            self.force_rep.append(0.0)
            self.r_max_m.append(math.nan)
            self.phase.append("")
            self.envelope_mode.append("")
        else:
            self.ref_pos.append(cmd.ref_pos_ned_m)
            self.ref_vel.append(cmd.ref_vel_ned_mps)
            self.ref_acc.append(cmd.ref_acc_ned_mps2)
            self.euler_cmd.append(cmd.euler_cmd_rad)
            self.thrust_n.append(float(cmd.thrust_n))
            self.ff_accel.append(cmd.ff_accel)
            self.force_att.append(cmd.force_att_n)
            self.force_rep.append(cmd.force_rep_n)
            self.r_max_m.append(float(cmd.r_max_m))
            self.phase.append(cmd.phase)
            self.envelope_mode.append(cmd.envelope_mode)

    def __len__(self) -> int:
        return len(self.t)

    def select(self, keep: np.ndarray) -> FlightLog:
        """A new log with only the rows where ``keep`` (bool, (N,)) is true."""
        idx = np.flatnonzero(keep)
        out = FlightLog()
        for f in dataclasses.fields(self):  # per-tick columns; everything else is the flight's own
            col = getattr(self, f.name)
            if isinstance(col, Column):
                col = col.take(idx)
            elif isinstance(col, list):
                col = [col[i] for i in idx]
            setattr(out, f.name, col)
        return out

    def arr(self, name: str) -> np.ndarray:
        """Column ``name`` as a numpy array ((N,) or (N, k))."""
        col = getattr(self, name)
        return col.array() if isinstance(col, Column) else np.asarray(col, dtype=np.float64)


def _first_index(mask: np.ndarray) -> int | None:
    idx = np.flatnonzero(mask)
    return int(idx[0]) if idx.size else None


def _path_len(xy: np.ndarray) -> float:
    if len(xy) < 2:
        return 0.0
    d = np.diff(xy, axis=0)
    d = d[np.all(np.isfinite(d), axis=1)]
    return float(np.sum(np.hypot(d[:, 0], d[:, 1])))


def clearances(log: FlightLog, obstacles, airframe_r_m: float) -> np.ndarray:
    """Per obstacle, the minimum clearance (m) over the flight (airframe and payload; +inf if never below), moving
    obstacles placed by the log's mission clock zero (:func:`companion.report.scoring.obstacle_clearances`)."""
    return obstacle_clearances(log.arr("t"), log.arr("pos"), log.arr("payload_pos"), obstacles, airframe_r_m,
                               log.obstacle_clock_t0_s)


def estimation_error(log: FlightLog) -> dict[str, Any] | None:
    """RMS and max of the swing estimate's angle error against the measured swing, over the ticks with both
    (rad); None when the controller never flew on an estimate or nothing measured the truth."""
    if not log.swing_used:
        return None
    used = log.arr("swing_used")[:, :2]
    truth = log.arr("swing")[:, :2]
    both = np.all(np.isfinite(used), axis=1) & np.all(np.isfinite(truth), axis=1)
    if not np.any(both):
        return None
    err = np.hypot(*(used[both] - truth[both]).T)
    return {"ticks": int(np.sum(both)), "rms_rad": float(np.sqrt(np.mean(err ** 2))), "max_rad": float(np.max(err))}


def compute_metrics(log: FlightLog, mission) -> dict[str, Any]:
    """The report dict of issue 4 for a recorded flight of ``mission`` (see module docstring)."""
    t = log.arr("t")
    if t.size == 0:
        raise ValueError("log: empty flight log")
    pos = log.arr("pos")
    pay = log.arr("payload_pos")
    sw = log.arr("swing")
    goal = np.asarray(mission.goal_ned_m, dtype=np.float64)
    phases = np.array(log.phase)
    i_cruise = _first_index(phases == "cruise")
    t_cruise = float(t[i_cruise]) if i_cruise is not None else float(t[0])
    d_goal = np.hypot(pos[:, 0] - goal[0], pos[:, 1] - goal[1])
    i_goal = _first_index(d_goal < log.goal_tol_m)
    end = (i_goal + 1) if i_goal is not None else len(t)
    obstacles = log.obstacles or tuple(mission.obstacles)
    vp = mission.vehicle
    sc = score(clearances(log, obstacles, vp.r_uav + vp.L_uav), obstacles)
    swing_abs = np.nanmax(np.abs(sw[:, :2]), axis=1) if np.any(np.isfinite(sw[:, :2])) else np.full(len(t), np.nan)
    finite = np.isfinite(swing_abs)
    max_swing = float(np.max(swing_abs[finite])) if np.any(finite) else None
    settle_abs: float | None
    if not np.any(finite):
        settle_abs = None
    else:
        over = np.flatnonzero(finite & (swing_abs >= SETTLE_RAD))
        if over.size == 0:
            settle_abs = float(t[0])
        elif over[-1] == len(t) - 1:
            settle_abs = None
        else:
            settle_abs = float(t[over[-1] + 1])
    t_goal = float(t[i_goal]) if i_goal is not None else None
    rep = {
        "mission": mission.name,
        "planner": log.planner or mission.planner,
        "controller": log.controller or mission.controller,
        "reached_goal": i_goal is not None,
        "time_to_goal_s": None if t_goal is None else t_goal - t_cruise,
        "time_to_goal_from_start_s": None if t_goal is None else t_goal - float(t[0]),
        "path_length_m": _path_len(pos[:end, :2]),
        "payload_path_length_m": _path_len(pay[:end, :2]),
        "max_swing_rad": max_swing,
        "swing_settle_s": None if settle_abs is None else max(0.0, settle_abs - t_cruise),
        "swing_settle_after_arrival_s": (
            None if settle_abs is None or t_goal is None else max(0.0, settle_abs - t_goal)
        ),
        "min_clearance_m": sc.min_clearance_m,
        "collisions": sc.collisions,
        "collisions_moving": sc.collisions_moving,
        "obstacle_clock_t0_s": log.obstacle_clock_t0_s,
        "sim_time_s": float(t[-1] - t[0]),
        "wall_time_s": log.wall_time_s,
    }
    if getattr(mission, "waypoints", ()):
        rep["waypoints"] = waypoint_metrics(log, mission, i_cruise or 0, swing_abs, obstacles)
    if getattr(mission, "fence", None) is not None:
        rep["fence"] = fence_metrics(log, mission)
    return rep


def _leg_clearance(log: FlightLog, a: int, b: int, obstacles, airframe_r_m: float) -> float | None:
    """Smallest clearance (m) over the rows a..b−1 and every obstacle (None: no obstacle below reach)."""
    if b <= a or not obstacles:
        return None
    c = obstacle_clearances(log.t[a:b], log.pos[a:b], log.payload_pos[a:b], obstacles, airframe_r_m,
                            log.obstacle_clock_t0_s)
    m = float(np.min(c)) if len(c) else math.inf
    return m if math.isfinite(m) else None


def waypoint_metrics(log: FlightLog, mission, i_cruise: int, swing_abs: np.ndarray, obstacles) -> list[dict]:
    """Per waypoint, then the goal: when it was reached or passed (``reached_at_s``, from the cruise start like
    ``time_to_goal_s``; None: never), the closest the airframe came (m), and over the leg that ends there (from
    the previous point's passage, or the cruise start): the largest swing (rad) and the smallest clearance (m).

    The passages are replayed from the log's cruise rows with the flight's own rule
    (:class:`companion.flight.legs.Legs`: pass-through within 0.6 m or past the corner, a hold waypoint by the
    flight's arrival tolerance ``goal_tol_m`` and dwell); the goal's leg ends where the vehicle was first within
    that tolerance after the last waypoint. Points after one never reached have None everywhere (legs not flown)."""
    from companion.estimation.estimate import Estimate
    from companion.flight.legs import Legs

    t, pos, ref = log.arr("t"), log.arr("pos"), log.arr("ref_pos")
    timed = (log.planner or mission.planner) == "shaped"  # its reference passes points too (Legs.update)
    legs = Legs(mission, 0.0)
    reach_i: list[int | None] = [None] * len(mission.waypoints)
    zero = np.zeros(3)
    for i in range(i_cruise, len(t)):
        if log.phase[i] != "cruise" or legs.at_goal:
            continue
        k = legs.index
        legs.update(Estimate(float(t[i]), pos[i], zero, zero, zero, None, "none", pos_accuracy_m=log.goal_tol_m),
                    (float(ref[i, 0]), float(ref[i, 1])) if timed else None)
        if legs.reached_t_s[k] is not None and reach_i[k] is None:
            reach_i[k] = int(np.searchsorted(t, legs.reached_t_s[k]))
    goal = np.asarray(mission.goal_ned_m, dtype=np.float64)
    d_goal = np.hypot(pos[:, 0] - goal[0], pos[:, 1] - goal[1])
    after = reach_i[-1] if reach_i else i_cruise
    i_goal = None if after is None else _first_index((d_goal < log.goal_tol_m) & (np.arange(len(t)) >= after))
    names = [f["name"] for f in legs.facts()] + ["goal"]
    ends = [*reach_i, i_goal]
    vp = mission.vehicle
    out: list[dict] = []
    start: int | None = i_cruise
    for k, (name, end) in enumerate(zip(names, ends, strict=True)):
        if start is None:  # an earlier point was never reached: this leg was never flown
            out.append({"name": name} | dict.fromkeys(("reached_at_s", "closest_m", "leg_max_swing_rad",
                                                        "leg_min_clearance_m")))
            continue
        stop = len(t) if end is None else end + 1
        # the closest approach: over this leg and the next (the passage counts on entering the radius)
        far = len(t) if k + 1 >= len(ends) or ends[k + 1] is None else ends[k + 1] + 1
        p = np.asarray(legs.targets[k].pos_ned_m, dtype=np.float64)
        d = np.hypot(pos[start:far, 0] - p[0], pos[start:far, 1] - p[1])
        sw = swing_abs[start:stop]
        sw = sw[np.isfinite(sw)]
        out.append({"name": name, "reached_at_s": None if end is None else float(t[end] - t[i_cruise]),
                    "closest_m": round(float(np.min(d)), 3) if d.size else None,
                    "leg_max_swing_rad": float(np.max(sw)) if sw.size else None,
                    "leg_min_clearance_m": _leg_clearance(log, start, stop, obstacles, vp.r_uav + vp.L_uav)})
        start = end
    return out


def fence_metrics(log: FlightLog, mission) -> dict[str, Any]:
    """How far inside the fence the flight stayed (m): the airframe's circle (r_uav + L_uav) and the payload
    point, over every row; ``breaches``: rows where either was outside (negative margin)."""
    from companion.planning.fence_guard import fence_margin_m

    vp = mission.vehicle
    pos, pay = log.arr("pos"), log.arr("payload_pos")
    air = fence_margin_m(mission.fence, pos[:, :2]) - (vp.r_uav + vp.L_uav)
    ok = np.all(np.isfinite(pay[:, :2]), axis=1)
    pm = np.full(len(pos), np.inf)
    pm[ok] = fence_margin_m(mission.fence, pay[ok, :2])
    return {"min_margin_airframe_m": float(np.min(air)) if len(air) else None,
            "min_margin_payload_m": float(np.min(pm)) if np.any(ok) else None,
            "breaches": int(np.sum((air < 0.0) | (pm < 0.0)))}
