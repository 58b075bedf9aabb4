"""The control loop's timing over a flight: each tick's compute, CPU and send time, lateness in real time, and
the counts the report gives (``loop`` in report.json). Filled by the runners; pure data."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: The provisional report's loop timings: the last 10 s at 250 Hz (see :meth:`LoopStats.summary`).
PROVISIONAL_WINDOW_TICKS = 2_500


@dataclass
class LoopStats:
    """Tick timing: compute time per tick (receive → setpoint sent) and lateness in real time."""

    ticks: int = 0
    late_ticks: int = 0
    preempted_ticks: int = 0  # ticks during which the kernel switched the control thread out
    scheduling: str = "SCHED_OTHER"  # what the control thread ran as
    ingest_errors: int = 0
    watchdog_steps: int = 0
    #: lockstep only (None in real time, where the watchdog ticks whenever the wall-clock ticks stop): watchdog ticks
    #: since the vehicle's last datagram, about one per 0.1 s while the loop listens, so a vehicle gone quiet shows
    #: many before a ``link_lost`` and a stall of the companion's own about none
    watchdog_since_rx: int | None = None
    tick_s: list[float] = field(default_factory=list)
    tick_cpu_s: list[float] = field(default_factory=list)  # the same ticks in this thread's CPU time
    send_s: list[float] = field(default_factory=list)
    ingest_s: list[float] = field(default_factory=list)  # live obstacle parsing after each tick (outside it)
    after_s: list[float] = field(default_factory=list)  # the flight core's bookkeeping after the send (outside it)
    jitter_s: list[float] = field(default_factory=list)
    first: tuple[float, float] | None = None  # (wall monotonic s, vehicle time s) of the first tick with telemetry
    last: tuple[float, float] | None = None

    def summary(self, window: int | None = None) -> dict[str, float | int | None]:
        """ticks; tick (compute) and send time p50/p99/max (ms); the tick's CPU time p50/p99 (ms: what it costs
        when not preempted; on a busy machine the wall time includes other processes' time slices); late ticks;
        preempted ticks and the thread's scheduling policy; jitter p99 and max (ms, real time only); p99 of the
        obstacle input's parsing and of the flight core's bookkeeping, both after the send (ms).

        ``window``: the timings of the last ``window`` ticks only (``window_ticks`` says so). The journal's
        provisional report, made on the event loop once a second, uses it: over a whole long flight the
        percentiles cost 50 ms at 150,000 ticks (10 min) and 150 ms at 450,000 (30 min), a stall every second;
        over the last 2,500 ticks, ~1.2 ms whatever the flight's length."""
        def arr(xs: list[float]) -> np.ndarray:
            xs = xs[-window:] if window else xs
            return np.array(xs) if xs else np.zeros(1)

        t, tc, snd, j = arr(self.tick_s), arr(self.tick_cpu_s), arr(self.send_s), arr(self.jitter_s)
        ingest = self.ingest_s[-window:] if window else self.ingest_s
        after = self.after_s[-window:] if window else self.after_s
        return {
            "ticks": self.ticks,
            "window_ticks": window,
            "tick_ms_p50": float(np.percentile(t, 50) * 1e3),
            "tick_ms_p99": float(np.percentile(t, 99) * 1e3),
            "tick_ms_max": float(t.max() * 1e3),
            "tick_cpu_ms_p50": float(np.percentile(tc, 50) * 1e3),
            "tick_cpu_ms_p99": float(np.percentile(tc, 99) * 1e3),
            "send_ms_p50": float(np.percentile(snd, 50) * 1e3),
            "send_ms_p99": float(np.percentile(snd, 99) * 1e3),
            "ingest_ms_p99": float(np.percentile(ingest, 99) * 1e3) if ingest else 0.0,
            "after_ms_p99": float(np.percentile(after, 99) * 1e3) if after else 0.0,
            "late_ticks": self.late_ticks,
            "preempted_ticks": self.preempted_ticks,
            "scheduling": self.scheduling,
            "ingest_errors": self.ingest_errors,
            "watchdog_steps": self.watchdog_steps,
            "watchdog_steps_since_rx": self.watchdog_since_rx,
            "jitter_ms_p99": float(np.percentile(np.abs(j), 99) * 1e3),
            "jitter_ms_max": float(np.abs(j).max() * 1e3),  # the longest the loop kept a tick waiting (a stall)
            "realtime_factor": self.realtime_factor(),
        }

    def realtime_factor(self) -> float | None:
        """Vehicle seconds flown per wall second between the first and the last tick (lockstep speed)."""
        if self.first is None or self.last is None or self.last[0] <= self.first[0]:
            return None
        return (self.last[1] - self.first[1]) / (self.last[0] - self.first[0])
