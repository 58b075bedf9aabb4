"""The bundled vehicle's IMU: true specific force and body rates plus a seeded noise and bias model.

Per axis, for accelerometer and gyroscope alike (continuous-time parameters, as the PX4 SITL IMU plugin of
Gazebo Classic and its iris model take them):

* white noise of density σ_w (accelerometer m/s²/√Hz, gyro rad/s/√Hz): each sample, taken every
  ``sample_dt_s`` (one per control period, like PX4 SITL's 250 Hz IMU), gets N(0, σ_w²/Δt);
* bias random walk of density σ_b (m/s³/√Hz, rad/s²/√Hz): between samples t₀ < t₁ the bias moves by
  N(0, σ_b²·(t₁ − t₀)); it starts at zero (no turn-on bias).

Defaults are the iris model's (PX4 SITL, Gazebo Classic): accelerometer 0.00186 m/s²/√Hz and 0.006 m/s³/√Hz,
gyroscope 0.00018665 rad/s/√Hz and 3.8785e-5 rad/s²/√Hz. ``scale`` multiplies all four (0 = ideal sensor,
10 = a badly mounted IMU). The generator is numpy's PCG64 seeded with ``seed``; samples are drawn only when a
message needs one (at most once per simulated instant, shared by every link), so a run is repeatable bit for
bit given the same seed and the same requests. Pure: numpy only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ImuNoise:
    """Noise densities (SI, per axis), the multiplier ``scale`` and the seed."""

    accel_noise_density: float = 0.00186  # m/s²/√Hz
    accel_bias_random_walk: float = 0.006  # m/s³/√Hz
    gyro_noise_density: float = 0.00018665  # rad/s/√Hz
    gyro_bias_random_walk: float = 3.8785e-5  # rad/s²/√Hz
    scale: float = 1.0
    seed: int = 0
    sample_dt_s: float = 0.004

    def validate(self) -> None:
        """Raise ``ValueError("<key>: ...")`` for negative or non-finite values."""
        for k in ("accel_noise_density", "accel_bias_random_walk", "gyro_noise_density", "gyro_bias_random_walk",
                  "scale"):
            v = getattr(self, k)
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"{k}: must be finite and >= 0, got {v}")
        if not self.sample_dt_s > 0.0:
            raise ValueError("sample_dt_s: must be > 0")


class ImuModel:
    """Stateful sampler: ``sample(t_us, specific_force_frd, rates_frd)`` → (accelerometer, gyroscope)."""

    def __init__(self, noise: ImuNoise) -> None:
        noise.validate()
        self.noise = noise
        self.scale = noise.scale
        self._rng = np.random.Generator(np.random.PCG64(noise.seed))
        self.accel_bias = [0.0, 0.0, 0.0]  # m/s², FRD
        self.gyro_bias = [0.0, 0.0, 0.0]  # rad/s, FRD
        self._t_us: int | None = None
        self._last: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
        self._normals: list[list[float]] = []  # standard normal draws, taken from the generator in blocks
        self._next = 0

    def _draw6(self) -> list[float]:
        """Six standard normal numbers (drawn 256 rows at a time: the same sequence, far fewer calls)."""
        if self._next >= len(self._normals):
            self._normals = self._rng.standard_normal((256, 6)).tolist()
            self._next = 0
        row = self._normals[self._next]
        self._next += 1
        return row

    def sample(self, t_us: int, specific_force_frd_mps2, rates_frd_rad_s,
               ) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """Measured specific force (m/s², FRD) and body rates (rad/s, FRD) at simulated time ``t_us``, as
        tuples of floats; the same pair for repeated calls at one instant.

        Plain float arithmetic per axis, in the order numpy's element-wise operations would take (the same
        bits: the vehicle samples 50 times a simulated second, and 3-vectors cost more in numpy than in floats).
        """
        if self._t_us == t_us and self._last is not None:
            return self._last
        n = self.noise
        k = self.scale
        f0, f1, f2 = (float(a) for a in specific_force_frd_mps2)
        r0, r1, r2 = (float(w) for w in rates_frd_rad_s)
        if k > 0.0:
            ab, gb = self.accel_bias, self.gyro_bias
            if self._t_us is not None and t_us > self._t_us:
                s = math.sqrt((t_us - self._t_us) * 1e-6)
                w = self._draw6()
                ka, kg = k * n.accel_bias_random_walk, k * n.gyro_bias_random_walk
                for i in range(3):
                    ab[i] = ab[i] + ka * (w[i] * s)
                    gb[i] = gb[i] + kg * (w[3 + i] * s)
            s = math.sqrt(n.sample_dt_s)
            w = self._draw6()
            ka, kg = k * n.accel_noise_density, k * n.gyro_noise_density
            acc = (f0 + ab[0] + ka * (w[0] / s), f1 + ab[1] + ka * (w[1] / s), f2 + ab[2] + ka * (w[2] / s))
            gyro = (r0 + gb[0] + kg * (w[3] / s), r1 + gb[1] + kg * (w[4] / s), r2 + gb[2] + kg * (w[5] / s))
        else:
            acc = (f0, f1, f2)
            gyro = (r0, r1, r2)
        self._t_us = t_us
        self._last = (acc, gyro)
        return self._last
