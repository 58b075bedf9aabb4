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
obstacle's top), collisions (obstacles with clearance < 0), planner, controller, sim_time_s.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from companion.core.obstacles import Obstacle

GOAL_TOL_M = 0.1
_NAN4 = np.full(4, np.nan)
_NAN4.flags.writeable = False
SETTLE_RAD = 0.05


@dataclass
class FlightLog:
    """Append-per-tick recorder. After :meth:`append` calls, the ``*_arr`` views are numpy arrays (N, k)."""

    planner: str = ""
    controller: str = ""
    mission: str = ""
    obstacles: tuple[Obstacle, ...] = ()
    goal_tol_m: float = GOAL_TOL_M  # "at the goal" horizontally (the flight's arrival tolerance, m)
    t: list[float] = field(default_factory=list)
    pos: list[np.ndarray] = field(default_factory=list)
    vel: list[np.ndarray] = field(default_factory=list)
    euler: list[np.ndarray] = field(default_factory=list)
    swing: list[np.ndarray] = field(default_factory=list)  # [α, β, α̇, β̇], NaN when unknown (the best measurement)
    swing_used: list[np.ndarray] = field(default_factory=list)  # the estimate the controller flew on, NaN if none
    payload_pos: list[np.ndarray] = field(default_factory=list)
    ref_pos: list[np.ndarray] = field(default_factory=list)
    ref_vel: list[np.ndarray] = field(default_factory=list)
    ref_acc: list[np.ndarray] = field(default_factory=list)
    euler_cmd: list[np.ndarray] = field(default_factory=list)
    thrust_n: list[float] = field(default_factory=list)
    ff_accel: list[np.ndarray] = field(default_factory=list)
    force_att: list[np.ndarray] = field(default_factory=list)
    force_rep: list[np.ndarray] = field(default_factory=list)
    r_max_m: list[float] = field(default_factory=list)
    phase: list[str] = field(default_factory=list)
    envelope_mode: list[str] = field(default_factory=list)
    wall_time_s: float | None = None

    def append(self, t_s: float, pos, vel, euler, swing, payload_pos, cmd: Any | None = None,
               swing_used=None) -> None:
        """Record one tick; ``cmd`` is a :class:`companion.flight.core.Command` (or None: zeros); ``swing_used``
        the swing estimate the controller flew on (None when it flew on the measurement or on nothing)."""
        self.t.append(float(t_s))
        self.swing_used.append(_NAN4 if swing_used is None else np.array(swing_used, dtype=np.float64))
        self.pos.append(np.array(pos, dtype=np.float64))
        self.vel.append(np.array(vel, dtype=np.float64))
        self.euler.append(np.array(euler, dtype=np.float64))
        self.swing.append(np.full(4, np.nan) if swing is None else np.array(swing, dtype=np.float64))
        self.payload_pos.append(
            np.full(3, np.nan) if payload_pos is None else np.array(payload_pos, dtype=np.float64)
        )
        z3 = np.zeros(3)
        if cmd is None:
            self.ref_pos.append(z3)
            self.ref_vel.append(z3)
            self.ref_acc.append(z3)
            self.euler_cmd.append(z3)
            self.thrust_n.append(0.0)
            self.ff_accel.append(z3)
            self.force_att.append(np.zeros(2))
            self.force_rep.append(np.zeros(2))
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
        for f in dataclasses.fields(self):  # per-tick columns are lists; everything else is the flight's own
            col = getattr(self, f.name)
            setattr(out, f.name, [col[i] for i in idx] if isinstance(col, list) else col)
        return out

    def arr(self, name: str) -> np.ndarray:
        """Column ``name`` as a numpy array ((N,) or (N, k))."""
        return np.asarray(getattr(self, name), dtype=np.float64)


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
    """Per obstacle, the minimum clearance (m) over the flight (airframe and payload; +inf if never below)."""
    pos = log.arr("pos")
    pay = log.arr("payload_pos")
    out = np.full(len(obstacles), math.inf)
    for i, o in enumerate(obstacles):
        below = pos[:, 2] > -o.height_m
        if np.any(below):
            d = np.hypot(pos[below, 0] - o.x_m, pos[below, 1] - o.y_m) - o.radius_m - airframe_r_m
            out[i] = min(out[i], float(np.min(d)))
        pb = np.isfinite(pay[:, 2]) & (pay[:, 2] > -o.height_m)
        if np.any(pb):
            d = np.hypot(pay[pb, 0] - o.x_m, pay[pb, 1] - o.y_m) - o.radius_m
            out[i] = min(out[i], float(np.min(d)))
    return out


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
    clear = clearances(log, obstacles, vp.r_uav + vp.L_uav)
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
    min_clear = float(np.min(clear)) if len(clear) and np.all(np.isfinite(clear[np.isfinite(clear)])) and np.any(
        np.isfinite(clear)) else None
    return {
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
        "min_clearance_m": min_clear,
        "collisions": int(np.sum(clear < 0.0)),
        "sim_time_s": float(t[-1] - t[0]),
        "wall_time_s": log.wall_time_s,
    }
