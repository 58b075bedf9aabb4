"""`slungpilot bench model`: RK4 steps per second of the compiled model, single and batched."""

from __future__ import annotations

import time

import numpy as np

from companion.core import model
from companion.core.vehicle_params import VehicleParams


def run(seconds: float = 2.0, batch: int = 64) -> dict[str, float]:
    """Measure cold start and throughput; returns numbers keyed by name (steps/s, seconds)."""
    t0 = time.perf_counter()
    model.warm_up()
    cold_s = time.perf_counter() - t0
    p = VehicleParams()
    pk = p.packed()
    u = np.array([p.hover_thrust_n, 0.0, 0.0, 0.0])
    d = np.full(6, 0.2)
    x = np.zeros(16)
    x[6] = 0.2

    # (a) one RK4 step per Python call: what a lockstep simulator that talks between steps pays.
    n = 0
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < seconds / 3:
        for _ in range(1000):
            x = model._rk4(x, u, d, pk, 1e-3, 1)
        n += 1000
    per_call = n / (time.perf_counter() - t0)

    # (b) many steps inside one compiled call: the kernel's own speed.
    x = np.zeros(16)
    t0 = time.perf_counter()
    n = 0
    while time.perf_counter() - t0 < seconds / 3:
        x = model._rk4(x, u, d, pk, 1e-3, 10000)
        n += 10000
    in_kernel = n / (time.perf_counter() - t0)

    # (c) a batch of vehicles stepped together.
    X = np.zeros((batch, 16))
    U = np.tile(u, (batch, 1))
    D = np.tile(d, (batch, 1))
    t0 = time.perf_counter()
    n = 0
    while time.perf_counter() - t0 < seconds / 3:
        X = model._rk4_batch(X, U, D, pk, 1e-3, 100)
        n += 100 * batch
    batched = n / (time.perf_counter() - t0)
    return {
        "cold_start_s": cold_s,
        "steps_per_s_one_per_call": per_call,
        "steps_per_s_in_kernel": in_kernel,
        f"steps_per_s_batch{batch}": batched,
    }
