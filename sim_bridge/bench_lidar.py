"""``python -m sim_bridge.bench_lidar``: what the bundled vehicle's LiDAR costs (issue 26). Prints, nothing asserted:

* one scan (µs): :meth:`sim_bridge.lidar.Lidar.scan` (360 rays, noise, dropouts) in the Table 2 forest and in a
  dense forest of ``--trunks`` trunks around the sensor (default 200 within 12 m), level and tilted;
* packing one scan: the 5 OBSTACLE_DISTANCE messages (pymavlink, framed, dropped) and the Zenoh JSON sample;
* the vehicle's own CPU per lockstep control step in-process (:func:`sim_bridge.bench.run_bench_step_inprocess`),
  without a world and with the forest and its LiDAR at 10 Hz (one scan every 25 steps).
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from companion.core.obstacles import Obstacle
from companion.zenoh_io import schema
from sim_bridge.bench import run_bench_step_inprocess
from sim_bridge.lidar import Lidar, LidarConfig
from sim_bridge.scan_sender import ScanSender
from sim_bridge.world import World, WorldArrays, load_world


class _Sink:
    def write(self, buf: bytes) -> None:
        pass


def _per_call_us(fn, n: int) -> float:
    """Best of 3 runs of ``n`` calls: µs per call."""
    best = math.inf
    for _ in range(3):
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        best = min(best, (time.perf_counter() - t0) / n * 1e6)
    return best


def dense_world(n: int, seed: int = 1) -> World:
    """``n`` trunks (radius 0.1-0.4 m) uniformly within 12 m of the origin, none within 1 m."""
    rng = np.random.default_rng(seed)
    r = np.sqrt(rng.uniform(1.0, 144.0, n))
    a = rng.uniform(0.0, 2 * math.pi, n)
    return World("dense", tuple(Obstacle(float(x), float(y), float(rr), source="world") for x, y, rr in
                                zip(r * np.cos(a), r * np.sin(a), rng.uniform(0.1, 0.4, n), strict=True)))


def run(n_trunks: int = 200, steps: int = 3000) -> dict[str, float]:
    """The measurements, by name (µs)."""
    lid = Lidar(LidarConfig(dropout=0.01))
    pos = np.array([1.0, 0.2, -2.0])
    out: dict[str, float] = {}
    for name, world in (("forest", load_world("forest")), (f"dense{n_trunks}", dense_world(n_trunks))):
        tr = WorldArrays(world).at(0.0)
        out[f"scan_{name}_level_us"] = _per_call_us(lambda tr=tr: lid.scan(pos, (0.0, 0.0, 0.3), *tr), 2000)
        out[f"scan_{name}_tilted_us"] = _per_call_us(lambda tr=tr: lid.scan(pos, (0.2, -0.3, 0.3), *tr), 2000)
    tr = WorldArrays(load_world("forest")).at(0.0)
    ranges = lid.scan(pos, (0.0, 0.0, 0.3), *tr)
    sender = ScanSender(lid, load_world("forest"))
    mav = mavlink2.MAVLink(_Sink(), srcSystem=1, srcComponent=196)
    out["obstacle_distance_x5_us"] = _per_call_us(lambda: sender.send(ranges, 1_000_000, [mav]), 2000)
    out["zenoh_scan_json_us"] = _per_call_us(
        lambda: schema.encode_scan(0, "1", 1.0, 0.0, 1_000_000, 0.0, 0.0174, 0.1, 12.0, ranges), 2000)
    off = min(run_bench_step_inprocess(steps)["vehicle_cpu_us_per_step"] for _ in range(3))
    on = min(run_bench_step_inprocess(steps, ScanSender(Lidar(LidarConfig()), load_world("forest")))
             ["vehicle_cpu_us_per_step"] for _ in range(3))
    out["vehicle_step_no_world_us"] = off
    out["vehicle_step_forest_lidar_us"] = on
    return out


def main(argv: list[str] | None = None) -> int:
    """Print the benchmark."""
    ap = argparse.ArgumentParser(prog="python -m sim_bridge.bench_lidar", description=__doc__.split("\n")[0])
    ap.add_argument("--trunks", type=int, default=200, help="trunks of the dense forest (default 200)")
    args = ap.parse_args(argv)
    print("sim_bridge.bench_lidar: the bundled vehicle's 2-D LiDAR (360 rays, 1°, 12 m), best of 3, µs")
    for k, v in run(args.trunks).items():
        print(f"  {k:34s} {v:10.1f}")
    return 0


if __name__ == "__main__":
    import sys

    sys.exit(main())
