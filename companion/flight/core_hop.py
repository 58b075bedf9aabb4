"""The hop that identifies the payload before the cruise, when the mission says it is unknown
(``[payload] identify = true``), and what the flight core rebuilds when it learns the payload.

After the climb the core hovers over to a point up to :data:`HOP_M` towards its first target (phase
``identify``): the reference's own acceleration limits make it a step that swings the payload. The pilot keeps
the IMU and attitude from the hop's start for :data:`HOP_WINDOW_S` (the hop and the free swing after it), has
them identified beside the control loop, and hands the core the payload it found
(:meth:`HopMixin.end_identify`); the cruise starts from the hop's point with the planner, the controller, the
envelope and the swing-bounded accelerations rebuilt for it. The hop's length keeps the full-cable envelope
clear of every known trunk's safety ring; with less than :data:`MIN_HOP_M` of room it hovers in place (an
identification without excitation, which the verdict refuses: the flight keeps the declared payload).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence

import numpy as np

from companion.control import make_position_controller
from companion.control.adapt import adapt_to_payload
from companion.control.disturbance import ForceObserver
from companion.control.drag_id import DragIdentifier, declared_drag_c
from companion.control.swing_bias import SwingBias
from companion.core.envelope import full_cable_r_max_m
from companion.core.obstacles import Obstacle
from companion.core.vehicle_params import VehicleParams
from companion.estimation.estimate import Estimate
from companion.flight.phase import CorePhase
from companion.planning import make_planner
from companion.planning.shaping import pendulum_omega_rad_s, shaper_taus_s
from companion.planning.stop_cap import LATENCY_S, SeenCap

log = logging.getLogger(__name__)

HOP_M = 1.5  # the hop's length (m)
MIN_HOP_M = 0.5  # less room than this: no hop
HOP_WINDOW_S = 8.0  # IMU and attitude kept from the hop's start (s of vehicle time)
HOP_STEP_M = 0.05  # the room along the hop is checked every this far (m)
HOP_MARGIN_M = 0.1  # beyond the full-cable envelope and the trunk's safety ring (m)
SWING_READY_FADE = 0.9  # the swing estimate carries this much feed-forward: trusted enough to start the cruise


def hop_room_m(start_xy: np.ndarray, unit_xy: np.ndarray, obstacles: Sequence[Obstacle], clearance_m: float,
               max_m: float = HOP_M) -> float:
    """How far (m, at most ``max_m``) from ``start_xy`` along ``unit_xy`` every point stays more than
    ``clearance_m`` outside each obstacle's safety ring (radius + safe distance)."""
    room = 0.0
    for k in range(1, int(max_m / HOP_STEP_M) + 1):
        d = k * HOP_STEP_M
        px, py = start_xy[0] + d * unit_xy[0], start_xy[1] + d * unit_xy[1]
        if any(math.hypot(px - o.x_m, py - o.y_m) < o.radius_m + o.safe_distance_m + clearance_m for o in obstacles):
            break
        room = d
    return room


class HopMixin:
    """The flight core's identification hop, the climb's wait for a trusted swing estimate and payload adoption
    (mixed into :class:`~companion.flight.core.FlightCore`, whose attributes it uses)."""

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

    def _identify_done(self, est: Estimate) -> bool:
        """Whether the identify phase may end: identified, and the swing input ready (see :meth:`end_identify`)."""
        return self.hop_identified and self._swing_ready(est)

    def _after_climb(self) -> CorePhase:
        """The phase the climb ends in: ``identify`` once when the mission asks for it, else ``cruise``."""
        if self.mission.payload.identify and self.hop_target_ned_m is None:
            return CorePhase.IDENTIFY
        return CorePhase.CRUISE

    def _plan_hop(self, obstacles: Sequence[Obstacle]) -> None:
        """Where the hop goes, on the identify phase's first tick: towards the first target, as far as the
        full-cable envelope stays clear of ``obstacles`` (the ones the core flies around now)."""
        ref = self.ref
        start = np.array(ref.p[:2], dtype=np.float64)
        target = self.legs.current.pos_ned_m[:2] if self.legs is not None else self._goal_xy
        span = float(np.hypot(*(target - start)))
        unit = (target - start) / span if span > 1e-6 else np.array([1.0, 0.0])
        clearance = self._airframe_r + self._full_cable_r_max + HOP_MARGIN_M
        d = min(hop_room_m(start, unit, obstacles, clearance), span)
        if d < MIN_HOP_M:
            log.warning("no room for the identification hop (%.2f m clear); identifying at a hover", d)
            d = 0.0
        else:
            log.info("identification hop: %.2f m towards (%.1f, %.1f)", d, target[0], target[1])
        self.hop_length_m = round(d, 3)
        self.hop_target_ned_m = np.array([start[0] + d * unit[0], start[1] + d * unit[1], ref.p[2]])

    def end_identify(self, params: VehicleParams | None) -> None:
        """The identification is over: fly on with ``params`` (None: the payload the core had). The cruise starts
        once the swing input is ready again (a swing estimator restarted on the identified payload must earn its
        trust first, as after the climb: cruising off on an untrusted estimate swung ArduCopter's payload into the
        trunks)."""
        if params is not None:
            self.adopt_payload(params)
        self.hop_identified = True
        self.t_swing_wait_s = None

    def _build(self, params: VehicleParams, believed: VehicleParams) -> None:
        """The parts that follow the payload: ``params`` the model flown (planner, controller, thrust limits,
        envelope, the swing's wind equilibrium), ``believed`` the payload the swing-bounded accelerations are
        scaled for."""
        self.cfg = adapt_to_payload(self._gains, believed)
        self.params = params
        self.planner = make_planner(self.mission.planner, self.cfg.planner, params)
        self._timed = self.planner.time_parameterised
        self.controller = make_position_controller(self.mission.controller, self.cfg, params)
        hover = params.hover_thrust_n
        self._thrust_min = self.cfg.limits.thrust_min_frac * hover
        self._thrust_max = self.cfg.limits.thrust_max_frac * hover
        self._full_cable_r_max = full_cable_r_max_m(params)
        self.swing_bias = SwingBias(params.g / pendulum_omega_rad_s(params, "held") ** 2, params.g,
                                    self.cfg.feedforward.rate_filter_s)
        self.push = ForceObserver(params.M + params.m, params.m, params.l, self.cfg.feedforward.rate_filter_s,
                                  airframe_drag_declared=self.mission.payload.airframe_drag_n_per_mps2 > 0.0)
        pay = self.mission.payload
        self.drag_id = DragIdentifier(c_declared=declared_drag_c(pay.drag_n_per_mps2, params.m, params.g),
                                      k_airframe=pay.airframe_drag_n_per_mps2, m_total_kg=params.M + params.m,
                                      payload_weight_n=params.m * params.g)
        self._airframe_r = params.r_uav + params.L_uav
        # the speed cap inside the space the range sensor saw free: what passes before a lower cap takes effect is
        # a scan, a re-plan, and the reference's lag behind the plan (shaped: half its shapers' widths; a velocity
        # planner's reference lags its desired velocity: the safe planner's goal braking looks goal_lookahead_s ahead)
        pl = self.cfg.planner
        taus = shaper_taus_s(pl.shaper_tau_s, pendulum_omega_rad_s(params, "held"), pl.shaper_period_s)
        self.cap = SeenCap(pl.shaped_a_max_mps2 if self._timed else pl.a_goal_mps2,
                           LATENCY_S + (0.5 * sum(taus) if self._timed else pl.goal_lookahead_s),
                           self._airframe_r)

    def adopt_payload(self, params: VehicleParams) -> None:
        """Fly on with ``params`` (the identified payload) from the next tick; the reference goes on from where
        it is."""
        log.info("flying on with the identified payload: %.3f kg on %.2f m", params.m, params.l)
        seen = self.cap.seen
        self._build(params, params)
        self.cap.seen = seen
