"""The ``safe`` planner (ours): swing-aware clearance as a velocity barrier, flyable reference, trap escape.

Why not the paper's improved APF: its repulsion starts only Δd_min = 0.1 m outside contact, less than the
tracking error of a vehicle with a swinging payload, and its reference turns on radii the vehicle cannot
follow. This planner keeps the paper's idea — the clearance follows the live swing envelope, not the cable
length — and changes how it is enforced:

1. Envelope with prediction. With swing [α, β, α̇, β̇] the pendulum amplitude over the next half period is
   A = sqrt(angle² + (rate/ω)²), ω = sqrt(g/l), per axis; the envelope radius is
   max(r2, r1(Aα, Aβ), R_max now) (eqs. 20–21 at the predicted amplitude). Without swing sensing it is the
   full cable, max(l, r2).
2. Gap, not centre distance. For each obstacle (only while the payload can be below its top) the gap is
   g = |x − o| − r_o − Δd_min − R_env − (track_margin + |measured − reference|), evaluated at the reference
   point x: the reference is what the vehicle is told to fly, and its current tracking error is added to
   the margin.
3. Velocity barrier (a control-barrier condition on a single integrator): the reference may approach an
   obstacle no faster than min(γ·g, sqrt(2·a_brake·g)); the braking term is the speed-dependent influence
   range. Inside the ring (g < 0) it is pushed out at γ·|g|. Enforced by projecting the desired velocity on
   each constraint (three passes). The reference generator's acceleration limit exceeds a_brake, so the
   reference can honour it.
4. Steering instead of stalling. Within the influence range d_inf = influence_m + v²/(2·a_brake) of an
   obstacle the desired direction blends towards the obstacle's tangent with weight 1 − g/d_inf. One turning
   side for the whole encounter (sticky until no obstacle is in range): the side where the goal lies, or,
   head-on, the side with more room.
5. Local minima (trunk pairs, concave clusters): if the desired speed stays below ``stuck_speed_mps`` for
   ``stuck_time_s`` away from the goal, the turning side flips and stays locked until the vehicle is clear of
   all obstacles or closer to the goal than where it got stuck (boundary following, as in Bug algorithms).
6. Goal approach: speed min(v_max, sqrt(2·a_brake·d), ka·d) towards the goal — it brakes in time.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from companion.obstacles import Obstacle
from companion.planning.base import PlanInput, PlanOutput, saturate
from companion.planning.params import PlannerParams


def predicted_envelope_m(inp: PlanInput) -> float:
    """Envelope radius (m) at the swing amplitude predicted from angle and rate (see module docstring)."""
    r2 = inp.airframe_r_m
    l = inp.cable_l_m
    if inp.swing is None:
        return max(l, r2)
    a, b, da, db = (float(v) for v in inp.swing)
    w = math.sqrt(inp.g_mps2 / l)
    amp_a = min(math.hypot(a, da / w), 0.5 * math.pi)
    amp_b = min(math.hypot(b, db / w), 0.5 * math.pi)
    r1 = l * math.hypot(math.cos(amp_b) * math.sin(amp_a), math.sin(amp_b))
    return max(r1, r2, inp.r_max_m)


class SafePlanner:
    """Swing-aware barrier planner with trap escape (see module docstring)."""

    name = "safe"

    def __init__(self, params: PlannerParams) -> None:
        self.params = params
        self.side = 0  # turning side of the current encounter: +1 / −1, 0 = none
        self.locked = False  # side locked by the trap escape
        self.lock_goal_dist_m = math.inf
        self.slow_since_s: float | None = None
        self.escapes = 0

    def gaps(self, inp: PlanInput, obstacles: Sequence[Obstacle]) -> list[tuple[float, np.ndarray, Obstacle]]:
        """(gap m, unit normal from obstacle to the reference point, obstacle) for relevant obstacles."""
        r_env = predicted_envelope_m(inp)
        margin = self.params.track_margin_m + float(np.linalg.norm(inp.pos_m - inp.ref_pos_m))
        x = inp.ref_pos_m
        out = []
        for o in obstacles:
            if inp.z_ned_m + inp.cable_l_m < -o.height_m:
                continue  # payload cannot reach below the top
            d = x - np.array([o.x_m, o.y_m])
            dist = float(np.hypot(d[0], d[1]))
            n = d / dist if dist > 1e-9 else np.array([1.0, 0.0])
            out.append((dist - o.radius_m - o.safe_distance_m - r_env - margin, n, o))
        return out

    def plan(self, inp: PlanInput, obstacles: Sequence[Obstacle]) -> PlanOutput:
        """Desired horizontal velocity at the reference point (m/s, NED (2,))."""
        p = self.params
        e = inp.goal_m - inp.ref_pos_m
        dg = float(np.linalg.norm(e))
        e_dir = e / dg if dg > 1e-9 else np.zeros(2)
        speed = min(p.v_max_mps, math.sqrt(2.0 * p.a_brake_mps2 * dg), p.ka * dg)
        v_nom = speed * e_dir
        gaps = self.gaps(inp, obstacles)
        v_ref = float(np.linalg.norm(inp.ref_vel_mps))
        d_inf = p.influence_m + v_ref * v_ref / (2.0 * p.a_brake_mps2)
        near = [(g, n, o) for g, n, o in gaps if g < d_inf]

        # 4. steering: blend towards the tangent of the most pressing obstacle we are heading into
        if not near and (not self.locked or dg < self.lock_goal_dist_m):
            self.side = 0
            self.locked = False
        heading_in = [(g, n) for g, n, o in near if self._in_path(inp, e_dir, g, n, o)]
        v_dir = e_dir
        w = 0.0
        t = np.zeros(2)
        if heading_in and dg > 1e-9:
            g0, n0 = min(heading_in, key=lambda gn: gn[0])
            if self.side == 0:
                self.side = self._choose_side(n0, e_dir, inp, gaps)
            t = self.side * np.array([-n0[1], n0[0]])
            w = min(1.0, max(0.0, 1.0 - g0 / d_inf))
            blend = (1.0 - w) * e_dir + w * t
            nb = float(np.linalg.norm(blend))
            v_dir = blend / nb if nb > 1e-9 else t
        v = speed * v_dir if not heading_in else max(speed, 0.5 * p.v_max_mps * w) * v_dir

        # 3. barrier projection
        for _ in range(3):
            for g, n, _o in gaps:
                allow = p.gamma * g if g < 0.0 else min(p.gamma * g, math.sqrt(2.0 * p.a_brake_mps2 * g))
                vn = float(v @ n)
                if vn < -allow:
                    v = v + (-allow - vn) * n
        v = saturate(v, p.v_max_mps)

        # 5. local-minimum detector
        self._watch_stuck(inp.t_s, float(np.linalg.norm(v)), dg, bool(near))
        f_rep = v - v_nom
        return PlanOutput(v_des_mps=v, force_att=v_nom, force_rep=f_rep, mode="escape" if self.locked else "track")

    def _in_path(self, inp: PlanInput, e_dir: np.ndarray, gap: float, n: np.ndarray, o: Obstacle) -> bool:
        """Is obstacle ``o`` in the way: ahead along the goal direction and within the swept corridor?"""
        if self.locked:
            return True
        rel = np.array([o.x_m, o.y_m]) - inp.ref_pos_m
        along = float(rel @ e_dir)
        if along <= 0.0:
            return False
        lateral = abs(float(rel[0] * e_dir[1] - rel[1] * e_dir[0]))
        dist = float(np.hypot(rel[0], rel[1]))
        clearance = dist - gap  # = r_o + Δd + R_env + margins
        return lateral < clearance + self.params.track_margin_m

    def _choose_side(self, n0: np.ndarray, e_dir: np.ndarray, inp: PlanInput, gaps) -> int:
        cross = float(n0[0] * e_dir[1] - n0[1] * e_dir[0])
        if abs(cross) > 0.2:
            return 1 if cross > 0.0 else -1
        # head-on: pass on the side with more room next to the obstacle
        g0, _, o0 = min(gaps, key=lambda gno: abs(float(gno[1] @ n0) - 1.0))
        c0 = np.array([o0.x_m, o0.y_m])
        reach = float(np.hypot(*(inp.ref_pos_m - c0))) - g0 + 0.3
        best, best_room = 1, -math.inf
        for s in (1, -1):
            side_dir = s * np.array([-n0[1], n0[0]])
            probe = c0 + reach * side_dir
            room = min(
                (float(np.hypot(*(probe - np.array([o.x_m, o.y_m])))) - o.radius_m for _, _, o in gaps if o is not o0),
                default=math.inf,
            )
            if room > best_room + 1e-9:
                best, best_room = s, room
        return best

    def _watch_stuck(self, t_s: float, v: float, dg: float, near: bool) -> None:
        p = self.params
        if v >= p.stuck_speed_mps or dg < 0.3 or not near:
            self.slow_since_s = None
            return
        if self.slow_since_s is None:
            self.slow_since_s = t_s
        elif t_s - self.slow_since_s >= p.stuck_time_s:
            self.side = -self.side if self.side != 0 else 1
            self.locked = True
            self.lock_goal_dist_m = dg - 0.5
            self.slow_since_s = None
            self.escapes += 1
