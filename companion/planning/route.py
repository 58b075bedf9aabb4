"""Shortest route among inflated discs: the tangent (reduced visibility) graph, searched with Dijkstra.

In the plane, the shortest path from a start to a goal around discs is a taut string: straight segments
tangent to the discs joined by arcs along their boundaries. Its nodes are the tangent points — from the
start and the goal to every disc, and of the four common tangents of every pair of discs (two outer, two
inner) — and its edges the collision-free tangent segments plus the free arcs between consecutive tangent
points on each disc. Dijkstra on that graph gives the shortest route, or proves that none exists (a goal
fenced in, a start enclosed): the graph is complete for this geometry.

Each disc is an obstacle's safety circle inflated by the vehicle's envelope and margins (built by the
planner). A start or goal lying inside a disc but outside its ``hard`` radius shrinks that disc to just
exclude it (the inflation is a preference there, not a wall); inside a hard radius the point is blocked.

The graph is built and searched in one compiled kernel (numba, cached like the model's): O(N²) nodes,
O(N³) segment tests, a binary-heap Dijkstra; about 0.1 ms for ten discs.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numba import njit

from companion.core.kernel_cache import use_kernel_cache

EPS_M = 1e-6


@dataclass(frozen=True, slots=True)
class Route:
    """A route: ``points`` (n, 2) NED metres from start to goal (arcs sampled), ``length_m``."""

    points: np.ndarray
    length_m: float


use_kernel_cache(Path(__file__))


@njit(cache=True)
def _seg_blocked(ax, ay, bx, by, cx, cy, r, skip1, skip2):  # pragma: no cover - compiled
    """True if segment a→b enters a disc other than skip1/skip2."""
    dx, dy = bx - ax, by - ay
    dd = dx * dx + dy * dy
    for k in range(len(r)):
        if k in (skip1, skip2) or r[k] <= 0.0:
            continue
        if dd < 1e-18:
            t = 0.0
        else:
            t = ((cx[k] - ax) * dx + (cy[k] - ay) * dy) / dd
            t = min(1.0, max(0.0, t))
        ex, ey = ax + t * dx - cx[k], ay + t * dy - cy[k]
        rr = r[k] - 1e-6
        if rr > 0.0 and ex * ex + ey * ey < rr * rr:
            return True
    return False


@njit(cache=True)
def _inside_other(px, py, cx, cy, r, own):  # pragma: no cover - compiled
    for k in range(len(r)):
        if k == own or r[k] <= 0.0:
            continue
        rr = r[k] - 1e-6
        dx, dy = px - cx[k], py - cy[k]
        if rr > 0.0 and dx * dx + dy * dy < rr * rr:
            return True
    return False


@njit(cache=True)
def _route_kernel(sx, sy, gx, gy, cx, cy, r, arc_step, out):  # pragma: no cover - compiled
    """Shortest route; writes points into ``out`` (cap, 2); returns (n points, length) or (−1, inf)."""
    n = len(r)
    if not _seg_blocked(sx, sy, gx, gy, cx, cy, r, -1, -1):
        out[0, 0], out[0, 1], out[1, 0], out[1, 1] = sx, sy, gx, gy
        return 2, math.hypot(gx - sx, gy - sy)
    cap = 2 + 4 * n + 4 * n * max(n - 1, 0)
    nx = np.empty(cap)
    ny = np.empty(cap)
    nd = np.full(cap, -1, np.int64)
    na = np.zeros(cap)
    nx[0], ny[0], nx[1], ny[1] = sx, sy, gx, gy
    m = 2
    ecap = 1 + 4 * n + 2 * n * max(n - 1, 0)
    eu = np.empty(ecap, np.int64)
    ev = np.empty(ecap, np.int64)
    ne = 0
    # tangents from the start (node 0) and the goal (node 1)
    for pid in range(2):
        px, py = nx[pid], ny[pid]
        for k in range(n):
            if r[k] <= 0.0:
                continue
            dx, dy = px - cx[k], py - cy[k]
            d = math.hypot(dx, dy)
            if d <= r[k] + 1e-9:
                continue
            phi = math.atan2(dy, dx)
            beta = math.acos(min(1.0, r[k] / d))
            for sgn in (1.0, -1.0):
                a = phi + sgn * beta
                nx[m], ny[m], nd[m], na[m] = cx[k] + r[k] * math.cos(a), cy[k] + r[k] * math.sin(a), k, a
                eu[ne], ev[ne] = pid, m
                ne += 1
                m += 1
    # common tangents of every pair
    for i in range(n):
        if r[i] <= 0.0:
            continue
        for j in range(i + 1, n):
            if r[j] <= 0.0:
                continue
            dx, dy = cx[j] - cx[i], cy[j] - cy[i]
            d = math.hypot(dx, dy)
            phi = math.atan2(dy, dx)
            if d > abs(r[i] - r[j]) + 1e-9:  # outer: same angle on both
                beta = math.acos(max(-1.0, min(1.0, (r[i] - r[j]) / d)))
                for sgn in (1.0, -1.0):
                    a = phi + sgn * beta
                    nx[m], ny[m], nd[m], na[m] = cx[i] + r[i] * math.cos(a), cy[i] + r[i] * math.sin(a), i, a
                    nx[m + 1], ny[m + 1] = cx[j] + r[j] * math.cos(a), cy[j] + r[j] * math.sin(a)
                    nd[m + 1], na[m + 1] = j, a
                    eu[ne], ev[ne] = m, m + 1
                    ne += 1
                    m += 2
            if d > r[i] + r[j] + 1e-9:  # inner: opposite angles
                beta = math.acos(min(1.0, (r[i] + r[j]) / d))
                for sgn in (1.0, -1.0):
                    a = phi + sgn * beta
                    b = a + math.pi
                    nx[m], ny[m], nd[m], na[m] = cx[i] + r[i] * math.cos(a), cy[i] + r[i] * math.sin(a), i, a
                    nx[m + 1], ny[m + 1] = cx[j] + r[j] * math.cos(b), cy[j] + r[j] * math.sin(b)
                    nd[m + 1], na[m + 1] = j, b
                    eu[ne], ev[ne] = m, m + 1
                    ne += 1
                    m += 2
    ok = np.ones(m, np.bool_)
    for q in range(2, m):
        ok[q] = not _inside_other(nx[q], ny[q], cx, cy, r, nd[q])
        na[q] = na[q] % (2.0 * math.pi)
    # edges: (u, v, weight, disc of the arc or −1, signed sweep)
    fcap = 2 * ne + 4 * m
    fu = np.empty(fcap, np.int64)
    fv = np.empty(fcap, np.int64)
    fw = np.empty(fcap)
    fsweep = np.zeros(fcap)
    fdisc = np.full(fcap, -1, np.int64)
    nf = 0
    for e in range(ne):
        u, v = eu[e], ev[e]
        if not (ok[u] and ok[v]):
            continue
        if _seg_blocked(nx[u], ny[u], nx[v], ny[v], cx, cy, r, nd[u], nd[v]):
            continue
        w = math.hypot(nx[v] - nx[u], ny[v] - ny[u])
        fu[nf], fv[nf], fw[nf] = u, v, w
        nf += 1
        fu[nf], fv[nf], fw[nf] = v, u, w
        nf += 1
    # arcs: consecutive valid tangent points on each disc, counter-clockwise, unless another disc covers them
    for k in range(n):
        if r[k] <= 0.0:
            continue
        cnt = 0
        for q in range(2, m):
            if nd[q] == k and ok[q]:
                cnt += 1
        if cnt < 2:
            continue
        ids = np.empty(cnt, np.int64)
        cnt = 0
        for q in range(2, m):
            if nd[q] == k and ok[q]:
                ids[cnt] = q
                cnt += 1
        ids = ids[np.argsort(na[ids])]
        for a_i in range(cnt):
            u = ids[a_i]
            v = ids[(a_i + 1) % cnt]
            span = (na[v] - na[u]) % (2.0 * math.pi)
            if cnt == 1:
                continue
            # free if no other disc's blocked interval on this circle meets the arc
            mid = na[u] + 0.5 * span
            blocked = False
            for j in range(n):
                if j == k or r[j] <= 0.0:
                    continue
                dx, dy = cx[j] - cx[k], cy[j] - cy[k]
                d = math.hypot(dx, dy)
                if d >= r[k] + r[j] - 1e-9 or d + r[j] <= r[k] + 1e-9:
                    continue  # circle k does not enter disc j (apart, or disc j inside disc k)
                if d + r[k] <= r[j]:
                    blocked = True
                    break
                cg = (r[k] * r[k] + d * d - r[j] * r[j]) / (2.0 * r[k] * d)
                gam = math.acos(max(-1.0, min(1.0, cg)))
                phi = math.atan2(dy, dx)
                sep = abs(((mid - phi + math.pi) % (2.0 * math.pi)) - math.pi)
                if sep < 0.5 * span + gam - 1e-9:
                    blocked = True
                    break
            if blocked:
                continue
            w = r[k] * span
            fu[nf], fv[nf], fw[nf], fdisc[nf], fsweep[nf] = u, v, w, k, span
            nf += 1
            fu[nf], fv[nf], fw[nf], fdisc[nf], fsweep[nf] = v, u, w, k, -span
            nf += 1
    # adjacency (CSR)
    deg = np.zeros(m + 1, np.int64)
    for e in range(nf):
        deg[fu[e] + 1] += 1
    for q in range(m):
        deg[q + 1] += deg[q]
    adj = np.empty(nf, np.int64)
    fill = deg[:-1].copy()
    for e in range(nf):
        adj[fill[fu[e]]] = e
        fill[fu[e]] += 1
    # Dijkstra from node 0 to node 1
    dist = np.full(m, np.inf)
    pred = np.full(m, -1, np.int64)
    done = np.zeros(m, np.bool_)
    dist[0] = 0.0
    heap = [(0.0, np.int64(0))]
    while len(heap) > 0:
        du, u = heapq.heappop(heap)
        if done[u]:
            continue
        done[u] = True
        if u == 1:
            break
        for a_i in range(deg[u], deg[u + 1]):
            e = adj[a_i]
            v = fv[e]
            nd_ = du + fw[e]
            if nd_ < dist[v] - 1e-12:
                dist[v] = nd_
                pred[v] = e
                heapq.heappush(heap, (nd_, v))
    if not np.isfinite(dist[1]):
        return -1, np.inf
    # walk back, then write the points forward (arcs sampled)
    chain = np.empty(m, np.int64)
    nc = 0
    v = 1
    while v != 0:
        chain[nc] = pred[v]
        nc += 1
        v = fu[pred[v]]
    npts = 0
    out[0, 0], out[0, 1] = sx, sy
    npts = 1
    for ci in range(nc - 1, -1, -1):
        e = chain[ci]
        k = fdisc[e]
        if k >= 0:
            sw = fsweep[e]
            steps = max(1, math.ceil(abs(sw) / arc_step))
            a0 = na[fu[e]]
            for q in range(1, steps + 1):
                if npts >= out.shape[0]:
                    return -1, np.inf
                a = a0 + sw * q / steps
                out[npts, 0], out[npts, 1] = cx[k] + r[k] * math.cos(a), cy[k] + r[k] * math.sin(a)
                npts += 1
        else:
            if npts >= out.shape[0]:
                return -1, np.inf
            out[npts, 0], out[npts, 1] = nx[fv[e]], ny[fv[e]]
            npts += 1
    return npts, dist[1]


def effective_radii(points: list[np.ndarray], c: np.ndarray, r: np.ndarray, r_hard: np.ndarray
                    ) -> tuple[np.ndarray, bool]:
    """Radii shrunk so that each of ``points`` lies outside every disc; False if one is inside a hard radius."""
    r = r.copy()
    ok = True
    for p in points:
        d = np.hypot(c[:, 0] - p[0], c[:, 1] - p[1])
        inside = d < r + EPS_M
        if np.any(inside & (d < r_hard)):
            ok = False
        r[inside] = np.maximum(d[inside] - 10 * EPS_M, 0.0)
    return r, ok


def find_route(start: np.ndarray, goal: np.ndarray, centers: np.ndarray, radii: np.ndarray,
               hard_radii: np.ndarray | None = None, arc_step_rad: float = 0.15) -> Route | None:
    """Shortest route from ``start`` to ``goal`` (2,) around discs (centers (N, 2), radii (N,)), or None.

    ``hard_radii`` (default: the radii) is how far a start or goal inside a disc may shrink it (see module
    docstring): a start or goal inside a hard radius has no route. Arcs are sampled every ``arc_step_rad``.
    """
    s = np.asarray(start, dtype=np.float64)
    g = np.asarray(goal, dtype=np.float64)
    c = np.ascontiguousarray(np.asarray(centers, dtype=np.float64).reshape(-1, 2))
    r0 = np.asarray(radii, dtype=np.float64).reshape(-1)
    hard = r0 if hard_radii is None else np.asarray(hard_radii, dtype=np.float64).reshape(-1)
    r, ok = effective_radii([s, g], c, r0, hard)
    if not ok:
        return None
    out = np.empty((512 + 64 * len(r), 2))
    npts, length = _route_kernel(float(s[0]), float(s[1]), float(g[0]), float(g[1]),
                                 np.ascontiguousarray(c[:, 0]), np.ascontiguousarray(c[:, 1]),
                                 np.ascontiguousarray(r), float(arc_step_rad), out)
    if npts < 0:
        return None
    return Route(out[:npts].copy(), float(length))
