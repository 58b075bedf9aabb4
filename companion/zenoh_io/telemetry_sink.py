"""The flight's telemetry sink over Zenoh: each tick's swing, state, setpoint, status and obstacles handed to a
:class:`~companion.zenoh_io.telemetry.ZenohTelemetry` (which decimates and publishes)."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from companion.zenoh_io.telemetry import ZenohTelemetry


class ZenohTelemetrySink:
    """The app's ``TelemetrySink`` (``on_tick(est, cmd, app)``) over a :class:`ZenohTelemetry`.

    Per tick: swing (``est.swing``, ``cmd.r_max_m``, ``cmd.envelope_mode``), state (payload position from the
    swing and ``cable_l_m``), setpoint (every field of ``cmd``), status (``status_fn(app)``, default empty)
    and the obstacle set last returned by ``zt.obstacles_current`` (use ``zt.obstacle_source(...)`` as the
    app's obstacle source and ``zt.ingest`` as its obstacle ingest), or, once the pilot maps what its sensors
    see (``app.pilot.perception``), the set the planner was given last with the perceived trunks. Duck-typed:
    only those attribute names are read.
    """

    def __init__(self, zt: ZenohTelemetry, cable_l_m: float,
                 status_fn: Callable[[Any], Mapping[str, Any]] | None = None) -> None:
        self.zt = zt
        self.cable_l_m = cable_l_m
        self.status_fn = status_fn

    def on_transition(self, t: Any, app: Any) -> None:
        """Nothing: the sequence's state reaches subscribers in the 1 Hz status sample."""

    def on_tick(self, est: Any, cmd: Any, app: Any) -> None:
        """Publish this tick's samples (decimation happens inside :class:`ZenohTelemetry`)."""
        zt, t = self.zt, float(est.t_s)
        r_max = float(getattr(cmd, "r_max_m", math.nan)) if cmd is not None else math.nan
        mode = str(getattr(cmd, "envelope_mode", "none")) if cmd is not None else "none"
        src = getattr(est, "swing_source", None)
        truth = sigma = fade = None
        if src == "estimate":
            truth = app.state.measured_swing()
            last = app.swing_feed.last
            if last is not None:
                sigma, fade = float(last.sigma_rad), float(last.fade)
        zt.publish_swing(t, est.swing, r_max, mode, src, truth, sigma, fade)
        payload = None
        if est.swing is not None:
            a, b = float(est.swing[0]), float(est.swing[1])
            # = companion.core.model.payload_offset_ned_m (eqs. 3-4), inlined to keep numba out of the CLI tools
            payload = np.asarray(est.pos_ned_m, dtype=float) + self.cable_l_m * np.array(
                [math.sin(a) * math.cos(b), -math.sin(b), math.cos(a) * math.cos(b)])
        zt.publish_state(t, est.pos_ned_m, est.vel_ned_mps, est.euler_rad, payload)
        if cmd is not None:
            zt.publish_setpoint(t, {k: v for k, v in cmd._asdict().items() if k != "t_s"})
        zt.publish_status(t, self.status_fn(app) if self.status_fn is not None else {})
        obstacles = zt.last_obstacles
        pilot = getattr(app, "pilot", None)
        if pilot is not None and getattr(pilot, "perception", None) is not None:
            obstacles = pilot.obstacles.in_use  # the perceived trunks too (source "perception")
        if obstacles is not None:
            zt.publish_obstacles(t, obstacles)
