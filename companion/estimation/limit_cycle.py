"""A limit cycle of the flight loop itself, read from the controller's own corrections.

Why: the loop-lag fade (:mod:`companion.estimation.loop_lag`) sets the feed-forward's trust and the position gains
from the *mean* lag, but a jittery link reshuffles the setpoints the vehicle flies, and once in a while the loop
still falls into a ~1–1.5 Hz cycle at the tilt limit: through the fault suite's real-time proxy at 50 ± 25 ms each
way, 1 forest flight in ~30 cycled for ~2 s mid-cruise, and the bundled vehicle's air-mode mixer turned the
cycle into a 1.3 m climb. Such a cycle shows in the controller's correction (its commanded acceleration beyond the
reference's) before it grows: peaks of opposite sign on one axis, closer together than any payload's pendulum
swings the vehicle (half a period of a 0.5 m cable is 0.71 s). The raw commands would not do: the shaped
planner's own stops reverse a 0.39 rad tilt within 0.4 s (0.1 kg on 2 m, calm). On one, the guard lowers the loop gain
(the flight core multiplies the feed-forward's trust and the position gain scale by :meth:`LimitCycleDetector.scale`)
and lets it back up once the cycle has died. Docs: ``docs/companion.md``.
"""

from __future__ import annotations

import math

from companion.control.params import CycleGuardGains


class LimitCycleDetector:
    """The controller's horizontal correction (m/s², NED) in, one tick at a time; :meth:`scale` out (1 until a
    cycle is seen). A cycle: ``gains.peaks`` alternating peaks beyond ``gains.accel_mps2`` on one axis, each within
    ``gains.window_s`` of the one before.
    """

    def __init__(self, gains: CycleGuardGains) -> None:
        self.gains = gains
        self._sign = [0, 0]  # sign of each axis's last peak beyond the threshold (0: none yet)
        self._t_peak: list[float | None] = [None, None]  # when that peak began (s)
        self._run = [0, 0]  # alternating peaks in a row, each within the window of the one before
        self.t_detect_s: float | None = None  # the last detection (s, the caller's clock)
        self.t_first_s: float | None = None
        self.detections = 0

    def correction(self, t_s: float, north_mps2: float, east_mps2: float) -> None:
        """This tick's correction (m/s², NED north and east) at time ``t_s`` (s); non-finite values are ignored."""
        thr = self.gains.accel_mps2
        for axis, v in enumerate((north_mps2, east_mps2)):
            sign = 1 if v > thr else -1 if v < -thr else 0  # NaN compares False: no peak
            if sign == 0 or sign == self._sign[axis]:
                continue
            t_last = self._t_peak[axis]
            alternating = self._sign[axis] == -sign and t_last is not None and t_s - t_last <= self.gains.window_s
            self._run[axis] = self._run[axis] + 1 if alternating else 1
            if self._run[axis] >= self.gains.peaks:
                self._detected(t_s)
            self._sign[axis] = sign
            self._t_peak[axis] = t_s

    def reset(self) -> None:
        """Forget the peaks seen so far (the detections and the scale they set are kept)."""
        self._sign = [0, 0]
        self._t_peak = [None, None]
        self._run = [0, 0]

    def _detected(self, t_s: float) -> None:
        self.detections += 1
        self.t_detect_s = t_s
        if self.t_first_s is None:
            self.t_first_s = t_s

    def scale(self, t_s: float) -> float:
        """The loop-gain factor at ``t_s`` (s): ``gains.scale`` for ``hold_s`` after the last detection, then back
        to 1 linearly over ``recover_s``; 1 before any detection."""
        if self.t_detect_s is None or not math.isfinite(t_s):
            return 1.0
        g = self.gains
        since = t_s - self.t_detect_s
        if since <= g.hold_s:
            return g.scale
        return min(1.0, g.scale + (1.0 - g.scale) * (since - g.hold_s) / g.recover_s)
