"""The control loop's lag, measured from the companion's own attitude commands and the attitude that comes back.

Why it matters: the anti-swing feed-forward (:mod:`companion.control.position`) closes a loop through the
swing — the vehicle's acceleration moves the cable angle the feed-forward reads — and a loop has a delay
margin. Flown in lockstep with a delay line on both directions of the link (``fly_inprocess(link_delay_s=)``,
forest), the loop lag the companion sees is the bundled vehicle's attitude response (76 ms) plus both delays.
With the full feed-forward the hold at the goal is steady at 50 ms each way (tilt ≤ 0.10 rad) and falls into a
~1.3 Hz limit cycle at the 0.6 rad tilt limit from 60 ms each way; without feed-forward the position loop
itself cycles only from ~100 ms. In real time, through a proxy adding 50 ± 25 ms each way, the full
feed-forward fell into that cycle rarely (1 run in ~17). So the feed-forward is faded by the *excess* of the
measured lag over the lag the autopilot shows on a clean link
(:attr:`companion.autopilots.profile.VehicleProfile.nominal_loop_lag_s`), see :func:`lag_trust`; from a larger
excess the horizontal position gains are softened as well (:class:`companion.control.params.SmcGains`).

How it is measured: the lag is the delay K (ticks) that makes the commanded roll and pitch of K ticks ago match
the roll and pitch that arrive now, best in the least-squares sense over the last few seconds. Counted in
control ticks, it holds everything the loop goes through: the setpoint's trip out, the autopilot's attitude
response, the telemetry's trip back. A first-order attitude response reads as a delay about its time
constant. Without enough excitation (a steady hover) the last valid figure is kept. Cost per tick: one
ring-buffer write, and every ``step_s`` one update of ~60 squared errors (numpy, 11–20 µs on this VM).
"""

from __future__ import annotations

import math

import numpy as np

MIN_FILL = 0.2  # share of the exponential memory that must hold data before a lag counts


class LoopLagEstimator:
    """Loop lag (s) from commanded vs measured roll and pitch, counted in control ticks of ``period_s``.

    Per tick: :meth:`observe` the measured attitude (rad) first, then :meth:`command` the tick's setpoint (rad).
    Lags tried: 1 tick (the previous tick's command) up to ``max_lag_s`` in steps of about ``step_s``; errors are
    averaged with an exponential memory of ``memory_s``. A lag counts once the lagged commands differ from the
    measurement by at least ``min_rms_rad`` (RMS, the signal's own variation) and the best lag's error is at most
    ``contrast`` times the mean error over all lags, and not before a fifth of the memory is filled (the first
    ~0.7 s; a handful of samples at lift-off once read 148 ms for a 76 ms loop).
    """

    def __init__(self, period_s: float, *, max_lag_s: float = 0.5, step_s: float = 0.008, memory_s: float = 3.0,
                 min_rms_rad: float = 0.02, contrast: float = 0.25) -> None:
        if not (period_s > 0.0 and max_lag_s > period_s and memory_s > 0.0):
            raise ValueError(f"period_s, max_lag_s, memory_s: need 0 < period_s < max_lag_s and memory_s > 0, got "
                             f"{period_s}, {max_lag_s}, {memory_s}")
        self.period_s = float(period_s)
        self._stride = max(1, round(step_s / period_s))
        self._lags = np.arange(1, int(max_lag_s / period_s) + 1, self._stride)  # ticks; 1 = the previous command
        self._ring_n = int(self._lags[-1]) + self._stride + 1  # the strided view below never reaches index < 0
        # each command twice, at i and i + n: the lagged commands are then one strided view, newest first
        self._ring = np.zeros((2 * self._ring_n, 2))
        self._count = 0  # commands pushed
        self._err = np.zeros(self._lags.size)
        self._scratch = np.zeros((self._lags.size, 2))
        self._sq = np.zeros(self._lags.size)
        self._meas = np.zeros(2)
        self._weight = 0.0  # how much of the memory is filled (0..1), for a fair start
        self._lambda = math.exp(-self._stride * period_s / memory_s)
        self._min_ms = min_rms_rad * min_rms_rad
        self._contrast = contrast
        self.lag_s: float | None = None  # the last valid figure
        self.updates = 0  # lag updates that counted

    def observe(self, roll_rad: float, pitch_rad: float) -> float | None:
        """The measured attitude at this tick; returns the current lag estimate (s) or None (none valid yet)."""
        n = self._count
        if n <= self._lags[-1] or n % self._stride or not (math.isfinite(roll_rad) and math.isfinite(pitch_rad)):
            return self.lag_s
        a = (n - 1) % self._ring_n + self._ring_n
        b = a - self._stride * self._lags.size
        meas = self._meas
        meas[0] = roll_rad
        meas[1] = pitch_rad
        d = self._scratch
        np.subtract(self._ring[a:b:-self._stride], meas, out=d)
        np.multiply(d, d, out=d)
        sq = self._sq
        np.add(d[:, 0], d[:, 1], out=sq)
        lam = self._lambda
        self._err *= lam
        sq *= 1.0 - lam
        self._err += sq
        self._weight = lam * self._weight + (1.0 - lam)
        err = self._err  # weighted by self._weight: the thresholds are scaled instead of the errors
        k = int(err.argmin())
        mean = float(err.sum()) / err.size
        if (self._weight >= MIN_FILL and mean >= self._min_ms * self._weight
                and float(err[k]) <= self._contrast * mean):
            self.lag_s = float(self._lags[k]) * self.period_s
            self.updates += 1
        return self.lag_s

    def command(self, roll_rad: float, pitch_rad: float) -> None:
        """This tick's commanded roll and pitch (rad)."""
        if math.isfinite(roll_rad) and math.isfinite(pitch_rad):
            i = self._count % self._ring_n
            ring = self._ring
            ring[i, 0] = ring[i + self._ring_n, 0] = roll_rad
            ring[i, 1] = ring[i + self._ring_n, 1] = pitch_rad
        self._count += 1


def lag_trust(lag_s: float | None, nominal_s: float, full_excess_s: float, zero_excess_s: float,
              floor: float = 0.0) -> float:
    """A factor for a measured loop lag (s): 1 up to ``nominal_s + full_excess_s``, falling linearly to ``floor`` at
    ``nominal_s + zero_excess_s`` and staying there; 1 while nothing is measured (None). The feed-forward's trust
    (floor 0) and the position loop's gain scale (:class:`companion.control.params.SmcGains`) both use it."""
    if lag_s is None:
        return 1.0
    excess = lag_s - nominal_s
    if excess <= full_excess_s:
        return 1.0
    if excess >= zero_excess_s:
        return floor
    return floor + (1.0 - floor) * (zero_excess_s - excess) / (zero_excess_s - full_excess_s)
