"""A bounded, persistent map of the trunks the scans showed (pure: numpy only).

Each track is a small Kalman filter on (north, east, v_north, v_east) (m, m/s; constant velocity with white
acceleration noise ``accel_sigma_mps2``) plus a radius averaged by its uncertainty. Per scan:

- **predict** every track to the scan's time;
- **associate** detections to tracks, gated nearest neighbour: pairs by increasing Mahalanobis distance of the
  centres (χ² gate for 2 dof, or within the two radii plus :data:`GATE_M` for a track still uncertain), each
  track and detection used once; a detection left over starts a tentative track (at most ``max_tracks``: beyond,
  counted in ``full``);
- **confirm** a track after ``confirm_hits`` hits, or after two when they show it moving (its speed above 3σ of
  its uncertainty: a trunk crossing the path, often hidden again behind a nearer one before a third scan sees it,
  is worth publishing early with its velocity); only confirmed tracks are published;
- **retire** a track unseen in ``retire_misses`` scans *that could have seen it*: its centre within range and the
  ray towards it passing beyond its near side (free space where it should stand). A trunk behind another one, or
  out of range, is occluded, not missed. A tentative track unseen for ``tentative_s`` goes too.

Published (:attr:`LocalMap.obstacles`) as :class:`~companion.core.obstacles.Obstacle` with ``source="perception"``,
radius inflated by ``inflate_k`` × its 1σ (centre and radius), and its velocity where it is significant (above 2σ).
:meth:`LocalMap.free_distance_m` answers how far the last scan saw free along a heading.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass

import numpy as np

from companion.core.obstacles import Obstacle
from companion.perception.clusters import Detection
from companion.perception.points import ScanPoints
from companion.perception.visibility import free_distance_m, in_view_many

CHI2_GATE_2DOF = 9.21  # 99 %
GATE_M = 0.5  # Euclidean gate beyond the two radii (m)
MAX_GATE_M = 1.0  # never further (m): an uncertain track (unseen for long) must not take a neighbour's detection
MAX_SIGMA_M = 0.15  # the 1σ an inflation uses at most (m): a trunk unseen for long keeps growing in its filter
STILL_DRIFT_M2_PER_S = 1e-4  # a still trunk's centre variance grows this much per second unseen (m²/s)
MIN_SPEED_MPS = 0.2  # a trunk slower than this is published still (m/s)
ADVANCE_STEP_S = 0.05  # moving trunks are advanced in steps of this much vehicle time (s)
PUBLISH_STEP_M = 0.03  # a published trunk is replaced when its estimate moved this much (m, m/s)
MIN_HEIGHT_M = 1.0


@dataclass
class Track:
    """One trunk tracked by two models: ``x`` constant-velocity state (north, east, vn, ve) and ``p`` its 4×4
    covariance, ``xs``/``ps`` a still trunk's centre and covariance; radius and its variance,
    hits, misses in view since the last hit, the last time seen (s), the returns' mean NED height (m) and the highest
    point seen on it (m above the ground: its published height is 1 m more)."""

    id: int
    x: np.ndarray
    p: np.ndarray
    radius_m: float
    radius_var: float
    t_s: float
    last_seen_s: float
    z_m: float
    top_m: float = 0.0  # the highest point seen on it, above the ground (m)
    xs: np.ndarray | None = None  # the still model: centre (m) ...
    ps: np.ndarray | None = None  # ... and its 2×2 covariance (m²)
    hits: int = 1
    misses: int = 0
    confirmed: bool = False

    def __post_init__(self) -> None:
        if self.xs is None:
            self.xs, self.ps = self.x[:2].copy(), self.p[:2, :2].copy()

    @property
    def moving(self) -> bool:
        """Its speed stands out of its uncertainty (3σ) and reaches :data:`MIN_SPEED_MPS`."""
        return _significant(self)

    @property
    def pos(self) -> np.ndarray:
        """The centre (north, east; m): the constant-velocity model's when it moves, else the still model's."""
        return self.x[:2] if self.moving else self.xs

    @property
    def pos_cov(self) -> np.ndarray:
        """The centre's 2×2 covariance (m²), of the model :attr:`pos` is from."""
        return self.p[:2, :2] if self.moving else self.ps


class LocalMap:
    """Tracks from :class:`Detection` s; :meth:`update` per scan, :attr:`obstacles` the confirmed ones."""

    def __init__(self, confirm_hits: int = 3, retire_misses: int = 5, max_tracks: int = 256,
                 accel_sigma_mps2: float = 0.1, inflate_k: float = 2.0, tentative_s: float = 2.0,
                 safe_distance_m: float = 0.1) -> None:
        self.confirm_hits = confirm_hits
        self.retire_misses = retire_misses
        self.max_tracks = max_tracks
        self.q = accel_sigma_mps2 ** 2
        self.inflate_k = inflate_k
        self.tentative_s = tentative_s
        self.safe_distance_m = safe_distance_m
        self.tracks: dict[int, Track] = {}
        self.counts: Counter[str] = Counter()  # born, confirmed, retired, full, ...
        self.obstacles: tuple[Obstacle, ...] = ()
        self._published: dict[int, tuple[Obstacle, float]] = {}  # track id → (obstacle, time published, s)
        self._times: tuple[float, ...] = ()  # per obstacle: when it was published (s)
        self._moving = False
        self._advanced: tuple[float, tuple[Obstacle, ...] | None, tuple[Obstacle, ...]] = (math.nan, None, ())
        self.version = 0
        self.last: ScanPoints | None = None
        self._next_id = 1

    # ------------------------------------------------------------------ per scan
    def update(self, dets: list[Detection], pts: ScanPoints) -> None:
        """Fold one scan's detections in (``pts``: the same scan, for what it saw free)."""
        t = pts.t_s
        n = len(dets)
        dets = _distinct(dets)
        self.counts["duplicate_detections"] += n - len(dets)
        for tr in self.tracks.values():
            self._predict(tr, t)
        used = self._associate(dets)
        seen = set(used.values())
        unseen = [tr for tid, tr in self.tracks.items() if tid not in seen]
        if unseen:
            view = in_view_many(pts, np.array([tr.pos[0] for tr in unseen]), np.array([tr.pos[1] for tr in unseen]),
                                np.array([tr.radius_m for tr in unseen]), np.array([tr.z_m for tr in unseen]))
            for tr, v in zip(unseen, view.tolist(), strict=True):
                self._unseen(tr, pts, v)
        for k, det in enumerate(dets):
            if k not in used:
                self._birth(det, t)
        self._merge_overlaps()
        self.last = pts
        self._publish()

    def _merge_overlaps(self) -> None:
        """Two tracks whose trunks would overlap are one trunk seen twice (an arc split in two, a detection that
        missed its gate): the one with fewer hits goes (counted ``merged``)."""
        if len(self.tracks) < 2:
            return
        trs = list(self.tracks.values())
        xy = np.array([tr.pos for tr in trs])
        r = np.array([tr.radius_m for tr in trs])
        d = np.hypot(xy[:, None, 0] - xy[None, :, 0], xy[:, None, 1] - xy[None, :, 1])
        over = np.triu(d < np.minimum(r[:, None], r[None, :]) + 0.05, 1)  # a centre inside the other trunk
        for i, j in zip(*np.nonzero(over), strict=True):
            a, b = trs[int(i)], trs[int(j)]
            if a.id not in self.tracks or b.id not in self.tracks:
                continue
            loser = b if (a.hits, -a.id) >= (b.hits, -b.id) else a
            self._retire(loser, "merged")

    def _predict(self, tr: Track, t: float) -> None:
        dt = t - tr.t_s
        if dt <= 0.0:
            return
        f, q = _transition(dt, self.q)
        tr.x = f @ tr.x
        tr.p = f @ tr.p @ f.T + q
        tr.ps = tr.ps + np.eye(2) * (STILL_DRIFT_M2_PER_S * dt)  # the still model: it neither walks nor blurs
        tr.t_s = t

    def _associate(self, dets: list[Detection]) -> dict[int, int]:
        """Detection index → track id, gated nearest neighbour (greedy by Mahalanobis distance)."""
        if not dets or not self.tracks:
            return {}
        trs = list(self.tracks.values())
        tx = np.array([tr.pos for tr in trs])  # (T, 2)
        tp = np.array([tr.pos_cov for tr in trs])  # (T, 2, 2)
        tr_r = np.array([tr.radius_m for tr in trs])
        dx = np.array([[d.x_m, d.y_m] for d in dets])  # (D, 2)
        dc = np.array([d.cov_xy for d in dets])  # (D, 2, 2)
        d_r = np.array([d.radius_m for d in dets])
        dz = dx[None, :, :] - tx[:, None, :]  # (T, D, 2)
        s = tp[:, None] + dc[None, :]  # (T, D, 2, 2)
        a, b, c = s[..., 0, 0], s[..., 0, 1], s[..., 1, 1]
        det = a * c - b * b
        with np.errstate(divide="ignore", invalid="ignore"):
            m2 = (c * dz[..., 0] ** 2 - 2.0 * b * dz[..., 0] * dz[..., 1] + a * dz[..., 1] ** 2) / det
        m2 = np.where(det > 0.0, m2, np.inf)
        dist = np.hypot(dz[..., 0], dz[..., 1])
        ok = ((m2 <= CHI2_GATE_2DOF) | (dist <= GATE_M + 0.5 * (tr_r[:, None] + d_r[None, :]))) & (dist <= MAX_GATE_M)
        ti, di = np.nonzero(ok)
        order = np.lexsort((dist[ti, di], m2[ti, di]))
        used: dict[int, int] = {}
        taken: set[int] = set()
        for n in order.tolist():
            k, tid = int(di[n]), trs[int(ti[n])].id
            if k in used or tid in taken:
                continue
            used[k] = tid
            taken.add(tid)
            self._correct(self.tracks[tid], dets[k])
        return used

    def _correct(self, tr: Track, det: Detection) -> None:
        s = tr.p[:2, :2] + det.cov_xy  # H = [I 0]: the position is measured
        a, b, c, d = float(s[0, 0]), float(s[0, 1]), float(s[1, 0]), float(s[1, 1])
        det_s = a * d - b * c
        s_inv = np.array([[d, -b], [-c, a]]) / det_s
        k = tr.p[:, :2] @ s_inv
        z = np.array([det.x_m, det.y_m])
        tr.x = tr.x + k @ (z - tr.x[:2])
        tr.p = tr.p - k @ tr.p[:2, :]
        ks = tr.ps @ np.linalg.inv(tr.ps + det.cov_xy)  # the still model
        tr.xs = tr.xs + ks @ (z - tr.xs)
        tr.ps = tr.ps - ks @ tr.ps
        rv = max(det.radius_sigma_m ** 2, 1e-6)
        w = tr.radius_var / (tr.radius_var + rv)
        tr.radius_m += w * (det.radius_m - tr.radius_m)
        tr.radius_var = tr.radius_var * rv / (tr.radius_var + rv)
        tr.z_m += (det.z_m - tr.z_m) / min(tr.hits + 1, 20)
        tr.top_m = max(tr.top_m, -det.z_m)
        tr.hits += 1
        tr.misses = 0
        tr.last_seen_s = tr.t_s
        if not tr.confirmed and (tr.hits >= self.confirm_hits or (tr.hits >= 2 and tr.moving)):
            tr.confirmed = True
            self.counts["confirmed"] += 1

    def _birth(self, det: Detection, t: float) -> None:
        if len(self.tracks) >= self.max_tracks:
            self.counts["full"] += 1
            return
        p = np.zeros((4, 4))
        p[:2, :2] = det.cov_xy
        p[2, 2] = p[3, 3] = 1.0  # (1 m/s)² before any motion is seen
        tr = Track(self._next_id, np.array([det.x_m, det.y_m, 0.0, 0.0]), p, det.radius_m,
                   max(det.radius_sigma_m ** 2, 1e-6), t, t, det.z_m, -det.z_m)
        self._next_id += 1
        self.tracks[tr.id] = tr
        self.counts["born"] += 1
        if self.confirm_hits <= 1:
            tr.confirmed = True
            self.counts["confirmed"] += 1

    def _unseen(self, tr: Track, pts: ScanPoints, visible: bool) -> None:
        """A track no detection matched: a miss if the scan could see it (``visible``); retired after enough
        misses."""
        if not tr.confirmed and pts.t_s - tr.last_seen_s > self.tentative_s:
            self._retire(tr, "retired_tentative")
            return
        if visible:
            tr.misses += 1
            if tr.misses >= self.retire_misses:
                self._retire(tr, "retired")
        else:
            self.counts["unseen_out_of_view"] += 1

    def _retire(self, tr: Track, why: str) -> None:
        del self.tracks[tr.id]
        self.counts[why] += 1

    def _publish(self) -> None:
        """Rebuild :attr:`obstacles` from the confirmed tracks. A trunk's published obstacle changes only when its
        estimate moved by :data:`PUBLISH_STEP_M` or more (centre, radius, or velocity in m/s): a still trunk keeps
        the same obstacle, and while none changed the same tuple, so the planners' caches hold."""
        t = self.last.t_s if self.last is not None else 0.0
        out: list[Obstacle] = []
        times: list[float] = []
        changed = False
        for tr in self.tracks.values():
            if not tr.confirmed:
                continue
            cand = self._obstacle(tr)
            old = self._published.get(tr.id)
            if old is None or _moved(old[0].at_time(t - old[1]), cand):  # a moving one compared where it is now
                old = self._published[tr.id] = (cand, t)
                changed = True
            out.append(old[0])
            times.append(old[1])
        if len(self._published) != len(out):
            live = {tr.id for tr in self.tracks.values() if tr.confirmed}
            self._published = {k: v for k, v in self._published.items() if k in live}
            changed = True
        if changed:
            self.obstacles = tuple(out)
            self._times = tuple(times)
            self._moving = any(o.vx_mps != 0.0 or o.vy_mps != 0.0 for o in out)
            self.version += 1

    def obstacles_at(self, t_s: float) -> tuple[Obstacle, ...]:
        """:attr:`obstacles` with the moving ones advanced from the time each was published to ``t_s`` (s, vehicle
        time) rounded down to :data:`ADVANCE_STEP_S` (the planner re-reads a changed set: per tick was costly); the
        same tuple while none moves."""
        if not self._moving:
            return self.obstacles
        tq = math.floor(t_s / ADVANCE_STEP_S) * ADVANCE_STEP_S  # a new set at most 20 times a second, not per tick
        if self._advanced[0] != tq or self._advanced[1] is not self.obstacles:
            moved = tuple(o.at_time(max(0.0, tq - t0)) for o, t0 in zip(self.obstacles, self._times, strict=True))
            self._advanced = (tq, self.obstacles, moved)
        return self._advanced[2]

    def _obstacle(self, tr: Track) -> Obstacle:
        sig = math.sqrt(_max_eig2(tr.pos_cov) + tr.radius_var)
        r = min(tr.radius_m + self.inflate_k * min(sig, MAX_SIGMA_M), Obstacle.MAX_RADIUS_M)
        vn, ve = float(tr.x[2]), float(tr.x[3])
        if not _significant(tr) or math.hypot(vn, ve) > Obstacle.MAX_SPEED_MPS:
            vn = ve = 0.0
        height = min(max(tr.top_m + 1.0, MIN_HEIGHT_M), Obstacle.MAX_HEIGHT_M)
        return Obstacle(float(tr.pos[0]), float(tr.pos[1]), max(r, 0.01), height, self.safe_distance_m, vn, ve,
                        "perception")

    # ------------------------------------------------------------------ free space
    def free_distance_m(self, from_xy: tuple[float, float], heading_rad: float, max_m: float | None = None) -> float:
        """How far (m) from ``from_xy`` (mission frame north, east; m) along ``heading_rad`` (from north, clockwise)
        the last scan saw free (:func:`~companion.perception.visibility.free_distance_m`; 0 before any scan)."""
        return 0.0 if self.last is None else free_distance_m(self.last, from_xy, heading_rad, max_m)


def _moved(old: Obstacle, new: Obstacle) -> bool:
    """Whether ``new`` differs from ``old`` by :data:`PUBLISH_STEP_M` or more (centre, radius growth, velocity),
    by twice that (radius shrinking) or by 0.5 m in height."""
    step = PUBLISH_STEP_M
    return (math.hypot(new.x_m - old.x_m, new.y_m - old.y_m) >= step
            or not -2.0 * step < new.radius_m - old.radius_m < step  # growing counts sooner than shrinking
            or math.hypot(new.vx_mps - old.vx_mps, new.vy_mps - old.vy_mps) >= step
            or (new.vx_mps == 0.0 and new.vy_mps == 0.0) != (old.vx_mps == 0.0 and old.vy_mps == 0.0)
            or abs(new.height_m - old.height_m) >= 0.5)


def _significant(tr: Track) -> bool:
    """Whether a track moves: its speed stands out of its uncertainty (above 3σ) and reaches :data:`MIN_SPEED_MPS`
    (a still trunk's estimate wanders by a few cm/s)."""
    v2 = float(tr.x[2]) ** 2 + float(tr.x[3]) ** 2
    return v2 > max(9.0 * float(tr.p[2, 2] + tr.p[3, 3]), MIN_SPEED_MPS ** 2)


def _distinct(dets: list[Detection]) -> list[Detection]:
    """One detection per trunk: of two whose centres lie inside each other's circle (one arc split in two
    segments), the one with more returns."""
    out: list[Detection] = []
    for d in sorted(dets, key=lambda d: -d.n_points):
        if all(math.hypot(d.x_m - o.x_m, d.y_m - o.y_m) >= min(d.radius_m, o.radius_m) + 0.05 for o in out):
            out.append(d)
    return out


_TRANSITIONS: dict[tuple[float, float], tuple[np.ndarray, np.ndarray]] = {}


def _transition(dt: float, q: float) -> tuple[np.ndarray, np.ndarray]:
    """The constant-velocity transition over ``dt`` (s) and its process noise for acceleration variance ``q``
    ((m/s²)²); cached: every track is predicted over the same scan interval."""
    key = (dt, q)
    hit = _TRANSITIONS.get(key)
    if hit is None:
        f = np.eye(4)
        f[0, 2] = f[1, 3] = dt
        g = np.array([[0.5 * dt * dt, 0.0], [0.0, 0.5 * dt * dt], [dt, 0.0], [0.0, dt]])
        if len(_TRANSITIONS) > 64:
            _TRANSITIONS.clear()
        hit = _TRANSITIONS[key] = (f, q * (g @ g.T))
    return hit


def _max_eig2(p: np.ndarray) -> float:
    """The larger eigenvalue of ``p``'s upper-left 2×2 block (symmetric; m²), at least 0."""
    a, b, d = float(p[0, 0]), float(p[0, 1]), float(p[1, 1])
    return max(0.5 * (a + d) + math.sqrt(0.25 * (a - d) ** 2 + b * b), 0.0)
