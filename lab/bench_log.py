"""Memory and time of the per-tick flight log (``companion.report.metrics.FlightLog``): what a long flight keeps.

    python -m lab.bench_log [--ticks N]

Prints bytes held per tick (tracemalloc, after the rows are appended) and the time of one ``append``, for ticks
with a command (streaming) and without. A 30 min flight at 250 Hz is 450,000 ticks.
"""

from __future__ import annotations

import argparse
import time
import tracemalloc
from types import SimpleNamespace

import numpy as np

from companion.report.metrics import FlightLog


def _command(rng: np.random.Generator) -> SimpleNamespace:
    v3 = lambda: rng.normal(size=3)  # noqa: E731 - a fresh array per field, as the flight core makes them
    return SimpleNamespace(ref_pos_ned_m=v3(), ref_vel_ned_mps=v3(), ref_acc_ned_mps2=v3(), euler_cmd_rad=v3(),
                           thrust_n=15.0, ff_accel=v3(), force_att_n=rng.normal(size=2),
                           force_rep_n=rng.normal(size=2), r_max_m=0.3, phase="cruise", envelope_mode="swing")


def measure(ticks: int, with_command: bool) -> dict[str, float]:
    """Bytes per tick held by a FlightLog of ``ticks`` rows (the rows' arrays made afresh each tick, as the flight
    makes them: whatever the log keeps of them counts), and µs per append (rows made beforehand)."""
    rng = np.random.default_rng(0)

    def row(i: int) -> tuple:
        return (i * 0.004, rng.normal(size=3), rng.normal(size=3), rng.normal(size=3), rng.normal(size=4),
                rng.normal(size=3), _command(rng) if with_command else None, rng.normal(size=4))

    tracemalloc.start()
    base = tracemalloc.get_traced_memory()[0]
    log = FlightLog()
    for i in range(ticks):
        t, pos, vel, eul, sw, pp, cmd, used = row(i)
        log.append(t, pos, vel, eul, sw, pp, cmd, swing_used=used)
    del t, pos, vel, eul, sw, pp, cmd, used
    held = tracemalloc.get_traced_memory()[0] - base
    tracemalloc.stop()
    assert len(log) == ticks
    rows = [row(i) for i in range(min(ticks, 20_000))]
    timed = FlightLog()
    t0 = time.perf_counter()
    for t, pos, vel, eul, sw, pp, cmd, used in rows:
        timed.append(t, pos, vel, eul, sw, pp, cmd, swing_used=used)
    dt = time.perf_counter() - t0
    return {"bytes_per_tick": held / ticks, "append_us": dt / len(rows) * 1e6}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m lab.bench_log", description=__doc__.split("\n\n")[0])
    ap.add_argument("--ticks", type=int, default=50_000)
    args = ap.parse_args(argv)
    for with_command in (True, False):
        r = measure(args.ticks, with_command)
        per_30min = r["bytes_per_tick"] * 450_000 / 1e6
        print(f"{'with' if with_command else 'without'} a command: {r['bytes_per_tick']:.0f} B per tick "
              f"({per_30min:.0f} MB per 30 min at 250 Hz), append {r['append_us']:.1f} µs")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
