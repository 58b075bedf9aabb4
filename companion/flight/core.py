"""The per-tick pure glue of the companion: estimate → plan → reference → control → attitude setpoint.

Phases: ``climb`` (vertical, from wherever the vehicle is, to the mission's start altitude; skipped when
already there), ``cruise`` (planner towards the goal; horizontal from the planner, vertical straight to the
goal's altitude with a braking profile), ``hold`` (at the goal for ``mission.hold_s``), ``no_route`` (the
planner established that no route to the goal exists and holds where it stopped, for ``mission.hold_s``;
``FlightCore.no_route`` stays True), ``done`` (hold finished, no route, or timeout; :attr:`FlightCore.result`
says which; the app lands); ``hold_here`` / ``descend`` (the flight sequence stopped the mission: hover, or
descend, where the reference is). No I/O, no clocks: time comes from the estimates.

A time-parameterised planner (``shaped``) gives the horizontal reference itself (position, velocity,
acceleration, and the payload's nominal swing along it); the core flies it through cruise, hold, no_route
and done instead of integrating a desired velocity (hold_here and descend take over from it smoothly), and
keeps the anti-swing feed-forward from fighting the planned swing: the controller adds ff(swing) to the
reference acceleration, so the core hands it a_ref − ff(nominal swing) and the feed-forward acts on the
deviation from the nominal swing only.

Moving obstacles: a mission obstacle with a velocity (``vx_mps``/``vy_mps``) is at its file position at the
mission clock's zero — the first :meth:`FlightCore.update` (the first setpoint of the mission) — and moves
at constant velocity; the core advances it to each tick's time before planning. Live obstacles arrive
already advanced (:mod:`companion.zenoh_io.obstacle_store`).

Swing input: an :class:`~companion.estimation.estimate.Estimate` with ``swing`` None means no swing measurement —
the controller then flies without payload compensation and feed-forward and the planners use the
full-cable envelope max(l, r_uav + L_uav) (``Command.envelope_mode == "full_cable"``).

A swing that comes from the payload's own position stream (``swing_source == "payload_position"``, 10 Hz
on the bundled vehicle, like ArduPilot's slung-payload stream) is used for the envelope and the planner
only, not by the controller: the feed-forward differentiates α̇, and a 10 Hz staircase differentiated at
250 Hz makes it inject spikes that excite the swing (measured: the forest flown that way swung to
0.75 rad and never reached the goal). Only the cable-angle sensor, sampled at the control rate, feeds the
payload compensation and the feed-forward. So does the swing estimator's output (``swing_source ==
"estimate"``, a model-based estimate at the control rate): its feed-forward is scaled by ``swing_fade`` and its
envelope assumes the swing angle ``swing_bound_rad`` (|swing| + 3σ).

Loop lag: the core measures how long its attitude commands take to come back as attitude
(:class:`~companion.estimation.loop_lag.LoopLagEstimator`, counted in ticks of ``period_s``) and scales the
swing the controller acts on (payload compensation and feed-forward, like ``swing_fade``) by
:func:`~companion.estimation.loop_lag.lag_trust` of the excess over the profile's clean-link lag: a slow or
jittery link fades the feed-forward before its loop runs out of delay margin; a slower one also softens the SMC's
horizontal gains (``controller.gain_scale``).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from companion.autopilots.profile import VehicleProfile
from companion.control import (
    ControllerConfig,
    PositionController,
    SwingAccelEstimator,
    attitude_from_force,
    feedforward_acc,
    limit_force_xyz,
    make_position_controller,
)
from companion.core.envelope import full_cable_r_max_m, r_max_m
from companion.core.mission import Mission
from companion.core.obstacles import Obstacle
from companion.estimation.estimate import Estimate, swing_sigma_rad, widened_swing
from companion.estimation.loop_lag import LoopLagEstimator, lag_trust
from companion.planning import PlanInput, Planner, PlanOutput, ReferenceGenerator, make_planner

log = logging.getLogger(__name__)

PHASES = ("climb", "cruise", "hold", "no_route", "done", "hold_here", "descend")
DESCENT_MPS = 0.5  # the companion's own landing descent (when the autopilot's land mode is not confirmed)
ARRIVE_HORIZ_M = 0.1  # arrival tolerance (m) where the autopilot reports no position accuracy, and the least
ARRIVE_ACCURACY_K = 1.0  # ... otherwise ARRIVE_ACCURACY_K × its 1σ horizontal accuracy (PX4's ESTIMATOR_STATUS)
ARRIVE_DWELL_S = 0.3  # the vehicle must stay within the tolerance this long for the arrival to count
ARRIVE_VERT_M = 0.25
SWING_READY_FADE = 0.9  # the swing estimate carries this much feed-forward: trusted enough to start the cruise
TIMED_PHASES = ("cruise", "hold", "no_route", "done")  # where a time-parameterised planner gives the reference


@dataclass(frozen=True, slots=True)
class Command:
    """One attitude setpoint plus what led to it (for SET_ATTITUDE_TARGET, the report and telemetry).

    q_ned_frd_wxyz: attitude quaternion [w, x, y, z] body FRD → NED; thrust_n (N) and thrust_norm (0..1,
    via the vehicle profile); euler_cmd_rad [φ, θ, ψ]; reference position/velocity/acceleration (NED, SI);
    force_att_n / force_rep_n: the planner's attractive and repulsive parts (2,) (velocity units for the
    APF-as-gradient-flow, see :mod:`companion.planning.apf`); r_max_m: envelope radius used;
    envelope_mode: ``"swing"`` or ``"full_cable"``; phase; ff_accel (3,) m/s² anti-swing feed-forward;
    plan_mode: ``"track"`` or ``"escape"`` (safe planner's trap escape), ``"brake"`` / ``"no_route"`` (shaped
    planner stopping); no_route: the planner found no route to the goal (the mission ends ``no_route``).
    """

    t_s: float
    q_ned_frd_wxyz: np.ndarray
    thrust_n: float
    thrust_norm: float
    euler_cmd_rad: np.ndarray
    ref_pos_ned_m: np.ndarray
    ref_vel_ned_mps: np.ndarray
    ref_acc_ned_mps2: np.ndarray
    force_att_n: np.ndarray
    force_rep_n: np.ndarray
    r_max_m: float
    envelope_mode: str
    phase: str
    ff_accel: np.ndarray
    plan_mode: str = "track"
    no_route: bool = False


LIFT_MARGIN_M = 0.3  # a payload lifted off the ground hangs this far clear of it before the vehicle moves sideways


def climb_altitude_ned_m(z0_ned_m: float, start_z_ned_m: float, cable_m: float) -> float:
    """Where the vertical climb ends (NED z, m): the mission's start altitude, but a vehicle taking off with its
    payload on the ground (less than a cable's length up) first lifts it straight up, to a cable's length plus
    LIFT_MARGIN_M, before it moves sideways.

    Moving off diagonally drags the payload: the cable snaps taut at an angle and the payload swings from there
    (Group 1, origin to 5 m above (3, 4), took off at 45°: 0.55 rad at lift-off, against 0.2 rad in flight)."""
    lift_z = -(cable_m + LIFT_MARGIN_M)
    if z0_ned_m > -cable_m and start_z_ned_m > lift_z:
        return lift_z
    return start_z_ned_m


class FlightCore:
    """Per-tick flight logic for one mission; call :meth:`update` with each new estimate.

    ``period_s``: the control period (s): the loop lag is counted in it, and the first tick steps by it."""

    def __init__(self, mission: Mission, gains: ControllerConfig | None = None, profile: VehicleProfile | None = None,
                 period_s: float = 0.004):
        self.mission = mission
        self.cfg = gains or ControllerConfig()
        self.profile = profile or VehicleProfile()
        self.params = mission.vehicle
        self.period_s = period_s
        self.planner: Planner = make_planner(mission.planner, self.cfg.planner, self.params)
        self._timed = self.planner.time_parameterised
        self._moving_mission = any(o.vx_mps != 0.0 or o.vy_mps != 0.0 for o in mission.obstacles)
        self.no_route = False
        self.t_no_route_s: float | None = None
        self._timed_stop = False  # hold_here / descend asked while a time-parameterised planner was flying
        self.controller: PositionController = make_position_controller(mission.controller, self.cfg, self.params)
        self.swing_acc = SwingAccelEstimator(self.cfg.feedforward.rate_filter_s)
        self.loop_lag = LoopLagEstimator(period_s)
        self.lag_trust = 1.0  # the feed-forward's trust from the measured loop lag (this tick)
        self.lag_stats = _LagStats(period_s)
        self.ref: ReferenceGenerator | None = None
        self.phase = "climb"
        #: with a swing estimator as the swing input, the climb holds at the start altitude up to this long (s)
        #: until the estimate is trusted (fade >= SWING_READY_FADE): cruising off on a still-fading feed-forward
        #: swung the payload to 0.35 rad in the first second (bundled vehicle, sensorless). 0 = never wait.
        self.swing_wait_s = 0.0
        self.t_swing_wait_s: float | None = None  # when the climb started waiting for the estimate
        self._climb_z = float(mission.start_ned_m[2])  # where the climb ends (NED z, m; see climb_altitude_ned_m)
        self.timed_out = False
        self.t0_s: float | None = None
        self.t_prev_s: float | None = None
        self.t_arrived_s: float | None = None
        self._t_within_s: float | None = None  # since when the vehicle is within the arrival tolerance
        #: the arrival rule of this flight, for the report: tolerance (m), dwell (s), the accuracy it came from
        self.arrival: dict[str, float | None] = {"tolerance_m": ARRIVE_HORIZ_M, "dwell_s": ARRIVE_DWELL_S,
                                                 "accuracy_m": None, "t_s": None}
        self.yaw_rad = 0.0
        hover = self.params.hover_thrust_n
        lim = self.cfg.limits
        self._thrust_min = lim.thrust_min_frac * hover
        self._thrust_max = lim.thrust_max_frac * hover
        self._full_cable_r_max = full_cable_r_max_m(self.params)
        self._airframe_r = self.params.r_uav + self.params.L_uav
        self._goal_xy = np.array(mission.goal_ned_m[:2], dtype=np.float64)
        self._hold_ned_m = np.array(mission.goal_ned_m, dtype=np.float64)  # where hold / done / hold_here hover

    # ------------------------------------------------------------------------------------------------
    @property
    def result(self) -> str | None:
        """The mission's verdict once the core is done (``"completed"``, ``"timeout"`` or ``"no_route"``: the
        planner established that no route to the goal exists and held), else None."""
        if self.phase != "done":
            return None
        if self.no_route:
            return "no_route"
        return "timeout" if self.timed_out else "completed"

    def hold_here(self) -> None:
        """Stop the mission and hover where the reference is now (a hold the flight sequence asked for).

        With a time-parameterised planner flying, "now" is the planner's own stop: along its checked path at
        the swing-bounded deceleration (from 3.6 m/s a straight-line stop at the reference generator's limits
        overshoots by 6 m, through whatever is ahead, and flies back)."""
        if self.ref is not None:
            self._hold_ned_m = np.array(self.ref.p, dtype=np.float64)
        self._stop_timed()
        self.phase = "hold_here"

    def descend(self) -> None:
        """Stop the mission and descend at :data:`DESCENT_MPS` over where the reference is now (the
        companion's own landing, when the autopilot's land mode was not confirmed); with a time-parameterised
        planner, over the end of its stop (see :meth:`hold_here`)."""
        if self.ref is not None:
            self._hold_ned_m = np.array(self.ref.p, dtype=np.float64)
        self._stop_timed()
        self.phase = "descend"

    def _stop_timed(self) -> None:
        if self._timed and (self.phase in TIMED_PHASES or self._timed_stop):
            self.planner.stop()
            self._timed_stop = True

    # ------------------------------------------------------------------------------------------------
    def _vertical_speed(self, z_target: float) -> float:
        """Desired vertical reference speed (m/s) towards ``z_target`` with a braking profile."""
        assert self.ref is not None
        p = self.cfg.planner
        dz = z_target - self.ref.p[2]
        v = min(p.vz_max_mps, math.sqrt(2.0 * 0.5 * p.az_max_mps2 * abs(dz)), p.ka * abs(dz))
        return math.copysign(v, dz)

    @staticmethod
    def arrival_tolerance_m(est: Estimate) -> float:
        """How close (m, horizontally) counts as at the goal: ARRIVE_HORIZ_M, widened to ARRIVE_ACCURACY_K times
        the autopilot's reported 1σ position accuracy: the estimated position wanders by about that much, so a
        tighter tolerance is met only by chance (PX4 SIH reports 0.29 m; at 0.1 m its arrival took seconds)."""
        acc = est.pos_accuracy_m
        return ARRIVE_HORIZ_M if acc is None else max(ARRIVE_HORIZ_M, ARRIVE_ACCURACY_K * acc)

    def _swing_ready(self, est: Estimate) -> bool:
        """Whether the swing input is ready for the cruise (see :attr:`swing_wait_s`); starts the wait clock."""
        if self.swing_wait_s <= 0.0 or (est.swing is not None and est.swing_source != "estimate"):
            return True
        if est.swing_source == "estimate" and est.swing_fade >= SWING_READY_FADE:
            return True
        if self.t_swing_wait_s is None:
            self.t_swing_wait_s = est.t_s
            log.info("at the start altitude: waiting up to %.1f s for the swing estimate to settle", self.swing_wait_s)
        if est.t_s - self.t_swing_wait_s >= self.swing_wait_s:
            log.warning("the swing estimate did not settle within %.1f s: cruising on the full-cable envelope and "
                        "the faded feed-forward", self.swing_wait_s)
            return True
        return False

    def _advance_phase(self, est: Estimate) -> None:
        m = self.mission
        t = est.t_s
        if (self.t0_s is not None and t - self.t0_s > m.timeout_s
                and self.phase in ("climb", "cruise", "hold", "no_route")):
            log.warning("mission %s: timeout after %.1f s in phase %s", m.name, m.timeout_s, self.phase)
            self.timed_out = True
            self.phase = "done"
        if self.phase == "climb":
            assert self.ref is not None
            if abs(float(est.pos_ned_m[2]) - self._climb_z) < ARRIVE_VERT_M and abs(
                self.ref.p[2] - self._climb_z
            ) < 0.02 and self._swing_ready(est):
                self.phase = "cruise"
        elif self.phase == "cruise":
            dh = math.hypot(est.pos_ned_m[0] - m.goal_ned_m[0], est.pos_ned_m[1] - m.goal_ned_m[1])
            tol = self.arrival_tolerance_m(est)
            if dh < tol and abs(float(est.pos_ned_m[2]) - m.goal_ned_m[2]) < ARRIVE_VERT_M:
                if self._t_within_s is None:
                    self._t_within_s = t
                if t - self._t_within_s >= ARRIVE_DWELL_S:
                    self.phase = "hold"
                    self.t_arrived_s = self._t_within_s
                    self.arrival.update(tolerance_m=tol, accuracy_m=est.pos_accuracy_m, t_s=self._t_within_s)
            else:
                self._t_within_s = None
        elif self.phase == "hold":
            assert self.t_arrived_s is not None
            if t - self.t_arrived_s >= m.hold_s:
                self.phase = "done"
        elif self.phase == "no_route":
            assert self.t_no_route_s is not None
            if t - self.t_no_route_s >= m.hold_s:
                self.phase = "done"

    def _advance_obstacles(self, obs: Sequence[Obstacle], t_s: float) -> Sequence[Obstacle]:
        """Moving mission obstacles at time ``t_s`` (see module docstring); the others unchanged."""
        if not self._moving_mission or self.t0_s is None:
            return obs
        dt = t_s - self.t0_s
        return [o.at_time(dt) if o.source == "mission" else o for o in obs]

    # ------------------------------------------------------------------------------------------------
    def update(self, est: Estimate, obstacles: Sequence[Obstacle] | None = None) -> Command:
        """The setpoint for this tick and the bookkeeping after it: :meth:`setpoint`, then
        :meth:`after_setpoint`. ``obstacles`` None means the mission's own list."""
        cmd = self.setpoint(est, obstacles)
        self.after_setpoint(est, cmd)
        return cmd

    def after_setpoint(self, est: Estimate, cmd: Command) -> None:
        """What this tick adds that does not shape its own setpoint, for a caller that sends the setpoint first:
        the loop-lag measurement (this tick's attitude against the commands of the ticks before) and this
        tick's command into its ring. The next :meth:`setpoint` uses the lag measured here.

        The measurement updates every other tick and costs more than the rest of the bookkeeping (~10 numpy
        calls, which run cold in a real-time tick), so the app does it after the setpoint is out."""
        self.loop_lag.observe(float(est.euler_rad[0]), float(est.euler_rad[1]))
        euler = cmd.euler_cmd_rad
        self.loop_lag.command(float(euler[0]), float(euler[1]))

    def setpoint(self, est: Estimate, obstacles: Sequence[Obstacle] | None = None) -> Command:
        """The setpoint for this tick (no loop-lag bookkeeping: :meth:`after_setpoint`, or :meth:`update` for both).
        ``obstacles`` None means the mission's own list.

        Cost matters here (it runs at the control rate, and the lockstep loop waits for it): tiny vectors
        are handled as floats (math.hypot, no numpy temporaries); arrays are built only for the Command.
        """
        m = self.mission
        obs = m.obstacles if obstacles is None else obstacles
        pos = est.pos_ned_m
        vel = est.vel_ned_mps
        z = float(pos[2])
        if self.ref is None:
            self.ref = ReferenceGenerator(self.cfg.planner, np.asarray(pos, dtype=np.float64))
            self.t0_s = est.t_s
            self.yaw_rad = float(est.euler_rad[2])
            self._climb_z = climb_altitude_ned_m(z, float(m.start_ned_m[2]), self.params.l)
            if abs(z - self._climb_z) < ARRIVE_VERT_M:
                self.phase = "cruise"
        dt = self.period_s if self.t_prev_s is None else est.t_s - self.t_prev_s
        self.t_prev_s = est.t_s
        self._advance_phase(est)
        obs = self._advance_obstacles(obs, est.t_s)
        ff_cfg, smc_cfg = self.cfg.feedforward, self.cfg.smc
        lag = self.loop_lag.lag_s  # as measured up to the last tick (after_setpoint)
        nominal = self.profile.nominal_loop_lag_s
        self.lag_trust = lag_trust(lag, nominal, ff_cfg.lag_full_excess_s, ff_cfg.lag_zero_excess_s)
        gain_scale = 1.0
        if self.controller.softens_with_lag:
            gain_scale = self.controller.gain_scale = lag_trust(lag, nominal, smc_cfg.lag_scale_start_s,
                                                                smc_cfg.lag_scale_end_s, smc_cfg.lag_scale_min)
        self.lag_stats.add(lag, self.lag_trust, gain_scale)

        swing = None if est.swing is None else np.asarray(est.swing, dtype=np.float64)
        if swing is not None:
            a_env, b_env = float(swing[0]), float(swing[1])
            if est.swing_bound_rad is not None:  # an uncertain estimate: the envelope assumes |swing| + 3σ
                a_env, b_env = widened_swing(a_env, b_env, est.swing_bound_rad)
            r_max = r_max_m(a_env, b_env, self.params)
            mode = "swing"
            swing_acc = self.swing_acc.update_scalar(est.t_s, float(swing[2]), float(swing[3]))
        else:
            r_max = self._full_cable_r_max
            mode = "full_cable"
            self.swing_acc.reset()
            swing_acc = (0.0, 0.0)

        f_att = _ZERO2
        f_rep = _ZERO2
        plan_mode = "track"
        ref = self.ref
        acc_ctl = None
        timed_now = self._timed and (self.phase in TIMED_PHASES or self._timed_stop)
        if timed_now:
            out = self._plan_timed(est, obs, swing, r_max, z, dt)
            f_att, f_rep, plan_mode = out.force_att, out.force_rep, out.mode
            acc_ctl = self._acc_for_controller(out, est)
        elif self.phase == "climb":
            vdx = vdy = 0.0
            vdz = self._vertical_speed(self._climb_z)
        elif self.phase == "cruise":
            inp = PlanInput(
                t_s=est.t_s, pos_m=np.asarray(pos[:2], dtype=np.float64), vel_mps=np.asarray(vel[:2], dtype=np.float64),
                ref_pos_m=np.array(ref.p[:2]), ref_vel_mps=np.array(ref.v[:2]), goal_m=self._goal_xy, r_max_m=r_max,
                swing=swing, cable_l_m=self.params.l, airframe_r_m=self._airframe_r, g_mps2=self.params.g, z_ned_m=z,
            )
            out = self.planner.plan(inp, obs)
            vdx, vdy = float(out.v_des_mps[0]), float(out.v_des_mps[1])
            vdz = self._vertical_speed(float(m.goal_ned_m[2]))
            f_att, f_rep, plan_mode = out.force_att, out.force_rep, out.mode
        else:  # hold / done: hover at the goal; hold_here / descend: at the point where they were asked for
            ka = self.cfg.planner.ka
            hold = self._hold_ned_m
            vdx = ka * (float(hold[0]) - ref.p[0])
            vdy = ka * (float(hold[1]) - ref.p[1])
            vdz = DESCENT_MPS if self.phase == "descend" else self._vertical_speed(float(hold[2]))
        if dt > 0.0 and not timed_now:
            ref.step((vdx, vdy, vdz), dt)

        ctl_swing = swing if est.swing_source in ("cable_sensor", "estimate") else None
        trust = self._swing_trust(est)
        if ctl_swing is not None and trust < 1.0:  # an untrusted estimate or a lagging loop: less (or no) feed-forward
            ctl_swing = ctl_swing * trust
            swing_acc = (swing_acc[0] * trust, swing_acc[1] * trust)
        ctl = self.controller.update(
            pos, vel, ref.p, ref.v, ref.a if acc_ctl is None else acc_ctl, ctl_swing,
            swing_acc if ctl_swing is not None else (0.0, 0.0), max(dt, 1e-4),
        )
        lim = self.cfg.limits
        fx, fy, fz = ctl.force_ned_n.tolist()
        force = limit_force_xyz(fx, fy, fz, lim.tilt_max_rad, self._thrust_min, self._thrust_max)
        q, thrust, euler = attitude_from_force(force, self.yaw_rad)
        return Command(
            t_s=est.t_s, q_ned_frd_wxyz=q, thrust_n=thrust,
            thrust_norm=self.profile.thrust_to_norm(thrust, self.params.hover_thrust_n), euler_cmd_rad=euler,
            ref_pos_ned_m=np.array(ref.p), ref_vel_ned_mps=np.array(ref.v), ref_acc_ned_mps2=np.array(ref.a),
            force_att_n=f_att, force_rep_n=f_rep, r_max_m=r_max, envelope_mode=mode, phase=self.phase,
            ff_accel=ctl.ff_acc_mps2, plan_mode=plan_mode, no_route=self.no_route,
        )

    def _plan_timed(self, est: Estimate, obs: Sequence[Obstacle], swing: np.ndarray | None, r_max: float, z: float,
                    dt: float) -> PlanOutput:
        """Cruise / hold / no_route / done with a time-parameterised planner: its horizontal reference, the
        vertical channel towards the goal's altitude (or held where it is after no route)."""
        m = self.mission
        ref = self.ref
        assert ref is not None
        inp = PlanInput(
            t_s=est.t_s, pos_m=np.asarray(est.pos_ned_m[:2], dtype=np.float64),
            vel_mps=np.asarray(est.vel_ned_mps[:2], dtype=np.float64), ref_pos_m=np.array(ref.p[:2]),
            ref_vel_mps=np.array(ref.v[:2]), goal_m=self._goal_xy, r_max_m=r_max, swing=swing,
            cable_l_m=self.params.l, airframe_r_m=self._airframe_r, g_mps2=self.params.g, z_ned_m=z,
            swing_sigma_rad=swing_sigma_rad(est),
        )
        out = self.planner.plan(inp, obs)
        if out.no_route and not self.no_route:
            self.no_route = True
            if self.phase == "cruise":
                self.phase = "no_route"
                self.t_no_route_s = est.t_s
                log.warning("mission %s: no route to the goal; holding at (%.2f, %.2f)", m.name, ref.p[0], ref.p[1])
        r = out.reference
        assert r is not None
        if dt > 0.0:
            if self.phase == "descend":
                ref.step_vertical(DESCENT_MPS, dt)
            else:
                z_target = float(m.goal_ned_m[2]) if not (self.no_route or self._timed_stop) else ref.p[2]
                ref.step_vertical(self._vertical_speed(z_target), dt)
        ref.set_horizontal(r.pos_m, r.vel_mps, r.acc_mps2)
        return out

    def _acc_for_controller(self, out: PlanOutput, est: Estimate) -> list[float] | None:
        """Reference acceleration for the controller: a_ref − ff(nominal swing) with a feed-forward controller
        (``swing_feedforward``, the smc_ff) fed the cable sensor or the swing estimate (the feed-forward then acts
        on the deviation from the planned swing; scaled by the same trust as the controller's swing), else None."""
        r = out.reference
        if (r is None or not self.controller.swing_feedforward
                or est.swing_source not in ("cable_sensor", "estimate")):
            return None
        fade = self._swing_trust(est)
        a, b, da, db, dda, ddb = r.swing_nom
        ff = feedforward_acc(np.array((a, b, da, db)), np.array((dda, ddb)), self.cfg.feedforward, self.params.l)
        ref = self.ref
        assert ref is not None
        return [ref.a[0] - fade * float(ff[0]), ref.a[1] - fade * float(ff[1]), ref.a[2] - fade * float(ff[2])]
    def _swing_trust(self, est: Estimate) -> float:
        """How much of the swing the controller acts on (0..1): the estimate's ``swing_fade`` (1 for the cable
        sensor) times this tick's loop-lag trust."""
        fade = max(0.0, min(1.0, float(est.swing_fade))) if est.swing_source == "estimate" else 1.0
        return fade * self.lag_trust


class _LagStats:
    """The loop lag over a flight, for the report: range of the measured lag, least trust, time faded."""

    def __init__(self, period_s: float) -> None:
        self.period_s = period_s
        self.lag_min_s: float | None = None
        self.lag_max_s: float | None = None
        self.last_lag_s: float | None = None
        self.trust_min = 1.0
        self.faded_ticks = 0
        self.gain_scale_min = 1.0
        self.softened_ticks = 0

    def add(self, lag_s: float | None, trust: float, gain_scale: float = 1.0) -> None:
        if lag_s is not None:
            self.last_lag_s = lag_s
            self.lag_min_s = lag_s if self.lag_min_s is None else min(self.lag_min_s, lag_s)
            self.lag_max_s = lag_s if self.lag_max_s is None else max(self.lag_max_s, lag_s)
        if trust < 1.0:
            self.faded_ticks += 1
            self.trust_min = min(self.trust_min, trust)
        if gain_scale < 1.0:
            self.softened_ticks += 1
            self.gain_scale_min = min(self.gain_scale_min, gain_scale)

    def facts(self, nominal_s: float) -> dict[str, float | None]:
        """Loop lag (ms): min, max, last, the profile's nominal; least feed-forward trust and seconds faded; least
        position-gain scale and seconds softened."""
        def ms(v: float | None) -> float | None:
            return None if v is None else round(v * 1e3, 1)
        return {"lag_ms_min": ms(self.lag_min_s), "lag_ms_max": ms(self.lag_max_s), "lag_ms_last": ms(self.last_lag_s),
                "nominal_ms": ms(nominal_s), "ff_trust_min": round(self.trust_min, 3),
                "faded_s": round(self.faded_ticks * self.period_s, 2), "gain_scale_min": round(self.gain_scale_min, 3),
                "softened_s": round(self.softened_ticks * self.period_s, 2)}


_ZERO2 = np.zeros(2)
_ZERO2.flags.writeable = False

