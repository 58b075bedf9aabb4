"""What the 3-D view draws, as pure geometry (numpy only): entity paths, colours, airframe, envelope, trunks.

Everything is in the autopilot's local NED frame, metres, as the companion flies it; the view declares
``world`` as right-handed Z-down, so altitude points up on screen. Trunks stand on the ground (z = 0) up to
z = −height. The swing envelope is drawn as a cylinder of radius R_max (eq. 21) around the vehicle, from the
airframe down to the cable's length: its geometry is a unit circle that the view scales by R_max per frame.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from companion.core.obstacles import Obstacle

# ---- entity paths (a vehicle's own subtree in the fleet view is ``world/<id>/...`` and ``plots/<id>/...``)
WORLD = "world"
UAV = "uav"                 # Transform3D: translation = position, rotation = attitude (body FRD → NED)
AIRFRAME = "uav/airframe"   # static: arms and rotor circles in the body frame
ENVELOPE = "envelope"       # Transform3D: translation = position, scale = (R_max, R_max, 1)
ENVELOPE_SHAPE = "envelope/cylinder"  # static: unit circles at the airframe and at the cable's length
PAYLOAD = "payload"
CABLE = "cable"
REFERENCE = "reference"
PATHS = "path"              # path/<flown|payload|reference>/<segment>
TRUNKS = "trunks"           # trunks/mission, trunks/live, trunks/gone
MISSION = "mission"         # mission/start, mission/goal

# ---- colours (RGB)
RGB_AIRFRAME = (30, 30, 30)
RGB_UAV = (31, 119, 180)
RGB_PAYLOAD = (214, 39, 40)
RGB_ENVELOPE = (31, 119, 180)
RGB_REFERENCE = (150, 150, 150)
RGB_TRUNK_MISSION = (139, 69, 19)
RGB_TRUNK_LIVE = (255, 127, 14)
RGB_TRUNK_GONE = (120, 120, 120)
RGB_SAFE_RING = (139, 69, 19)
RGB_START = (20, 20, 20)
RGB_GOAL = (44, 160, 44)


def circle_xy(n: int = 48) -> np.ndarray:
    """(n + 1, 2) points of the closed unit circle."""
    th = np.linspace(0.0, 2.0 * math.pi, n + 1)
    return np.column_stack([np.cos(th), np.sin(th)])


def airframe_strips(r_uav_m: float, L_uav_m: float, n: int = 24) -> list[np.ndarray]:
    """Line strips of the airframe in the body FRD frame (m): an X of arms of length ``r_uav_m`` and a rotor
    circle of radius ``L_uav_m`` at each arm tip (eq. 20's r_uav and L_uav)."""
    strips: list[np.ndarray] = []
    c = circle_xy(n)
    for k in range(4):
        ang = math.pi / 4 + k * math.pi / 2
        tip = np.array([r_uav_m * math.cos(ang), r_uav_m * math.sin(ang), 0.0])
        strips.append(np.array([[0.0, 0.0, 0.0], tip]))
        strips.append(np.column_stack([tip[0] + L_uav_m * c[:, 0], tip[1] + L_uav_m * c[:, 1], np.zeros(len(c))]))
    return strips


def envelope_strips(cable_l_m: float, n: int = 48, verticals: int = 8) -> list[np.ndarray]:
    """Wire frame of a unit-radius cylinder from z = 0 (the airframe) down to z = ``cable_l_m`` (NED, m):
    two circles and ``verticals`` lines. Scaled by (R_max, R_max, 1) it is the swing envelope."""
    c = circle_xy(n)
    top = np.column_stack([c, np.zeros(len(c))])
    bottom = np.column_stack([c, np.full(len(c), cable_l_m)])
    strips = [top, bottom]
    for k in range(verticals):
        ang = 2.0 * math.pi * k / verticals
        x, y = math.cos(ang), math.sin(ang)
        strips.append(np.array([[x, y, 0.0], [x, y, cable_l_m]]))
    return strips


def quat_xyzw_from_euler(euler_rad: np.ndarray) -> np.ndarray:
    """(N, 4) quaternions [x, y, z, w] (body FRD → NED, Rerun's order) of (N, 3) ZYX Euler angles [φ, θ, ψ]
    (rad); the vectorised form of :func:`companion.core.rotations.quat_from_euler` (which returns w first)."""
    e = np.atleast_2d(np.asarray(euler_rad, dtype=np.float64))
    cr, sr = np.cos(0.5 * e[:, 0]), np.sin(0.5 * e[:, 0])
    cp, sp = np.cos(0.5 * e[:, 1]), np.sin(0.5 * e[:, 1])
    cy, sy = np.cos(0.5 * e[:, 2]), np.sin(0.5 * e[:, 2])
    w = cr * cp * cy + sr * sp * sy
    x = sr * cp * cy - cr * sp * sy
    y = cr * sp * cy + sr * cp * sy
    z = cr * cp * sy - sr * sp * cy
    return np.column_stack([x, y, z, w])


def payload_pos_ned_m(pos_ned_m: np.ndarray, alpha_rad: np.ndarray, beta_rad: np.ndarray, l_m: float) -> np.ndarray:
    """(N, 3) payload positions (NED, m) from (N, 3) airframe positions and swing angles (rad): eqs. 3–4,
    ξ_p = ξ + l·[sα·cβ, −sβ, cα·cβ], vectorised (:func:`companion.core.model.payload_offset_ned_m` per row)."""
    a = np.asarray(alpha_rad, dtype=np.float64)
    b = np.asarray(beta_rad, dtype=np.float64)
    off = l_m * np.column_stack([np.sin(a) * np.cos(b), -np.sin(b), np.cos(a) * np.cos(b)])
    return np.asarray(pos_ned_m, dtype=np.float64) + off


@dataclass(frozen=True)
class TrunkArrays:
    """Trunks as the view's cylinder batch: centres (N, 3) NED m (mid-height), lengths and radii (N,) m,
    safe-distance radii (N,) m, labels (N,) (where the trunk came from)."""

    centers: np.ndarray
    lengths: np.ndarray
    radii: np.ndarray
    safe_radii: np.ndarray
    labels: list[str]

    def __len__(self) -> int:
        return len(self.labels)


def trunk_arrays(obstacles: Sequence[Obstacle]) -> TrunkArrays:
    """The cylinders of ``obstacles`` (each standing on z = 0 up to z = −height) with ``source`` labels."""
    n = len(obstacles)
    centers = np.zeros((n, 3))
    lengths = np.zeros(n)
    radii = np.zeros(n)
    safe = np.zeros(n)
    labels = []
    for i, o in enumerate(obstacles):
        centers[i] = (o.x_m, o.y_m, -0.5 * o.height_m)
        lengths[i] = o.height_m
        radii[i] = o.radius_m
        safe[i] = o.radius_m + o.safe_distance_m
        labels.append(o.source)
    return TrunkArrays(centers, lengths, radii, safe, labels)


def split_trunks(
    seen: Sequence[Obstacle], current: Sequence[Obstacle] | None
) -> tuple[list[Obstacle], list[Obstacle], list[Obstacle]]:
    """(mission, live, gone): the mission's own trunks; live trunks in the current set (every non-mission
    trunk seen when ``current`` is None: nothing tells them apart then); and the trunks of live publishers
    that have nothing in the current set any more (expired or withdrawn). A publisher that still publishes
    has only its current trunks drawn, so a moving trunk leaves no trail."""
    mission = [o for o in seen if o.source == "mission"]
    live_seen = [o for o in seen if o.source != "mission"]
    if current is None:
        return mission, live_seen, []
    live = [o for o in current if o.source != "mission"]
    sources_now = {o.source for o in live}
    gone = [o for o in live_seen if o.source not in sources_now]
    return mission, live, gone
