"""Controller gains and limits (tables of ``config/controller.toml``), SI units, per axis [x, y, z] NED."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from pathlib import Path

from companion.config import dataclass_from_table, read_toml, shipped_config
from companion.errors import ConfigError
from companion.planning.params import PlannerParams

Vec3 = tuple[float, float, float]


def _check_positive(obj: object, allow_zero: tuple[str, ...] = ()) -> None:
    for f in fields(obj):  # type: ignore[arg-type]
        v = getattr(obj, f.name)
        vals = v if isinstance(v, tuple) else (v,)
        for x in vals:
            if not math.isfinite(x):
                raise ValueError(f"{f.name}: must be finite, got {v}")
            if x < 0.0 or (x == 0.0 and f.name not in allow_zero):
                raise ValueError(f"{f.name}: must be {'>= 0' if f.name in allow_zero else '> 0'}, got {v}")


@dataclass(frozen=True)
class SmcGains:
    """Position SMC, eqs. 30–37: S = c·e + ė; F = m_tot·(c·ė + r̈ + k·S) − f + k_sat·sat(S/Δ).

    c (1/s), k (1/s), k_sat (N, >= wind bound λ), boundary Δ (m/s) — per axis x, y, z.
    On a slow link the horizontal c and k are scaled by √s (so the stiffness c·k by s, the damping ratio kept), where
    s is 1 up to ``lag_scale_start_s`` of measured loop lag beyond the autopilot's clean-link lag, falling linearly
    to ``lag_scale_min`` at ``lag_scale_end_s`` (see :mod:`companion.estimation.loop_lag`).
    ``ki`` (1/s²): horizontal integral action while the reference hovers (slower than 0.3 m/s), clamped at
    ``i_limit_mps2`` (m/s²): a mean wind's drag leaves no standing offset at a hold or the goal (0: off).
    """

    c: Vec3 = (1.2, 1.2, 2.0)
    k: Vec3 = (2.5, 2.5, 3.0)
    k_sat: Vec3 = (0.6, 0.6, 0.8)
    boundary: Vec3 = (0.3, 0.3, 0.3)
    lag_scale_start_s: float = 0.05
    lag_scale_end_s: float = 0.15
    lag_scale_min: float = 0.25
    ki: float = 0.5
    i_limit_mps2: float = 1.5

    def validate(self) -> None:
        """Raise ``ValueError("<key>: ...")`` for non-positive gains or a lag scale that does not fall into (0, 1]."""
        _check_positive(self, allow_zero=("k_sat", "lag_scale_start_s", "ki"))
        if self.lag_scale_end_s <= self.lag_scale_start_s:
            raise ValueError(f"lag_scale_end_s: must be > lag_scale_start_s ({self.lag_scale_start_s}), got "
                             f"{self.lag_scale_end_s}")
        if self.lag_scale_min > 1.0:
            raise ValueError(f"lag_scale_min: must be in (0, 1], got {self.lag_scale_min}")


@dataclass(frozen=True)
class FeedForwardGains:
    """Anti-swing feed-forward (eq. 48 plus swing angle and rate terms), added to the commanded acceleration.

    u_x = +l·(k_angle·α + k_rate·α̇ − a1·α̈), u_y = −l·(k_angle·β + k_rate·β̇ − a2·β̈),
    u_z = −l·a3·(α̈ + β̈) (m/s², NED); signs derived in :mod:`companion.control.position`.
    a1, a2, a3 dimensionless (eq. 48), k_angle in 1/s², k_rate in 1/s; ``rate_filter_s`` is the time
    constant of the filtered derivative that estimates α̈, β̈; ``max_mps2`` bounds the horizontal feed-forward
    (m/s²): the bundled vehicle's flights need at most 2.6, while on a vehicle whose attitude loop lags the model's
    (ArduCopter SITL) an unbounded feed-forward pumped the swing with up to 12.
    ``lag_full_excess_s`` / ``lag_zero_excess_s`` (s): the feed-forward is fully on while the measured loop lag
    exceeds the autopilot's clean-link lag by at most the first, and off from the second on (linear between);
    see :mod:`companion.estimation.loop_lag` for the measurement and the delay margin behind the defaults.
    """

    a1: float = 0.1
    a2: float = 0.1
    a3: float = 0.0
    k_angle: float = 8.0
    k_rate: float = 1.9
    rate_filter_s: float = 0.02
    max_mps2: float = 3.0
    lag_full_excess_s: float = 0.05
    lag_zero_excess_s: float = 0.17

    def validate(self) -> None:
        """Raise ``ValueError("<key>: ...")`` for negative gains, a1, a2 >= 0.5 (algebraic loop gain), or a lag
        fade that does not fall (zero excess <= full excess)."""
        _check_positive(self, allow_zero=("a1", "a2", "a3", "k_angle", "k_rate", "lag_full_excess_s"))
        if self.lag_zero_excess_s <= self.lag_full_excess_s:
            raise ValueError(f"lag_zero_excess_s: must be > lag_full_excess_s ({self.lag_full_excess_s}), got "
                             f"{self.lag_zero_excess_s}")
        for key in ("a1", "a2", "a3"):
            if getattr(self, key) >= 0.5:
                raise ValueError(f"{key}: must be < 0.5 (α̈ depends on the acceleration it commands), got "
                                 f"{getattr(self, key)}")


@dataclass(frozen=True)
class PidGains:
    """Cascade PID baseline: v_sp = ṙ + kp·e; a = r̈ + kv·(v_sp − v) + ki·∫(v_sp − v) (per axis)."""

    kp: Vec3 = (1.2, 1.2, 1.5)
    kv: Vec3 = (2.5, 2.5, 3.0)
    ki: Vec3 = (0.3, 0.3, 0.5)
    i_limit_mps2: float = 2.0

    def validate(self) -> None:
        """Raise ``ValueError("<key>: ...")`` for negative gains."""
        _check_positive(self, allow_zero=("ki",))


@dataclass(frozen=True)
class LimitGains:
    """Output limits: max tilt (rad), thrust range as fractions of hover thrust, max acceleration (m/s²).

    On a slow link the max tilt shrinks to ``tilt_slow_link_rad``: linearly from ``slow_link_start_s`` of measured
    loop lag beyond the autopilot's clean-link lag to ``slow_link_end_s`` (``LoopMargin.factors`` in
    :mod:`companion.flight.loop_margin`). A loop that far out of margin cannot use the full range: at the forest's
    turn, 170 ms behind a vehicle whose mixer lifts for yaw, its 0.5-0.6 rad commands made the vehicle climb up to
    0.4 m (``docs/measurements.md``, 2026-12-04)."""

    tilt_max_rad: float = 0.6
    thrust_min_frac: float = 0.2
    thrust_max_frac: float = 2.2
    acc_max_mps2: float = 6.0
    tilt_slow_link_rad: float = 0.4
    slow_link_start_s: float = 0.05
    slow_link_end_s: float = 0.08

    def validate(self) -> None:
        """Raise ``ValueError("<key>: ...")`` for values outside their physical range."""
        _check_positive(self)
        if self.tilt_max_rad >= 1.4:
            raise ValueError(f"tilt_max_rad: must be < 1.4 rad, got {self.tilt_max_rad}")
        if self.tilt_slow_link_rad > self.tilt_max_rad:
            raise ValueError(f"tilt_slow_link_rad: must be <= tilt_max_rad ({self.tilt_max_rad}), got "
                             f"{self.tilt_slow_link_rad}")
        if self.slow_link_end_s <= self.slow_link_start_s:
            raise ValueError(f"slow_link_end_s: must be > slow_link_start_s ({self.slow_link_start_s}), got "
                             f"{self.slow_link_end_s}")
        if self.thrust_min_frac >= 1.0 or self.thrust_max_frac <= 1.0:
            raise ValueError("thrust_max_frac: thrust range must contain hover (min < 1 < max)")


@dataclass(frozen=True)
class CycleGuardGains:
    """The guard against a limit cycle of the loop itself (:mod:`companion.estimation.limit_cycle`).

    A cycle is ``peaks`` alternating peaks beyond ``accel_mps2`` (m/s²) on one horizontal axis, each within
    ``window_s`` (s) of the one before, in the controller's correction (its commanded acceleration beyond the
    reference's, so a planned manoeuvre never counts): faster than the pendulum of any cable of 0.5 m or more
    (0.7 Hz), as slow as the ~1–1.5 Hz cycle a lagging link drives. It is looked for only while the measured loop
    lag exceeds the autopilot's clean-link lag by ``min_excess_s`` (s): a loop with its clean-link margin does not
    cycle, and there a reversal is a transient (a trunk seen late). Each one multiplies the feed-forward's trust and
    the position gain scale by ``scale`` for ``hold_s`` (s), recovering linearly to 1 over ``recover_s`` (s).
    ``scale`` 1 turns the guard off.
    """

    accel_mps2: float = 2.5
    window_s: float = 0.6
    peaks: int = 2
    min_excess_s: float = 0.03
    scale: float = 0.4
    hold_s: float = 2.0
    recover_s: float = 3.0

    def validate(self) -> None:
        """Raise ``ValueError("<key>: ...")`` for non-positive values, fewer than 2 peaks or a scale outside (0, 1]."""
        _check_positive(self, allow_zero=("min_excess_s",))
        if self.peaks < 2:
            raise ValueError(f"peaks: must be >= 2 (a cycle reverses at least once), got {self.peaks}")
        if self.scale > 1.0:
            raise ValueError(f"scale: must be in (0, 1], got {self.scale}")


@dataclass(frozen=True)
class ControllerConfig:
    """Every tunable of the flight core, as loaded from ``config/controller.toml``."""

    smc: SmcGains = field(default_factory=SmcGains)
    feedforward: FeedForwardGains = field(default_factory=FeedForwardGains)
    pid: PidGains = field(default_factory=PidGains)
    limits: LimitGains = field(default_factory=LimitGains)
    planner: PlannerParams = field(default_factory=PlannerParams)
    cycle: CycleGuardGains = field(default_factory=CycleGuardGains)


_TABLES = {
    "smc": SmcGains,
    "feedforward": FeedForwardGains,
    "pid": PidGains,
    "limits": LimitGains,
    "planner": PlannerParams,
    "cycle": CycleGuardGains,
}

DEFAULT_CONTROLLER_TOML = shipped_config("controller.toml")


def load_controller_config(path: str | Path | None = None) -> ControllerConfig:
    """Load gains from a TOML file (default ``config/controller.toml``); missing tables/keys keep defaults.

    Raises :class:`ConfigError` naming file, table and key for unknown keys, wrong types or bad values.
    """
    p = Path(path) if path is not None else DEFAULT_CONTROLLER_TOML
    data = read_toml(p)
    unknown = sorted(set(data) - set(_TABLES))
    if unknown:
        raise ConfigError(f"{p}: unknown table {unknown[0]!r} (known: {', '.join(_TABLES)})")
    parts = {
        name: dataclass_from_table(cls, data.get(name, {}), where=f"{p}: [{name}]") for name, cls in _TABLES.items()
    }
    return ControllerConfig(**parts)
