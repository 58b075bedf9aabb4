"""The telemetry streams' keys and rates (:class:`TelemetryOptions`, ``--zenoh-rates`` as :func:`parse_rates`
reads it) and the decimation by sim time that applies them."""

from __future__ import annotations

import math
from dataclasses import dataclass

from companion.errors import ConfigError
from companion.zenoh_io.session import DEFAULT_PREFIX, check_key_part

RATE_STREAMS = ("swing", "state", "setpoint", "status")


def parse_rates(text: str | None) -> dict[str, float]:
    """``"swing=25,state=10"`` → ``{"swing_hz": 25.0, "state_hz": 10.0}`` (:class:`TelemetryOptions` fields);
    raises ``ValueError`` naming the bad part."""
    out: dict[str, float] = {}
    for part in (text or "").split(","):
        if not part.strip():
            continue
        name, sep, value = part.partition("=")
        name = name.strip()
        if not sep or name not in RATE_STREAMS:
            raise ValueError(f"{part.strip()!r}: expected STREAM=HZ with STREAM one of {', '.join(RATE_STREAMS)}")
        try:
            hz = float(value)
        except ValueError:
            raise ValueError(f"{part.strip()!r}: {value.strip()!r} is not a number of Hz") from None
        if not (math.isfinite(hz) and hz >= 0.0):
            raise ValueError(f"{part.strip()!r}: a rate must be finite and >= 0 Hz")
        out[f"{name}_hz"] = hz
    return out


@dataclass(frozen=True, slots=True)
class TelemetryOptions:
    """Keys and rates of the telemetry streams (rates in Hz of sim time; 0 means every call).

    ``express`` off by default: with Zenoh's batching a starved TX thread does not drop samples (with
    express each sample takes one of the 16 queue slots, and samples were lost under CPU load), and the
    latency is the same in our measurements. ``background``: encode and put in a worker thread.
    """

    prefix: str = DEFAULT_PREFIX
    vehicle_id: str = "1"
    swing_hz: float = 0.0  # 0: every control tick
    state_hz: float = 50.0
    setpoint_hz: float = 50.0
    status_hz: float = 1.0
    obstacles_min_hz: float = 1.0
    obstacles_max_hz: float = 20.0
    express: bool = False
    subscribe_obstacles: bool = True
    background: bool = True

    def validate(self) -> None:
        """Raise ``ValueError("<key>: ...")`` on bad keys or rates."""
        for key in ("prefix", "vehicle_id"):
            try:
                check_key_part(key, getattr(self, key))
            except ConfigError as exc:
                raise ValueError(str(exc)) from None
        for key in ("swing_hz", "state_hz", "setpoint_hz", "status_hz", "obstacles_min_hz", "obstacles_max_hz"):
            v = getattr(self, key)
            if not math.isfinite(v) or v < 0.0:
                raise ValueError(f"{key}: must be a finite rate >= 0 Hz, got {v!r}")
        if self.obstacles_min_hz <= 0.0:
            raise ValueError("obstacles_min_hz: must be > 0 Hz (the obstacles stream is sent at least this often)")


class _Every:
    """Decimation by the caller's clock: due at most once per ``period_s``, phase-locked to the schedule;
    a clock that jumps back or far ahead restarts the schedule."""

    def __init__(self, rate_hz: float) -> None:
        self.period_s = 1.0 / rate_hz if rate_hz > 0.0 else 0.0
        self._last = -math.inf
        self._next = -math.inf

    def due(self, t_s: float) -> bool:
        if self.period_s == 0.0:
            return True
        if self._last <= t_s < self._next - 1e-9:
            return False
        if t_s < self._last or t_s >= self._next + self.period_s:
            self._next = t_s + self.period_s
        else:
            self._next += self.period_s
        self._last = t_s
        return True
