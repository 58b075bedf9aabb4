"""The per-tick pure glue of the companion: estimate → plan → reference → control → attitude setpoint.

Phases (:class:`~companion.flight.phase.CorePhase`): climb, cruise, hold at the goal, no_route, done, and the
sequence's hold_here / descend (:mod:`companion.flight.core_orders`). No I/O, no clocks: time comes from the
estimates. How a time-parameterised planner's reference is flown, moving obstacles, swing inputs and the loop
lag: docs/companion.md, *The flight core*.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence

import numpy as np

from companion.autopilots.profile import VehicleProfile
from companion.control import (
    ControllerConfig,
    PositionController,
    SwingAccelEstimator,
    attitude_from_force,
    limit_force_xyz,
)
from companion.control.disturbance import ForceObserver, push_offset
from companion.control.drag_id import DragIdentifier
from companion.control.swing_bias import SwingBias, feedforward_offsets
from companion.core.envelope import r_max_m
from companion.core.floats import floats
from companion.core.mission import Mission
from companion.core.obstacles import Obstacle
from companion.core.vehicle_params import VehicleParams
from companion.estimation.estimate import Estimate, swing_sigma_rad, widened_swing
from companion.flight.arrival import ARRIVE_DWELL_S, ARRIVE_VERT_M, ArrivalRule, arrival_tolerance_m
from companion.flight.command import LIFT_MARGIN_M, Command, climb_altitude_ned_m
from companion.flight.core_hop import HopMixin
from companion.flight.core_orders import DESCENT_MPS, TIMED_PHASES, CoreOrders
from companion.flight.legs import Legs, capped, leg_plan, legs_done, planned_swing_acc
from companion.flight.liftoff import LiftOffGate, lift_gate
from companion.flight.loop_margin import LoopMargin
from companion.flight.phase import CorePhase
from companion.planning import PlanInput, Planner, PlanOutput, ReferenceGenerator
from companion.planning.fence_guard import fence_obstacles
from companion.planning.stop_cap import SeenCap, travel_headings_rad

log = logging.getLogger(__name__)

__all__ = ["ARRIVE_DWELL_S", "LIFT_MARGIN_M", "PHASES", "Command", "FlightCore", "climb_altitude_ned_m"]

PHASES = tuple(CorePhase)


class FlightCore(CoreOrders, HopMixin):
    """Per-tick flight logic for one mission; call :meth:`update` with each new estimate.

    ``period_s``: the control period (s): the loop lag is counted in it, and the first tick steps by it."""

    # built for the payload flown (companion.flight.core_hop.HopMixin._build), rebuilt when it is identified
    cfg: ControllerConfig
    params: VehicleParams
    planner: Planner
    controller: PositionController
    #: the speed cap inside the space the range sensor saw free (the pilot sets ``cap.seen`` on each mapped scan)
    cap: SeenCap
    #: the swing's slow equilibrium (a steady wind's drag), which the feed-forward leaves alone (issue 28)
    swing_bias: SwingBias
    #: the wind's push on the whole vehicle, taken off the position command beyond the ordinary (issue 28)
    push: ForceObserver
    #: the payload's drag angle per (m/s)² and the wind, identified from the swing's equilibrium (issue 28)
    drag_id: DragIdentifier
    #: whether the climb may lift the payload off in the wind now (issue 28; open unless the drags are declared)
    lift_gate: LiftOffGate

    def __init__(self, mission: Mission, gains: ControllerConfig | None = None, profile: VehicleProfile | None = None,
                 period_s: float = 0.004):
        self.mission = mission
        self._gains = gains or ControllerConfig()
        self.profile = profile or VehicleProfile()
        self.period_s = period_s
        #: where the identification hop hovers to (None: not flown; see companion.flight.core_hop)
        self.hop_target_ned_m: np.ndarray | None = None
        self.hop_length_m: float | None = None
        self.hop_identified = False  # the identification is over (end_identify): cruise once the swing is ready
        # the model flown is the mission's vehicle; the swing-bounded accelerations follow the payload the
        # companion believes it carries (issue 28): planner, controller, thrust limits, envelope, speed cap
        self._build(mission.vehicle, mission.companion_params())
        self._moving_mission = any(o.vx_mps != 0.0 or o.vy_mps != 0.0 for o in mission.obstacles)
        self.no_route = False
        self.t_no_route_s: float | None = None
        self._timed_stop = False  # hold_here / descend asked while a time-parameterised planner was flying
        #: the mission phase a hold_here stopped and where it hovered then (resume goes back to both)
        self._paused_from: tuple[CorePhase, np.ndarray] | None = None
        self._braking = False  # a pause: the reference brakes at its own limits, the hold is where it stops
        self.swing_acc = SwingAccelEstimator(self.cfg.feedforward.rate_filter_s)
        self._swing_nom: tuple | None = None  # this tick's planned swing (a timed plan's), else None
        self.margin = LoopMargin(period_s, self.cfg.cycle)
        self._correction = (0.0, 0.0)  # the controller's last horizontal correction (m/s², NED)
        self.loop_lag = self.margin.lag
        self.lag_trust = 1.0  # the feed-forward's trust from the loop's margin (this tick)
        self._tilt_max_rad = self.cfg.limits.tilt_max_rad  # this tick's max tilt: smaller on a slow link
        self.ref: ReferenceGenerator | None = None
        self.phase = CorePhase.CLIMB
        #: with a swing estimator as the swing input, the climb holds at the start altitude up to this long (s)
        #: until the estimate is trusted (fade >= SWING_READY_FADE, core_hop): cruising off on a fading feed-forward
        #: swung the payload to 0.35 rad in the first second (bundled vehicle, sensorless). 0 = never wait.
        self.swing_wait_s = 0.0
        self.t_swing_wait_s: float | None = None  # when the climb started waiting for the estimate
        self._climb_z = float(mission.start_ned_m[2])  # where the climb ends (NED z, m; see climb_altitude_ned_m)
        # open; armed by _start for a lift-off climb
        self.lift_gate = lift_gate(mission, self.params, self.cfg.planner, 0.0, 0.0)
        self.timed_out = False
        self.t0_s: float | None = None
        self.t_prev_s: float | None = None
        self._thrust_prev: float | None = None  # (N) the thrust commanded last tick (the wind push observer)
        self.t_arrived_s: float | None = None
        self._arrival = ArrivalRule(np.asarray(mission.goal_ned_m, dtype=np.float64))
        #: the arrival rule of this flight, for the report: tolerance (m), dwell (s), the accuracy it came from
        self.arrival = self._arrival.facts
        self.yaw_rad = 0.0
        self._goal_xy = np.array(mission.goal_ned_m[:2], dtype=np.float64)
        self._hold_ned_m = np.array(mission.goal_ned_m, dtype=np.float64)  # where hold / done / hold_here hover
        #: a multi-leg mission's waypoints (None without: straight to the goal), the fence's keep-out discs
        self.legs = Legs(mission, self.cfg.planner.v_max_mps) if mission.waypoints else None
        self._fence_obs = fence_obstacles(mission.fence)

    # ------------------------------------------------------------------------------------------------
    @property
    def result(self) -> str | None:
        """The mission's verdict once the core is done (``"completed"``, ``"timeout"`` or ``"no_route"``: the
        planner established that no route to the goal exists and held), else None."""
        if self.phase != CorePhase.DONE:
            return None
        if self.no_route:
            return "no_route"
        return "timeout" if self.timed_out else "completed"

    # ------------------------------------------------------------------------------------------------
    def _vertical_speed(self, z_target: float) -> float:
        """Desired vertical reference speed (m/s) towards ``z_target`` with a braking profile."""
        assert self.ref is not None
        p = self.cfg.planner
        dz = z_target - self.ref.p[2]
        v = min(p.vz_max_mps, math.sqrt(2.0 * 0.5 * p.az_max_mps2 * abs(dz)), p.ka * abs(dz))
        return math.copysign(v, dz)

    arrival_tolerance_m = staticmethod(arrival_tolerance_m)

    def _advance_phase(self, est: Estimate) -> None:
        m = self.mission
        t = est.t_s
        if (self.t0_s is not None and t - self.t0_s > m.timeout_s
                and self.phase in (CorePhase.CLIMB, CorePhase.IDENTIFY, CorePhase.CRUISE, CorePhase.HOLD,
                                   CorePhase.NO_ROUTE)):
            log.warning("mission %s: timeout after %.1f s in phase %s", m.name, m.timeout_s, self.phase)
            self.timed_out = True
            self.phase = CorePhase.DONE
        if self.phase == CorePhase.CLIMB:
            assert self.ref is not None
            if self.lift_gate.timed_out(t):  # the wind held the payload on the ground too long: no route from here
                self.no_route, self.phase = True, CorePhase.DONE
            elif abs(float(est.pos_ned_m[2]) - self._climb_z) < ARRIVE_VERT_M and abs(
                self.ref.p[2] - self._climb_z
            ) < 0.02 and self._swing_ready(est):
                self.phase = self._after_climb()
        elif self.phase == CorePhase.IDENTIFY:
            if self._identify_done(est):
                self.phase = CorePhase.CRUISE
        elif self.phase == CorePhase.CRUISE:
            plan_xy = (self.ref.p[0], self.ref.p[1]) if self._timed and self.ref is not None else None
            arrived = self._arrival.arrived(est) if legs_done(self.legs, est, plan_xy) else None
            if arrived is not None:
                self.phase = CorePhase.HOLD
                self.t_arrived_s = arrived
        elif self.phase == CorePhase.HOLD:
            assert self.t_arrived_s is not None
            if t - self.t_arrived_s >= m.hold_s:
                self.phase = CorePhase.DONE
        elif self.phase == CorePhase.NO_ROUTE:
            assert self.t_no_route_s is not None
            if t - self.t_no_route_s >= m.hold_s:
                self.phase = CorePhase.DONE

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
        self.margin.after(est.t_s, est.euler_rad, cmd.euler_cmd_rad, self._correction, self.profile.nominal_loop_lag_s)

    def setpoint(self, est: Estimate, obstacles: Sequence[Obstacle] | None = None) -> Command:
        """The setpoint for this tick (no loop-lag bookkeeping: :meth:`after_setpoint`, or :meth:`update` for both).
        ``obstacles`` None means the mission's own list.

        Cost matters here (it runs at the control rate, and the lockstep loop waits for it): tiny vectors
        are handled as floats (math.hypot, no numpy temporaries); arrays are built only for the Command.
        """
        obs = self.mission.obstacles if obstacles is None else obstacles
        if self.ref is None:
            self._start(est)
        dt = self.period_s if self.t_prev_s is None else est.t_s - self.t_prev_s
        self.t_prev_s = est.t_s
        self._advance_phase(est)
        obs = self._advance_obstacles(obs, est.t_s)
        obs = [*obs, *self._fence_obs] if self._fence_obs else obs
        if self.phase == CorePhase.IDENTIFY and self.hop_target_ned_m is None:
            self._plan_hop(obs)
        self._update_lag_trust()
        self._swing_nom = None
        swing, r_max, mode, swing_acc = self._envelope(est)
        f_att, f_rep, plan_mode, acc_ctl = self._reference(est, obs, swing, r_max, dt)
        ref = self.ref
        ctl_swing = swing if est.swing_source in ("cable_sensor", "estimate") else None
        trust = self._swing_trust(est)
        swing_acc_raw = swing_acc
        if ctl_swing is not None and trust < 1.0:  # an untrusted estimate or a lagging loop: less (or no) feed-forward
            ctl_swing = ctl_swing * trust
            swing_acc = (swing_acc[0] * trust, swing_acc[1] * trust)
        if self.controller.swing_feedforward:
            feedforward_offsets(self.controller, self.swing_bias, est.t_s, None if ctl_swing is None else swing,
                                swing_acc_raw, est.vel_ned_mps, self._swing_nom, trust, self.cfg.feedforward,
                                self.params.l)
            push_offset(self.controller, self.push, est.t_s, est.vel_ned_mps, est.euler_rad, self._thrust_prev,
                        None if ctl_swing is None else swing, swing_acc_raw, trust)
            self.drag_id.update(est.t_s, None if ctl_swing is None else self.swing_bias.mean, est.vel_ned_mps,
                                self.push.mean)
            if self.drag_id.c > 0.0:  # a payload drag, declared or identified: the wind drags, its push is taken off
                self.push.lower_band(dt)
        ctl = self.controller.update(
            est.pos_ned_m, est.vel_ned_mps, ref.p, ref.v, ref.a if acc_ctl is None else acc_ctl, ctl_swing,
            swing_acc if ctl_swing is not None else (0.0, 0.0), max(dt, 1e-4),
        )
        acc, acc_ref = ctl.acc_cmd_mps2.tolist(), floats(ref.a if acc_ctl is None else acc_ctl)
        self._correction = (acc[0] - acc_ref[0], acc[1] - acc_ref[1])  # for the limit-cycle guard (m/s², NED)
        fx, fy, fz = ctl.force_ned_n.tolist()
        force = limit_force_xyz(fx, fy, fz, self._tilt_max_rad, self._thrust_min, self._thrust_max)
        q, thrust, euler = attitude_from_force(force, self.yaw_rad)
        self._thrust_prev = thrust
        return Command(
            t_s=est.t_s, q_ned_frd_wxyz=q, thrust_n=thrust,
            thrust_norm=self.profile.thrust_to_norm(thrust, self.params.hover_thrust_n), euler_cmd_rad=euler,
            ref_pos_ned_m=np.array(ref.p), ref_vel_ned_mps=np.array(ref.v), ref_acc_ned_mps2=np.array(ref.a),
            force_att_n=f_att, force_rep_n=f_rep, r_max_m=r_max, envelope_mode=mode, phase=self.phase,
            ff_accel=ctl.ff_acc_mps2, plan_mode=plan_mode, no_route=self.no_route,
        )

    def _start(self, est: Estimate) -> None:
        """The mission's first tick: the reference starts where the vehicle is, the mission clock at zero."""
        z = float(est.pos_ned_m[2])
        self.ref = ReferenceGenerator(self.cfg.planner, np.asarray(est.pos_ned_m, dtype=np.float64))
        self.t0_s = est.t_s
        self.yaw_rad = float(est.euler_rad[2])
        self._climb_z = climb_altitude_ned_m(z, float(self.mission.start_ned_m[2]), self.params.l)
        self.lift_gate = lift_gate(self.mission, self.params, self.cfg.planner, z, self._climb_z,
                                   (float(est.pos_ned_m[0]), float(est.pos_ned_m[1])))
        if abs(z - self._climb_z) < ARRIVE_VERT_M:
            self.phase = self._after_climb()

    def _update_lag_trust(self) -> None:
        """This tick's feed-forward trust, the SMC's gain scale and the max tilt (:meth:`LoopMargin.factors`)."""
        softens = self.controller.softens_with_lag
        self.lag_trust, gain_scale, self._tilt_max_rad = self.margin.factors(
            self.t_prev_s, self.cfg, self.profile.nominal_loop_lag_s, softens)
        if softens:
            self.controller.gain_scale = gain_scale

    def _envelope(self, est: Estimate) -> tuple[np.ndarray | None, float, str, tuple[float, float]]:
        """(swing as an array or None, envelope radius r_max (m), envelope mode, swing accelerations (rad/s²))."""
        swing = None if est.swing is None else np.asarray(est.swing, dtype=np.float64)
        if swing is None:
            self.swing_acc.reset()
            return None, self._full_cable_r_max, "full_cable", (0.0, 0.0)
        a_env, b_env = float(swing[0]), float(swing[1])
        if est.swing_bound_rad is not None:  # an uncertain estimate: the envelope assumes |swing| + 3σ
            a_env, b_env = widened_swing(a_env, b_env, est.swing_bound_rad)
        swing_acc = self.swing_acc.update_scalar(est.t_s, float(swing[2]), float(swing[3]))
        return swing, r_max_m(a_env, b_env, self.params), "swing", swing_acc

    def _reference(self, est: Estimate, obs: Sequence[Obstacle], swing: np.ndarray | None, r_max: float,
                   dt: float) -> tuple[np.ndarray, np.ndarray, str, list[float] | None]:
        """Step the reference for this tick's phase; (attractive, repulsive force, plan mode, the controller's
        reference acceleration when a time-parameterised plan gives it, else None)."""
        pos, ref, z = est.pos_ned_m, self.ref, float(est.pos_ned_m[2])
        if self._timed and (self.phase in TIMED_PHASES or self._timed_stop):
            out = self._plan_timed(est, obs, swing, r_max, z, dt)
            return out.force_att, out.force_rep, out.mode, self._acc_for_controller(out, est)
        f_att, f_rep, plan_mode = _ZERO2, _ZERO2, "track"
        if self.phase == CorePhase.CLIMB:
            vdx = vdy = 0.0
            gate = self.lift_gate
            if gate.armed:  # upwind of the payload, to lift it at its drag equilibrium (companion.flight.liftoff)
                vdx, vdy = gate.lean_velocity((ref.p[0], ref.p[1]), self.push.mean, obs, self._airframe_r)
            vdz = self._vertical_speed(gate.target_z(est.t_s, (float(pos[0]), float(pos[1])), ref.p[2],
                                                     self.push.mean, obs, self._climb_z))
        elif self.phase == CorePhase.CRUISE:
            vel = est.vel_ned_mps
            goal, z_goal, legs_in, cap = leg_plan(self.legs, self.mission, self._goal_xy, False)
            inp = PlanInput(
                t_s=est.t_s, pos_m=np.asarray(pos[:2], dtype=np.float64), vel_mps=np.asarray(vel[:2], dtype=np.float64),
                ref_pos_m=np.array(ref.p[:2]), ref_vel_mps=np.array(ref.v[:2]), goal_m=goal, r_max_m=r_max,
                swing=swing, cable_l_m=self.params.l, airframe_r_m=self._airframe_r, g_mps2=self.params.g, z_ned_m=z,
                v_cap_mps=self.cap.cap_mps(est.pos_ned_m, est.vel_ned_mps, r_max), **legs_in,
            )
            out = self.planner.plan(inp, obs)
            if out.no_route:
                self.no_route_here(est.t_s)
            vdx, vdy = float(out.v_des_mps[0]), float(out.v_des_mps[1])
            vdx, vdy = capped(vdx, vdy, cap)  # the leg's speed limit
            vdz = self._vertical_speed(z_goal)
            f_att, f_rep, plan_mode = out.force_att, out.force_rep, out.mode
        else:  # hold / done: hover at the goal; hold_here / descend: at the point where they were asked for
            ka = self.cfg.planner.ka
            if self._braking:  # desired velocity 0 until the reference stands, then hold there
                self._hold_ned_m = np.array(ref.p, dtype=np.float64)
                self._braking = (self.phase in (CorePhase.HOLD_HERE, CorePhase.NO_ROUTE)
                                 and math.hypot(ref.v[0], ref.v[1]) > 0.02)
            hop = self.hop_target_ned_m if self.phase == CorePhase.IDENTIFY else None
            hold = self._hold_ned_m if hop is None else hop
            vdx = ka * (float(hold[0]) - ref.p[0])
            vdy = ka * (float(hold[1]) - ref.p[1])
            vdz = DESCENT_MPS if self.phase == CorePhase.DESCEND else self._vertical_speed(float(hold[2]))
        if dt > 0.0:
            ref.step((vdx, vdy, vdz), dt)
        return f_att, f_rep, plan_mode, None

    def _plan_timed(self, est: Estimate, obs: Sequence[Obstacle], swing: np.ndarray | None, r_max: float, z: float,
                    dt: float) -> PlanOutput:
        """Cruise / hold / no_route / done with a time-parameterised planner: its horizontal reference, the
        vertical channel towards the goal's altitude (or held where it is after no route)."""
        m = self.mission
        ref = self.ref
        assert ref is not None
        goal, z_goal, legs_in, _ = leg_plan(self.legs, m, self._goal_xy, True)
        inp = PlanInput(
            t_s=est.t_s, pos_m=np.asarray(est.pos_ned_m[:2], dtype=np.float64),
            vel_mps=np.asarray(est.vel_ned_mps[:2], dtype=np.float64), ref_pos_m=np.array(ref.p[:2]),
            ref_vel_mps=np.array(ref.v[:2]), goal_m=goal, r_max_m=r_max, swing=swing,
            cable_l_m=self.params.l, airframe_r_m=self._airframe_r, g_mps2=self.params.g, z_ned_m=z,
            swing_sigma_rad=swing_sigma_rad(est), v_cap_mps=self.cap.cap_mps(est.pos_ned_m, est.vel_ned_mps, r_max),
            drift_ned_m=(0.0, 0.0) if swing is None else self.swing_bias.drift_ned_m(self.params.l),
            drag_c=0.0 if swing is None else self.drag_id.c, wind_mps=self.drag_id.wind_estimate,
            gust_drag_tan=0.0 if swing is None else self.drag_id.gust_drag_tan, **legs_in,
        )
        out = self.planner.plan(inp, obs)
        if out.no_route:
            self.no_route_here(est.t_s)
        r = out.reference
        assert r is not None
        self._swing_nom = r.swing_nom
        if dt > 0.0:
            if self.phase == CorePhase.DESCEND:
                ref.step_vertical(DESCENT_MPS, dt)
            else:
                z_target = z_goal if not (self.no_route or self._timed_stop) else ref.p[2]
                ref.step_vertical(self._vertical_speed(z_target), dt)
        ref.set_horizontal(r.pos_m, r.vel_mps, r.acc_mps2)
        return out

    def travel_headings_rad(self) -> tuple[float, ...]:
        """Where the pilot measures the seen-free distance (:func:`companion.planning.stop_cap.travel_headings_rad`)."""
        ref = self.ref
        goal = self.legs.current.pos_ned_m if self.legs is not None else self._goal_xy
        return travel_headings_rad(ref.p if ref is not None else self.mission.start_ned_m,
                                   ref.v if ref is not None else None, goal)

    def _acc_for_controller(self, out: PlanOutput, est: Estimate) -> list[float] | None:
        """The controller's reference acceleration with a timed plan (:func:`planned_swing_acc`), or None."""
        if not self.controller.swing_feedforward or est.swing_source not in ("cable_sensor", "estimate"):
            return None
        assert self.ref is not None
        return planned_swing_acc(out, self.ref.a, self._swing_trust(est), self.cfg.feedforward, self.params.l)

    def _swing_trust(self, est: Estimate) -> float:
        """How much of the swing the controller acts on (0..1): the estimate's ``swing_fade`` (1 for the cable
        sensor) times this tick's loop-lag trust."""
        fade = max(0.0, min(1.0, float(est.swing_fade))) if est.swing_source == "estimate" else 1.0
        return fade * self.lag_trust


_ZERO2 = np.zeros(2)
_ZERO2.flags.writeable = False

