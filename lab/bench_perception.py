"""Micro-benchmark of perception: µs per scan for each stage (assembly, points, clusters, map update).

A level vehicle at 2 m altitude in a forest of N trunks (radius 0.15-0.35 m) all within the sensor's 12 m; a
360-ray, 1° scan with 1 cm range noise, sent as five ``OBSTACLE_DISTANCE`` parts of 72 rays as the bundled
vehicle sends it (assembly is timed from the parts). Each stage is timed per scan in the thread's CPU time
(``time.thread_time``: a loaded machine's waits left out); the median and 95th percentile over ``--scans`` scans are
printed. Speed is printed, never asserted.

    slungpilot bench perception [--seconds S]      python -m lab.bench_perception [--scans 300]

:func:`raycast` is also the tests' sensor: exact ray–circle intersections in the horizontal plane.
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Sequence

import numpy as np

from companion.perception.pipeline import Perception
from companion.perception.scan import UINT16_MAX, ScanPart


def raycast(pos_xy: tuple[float, float], yaw_rad: float, trunks: Sequence[tuple[float, float, float]],
            n_rays: int = 360, range_max_m: float = 12.0, noise_m: float = 0.0,
            rng: np.random.Generator | None = None) -> np.ndarray:
    """Ranges (m; +inf = no return within ``range_max_m``) of ``n_rays`` level rays over 360° in body FRD (ray k at
    k·360°/n from the nose, clockwise) from ``pos_xy`` (north, east; m) with heading ``yaw_rad`` against trunks
    (north, east, radius; m), with Gaussian range noise ``noise_m`` (1σ, m)."""
    ang = yaw_rad + np.arange(n_rays) * (2.0 * math.pi / n_rays)
    d = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    best = np.full(n_rays, math.inf)
    for cx, cy, r in trunks:
        oc = np.array([cx - pos_xy[0], cy - pos_xy[1]])
        b = d @ oc
        disc = b * b - (oc @ oc - r * r)
        t = b - np.sqrt(np.maximum(disc, 0.0))
        hit = (disc >= 0.0) & (t > 0.0)
        best = np.where(hit & (t < best), t, best)
    if noise_m > 0.0:
        gen = rng or np.random.default_rng(0)
        best = best + gen.normal(0.0, noise_m, n_rays)
    best[best > range_max_m] = math.inf
    return best


def obstacle_distance_parts(ranges_m: np.ndarray, time_usec: int, system_id: int = 1, range_max_m: float = 12.0,
                            range_min_m: float = 0.1) -> list[ScanPart]:
    """A 1° 360-ray scan as the bundled vehicle sends it: five parts of 72 rays (cm; +inf → max + 1, NaN →
    UINT16_MAX), body FRD."""
    max_cm, min_cm = round(range_max_m * 100), round(range_min_m * 100)
    cm = np.where(np.isnan(ranges_m), UINT16_MAX,
                  np.where(np.isinf(ranges_m), max_cm + 1, np.clip(np.round(ranges_m * 100), 0, max_cm)))
    cm = cm.astype(int)
    return [ScanPart(time_usec, tuple(int(v) for v in cm[72 * k:72 * k + 72]), min_cm, max_cm, 1.0, 72.0 * k, 12,
                     system_id) for k in range(5)]


def forest(n: int, rng: np.random.Generator, range_m: float = 11.0) -> list[tuple[float, float, float]]:
    """``n`` trunks (north, east, radius; m) around the origin, 1.5..``range_m`` m away, at least 1 m apart."""
    out: list[tuple[float, float, float]] = []
    while len(out) < n:
        d, a = rng.uniform(1.5, range_m), rng.uniform(0, 2 * math.pi)
        x, y, r = d * math.cos(a), d * math.sin(a), rng.uniform(0.15, 0.35)
        if all(math.hypot(x - u, y - v) > r + w + 1.0 for u, v, w in out):
            out.append((x, y, r))
    return out


def bench(n_trunks: int, scans: int, seed: int = 7) -> dict[str, tuple[float, float]]:
    """Per stage: (median, p95) µs per scan over ``scans`` scans of a forest of ``n_trunks``."""
    rng = np.random.default_rng(seed)
    trunks = forest(n_trunks, rng)
    p = Perception(1, timer=time.thread_time)
    samples: dict[str, list[float]] = {k: [] for k in ("assembly", "points", "clusters", "map", "total")}
    for k in range(scans):
        t = 1.0 + 0.1 * k
        p.on_position(t - 0.01, (0.0, 0.0, -2.0))
        p.on_attitude(t - 0.01, (0.0, 0.0, 0.0))
        p.on_position(t + 0.01, (0.0, 0.0, -2.0))
        p.on_attitude(t + 0.01, (0.0, 0.0, 0.0))
        parts = obstacle_distance_parts(raycast((0.0, 0.0), 0.0, trunks, noise_m=0.01, rng=rng), round(t * 1e6))
        asm = 0.0
        t0 = time.thread_time()
        for part in parts:
            p.on_part(part)
            asm += p.stage_s.get("assembly", 0.0)
        total = time.thread_time() - t0
        for stage in ("points", "clusters", "map"):
            samples[stage].append(p.stage_s[stage])
        samples["assembly"].append(asm)
        samples["total"].append(total)
    return {k: (float(np.median(v)) * 1e6, float(np.percentile(v, 95)) * 1e6) for k, v in samples.items()}


def print_bench(scans: int = 300) -> int:
    """Print the table (µs per scan) for 5, 20 and 50 trunks in view."""
    print(f"slungpilot bench perception: µs of CPU per 360-ray scan (median / p95 over {scans} scans)")
    print(f"{'trunks':>7} {'assembly':>16} {'points':>16} {'clusters':>16} {'map':>16} {'total':>16}")
    for n in (5, 20, 50):
        r = bench(n, scans)
        cells = " ".join(f"{r[k][0]:>8.0f} / {r[k][1]:<5.0f}" for k in ("assembly", "points", "clusters", "map",
                                                                          "total"))
        print(f"{n:>7} {cells}")
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m lab.bench_perception", description=__doc__.split("\n")[0])
    ap.add_argument("--scans", type=int, default=300, help="scans per forest size")
    return print_bench(ap.parse_args(argv).scans)


if __name__ == "__main__":
    raise SystemExit(main())
