"""The ``safe`` planner (ours): swing-aware clearance as a velocity barrier, flyable reference, trap escape.

Why not the paper's improved APF: its repulsion starts only Δd_min = 0.1 m outside contact, less than the
tracking error of a vehicle with a swinging payload, and its reference turns on radii the vehicle cannot
follow. This planner keeps the paper's idea — the clearance follows the live swing envelope, not the cable
length — and changes how it is enforced:

1. Envelope with prediction. With swing [α, β, α̇, β̇] the pendulum amplitude over the next half period is
   A = sqrt(angle² + (rate/ω)²), ω = sqrt(g/l), per axis; the envelope radius is
   max(r2, r1(Aα, Aβ), R_max now) (eqs. 20–21 at the predicted amplitude). Without swing sensing it is the
   full cable, max(l, r2).
2. Gap, not centre distance. For each obstacle (only while the payload can be below its top) the gap is g =
   |x − o| − r_o − Δd_min − R_env − (track_margin + |measured − reference|), evaluated at the reference point
   x: the reference is what the vehicle is told to fly, and its tracking error is added to the margin — the
   larger of the error now and the error predicted ``error_lookahead_s`` ahead from the velocity difference
   (in hard turns the anti-swing feed-forward moves the airframe after its payload, 0.3–0.4 m off the
   reference; the margin must widen before, not after). The reference's velocity lags the planner's (velocity
   loop 1/k_vel plus the acceleration lag, ~0.4 s): a barrier on the gap at x alone let the reference coast
   0.2–0.3 m into the ring in tight turns of random forests. So each gap is also measured at x + T·v_ref (T =
   ``lookahead_s`` for the barrier, ``steer_lookahead_s`` for steering) and the smaller one counts: the
   planner acts on where the reference is going, a discrete second-order barrier. The vehicle lags the
   reference in turn: when the reference brakes beside a trunk with the payload swinging towards it, the
   feed-forward carries the airframe on after its payload, 0.4–0.5 m past the reference. So the barrier also
   measures the gap at where the vehicle itself goes, p + T_v·v (T_v = ``vehicle_lookahead_s``, v the vehicle's
   velocity relative to the obstacle), with the ring less the tracking-error margin (it is the vehicle's own
   position). A predicted point past the obstacle's centre is measured along the normal at p, so a fast
   approach never reads as the far side. (In dense forests, 800 in-process flights: 14 contacts to 0; see
   docs/planning.md.)
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
   Once the reference has come no closer to the goal by :data:`PROGRESS_M` for ``safe_no_progress_s``, there
   is no route it can find: ``PlanOutput.no_route``, and the flight core brakes and holds there (before, a
   goal ringed by trunks was circled until the mission's timeout).
6. Goal approach: speed min(v_max, sqrt(2·a_goal·d'), ka·d) towards the goal, with the braking distance
   d' = d − T_g·v_along measured from where the lagging reference will be (T_g = ``goal_lookahead_s``):
   the reference stops at the goal instead of overshooting it and dragging the swinging payload past. A
   waypoint passed without stopping (``PlanInput.goal_pass_mps`` = v_p > 0) is approached at
   min(v_max, sqrt(v_p² + 2·a_goal·d'), v_p + ka·d): braked to v_p, not to rest.
7. Moving obstacles (a velocity v_o, from the mission file, Zenoh or the perception map; the flight core gives
   them at the tick's position). The barrier of 3 is a control-barrier condition on the gap, whose rate is
   (v − v_o)·n for a moving obstacle, not v·n: the condition becomes v·n >= −allow + v_o·n, so a trunk coming
   at the reference pushes it aside in time (at the same braking-distance allowance) and one moving away may be
   followed. The look-ahead gaps of 2 are measured along the velocity relative to the obstacle, x + T·(v_ref −
   v_o): where the reference will be *relative to where the obstacle will be*. Standing obstacles (v_o = 0) take
   the unchanged code path (the Table 2 forest flies bit-identically). In-process (8 trunks/100 m², two crossing
   trunks, 100 seeds) crossing-trunk hits went from 31 forests to 0 (docs/planning.md, "Moving obstacles").
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from companion.core.floats import floats
from companion.core.obstacles import Obstacle
from companion.planning.base import PlanInput, PlanOutput
from companion.planning.params import PlannerParams


def predicted_envelope_m(inp: PlanInput) -> float:
    """Envelope radius (m) at the swing amplitude predicted from angle and rate (see module docstring)."""
    r2 = inp.airframe_r_m
    l = inp.cable_l_m
    if inp.swing is None:
        return max(l, r2)
    a, b, da, db = map(float, floats(inp.swing))
    w = math.sqrt(inp.g_mps2 / l)
    amp_a = min(math.hypot(a, da / w), 0.5 * math.pi)
    amp_b = min(math.hypot(b, db / w), 0.5 * math.pi)
    r1 = l * math.hypot(math.cos(amp_b) * math.sin(amp_a), math.sin(amp_b))
    return max(r1, r2, inp.r_max_m)


def _gap_at(x: float, y: float, o: Obstacle, ring_m: float) -> tuple[float, float, float]:
    """(distance − ring_m, unit normal x, y from the obstacle's centre to the point (x, y))."""
    dx, dy = x - o.x_m, y - o.y_m
    dist = math.hypot(dx, dy)
    if dist > 1e-9:
        return dist - ring_m, dx / dist, dy / dist
    return dist - ring_m, 1.0, 0.0


def _vehicle_gap(px: float, py: float, dx: float, dy: float, o: Obstacle, ring_m: float
                 ) -> tuple[float, float, float]:
    """(gap m, unit normal x, y) at the vehicle's predicted point (px + dx, py + dy): as :func:`_gap_at`, but a
    point past the obstacle's centre (seen from (px, py)) is measured along the normal at (px, py), negative."""
    qx, qy = px + dx, py + dy
    g, nx, ny = _gap_at(qx, qy, o, ring_m)
    _, n0x, n0y = _gap_at(px, py, o, ring_m)
    along = (qx - o.x_m) * n0x + (qy - o.y_m) * n0y
    if along < 0.0:
        return along - ring_m, n0x, n0y
    return g, nx, ny


PROGRESS_M = 0.5  # closer to the goal than the best so far by this much (m): progress
UNPLANNED_S = 0.5  # a gap this long between plans (a pause, a hold): the progress count starts afresh (s)


class SafePlanner:
    """Swing-aware barrier planner with trap escape (see module docstring).

    Per-tick work is plain float arithmetic (math.hypot on 2-vectors); numpy only at the interface.
    """

    name = "safe"
    time_parameterised = False

    def __init__(self, params: PlannerParams) -> None:
        self.params = params
        self.side = 0  # turning side of the current encounter: +1 / −1, 0 = none
        self.locked = False  # side locked by the trap escape
        self.lock_goal_dist_m = math.inf
        self.slow_since_s: float | None = None
        self.escapes = 0
        self.best_goal_m = math.inf  # the reference's least distance to the goal so far (m), and when it came
        self.t_progress_s = 0.0
        self._counted: tuple[float, float, float] | None = None  # (goal x, y, time) of the last plan
        self.no_route = False

    def _gaps(self, inp: PlanInput, obstacles: Sequence[Obstacle]) -> list[tuple]:
        """(steering gap m, its unit normal x, y (from the obstacle), obstacle, barrier gap m, its normal x, y, gap
        at the reference itself m, its normal x, y) for the obstacles the payload can reach.

        The reference's velocity lags the planner's (first-order loop of 1/k_vel plus the acceleration lag),
        so each gap is also measured at the point the reference reaches if it keeps its velocity: after
        ``steer_lookahead_s`` for steering, after ``lookahead_s`` for the barrier; the smaller gap counts.
        """
        r_env = predicted_envelope_m(inp)
        px, py = float(inp.pos_m[0]), float(inp.pos_m[1])
        x, y = float(inp.ref_pos_m[0]), float(inp.ref_pos_m[1])
        # tracking error now and as predicted error_lookahead_s ahead (the error grows in hard turns, when the
        # anti-swing feed-forward moves the airframe after its payload): the larger one widens the margin
        t_e = self.params.error_lookahead_s
        pvx, pvy = float(inp.vel_mps[0]), float(inp.vel_mps[1])  # the vehicle's velocity and the reference's
        vx, vy = float(inp.ref_vel_mps[0]), float(inp.ref_vel_mps[1])
        evx, evy = pvx - vx, pvy - vy
        err = max(math.hypot(px - x, py - y), math.hypot(px - x + t_e * evx, py - y + t_e * evy))
        margin = self.params.track_margin_m + err
        reach_z = inp.z_ned_m + inp.cable_l_m
        base = r_env + margin
        t_b, t_s = self.params.lookahead_s, self.params.steer_lookahead_s
        t_v = self.params.vehicle_lookahead_s
        bare = r_env + self.params.track_margin_m  # the ring at the vehicle's own position: no tracking error
        out = []
        for o in obstacles:
            if reach_z < -o.height_m:
                continue  # payload cannot reach below the top
            ring = o.radius_m + o.safe_distance_m + base
            g0, n0x, n0y = _gap_at(x, y, o, ring)
            g, nx, ny = g0, n0x, n0y
            if o.vx_mps != 0.0 or o.vy_mps != 0.0:  # moving: look ahead along the velocity relative to it
                wx, wy = vx - o.vx_mps, vy - o.vy_mps
            else:
                wx, wy = vx, vy
            gs, sx, sy = _gap_at(x + t_s * wx, y + t_s * wy, o, ring)
            gb, bx, by = _gap_at(x + t_b * wx, y + t_b * wy, o, ring)
            gv, vnx, vny = _vehicle_gap(px, py, t_v * (pvx - o.vx_mps), t_v * (pvy - o.vy_mps), o,
                                        o.radius_m + o.safe_distance_m + bare)
            if gv < gb:
                gb, bx, by = gv, vnx, vny
            if gs < g:
                g, nx, ny = gs, sx, sy
            out.append((g, nx, ny, o, gb, bx, by, g0, n0x, n0y) if gb < g else (g, nx, ny, o, g, nx, ny, g0, n0x, n0y))
        return out

    def gaps(self, inp: PlanInput, obstacles: Sequence[Obstacle]) -> list[tuple[float, np.ndarray, Obstacle]]:
        """(gap m at the reference point itself, unit normal from the obstacle (2,), obstacle) per relevant
        obstacle (no look-ahead; the margin includes the current and predicted tracking error)."""
        return [(gn[7], np.array(gn[8:10]), gn[3]) for gn in self._gaps(inp, obstacles)]

    def stop(self) -> None:
        """Nothing to stop: the flight core holds the reference itself (:class:`~companion.planning.base.Planner`)."""

    def facts(self) -> dict[str, float]:
        """The report's part: how many trap escapes the flight took; after a no route, how close (m) the reference
        came to the goal, and for how long (s) it came no closer."""
        if not self.no_route:
            return {"escapes": self.escapes}
        return {"escapes": self.escapes, "no_route_closest_to_goal_m": round(self.best_goal_m, 3),
                "no_route_no_progress_s": self.params.safe_no_progress_s}

    def resume(self) -> None:
        """Nothing to resume: the flight core flies on itself (:class:`~companion.planning.base.Planner`)."""

    def plan(self, inp: PlanInput, obstacles: Sequence[Obstacle]) -> PlanOutput:
        """Desired horizontal velocity at the reference point (m/s, NED (2,))."""
        p = self.params
        rx, ry = float(inp.ref_pos_m[0]), float(inp.ref_pos_m[1])
        ex, ey = float(inp.goal_m[0]) - rx, float(inp.goal_m[1]) - ry
        dg = math.hypot(ex, ey)
        if dg > 1e-9:
            edx, edy = ex / dg, ey / dg
        else:
            edx = edy = 0.0
        speed = self._goal_speed(inp, dg, edx, edy)
        nom_x, nom_y = speed * edx, speed * edy
        gaps = self._gaps(inp, obstacles)
        v_ref = math.hypot(float(inp.ref_vel_mps[0]), float(inp.ref_vel_mps[1]))
        d_inf = p.influence_m + v_ref * v_ref / (2.0 * p.a_brake_mps2)
        near = [gn for gn in gaps if gn[0] < d_inf]

        # 4. steering: blend towards the tangent of the most pressing obstacle we are heading into
        if not near and (not self.locked or dg < self.lock_goal_dist_m):
            self.side = 0
            self.locked = False
        heading_in = [gn for gn in near if self._in_path(rx, ry, edx, edy, gn[0], gn[3])]
        vdx, vdy, w = self._steer(heading_in, gaps, rx, ry, edx, edy, dg, d_inf)
        sp = speed if not heading_in else max(speed, 0.5 * p.v_max_mps * w)
        vx, vy = sp * vdx, sp * vdy

        # 3. barrier projection: (allowed approach speed, normal) per obstacle, then three passes
        vx, vy, vn = self._project(vx, vy, self._barriers(gaps), inp.v_cap_mps)

        # 5. local-minimum detector, and no route once the goal comes no closer
        self._watch_stuck(inp.t_s, vn, dg, bool(near))
        self._watch_progress(inp.t_s, dg, float(inp.goal_m[0]), float(inp.goal_m[1]))
        if self.no_route:
            return PlanOutput(v_des_mps=np.zeros(2), force_att=np.array((nom_x, nom_y)),
                              force_rep=np.array((-nom_x, -nom_y)), mode="no_route", no_route=True)
        return PlanOutput(
            v_des_mps=np.array((vx, vy)), force_att=np.array((nom_x, nom_y)),
            force_rep=np.array((vx - nom_x, vy - nom_y)), mode="escape" if self.locked else "track",
        )

    def _goal_speed(self, inp: PlanInput, dg: float, edx: float, edy: float) -> float:
        """The speed (m/s) towards the goal ``dg`` m away along (edx, edy): braking at ``a_goal_mps2`` to rest (or
        to the waypoint's pass speed), the braking distance measured from where the lagging reference will be in
        ``goal_lookahead_s``."""
        p = self.params
        v_along = float(inp.ref_vel_mps[0]) * edx + float(inp.ref_vel_mps[1]) * edy
        d_brake = max(0.0, dg - p.goal_lookahead_s * max(0.0, v_along))
        v_pass = inp.goal_pass_mps
        if v_pass > 0.0:  # a waypoint passed without stopping: brake to v_pass at it, not to rest
            return min(p.v_max_mps, math.sqrt(v_pass * v_pass + 2.0 * p.a_goal_mps2 * d_brake), v_pass + p.ka * dg)
        return min(p.v_max_mps, math.sqrt(2.0 * p.a_goal_mps2 * d_brake), p.ka * dg)

    def _steer(self, heading_in: list[tuple], gaps: list[tuple], rx: float, ry: float, edx: float, edy: float,
               dg: float, d_inf: float) -> tuple[float, float, float]:
        """(direction x, y, blend weight w): the goal direction blended towards the tangent (on the chosen side)
        of the nearest obstacle the reference is heading into, by 1 − gap / ``d_inf``."""
        vdx, vdy = edx, edy
        w = 0.0
        if heading_in and dg > 1e-9:
            g0, n0x, n0y, *_ = min(heading_in, key=lambda gn: gn[0])
            if self.side == 0:
                self.side = self._choose_side(n0x, n0y, edx, edy, rx, ry, gaps)
            tx, ty = -self.side * n0y, self.side * n0x
            w = min(1.0, max(0.0, 1.0 - g0 / d_inf))
            bx = (1.0 - w) * edx + w * tx
            by = (1.0 - w) * edy + w * ty
            nb = math.hypot(bx, by)
            if nb > 1e-9:
                vdx, vdy = bx / nb, by / nb
            else:
                vdx, vdy = tx, ty
        return vdx, vdy, w

    def _project(self, vx: float, vy: float, barriers: list[tuple[float, float, float]],
                 v_cap_mps: float) -> tuple[float, float, float]:
        """(vx, vy, |v|) in m/s: the velocity with its approach speed towards each obstacle cut to the barrier's
        allowance (three passes), then capped at ``v_max_mps`` or the seen-free space's ``v_cap_mps``."""
        p = self.params
        for _ in range(3):
            for allow, nx, ny in barriers:
                vn = vx * nx + vy * ny
                if vn < -allow:
                    k = -allow - vn
                    vx += k * nx
                    vy += k * ny
        vn = math.hypot(vx, vy)
        v_lim = p.v_max_mps if v_cap_mps >= p.v_max_mps else v_cap_mps  # the seen-free space's cap
        if vn > v_lim:
            vx, vy = vx * (v_lim / vn), vy * (v_lim / vn)
            vn = math.hypot(vx, vy)
        return vx, vy, vn

    def _barriers(self, gaps: list[tuple]) -> list[tuple[float, float, float]]:
        """(allowed approach speed m/s, unit normal x, y from the obstacle) per gap: the reference's velocity v must
        keep v·n >= −allow. A moving obstacle (velocity v_o) closes the gap at (v − v_o)·n, so its allowance is
        lowered by v_o·n: the reference gives way to a trunk coming at it (see module docstring, 7)."""
        p = self.params
        out = []
        for gn in gaps:
            g = gn[4]
            allow = p.gamma * g if g < 0.0 else min(p.gamma * g, math.sqrt(2.0 * p.a_brake_mps2 * g))
            o = gn[3]
            if o.vx_mps != 0.0 or o.vy_mps != 0.0:
                allow -= o.vx_mps * gn[5] + o.vy_mps * gn[6]
            out.append((allow, gn[5], gn[6]))
        return out

    def _in_path(self, rx: float, ry: float, edx: float, edy: float, gap: float, o: Obstacle) -> bool:
        """Is obstacle ``o`` in the way: ahead along the goal direction and within the swept corridor?"""
        if self.locked:
            return True
        relx, rely = o.x_m - rx, o.y_m - ry
        along = relx * edx + rely * edy
        if along <= 0.0:
            return False
        lateral = abs(relx * edy - rely * edx)
        clearance = math.hypot(relx, rely) - gap  # = r_o + Δd + R_env + margins
        return lateral < clearance + self.params.track_margin_m

    def _choose_side(self, n0x: float, n0y: float, edx: float, edy: float, rx: float, ry: float, gaps) -> int:
        cross = n0x * edy - n0y * edx
        if abs(cross) > 0.2:
            return 1 if cross > 0.0 else -1
        # head-on: pass on the side with more room next to the obstacle
        g0, _, _, o0, *_ = min(gaps, key=lambda gn: abs(gn[1] * n0x + gn[2] * n0y - 1.0))
        reach = math.hypot(rx - o0.x_m, ry - o0.y_m) - g0 + 0.3
        best, best_room = 1, -math.inf
        for s in (1, -1):
            px, py = o0.x_m - reach * s * n0y, o0.y_m + reach * s * n0x
            room = min(
                (math.hypot(px - o.x_m, py - o.y_m) - o.radius_m for _, _, _, o, *_ in gaps if o is not o0),
                default=math.inf,
            )
            if room > best_room + 1e-9:
                best, best_room = s, room
        return best

    def _watch_progress(self, t_s: float, dg: float, gx: float, gy: float) -> None:
        """Declare no route once the goal (gx, gy), ``dg`` m away, came no closer by :data:`PROGRESS_M` for
        ``safe_no_progress_s`` of planning. A new goal (the next waypoint) or a gap in the plans (a pause, the
        sequence's hold) starts the count afresh."""
        last, self._counted = self._counted, (gx, gy, t_s)
        afresh = last is None or (last[0], last[1]) != (gx, gy) or t_s - last[2] > UNPLANNED_S
        if afresh or dg < self.best_goal_m - PROGRESS_M:
            self.best_goal_m, self.t_progress_s = dg, t_s
        elif t_s - self.t_progress_s >= self.params.safe_no_progress_s:
            self.no_route = True

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
