"""The obstacles as the shaped planner checks its plans against them (:mod:`companion.planning.shaped`).

The route search sees static trunks as discs with route rings (envelope + margins); the time-aware plan check sees
every relevant trunk, still or moving, as :class:`~companion.planning.clearance.Predicted` rings for the airframe
and the payload. A search runs again when the set changes: :func:`obstacle_signature` identifies a set apart from
the motion of its moving trunks, :func:`moved_off_prediction` tells when one left its predicted track.
:class:`Replan` is what one replan checks its candidates against.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import NamedTuple

import numpy as np

from companion.core.obstacles import Obstacle
from companion.planning.base import PlanInput
from companion.planning.clearance import Predicted

#: the wind's drift of the payload (PlanInput.drift_ned_m) beyond DRIFT_SLACK_M (m; eq. 49's Table 2 forest: drift
#: <= 0.017 m) is budgeted DRIFT_SHIFT times downwind (:func:`route_shift_m`), and DRIFT_SPREAD times all round
#: (:func:`drift_margin_m`: the wind turns)
DRIFT_SHIFT, DRIFT_SPREAD, DRIFT_SLACK_M = 2.0, 0.5, 0.05

#: (m) a moving trunk this far off its predicted track makes the route search run again
OFF_TRACK_M = 0.05


def drift_margin_m(inp: PlanInput) -> float:
    """(m) what the wind adds all round to the static rings of the plan check, DRIFT_SPREAD x the payload's drift
    (from forces: a re-plan's swing is not in it) beyond the ordinary: the drift's direction turns with the gusts,
    and the airframe gives way to the payload while it changes (the anti-swing feed-forward: 0.27 m off its plan
    at a 0.5-1.3 m drift, issue 28). The payload's downwind part is :func:`route_shift_m`."""
    return max(0.0, DRIFT_SPREAD * inp.drift_m - DRIFT_SLACK_M)


def route_shift_m(inp: PlanInput) -> tuple[float, float]:
    """(m, NED x y) where the plan check and the route search expect the wind to hold the payload off the path
    planned for it: DRIFT_SHIFT x the drift vector beyond DRIFT_SLACK_M. Measured in a gust: the payload 1.6-1.9 x
    the drift off its planned point, and growing (issue 28, docs/measurements.md)."""
    dx, dy = inp.drift_ned_m
    d = (dx * dx + dy * dy) ** 0.5
    if d <= DRIFT_SLACK_M:
        return 0.0, 0.0
    budget = DRIFT_SHIFT * (d - DRIFT_SLACK_M)
    if inp.gust_drag_tan > 0.0:  # the drift in the gust the turbulence measured so far can bring
        gust = inp.cable_l_m * math.sin(math.atan(inp.gust_drag_tan))
        budget = max(budget, gust - DRIFT_SLACK_M)
    return budget * dx / d, budget * dy / d


class Rings(NamedTuple):
    """The obstacles as one replan sees them (m): the static trunks' centres ``c`` with their bare safety rings and
    contact radii (the airframe's: is there a route at all), the route search's discs (centres ``route_c``, radii
    ``route_ring``, ``route_bare`` and ``route_contact``: each around both the trunk's own and the same moved upwind
    by the payload's wind drift, :func:`route_shift_m`), the moving obstacles, and every obstacle the payload can
    reach as :class:`Predicted` for the time-aware plan check."""

    c: np.ndarray
    route_ring: np.ndarray
    bare: np.ndarray
    contact: np.ndarray
    moving: list[Obstacle]
    pred: Predicted
    route_c: np.ndarray
    route_bare: np.ndarray
    route_contact: np.ndarray


def obstacle_rings(inp: PlanInput, obstacles: Sequence[Obstacle], env_m: float, margin_m: float,
                   growth_mps: float) -> Rings:
    """The :class:`Rings` of ``obstacles``. ``env_m``: the envelope about the planned payload path; ``margin_m``:
    the tracking margin; ``growth_mps``: how fast a moving trunk's rings grow with the look-ahead."""
    r2 = inp.airframe_r_m
    reach_z = inp.z_ned_m + inp.cable_l_m
    rel = [o for o in obstacles if reach_z >= -o.height_m]
    static = [o for o in rel if o.vx_mps == 0.0 and o.vy_mps == 0.0]
    moving = [o for o in rel if not (o.vx_mps == 0.0 and o.vy_mps == 0.0)]
    c = np.array([(o.x_m, o.y_m) for o in static], dtype=np.float64).reshape(-1, 2)
    ro = np.array([o.radius_m for o in static], dtype=np.float64)
    sd = np.array([o.safe_distance_m for o in static], dtype=np.float64)
    ring = ro + sd + env_m + margin_m
    bare = ro + sd + r2 + 0.02
    contact = ro + r2
    sx, sy = route_shift_m(inp)
    route_c, route_ring, route_bare, route_contact = c, ring, bare, contact
    if sx != 0.0 or sy != 0.0:
        # the trunk's disc and the payload's, moved upwind by the shift: one disc around both
        half = 0.5 * (sx * sx + sy * sy) ** 0.5
        route_c = c - np.array([0.5 * sx, 0.5 * sy])
        route_ring, route_bare, route_contact = ring + half, bare + half, contact + half
    dm = drift_margin_m(inp)
    allo = static + moving
    is_m = np.array([False] * len(static) + [True] * len(moving), dtype=np.bool_)
    r_all = np.array([o.radius_m + o.safe_distance_m for o in allo], dtype=np.float64)
    pred = Predicted(
        cx=np.array([o.x_m for o in allo], dtype=np.float64), cy=np.array([o.y_m for o in allo], dtype=np.float64),
        vx=np.array([o.vx_mps for o in allo], dtype=np.float64),
        vy=np.array([o.vy_mps for o in allo], dtype=np.float64),
        # static: the bare safety ring plus what the wind's drag holds the payload off its path beyond the
        # ordinary (the airframe gives way to it as it changes); moving: plus the tracking margin, growing with
        # the look-ahead
        ring_airframe=r_all + r2 + np.where(is_m, margin_m, -0.01 + dm),
        ring_payload=r_all + np.where(is_m, margin_m, -0.01 + dm),
        growth=np.where(is_m, growth_mps, 0.0), moving=is_m, payload_shift=(sx, sy),
    )
    return Rings(c, route_ring, bare, contact, moving, pred, route_c, route_bare, route_contact)


def obstacle_signature(obstacles: Sequence[Obstacle]) -> tuple:
    """What identifies the obstacle set apart from the motion of the moving ones."""
    return tuple(sorted((o.radius_m, o.height_m, o.safe_distance_m, o.vx_mps, o.vy_mps)
                        + ((o.x_m, o.y_m) if o.vx_mps == 0.0 and o.vy_mps == 0.0 else ())
                        for o in obstacles))


def moved_off_prediction(old: Predicted, pred: Predicted, dt_s: float) -> bool:
    """Whether the moving trunks of ``pred`` are no longer those ``old`` predicted ``dt_s`` ago: another set of
    moving ones, or one more than :data:`OFF_TRACK_M` from every prediction. Obstacles keep their order in a list
    that did not change (the signature is sorted), so each current moving trunk is compared with its nearest
    prediction."""
    if not np.array_equal(old.moving, pred.moving):
        return True
    m = pred.moving
    px, py = old.cx[m] + old.vx[m] * dt_s, old.cy[m] + old.vy[m] * dt_s
    d = np.hypot(pred.cx[m][:, None] - px[None, :], pred.cy[m][:, None] - py[None, :])
    return bool(d.size and float(d.min(axis=1).max()) > OFF_TRACK_M)


class Replan(NamedTuple):
    """One replan's inputs: time (s), grid indices of now and of the splice, the unshaped state there (m, m/s), the
    goal and remaining vias (m) with their speed caps, the obstacles (:func:`obstacle_rings`) and the plan check
    ``check(shaped rows, base) -> (first conflict time per obstacle, worst clearance, last index)``."""

    t: float
    k_now: int
    k_r: int
    p0: np.ndarray
    v0: np.ndarray
    goal: np.ndarray
    vias: tuple
    caps: tuple
    rings: Rings
    check: Callable


class Searched(NamedTuple):
    """What the last route search saw: when (s), the obstacle set's signature, their predictions and the ring (m)."""

    t: float
    sig: tuple
    pred: Predicted | None
    ring_m: float

    def why_again(self, t: float, obstacles: Sequence[Obstacle], pred: Predicted, ring_m: float,
                  refresh_s: float) -> str | None:
        """Why the route search must run again — ``"changed"``: obstacles appeared, vanished or changed, a moving
        one is off its predicted track by more than 0.05 m, or the envelope or margin grew by more than 0.05 m;
        ``"refresh"``: ``refresh_s`` passed since the last search — or None."""
        if ring_m > self.ring_m + 0.05:
            return "changed"
        if obstacle_signature(obstacles) != self.sig:
            return "changed"
        old = self.pred
        if old is None or len(old) != len(pred):
            return "changed"
        if np.any(pred.moving) and moved_off_prediction(old, pred, t - self.t):
            return "changed"
        if t - self.t >= refresh_s - 1e-9:
            return "refresh"
        return None
