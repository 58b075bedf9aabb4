"""The flight loop's delay margin, kept tick by tick: the measured loop lag, the limit-cycle guard, and what they
allow this tick — the feed-forward's trust, the position loop's gain scale and the max tilt — plus their record for
the report. Pure and synchronous; the flight core calls :meth:`LoopMargin.factors` before its setpoint and
:meth:`LoopMargin.after` once the setpoint is out."""

from __future__ import annotations

import math
from collections.abc import Sequence

from companion.control.params import ControllerConfig, CycleGuardGains
from companion.estimation.limit_cycle import LimitCycleDetector
from companion.estimation.loop_lag import LoopLagEstimator, lag_trust


class LoopMargin:
    """The loop lag (:class:`LoopLagEstimator`) and limit cycles (:class:`LimitCycleDetector`) of one flight."""

    def __init__(self, period_s: float, cycle_gains: CycleGuardGains) -> None:
        self.lag = LoopLagEstimator(period_s)
        self.cycle = LimitCycleDetector(cycle_gains)
        self.stats = LagStats(period_s)
        self._looking = False  # the lag is past the guard's min_excess_s: the detector is fed

    def factors(self, t_s: float | None, cfg: ControllerConfig, nominal_s: float,
                softens: bool) -> tuple[float, float, float]:
        """(feed-forward trust, position gain scale, max tilt in rad) for the tick at ``t_s`` (s), from the lag
        measured up to the last tick beyond the autopilot's clean-link ``nominal_s`` (s). Trust and gain scale are in
        (0, 1], times the guard's factor while it holds the loop down; the gain scale is 1 for a controller that does
        not soften (``softens``). The max tilt shrinks from ``cfg.limits.tilt_max_rad`` to ``tilt_slow_link_rad``."""
        ff, smc, lim = cfg.feedforward, cfg.smc, cfg.limits
        lag = self.lag.lag_s
        trust = lag_trust(lag, nominal_s, ff.lag_full_excess_s, ff.lag_zero_excess_s)
        gain = lag_trust(lag, nominal_s, smc.lag_scale_start_s, smc.lag_scale_end_s, smc.lag_scale_min) if softens \
            else 1.0
        tilt = lim.tilt_max_rad * lag_trust(lag, nominal_s, lim.slow_link_start_s, lim.slow_link_end_s,
                                            lim.tilt_slow_link_rad / lim.tilt_max_rad)
        guard = 1.0 if t_s is None else self.cycle.scale(t_s)
        if guard < 1.0:
            trust *= guard
            if softens:
                gain *= guard
        self.stats.add(lag, trust, gain, cycle=guard < 1.0, tilt_max_rad=tilt)
        return trust, gain, tilt

    def after(self, t_s: float, euler_rad: Sequence[float], euler_cmd_rad: Sequence[float],
              correction_mps2: tuple[float, float], nominal_s: float) -> None:
        """This tick's attitude (rad) against the commands before it, this tick's command (rad) into the lag's
        ring, and the controller's horizontal correction (m/s², NED: commanded acceleration beyond the reference's)
        into the limit-cycle detector while the lag exceeds the clean-link ``nominal_s`` (s) by the guard's
        ``min_excess_s`` (before that its peaks are forgotten)."""
        self.lag.observe(float(euler_rad[0]), float(euler_rad[1]))
        self.lag.command(float(euler_cmd_rad[0]), float(euler_cmd_rad[1]))
        lag = self.lag.lag_s
        looking = lag is not None and lag - nominal_s >= self.cycle.gains.min_excess_s
        if looking:
            self.cycle.correction(t_s, correction_mps2[0], correction_mps2[1])
        elif self._looking:
            self.cycle.reset()  # once, as the lag falls back: a clean link's tick allocates nothing here
        self._looking = looking

    def facts(self, nominal_s: float) -> dict[str, float | int | None]:
        """:meth:`LagStats.facts` plus the guard's: limit cycles seen, the first (s, vehicle clock), seconds held."""
        first = self.cycle.t_first_s
        return {**self.stats.facts(nominal_s), "limit_cycles": self.cycle.detections,
                "limit_cycle_first_s": None if first is None else round(first, 2),
                "cycle_guard_s": round(self.stats.cycle_ticks * self.stats.period_s, 2)}


class LagStats:
    """The loop lag over a flight, for the report: range of the measured lag, least trust, time faded."""

    def __init__(self, period_s: float) -> None:
        self.period_s = period_s
        self.lag_min_s: float | None = None
        self.lag_max_s: float | None = None
        self.last_lag_s: float | None = None
        self.trust_min = 1.0
        self.faded_ticks = 0
        self.gain_scale_min = 1.0
        self.softened_ticks = 0
        self.cycle_ticks = 0  # ticks the limit-cycle guard held the loop gain down
        self.tilt_max_min_rad = math.inf  # the least max tilt a slow link allowed (inf: never asked)

    def add(self, lag_s: float | None, trust: float, gain_scale: float = 1.0, cycle: bool = False,
            tilt_max_rad: float = math.inf) -> None:
        if lag_s is not None:
            self.last_lag_s = lag_s
            self.lag_min_s = lag_s if self.lag_min_s is None else min(self.lag_min_s, lag_s)
            self.lag_max_s = lag_s if self.lag_max_s is None else max(self.lag_max_s, lag_s)
        if trust < 1.0:
            self.faded_ticks += 1
            self.trust_min = min(self.trust_min, trust)
        if cycle:
            self.cycle_ticks += 1
        if gain_scale < 1.0:
            self.softened_ticks += 1
            self.gain_scale_min = min(self.gain_scale_min, gain_scale)
        if tilt_max_rad < self.tilt_max_min_rad:
            self.tilt_max_min_rad = tilt_max_rad

    def facts(self, nominal_s: float) -> dict[str, float | None]:
        """Loop lag (ms): min, max, last, the profile's nominal; least feed-forward trust and seconds faded; least
        position-gain scale and seconds softened; the least max tilt (rad) a slow link allowed."""
        def ms(v: float | None) -> float | None:
            return None if v is None else round(v * 1e3, 1)
        return {"lag_ms_min": ms(self.lag_min_s), "lag_ms_max": ms(self.lag_max_s), "lag_ms_last": ms(self.last_lag_s),
                "nominal_ms": ms(nominal_s), "ff_trust_min": round(self.trust_min, 3),
                "faded_s": round(self.faded_ticks * self.period_s, 2), "gain_scale_min": round(self.gain_scale_min, 3),
                "softened_s": round(self.softened_ticks * self.period_s, 2),
                "tilt_max_min_rad": None if math.isinf(self.tilt_max_min_rad) else round(self.tilt_max_min_rad, 3)}
