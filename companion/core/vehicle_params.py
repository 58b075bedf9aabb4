"""The physical parameters of quadrotor + payload (the paper's Table 1 by default; SI units) and how they are read
from TOML (a ``[vehicle]`` table). The model they parameterize: :mod:`companion.core.model`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np

from companion.config import dataclass_from_table, read_toml
from companion.errors import ConfigError


@dataclass(frozen=True)
class VehicleParams:
    """Physical parameters of quadrotor + payload (defaults: the paper's Table 1), SI units."""

    M: float = 1.25  # quadrotor mass, kg
    m: float = 0.25  # payload mass, kg
    g: float = 9.81  # gravity, m/s²
    Ixx: float = 0.0087  # body inertia, kg·m²
    Iyy: float = 0.0087
    Izz: float = 0.016
    Ip: float = 1.0e-6  # payload moment of inertia about the swing axes, kg·m²
    l: float = 1.0  # cable length, m
    r_uav: float = 0.10  # arm length, m (eq. 20)
    L_uav: float = 0.18  # propeller radius, m (eq. 20)
    #: total rotor thrust at full throttle, N: a property of the airframe, not of what hangs below it. Default:
    #: the bundled vehicle's rotors, 2.5 × the weight of the paper's 1.5 kg vehicle + payload (36.79 N)
    max_thrust_n: float = 2.5 * ((1.25 + 0.25) * 9.81)

    def validate(self) -> None:
        """Raise ``ValueError("<key>: ...")`` for non-physical values."""
        for f in fields(self):
            v = getattr(self, f.name)
            if not math.isfinite(v):
                raise ValueError(f"{f.name}: must be finite, got {v!r}")
            if f.name == "Ip":
                if v < 0.0:
                    raise ValueError(f"Ip: must be >= 0, got {v}")
            elif v <= 0.0:
                raise ValueError(f"{f.name}: must be > 0, got {v}")
        if self.g > 100.0:
            raise ValueError(f"g: {self.g} m/s² is not a planet we fly on")
        if self.m > 10.0 * self.M:
            raise ValueError(f"m: payload {self.m} kg is more than ten times the vehicle mass")
        if self.l > 20.0:
            raise ValueError(f"l: cable length {self.l} m is outside the model's range (<= 20 m)")
        # triangle inequality of a rigid body's principal moments
        ixx, iyy, izz = self.Ixx, self.Iyy, self.Izz
        if ixx + iyy < izz or iyy + izz < ixx or izz + ixx < iyy:
            raise ValueError("Izz: principal moments violate the triangle inequality Ixx + Iyy >= Izz")

    @property
    def total_mass(self) -> float:
        """M + m, kg."""
        return self.M + self.m

    @property
    def hover_thrust_n(self) -> float:
        """Thrust that holds the whole system at rest, (M+m)·g in N."""
        return (self.M + self.m) * self.g

    def packed(self) -> np.ndarray:
        """Parameters as the float64 array the compiled kernels take: [M, m, g, Ixx, Iyy, Izz, Ip, l]."""
        return np.array([self.M, self.m, self.g, self.Ixx, self.Iyy, self.Izz, self.Ip, self.l])

    def as_dict(self) -> dict[str, float]:
        """Plain dict, e.g. for reports and the Zenoh config queryable."""
        return asdict(self)


def load_vehicle_params(path: str | Path, section: str = "vehicle") -> VehicleParams:
    """Load :class:`VehicleParams` from ``[section]`` of a TOML file; missing keys keep Table 1 values.

    Raises :class:`ConfigError` naming file and key on unknown keys, wrong types or non-physical values.
    """
    data = read_toml(path)
    unknown = sorted(set(data) - {section})
    if unknown:
        raise ConfigError(f"{path}: unknown table or key {unknown[0]!r} (expected only [{section}])")
    return dataclass_from_table(VehicleParams, data.get(section, {}), where=f"{path}: [{section}]")


def vehicle_params_with(base: VehicleParams, overrides: dict, where: str) -> VehicleParams:
    """``base`` with fields replaced from a TOML table (mission files' ``[vehicle]``), validated."""
    return dataclass_from_table(VehicleParams, overrides, where=where, base=base)
