"""Two swing estimators side by side, the payload fixes choosing between them (pure: no I/O).

The swing estimator's model ties the swing to the airframe's motion: the cable's pull is part of what
accelerates the airframe, so the velocity and the IMU tell the filter about the swing between fixes. That is
right for a payload on a cable, and exactly right on the bundled vehicle. It is wrong where the pull on the
airframe is not a pendulum's: ArduCopter SITL's payload (``SIM_SlungPayload.cpp``) adds a "centripetal" tension
from the payload's absolute velocity (1 N for 0.25 kg at 2 m/s, pulling the airframe towards the payload) and
none of the payload's reaction to the airframe's acceleration. Replayed from a recorded flight, the fixes the
filter predicted were off by 0.049 rad RMS with the airframe's motion fused and 0.015 rad without it.

So with payload fixes two filters run: ``full`` (everything the swing input allows) and ``fixes`` (the fixes,
attitude and commanded thrust only, the force on the airframe left free: ``q_force`` = ``FIXES_Q_FORCE``). Each
scores every fix by how far it had predicted it (the innovation, m). The flight flies on ``full`` until the
other's mean squared error over the last ``WINDOW_FIXES`` fixes is below ``RATIO`` × its own, and back the same
way (the ratio is the hysteresis). Where the model fits, ``full`` predicts better and keeps the flight; the bundled
vehicle's flights never leave it (0.0037 vs 0.0059 rad RMS on the forest with fixes). Chosen by the error itself
rather than by the likelihood: the likelihood also rewards a covariance that has adapted to a misfit (q_swing's
scale), and chose ``full`` for 30–40 % of the same replay (0.027–0.030 rad instead of 0.015).
The ``fixes`` filter costs one update per fix (10 Hz); while it flies, the full filter is asked for its fade
every 50 ms.
"""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np

from companion.core.vehicle_params import VehicleParams
from companion.estimation.swing_config import SwingEstimate, SwingEstimatorConfig
from companion.estimation.swing_estimator import SwingEstimator

log = logging.getLogger(__name__)

FIXES_Q_FORCE = 300.0  # N²/s: the airframe's force free to change by ~17 N in a second (it is not modelled)
WINDOW_FIXES = 20  # fixes in the comparison (2 s of ArduPilot's 10 Hz)
MIN_FIXES = 10  # fewer than this in either: no switch
RATIO = 0.7  # the other filter takes over when its mean squared fix error is below this × the current one's
FULL_FADE_EVERY_S = 0.05  # while ``fixes`` flies, the full filter's fade is looked up this often (s)


def _mean_recent(sq_errors: list[tuple[float, float]]) -> tuple[float, int]:
    """Mean of the last ``WINDOW_FIXES`` squared fix errors (m²) and how many there were."""
    recent = sq_errors[-WINDOW_FIXES:]
    return (sum(v for _, v in recent) / len(recent) if recent else float("inf")), len(recent)


class TwoModelEstimator:
    """:class:`SwingEstimator`'s interface over ``full`` and ``fixes`` (see the module docstring). ``selected`` is
    the name of the filter :meth:`estimate` answers from; ``switches`` counts changes; ``ticks_on`` counts the
    :meth:`estimate` calls answered by each."""

    def __init__(self, params: VehicleParams, config: SwingEstimatorConfig | None = None, *, t0_s: float = 0.0,
                 vel0_ned_mps=None, swing_sigma0_rad: float | None = None) -> None:
        cfg = config or SwingEstimatorConfig()
        kw = {"t0_s": t0_s, "vel0_ned_mps": vel0_ned_mps, "swing_sigma0_rad": swing_sigma0_rad}
        self.full = SwingEstimator(params, cfg, **kw)
        self.fixes = SwingEstimator(params, replace(cfg, q_force=FIXES_Q_FORCE), **kw)
        self.selected = "full"
        self.switches = 0
        self.ticks_on = {"full": 0, "fixes": 0}
        self._scored = 0  # fixes of ``full`` already compared
        self._last_t_s: float | None = None  # time of the last estimate asked for (the last tick's)
        self._full_fade = (float("-inf"), 1.0)  # (t s, fade) of ``full``, refreshed every FULL_FADE_EVERY_S

    # -- inputs: both filters, except the airframe's motion ------------------------------------------------
    def set_thrust(self, t_s: float, thrust_n: float) -> None:
        self.full.set_thrust(t_s, thrust_n)
        self.fixes.set_thrust(t_s, thrust_n)

    def set_attitude_euler(self, t_s: float, euler_rad, rates_frd_rad_s=None) -> None:
        self.full.set_attitude_euler(t_s, euler_rad, rates_frd_rad_s)
        self.fixes.set_attitude_euler(t_s, euler_rad, rates_frd_rad_s)

    def update_imu(self, t_s: float, accel_frd_mps2, sigma_mps2=None) -> None:
        self.full.update_imu(t_s, accel_frd_mps2, sigma_mps2)

    def update_velocity(self, t_s: float, vel_ned_mps, pos_ned_m=None, sigma_mps: float | None = None) -> None:
        self.full.update_velocity(t_s, vel_ned_mps, pos_ned_m, sigma_mps)
        self.fixes.update_velocity(t_s, None, pos_ned_m)  # positions only: absolute fixes are taken against them

    def update_payload_offset(self, t_s: float, offset_ned_m, sigma_m: float | None = None) -> None:
        self.full.update_payload_offset(t_s, offset_ned_m, sigma_m)
        self.fixes.update_payload_offset(t_s, offset_ned_m, sigma_m)
        self._prime()

    def update_payload_position(self, t_s: float, payload_pos_ned_m, sigma_m: float | None = None) -> bool:
        used = self.full.update_payload_position(t_s, payload_pos_ned_m, sigma_m)
        self.fixes.update_payload_position(t_s, payload_pos_ned_m, sigma_m)
        self._prime()
        return used

    def _prime(self) -> None:
        """A fix arrives ~0.1 s after its time: predict the fixes filter from it to the last tick's time now, on the
        message's path, so that the next tick's estimate is the usual 4 ms step and not a 0.1 s one."""
        if self.selected == "fixes" and self._last_t_s is not None:
            self.fixes.estimate(self._last_t_s)

    # -- output ---------------------------------------------------------------------------------------------
    def _choose(self) -> None:
        """Compare the filters once per new fix scored by ``full``."""
        n_fixes = len(self.full.fix_sq_error)
        if n_fixes == self._scored:
            return
        self._scored = n_fixes
        e_full, n_full = _mean_recent(self.full.fix_sq_error)
        e_fixes, n_fixes_only = _mean_recent(self.fixes.fix_sq_error)
        if min(n_full, n_fixes_only) < MIN_FIXES:
            return
        mine, theirs, other = ((e_full, e_fixes, "fixes") if self.selected == "full" else (e_fixes, e_full, "full"))
        if theirs < RATIO * mine:
            log.info("swing estimate: the %s filter now (it predicts the payload fixes to %.3f m RMS, the other to "
                     "%.3f m)", other, theirs ** 0.5, mine ** 0.5)
            self.selected = other
            self.switches += 1

    @property
    def active(self) -> SwingEstimator:
        return self.full if self.selected == "full" else self.fixes

    def estimate(self, t_s: float) -> SwingEstimate:
        """The selected filter's estimate at ``t_s``. From ``fixes``, the fade is the lower of the two filters':
        the feed-forward comes from the full model, so the full filter's verdict on that model's fit (its q_swing
        scale, its NIS) still rules it. Flown with the fixes filter's own fade (1: its free force fits anything),
        the feed-forward kept ArduCopter SITL's payload in a 0.3 rad limit cycle at the goal, 3 m/s² saturated,
        in 2 of 4 flights (why is not measured; ArduCopter's attitude loop lagging ours would do it)."""
        self._choose()
        self.ticks_on[self.selected] += 1
        self._last_t_s = t_s
        if self.selected == "full":
            return self.full.estimate(t_s)
        se = self.fixes.estimate(t_s)
        if not abs(t_s - self._full_fade[0]) < FULL_FADE_EVERY_S:  # it changes slowly: every 50 ms is enough
            self._full_fade = (t_s, self.full.estimate(t_s).fade)
        fade = min(se.fade, self._full_fade[1])
        return se if fade == se.fade else replace(se, fade=fade)

    # -- what the report reads (the ``full`` filter's counters; the selection beside them) ------------------
    @property
    def dropped_late(self) -> int:
        return self.full.dropped_late

    @property
    def rejected_total(self) -> int:
        return self.full.rejected_total

    @property
    def resets(self) -> int:
        return self.full.resets

    @property
    def q_swing_scale(self) -> float:
        return self.full.q_swing_scale

    def selection_facts(self) -> dict[str, object]:
        """For the report: the filter in use at the end, switches, the share of ticks on ``fixes``, and how well
        each predicted the last window of fixes (RMS, m)."""
        total = sum(self.ticks_on.values())
        e_full, _ = _mean_recent(self.full.fix_sq_error)
        e_fixes, _ = _mean_recent(self.fixes.fix_sq_error)
        return {"selected": self.selected, "switches": self.switches,
                "fixes_filter_share": round(self.ticks_on["fixes"] / total, 3) if total else 0.0,
                "fix_prediction_rms_m": {"full": round(e_full ** 0.5, 4) if np.isfinite(e_full) else None,
                                         "fixes": round(e_fixes ** 0.5, 4) if np.isfinite(e_fixes) else None}}
