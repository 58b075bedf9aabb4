"""The ``shaped`` planner: a route through the inflated free space, flown as a swing-free timed reference.

Every replan cycle (``replan_rate_hz``, 20 Hz by default) from the *unshaped* motion's state a few steps
ahead of now (so the reference being flown never jumps, see :mod:`companion.planning.timeline`):

1. **Free space.** Each obstacle below which the payload can pass becomes a disc of radius
   r_o + Δd + R_env + margin around its predicted position. The envelope R_env is the farther of the airframe
   circle r_uav + L_uav carried a_max/ω² ahead of the payload path by the shaping (see below), and the
   payload at the largest swing the plan allows — the nominal bound atan(a_max/g), plus the measured
   deviation from the nominal swing, plus ``swing_sigma_k`` standard deviations of the swing estimate's
   uncertainty (``PlanInput.swing_sigma_rad``, 0 for the cable sensor) — or the whole cable without swing
   sensing. The margin is ``track_margin_m`` plus the recent peak tracking error. In wind each disc is the one
   around the trunk's and the trunk's moved upwind by the payload's drift (:mod:`~.shaped_obstacles`).
2. **Routes.** The shortest route around the discs (:mod:`companion.planning.route`) and, to find faster
   ones through wider gaps, the routes around the discs inflated by k·``route_extra_m`` and those on the
   other side of the fastest one's apex (:mod:`companion.planning.candidates`); each is relaxed into a
   minimum-curvature path in the real free space (:mod:`companion.planning.path`) and timed at the
   acceleration bound (:mod:`companion.planning.timing`). Candidates are compared by *time*, not length.
3. **Moving obstacles** (``vx_mps``/``vy_mps``) are predicted at constant velocity over the plan, with a ring
   that grows with the look-ahead (``predict_growth_mps``). Each candidate's shaped reference is checked
   against them at the time it gets there (:mod:`companion.planning.clearance`); where it would meet one,
   the obstacle's swept positions around that time (a capsule of discs) join the free-space model and the
   routes are searched again (at most three rounds).
4. **Shaping.** The chosen motion (bang-bang acceleration, |a| <= a_max) is smoothed by a three-stage
   moving-average cascade and mapped through the pendulum notch p_q = p_L + a_L/ω²
   (:mod:`companion.planning.shaping`): the payload follows the planned path with swing |a_L|/g and no
   residual swing when it stops; ω is the model's (acceleration-controlled support).
5. **Keeping a plan.** A valid current plan is replaced only by one faster by ``replan_hysteresis_s``.
   If no candidate is valid (a moving obstacle in the way, a gust's drift across a gap), the planner brakes
   along its heading and waits (mode ``wait``); where the goal itself lies within the wind's reach of a trunk
   for ``goal_wind_wait_s`` of waiting in all, it declares ``no_route`` (:mod:`~.wind_wait`).
6. **No route.** If no route exists even at the bare safety ring r_o + Δd + r_uav + L_uav around the static
   obstacles (a goal fenced in), the planner brakes, and after ``no_route_confirm_s`` of consistent failure
   declares ``no_route`` (``PlanOutput.no_route``) and holds where it stopped; it does not circle.

The reference rows carry the airframe position, velocity, acceleration and jerk and the nominal swing the
payload has along them, which the flight core uses to keep the anti-swing feed-forward from fighting the
planned swing.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from companion.core.model import VehicleParams
from companion.core.obstacles import Obstacle
from companion.planning import drag_timing, timing
from companion.planning.base import PlanInput, PlanOutput, ReferenceSample
from companion.planning.candidates import capsules, search_options, timed_routes, warm_up
from companion.planning.clearance import clearance
from companion.planning.legs_route import remaining_vias, route_through
from companion.planning.params import PlannerParams
from companion.planning.route import find_route
from companion.planning.shaped_obstacles import Replan, Searched, obstacle_rings, obstacle_signature
from companion.planning.shaping import box_widths, pendulum_omega_rad_s, shaper_taus_s
from companion.planning.timeline import Timeline
from companion.planning.timing import Profile, brake_rows, sample_motion, state_at, stop_along
from companion.planning.wind_wait import WindWait

LEAD_ROWS = 5  # a replan changes the unshaped motion from this many grid steps ahead of now

# an optional replan's motion may exceed a_max by the profile's discretisation (a few per cent), not by braking
OPTIONAL_A_FACTOR = 1.06
CAP_SLACK_MPS = 0.1  # a plan this much faster than the seen-free cap (PlanInput.v_cap_mps) is re-timed under it
CAP_STOP_MPS = 0.3  # a cap below this stops a plan faster than it (swing-bounded brake); below 0.05 m/s, any plan
_ZERO2 = np.zeros(2)
_ZERO2.flags.writeable = False


class ShapedPlanner:
    """Route + swing-free timed reference (see module docstring). Keeps its plan between calls."""

    name = "shaped"
    time_parameterised = True

    def __init__(self, params: PlannerParams, vehicle: VehicleParams | None = None) -> None:
        self.params = params
        self.vehicle = vehicle
        self.tl: Timeline | None = None
        self.omega = 0.0
        self.next_replan_s = -math.inf
        self.mode = "track"
        self.no_route = False
        self.no_route_since_s: float | None = None
        self.plan_end_k = 0
        self.plan_reaches_goal = False
        self.err_peak_m = 0.0
        self._err_t = -math.inf
        self.dev_peak_rad = 0.0
        self._dev_t = -math.inf
        self._last_nominal = (0.0, 0.0)
        self.replans = 0
        self.searches = 0
        self.splices = 0
        self.wind_wait = WindWait(params.goal_wind_wait_s)  # waits for the wind; the goal within its reach
        self.last: dict = {}
        self._searched = Searched(-math.inf, (), None, 0.0)  # the last route search's moment and what it saw
        self._search_goal: np.ndarray | None = None  # the goal of the last replan (a new one: search again)
        self.plan_option: tuple[bool, float] = (False, 0.0)
        self.plan_timed = self._search_timed = drag_timing.TimedFor()  # the drag, wind and share the plan was timed for
        self.plan_profile: Profile | None = None  # the unshaped plan being flown, from absolute row plan_k0
        self.plan_k0 = 0
        self.stop_requested = False
        self._rotation = 0
        warm_up()

    # ------------------------------------------------------------------------------------------------
    def _init(self, inp: PlanInput) -> None:
        p = self.params
        vp = self.vehicle
        if vp is None or abs(vp.l - inp.cable_l_m) > 1e-9:
            vp = VehicleParams(l=inp.cable_l_m, g=inp.g_mps2)
        self.omega = pendulum_omega_rad_s(vp, "held")
        widths = box_widths(shaper_taus_s(p.shaper_tau_s, self.omega, p.shaper_period_s), p.shaped_step_s)
        self.tl = Timeline(inp.t_s, inp.ref_pos_m, p.shaped_step_s, widths, self.omega, inp.g_mps2)
        self.plan_end_k = self.tl.index(inp.t_s)

    def _watch(self, inp: PlanInput) -> None:
        """Peak-hold the tracking error (m) and the swing's deviation from its nominal value (rad)."""
        t = inp.t_s
        hold = self.params.error_hold_s
        e = math.hypot(float(inp.pos_m[0]) - float(inp.ref_pos_m[0]), float(inp.pos_m[1]) - float(inp.ref_pos_m[1]))
        if e >= self.err_peak_m or t - self._err_t > hold:
            self.err_peak_m, self._err_t = e, t
        if inp.swing is not None:
            a, b = self._last_nominal
            d = math.hypot(float(inp.swing[0]) - a, float(inp.swing[1]) - b)
            if d >= self.dev_peak_rad or t - self._dev_t > hold:
                self.dev_peak_rad, self._dev_t = d, t

    def envelope_m(self, inp: PlanInput) -> float:
        """R_env (m) about the planned payload path (see module docstring, step 1)."""
        p = self.params
        r2 = inp.airframe_r_m
        lead = p.shaped_a_max_mps2 / (self.omega * self.omega)
        if inp.swing is None:
            reach = max(inp.cable_l_m, r2)
        else:
            theta = (math.atan(p.shaped_a_max_mps2 / inp.g_mps2) + self.dev_peak_rad
                     + p.swing_sigma_k * max(0.0, inp.swing_sigma_rad))
            reach = inp.cable_l_m * math.sin(min(theta, 0.5 * math.pi))
        return max(r2 + lead, reach)

    # ------------------------------------------------------------------------------------------------
    def plan(self, inp: PlanInput, obstacles: Sequence[Obstacle]) -> PlanOutput:
        """The reference at ``inp.t_s`` (replanning first when a cycle is due)."""
        if self.tl is None:
            self._init(inp)
        assert self.tl is not None
        self._watch(inp)
        t = inp.t_s
        if t >= self.next_replan_s - 1e-9:
            self._replan(inp, obstacles)
            if self.wind_wait.replanned(t):  # the goal within the wind's reach of a trunk too long: no route
                self.no_route = True
            period = 1.0 / self.params.replan_rate_hz
            self.next_replan_s = self.next_replan_s + period if t - self.next_replan_s < period else t + period
        row = self.tl.sample(t)
        self._last_nominal = (row[8], row[9])
        ref = ReferenceSample((row[0], row[1]), (row[2], row[3]), (row[4], row[5]), (row[6], row[7]),
                              (row[8], row[9], row[10], row[11], row[12], row[13]))
        goal_dir = (float(inp.goal_m[0]) - row[0], float(inp.goal_m[1]) - row[1])
        return PlanOutput(v_des_mps=np.array((row[2], row[3])), force_att=np.array(goal_dir),
                          force_rep=_ZERO2, mode=self.mode, reference=ref, no_route=self.no_route)

    def _rows(self, prof: Profile) -> np.ndarray:
        """Unshaped rows [p, v, a] (m, 6) of a profile, one per grid step from its start to its end."""
        h = self.params.shaped_step_s
        times = np.arange(0.0, prof.duration_s + h, h)
        pos, vel, acc = sample_motion(prof, times)
        return np.concatenate([pos, vel, acc], axis=1)

    # ------------------------------------------------------------------------------------------------
    def _replan(self, inp: PlanInput, obstacles: Sequence[Obstacle]) -> None:
        """Keep the current plan, splice a better one in from LEAD_ROWS ahead, or stop (see module docstring)."""
        tl = self.tl
        assert tl is not None
        p = self.params
        self.replans += 1
        r = self._replan_inputs(inp, obstacles)
        t, k_now, k_r, p0, v0, goal = r.t, r.k_now, r.k_r, r.p0, r.v0, r.goal
        # the current plan: still clear?
        first_cur, _, _ = r.check(tl.ref, tl.base)
        cur_ok = bool(np.all(np.isinf(first_cur)))
        remaining = max(0.0, (self.plan_end_k - k_r) * tl.h_s)
        at_goal = math.hypot(float(goal[0] - p0[0]), float(goal[1] - p0[1])) < 1e-3
        if at_goal and not r.vias and math.hypot(float(v0[0]), float(v0[1])) < 1e-3 and cur_ok:
            self.mode = "track"
            self.last = {"kept": True, "reason": "at goal"}
            return
        if self.no_route or self.stop_requested:
            self._hold(k_r, k_now, p0, v0, cur_ok, "no_route" if self.no_route else "hold")
            return
        if self._search_goal is not None and not np.array_equal(goal, self._search_goal):
            self.plan_reaches_goal = False  # a multi-leg mission's next stretch: the plan ends at the last one
        self._search_goal = goal
        ring_now = self.envelope_m(inp) + self.err_peak_m + math.hypot(*r.rings.pred.payload_shift)
        valid = cur_ok and self.plan_reaches_goal
        why = self._searched.why_again(t, obstacles, r.rings.pred, ring_now, p.route_refresh_s) if valid else "invalid"
        cap, sp0 = inp.v_cap_mps, math.hypot(float(v0[0]), float(v0[1]))  # the cap inside the space seen free
        if cap < CAP_STOP_MPS and (sp0 > CAP_STOP_MPS or cap < 0.05):  # nothing seen free to go on in: stop
            self._hold(k_r, k_now, p0, v0, cur_ok, "brake")
            return
        why = "cap" if why is None and sp0 > cap + CAP_SLACK_MPS else why  # too fast for it: re-timed, not optional
        timed = drag_timing.TimedFor(*drag_timing.budgeted_drag(inp.drag_c, inp.wind_mps, inp.drift_ned_m,
                                                                inp.cable_l_m, inp.vel_mps))
        if why is None and self.plan_timed.outdated(timed):
            why = "drag"  # timed for another payload drag or wind than measured now: re-timed, not optional
        p = p if cap >= p.shaped_v_max_mps else replace(p, shaped_v_max_mps=cap)
        if why is None:
            self.last = {"kept": True, "reason": "valid, nothing changed"}
            return
        self.searches += 1
        self._searched, self._search_timed = Searched(t, obstacle_signature(obstacles), r.rings.pred, ring_now), timed
        options = self._refresh_options(p) if why == "refresh" else None
        if why != "refresh" and not self._route_exists(r, p, cur_ok):
            return
        self.no_route_since_s = None
        optional = cur_ok and self.plan_reaches_goal and why not in ("cap", "drag")  # a new one must be better
        # a re-timing for the drag may be slower, never harder braking (a plan that swings more than the drag saves)
        chosen, cands, tried = self._candidates(inp, r, p, options, optional or why == "drag", timed)
        self.last = {"candidates": tried, "cur_ok": cur_ok, "remaining_s": remaining,
                     "durations": [round(cd.duration_s, 3) for cd in cands]}
        if chosen is not None:
            self._adopt(chosen, k_r, optional, remaining, p)
            return
        # nothing valid: keep a valid current plan, else stop and wait
        if cur_ok and self.plan_reaches_goal:
            self.last.update({"kept": True, "reason": "no better valid candidate"})
            return
        self._hold(k_r, k_now, p0, v0, cur_ok, "wait")
        self.wind_wait.waiting(r.rings, goal)

    def _refresh_options(self, p: PlannerParams) -> list[tuple[bool, float]]:
        """Nothing changed and the plan is good: re-time its own route and try one other option in turn."""
        other = [o for o in search_options(p) if o != self.plan_option]
        k = self._rotation
        self._rotation += 1
        return [self.plan_option] + ([other[k % len(other)]] if other else [])

    def _replan_inputs(self, inp: PlanInput, obstacles: Sequence[Obstacle]) -> Replan:
        """This replan's splice point, start state, goal, vias, obstacle rings and its plan check."""
        tl = self.tl
        assert tl is not None
        p = self.params
        t = inp.t_s
        h = tl.h_s
        k_now = tl.index(t)
        k_r = k_now + LEAD_ROWS
        u0 = tl.unshaped_at(k_r)
        p0, v0 = u0[0:2], u0[2:4]
        goal = np.asarray(inp.goal_m, dtype=np.float64)
        vias, caps = remaining_vias(p0, inp.via_m, goal, inp.leg_caps_mps) if inp.via_m else ((), ())
        rings = obstacle_rings(inp, obstacles, self.envelope_m(inp), p.track_margin_m + self.err_peak_m,
                               p.predict_growth_mps)
        l_m = inp.cable_l_m

        def check(ref: np.ndarray, base: int) -> tuple[np.ndarray, np.ndarray, int]:
            fut, k_f = tl.future(k_now, ref, base)
            first, worst = clearance(fut, tl.time_of(k_f), h, t, l_m, rings.pred)
            return first, worst, k_f

        return Replan(t, k_now, k_r, p0, v0, goal, vias, caps, rings, check)

    def _route_exists(self, r: Replan, p: PlannerParams, cur_ok: bool) -> bool:
        """Whether a static route exists at all (the bare safety ring); none: brake, and ``no_route`` once it has
        lasted ``no_route_confirm_s``."""
        found = (route_through(r.p0, r.vias, r.goal, r.rings.c, r.rings.bare, r.rings.contact) if r.vias
                 else find_route(r.p0, r.goal, r.rings.c, r.rings.bare, r.rings.contact))
        if found is None:
            if self.no_route_since_s is None:
                self.no_route_since_s = r.t
            if r.t - self.no_route_since_s >= p.no_route_confirm_s - 1e-9:
                self.no_route = True
            self._hold(r.k_r, r.k_now, r.p0, r.v0, cur_ok, "no_route" if self.no_route else "brake")
            self.last = {"no_route_search_failed": True, "since": self.no_route_since_s}
            return False
        return True

    def _candidates(self, inp: PlanInput, r: Replan, p: PlannerParams, options, optional: bool,
                    timed: drag_timing.TimedFor):
        """(the first timed route whose plan clears every obstacle as (candidate, rows, unshaped, shaped, base) or
        None, the last round's candidates, how many were checked); up to three rounds, capsules around moving
        obstacles at their conflict times after the first; timed for the drag and wind ``timed``."""
        tl = self.tl
        assert tl is not None
        g = r.rings
        cc, rr, hh = g.route_c, g.route_ring, g.route_contact
        dg = timing.drag_budget(timed.drag_c, timed.wind_mps, p.drag_swing_budget_rad, inp.g_mps2)
        chosen, tried = None, 0
        for rnd in range(3):
            if rnd > 0:  # with capsules in the way: the three smallest plain inflations are enough
                options = [(False, e) for walled, e in search_options(p) if not walled][:3]
            cands = timed_routes(r.p0, r.v0, r.goal, cc, rr, hh, p.shaped_a_max_mps2, p, options, r.vias, r.caps, dg)
            if not cands and options is not None:
                cands = timed_routes(r.p0, r.v0, r.goal, cc, rr, hh, p.shaped_a_max_mps2, p, None, r.vias, r.caps, dg)
            if not cands:
                # only the bare ring lets a route through: at half the acceleration (less lead, less swing)
                bare = np.maximum(rr - (g.route_ring - g.route_bare).max(initial=0.0), 0.0) if len(rr) else rr
                cands = timed_routes(r.p0, r.v0, r.goal, cc, bare, hh, 0.5 * p.shaped_a_max_mps2, p, None, r.vias,
                                     r.caps, dg)
            conflicts: list[tuple[int, float]] = []
            for cand in cands:
                if optional and cand.profile.a_peak_mps2 > OPTIONAL_A_FACTOR * p.shaped_a_max_mps2:
                    continue  # an optional switch keeps the swing bound (no harder braking than a_max)
                tried += 1
                rows = self._rows(cand.profile)
                u, ref, base = tl.preview(r.k_r, rows, r.k_now)
                first, _worst, _ = r.check(ref, base)
                if np.all(np.isinf(first)):
                    chosen = (cand, rows, u, ref, base)
                    break
                if not conflicts:
                    conflicts = [(j, float(first[j])) for j in np.flatnonzero(np.isfinite(first)) if g.pred.moving[j]]
            if chosen is not None or not conflicts or not g.moving:
                break
            # capsules around the moving obstacles' positions at the conflict times
            cc, rr, hh = capsules(cc, rr, hh, conflicts, g.pred, r.t, self.envelope_m(inp),
                                  p.track_margin_m + self.err_peak_m, inp.airframe_r_m, p.predict_growth_mps)
        return chosen, cands, tried

    def _adopt(self, chosen, k_r: int, optional: bool, remaining: float, p: PlannerParams) -> None:
        """Splice the chosen candidate in at ``k_r`` unless it is optional and not shorter than the ``remaining``
        time (s) of the current plan by the hysteresis."""
        tl = self.tl
        assert tl is not None
        cand, rows, u, ref, base = chosen
        better = not optional or cand.duration_s < remaining - p.replan_hysteresis_s
        if better:
            tl.install(u, ref, base)
            self.plan_end_k = k_r + len(rows) - 1
            self.plan_profile, self.plan_k0 = cand.profile, k_r
            self.plan_reaches_goal = cand.reaches_goal
            self.plan_option, self.plan_timed = (cand.walled, cand.extra_m), self._search_timed
            self.splices += 1
            self.last.update({"spliced": True, "duration_s": cand.duration_s, "extra_m": cand.extra_m})
        else:
            self.last.update({"kept": True, "best_s": cand.duration_s})
        self.mode = "track"

    def facts(self) -> dict[str, Any]:
        """The report's part: route searches and splices, the waits for the wind (:mod:`~.wind_wait`)."""
        return {"searches": self.searches, "splices": self.splices, **self.wind_wait.facts()}

    def stop(self) -> None:
        """Stop along the planned path as soon as the swing bound allows and hold there (a hold the flight
        sequence asked for); takes effect at the next call of :meth:`plan`."""
        self.stop_requested = True
        self.next_replan_s = -math.inf

    def resume(self) -> None:
        """Fly on after :meth:`stop` (a ground station's pause ended): the next :meth:`plan` searches a route from
        where the stop left the plan."""
        self.stop_requested = False
        self.plan_reaches_goal = False
        self.next_replan_s = -math.inf

    def _hold(self, k_r: int, k_now: int, p0: np.ndarray, v0: np.ndarray, cur_ok: bool, mode: str) -> None:
        """Stop and hold there: when the current plan still heads for the goal, or when the stop already under
        way is no longer clear (a new one from the state at k_r). The stop follows the current plan's path
        (which was checked clear) at the swing-bounded deceleration a_max; without one, straight ahead at
        ``shaped_brake_mps2``."""
        tl = self.tl
        assert tl is not None
        self.mode = mode
        moving = math.hypot(float(v0[0]), float(v0[1])) > 1e-6
        if not (self.plan_reaches_goal or (moving and not cur_ok)):
            return
        rows = None
        prof = self.plan_profile
        if prof is not None and self.plan_reaches_goal:
            s0, sp = state_at(prof, (k_r - self.plan_k0) * tl.h_s)
            if abs(sp - math.hypot(float(v0[0]), float(v0[1]))) < 0.05:
                pos, vel, acc = stop_along(prof, s0, sp, self.params.shaped_a_max_mps2, tl.h_s)
                rows = np.concatenate([pos, vel, acc], axis=1)
                rows[0, 0:4] = np.r_[p0, v0]  # exactly continuous with the state being replaced
        if rows is None:
            rows = brake_rows(p0, v0, self.params.shaped_brake_mps2, self.params.shaped_step_s)
        tl.splice(k_r, rows, k_now)
        self.plan_end_k = k_r + len(rows) - 1
        self.plan_reaches_goal = False
        self.plan_profile = None
        self.splices += 1
