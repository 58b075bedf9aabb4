"""Scoring a blind flight's map against the world's trunks (pure: numpy only).

Used by ``slungpilot evaluate --perception`` (:mod:`lab.perception_eval`); defined here so that the definitions
are tested on synthetic inputs.

* **Could it have been seen** (:func:`sightable`): a true trunk counts for recall when, from the flown path (the
  logged vehicle positions above ``min_alt_m``, sampled every ``sample_s``), it stood within the sensor's range
  (its near side within ``range_m``), subtended at least :data:`MIN_RAYS` rays of the sensor's angular step (the
  clusterer fits no circle to fewer returns), and the straight line from the vehicle to its near side passed no
  other trunk (2-D line of sight: a trunk behind another is occluded), for at least ``min_time_s`` of flight in
  all (the map confirms a trunk after a few scans). Moving trunks block the line where they are at that time.
  The sensor's tilt is ignored: a scan tilted into the ground or over a short trunk saw less than this says.
* **Matching** (:func:`match_trunks`): the map's final trunks to the static true trunks, greedily by increasing
  centre distance, each used once, a pair only within ``match_m``. Precision = matched map trunks / map trunks
  that are not a moving trunk (a map trunk within ``mover_m`` of a moving trunk's straight track is that trunk
  seen in passing, counted apart); recall = matched sightable trunks / sightable trunks. Centre error = distance
  between matched centres (m); radius error = map radius (as fitted, not inflated) − true radius (m).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

MATCH_M = 0.3  # a map trunk matches a true trunk whose centre is within this (m)
MOVER_M = 0.5  # a map trunk this close (m) to a moving trunk's track is that trunk seen in passing
MIN_RAYS = 3  # rays a trunk must subtend to be fitted (the clusterer's MIN_POINTS)
SAMPLE_S = 0.1  # the path is sampled at the LiDAR's default rate (s)
MIN_TIME_S = 0.5  # in range and sight this long (s) in all, to count for recall
MIN_ALT_M = 1.0  # below this height (m) the scan is near the ground: not counted


def _sample(t_s: np.ndarray, pos_ned_m: np.ndarray, sample_s: float, min_alt_m: float) -> tuple[np.ndarray,
                                                                                                   np.ndarray]:
    """The rows (times s, positions m) every ``sample_s`` with the vehicle above ``min_alt_m``."""
    keep = -pos_ned_m[:, 2] >= min_alt_m
    t, p = t_s[keep], pos_ned_m[keep]
    if t.size == 0:
        return t, p
    grid = np.arange(t[0], t[-1] + 1e-9, sample_s)
    idx = np.clip(np.searchsorted(t, grid), 0, t.size - 1)
    return t[idx], p[idx]


def sightable(trunks: Sequence[Any], t_s: np.ndarray, pos_ned_m: np.ndarray, *, range_m: float = 12.0,
              step_deg: float = 1.0, sample_s: float = SAMPLE_S, min_time_s: float = MIN_TIME_S,
              min_alt_m: float = MIN_ALT_M) -> np.ndarray:
    """Per trunk (objects with ``x_m, y_m, radius_m, vx_mps, vy_mps``; positions at vehicle time 0, m, m/s): could
    the sensor have seen it from the flown path (vehicle times ``t_s`` s, NED positions m)? See module docstring.
    Moving trunks get a verdict too (they are usually left out of recall by the caller)."""
    n = len(trunks)
    if n == 0:
        return np.zeros(0, dtype=bool)
    ts, ps = _sample(np.asarray(t_s, float), np.asarray(pos_ned_m, float), sample_s, min_alt_m)
    if ts.size == 0:
        return np.zeros(n, dtype=bool)
    x0 = np.array([[o.x_m, o.y_m] for o in trunks])
    v = np.array([[o.vx_mps, o.vy_mps] for o in trunks])
    r = np.array([o.radius_m for o in trunks])
    c = x0[None, :, :] + ts[:, None, None] * v[None, :, :]  # (S, T, 2) centres at each sample
    rel = c - ps[:, None, :2]  # vehicle → centre
    d = np.hypot(rel[..., 0], rel[..., 1])  # (S, T)
    near = d - r[None, :]
    wide = 2.0 * np.arcsin(np.clip(r[None, :] / np.maximum(d, 1e-9), 0.0, 1.0)) >= MIN_RAYS * math.radians(step_deg)
    ok = (near <= range_m) & (near > 0.0) & wide
    u = rel / np.maximum(d, 1e-9)[..., None]  # unit vectors (S, T, 2)
    # for each (sample, target i, blocker j): the blocker's centre along and across the line to target i
    along = np.einsum("sik,sjk->sij", u, rel)
    across = np.abs(u[..., 0][:, :, None] * rel[..., 1][:, None, :] - u[..., 1][:, :, None] * rel[..., 0][:, None, :])
    blocks = (across < r[None, None, :]) & (along > 0.0) & (along < near[:, :, None])
    blocks[:, np.arange(n), np.arange(n)] = False
    ok &= ~blocks.any(axis=2)
    return ok.sum(axis=0) * sample_s >= min_time_s - 1e-9


def _on_track(x: float, y: float, movers: Sequence[Any], mover_m: float) -> bool:
    """Is (x, y) (m) within ``mover_m`` of a moving trunk's straight track (beyond its radius)?"""
    for o in movers:
        sp = math.hypot(o.vx_mps, o.vy_mps)
        ux, uy = o.vx_mps / sp, o.vy_mps / sp
        if abs((x - o.x_m) * uy - (y - o.y_m) * ux) <= o.radius_m + mover_m:
            return True
    return False


def match_trunks(truth: Sequence[Any], sight: Sequence[bool], est: Sequence[dict[str, Any]], *,
                 movers: Sequence[Any] = (), match_m: float = MATCH_M, mover_m: float = MOVER_M) -> dict[str, Any]:
    """Score the map's trunks ``est`` (dicts with ``x_m, y_m, radius_m``) against the static true trunks ``truth``
    (``sight[i]``: trunk i could have been seen, :func:`sightable`); ``movers``: the moving true trunks. Returns
    counts, precision, recall and the matched pairs' centre and radius errors (m). See module docstring."""
    pairs = []
    for i, o in enumerate(truth):
        for k, e in enumerate(est):
            dist = math.hypot(e["x_m"] - o.x_m, e["y_m"] - o.y_m)
            if dist <= match_m:
                pairs.append((dist, i, k))
    pairs.sort()
    used_t: dict[int, int] = {}
    used_e: set[int] = set()
    for _, i, k in pairs:
        if i not in used_t and k not in used_e:
            used_t[i] = k
            used_e.add(k)
    unmatched = [k for k in range(len(est)) if k not in used_e]
    mover_hits = [k for k in unmatched if movers and _on_track(est[k]["x_m"], est[k]["y_m"], movers, mover_m)]
    false_pos = len(unmatched) - len(mover_hits)
    n_sight = int(sum(bool(s) for s in sight))
    found = sum(1 for i in used_t if sight[i])
    centre = [math.hypot(est[k]["x_m"] - truth[i].x_m, est[k]["y_m"] - truth[i].y_m) for i, k in used_t.items()]
    radius = [est[k]["radius_m"] - truth[i].radius_m for i, k in used_t.items()]
    scored = len(used_e) + false_pos
    return {
        "true_trunks": len(truth), "sightable": n_sight, "map_trunks": len(est), "matched": len(used_t),
        "matched_sightable": found, "false_positives": false_pos, "mover_tracks": len(mover_hits),
        "precision": len(used_e) / scored if scored else None,
        "recall": found / n_sight if n_sight else None,
        "centre_err_m": [round(c, 4) for c in centre], "radius_err_m": [round(x, 4) for x in radius],
        "pairs": [[i, k] for i, k in used_t.items()],  # (true trunk, map trunk) indices, in centre_err_m's order
    }
