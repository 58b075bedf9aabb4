"""The swing estimator in the flight: which autopilot messages feed it, when it starts, and which swing the
flight core gets (pure: no I/O). The app hands every accepted telemetry event
(:mod:`companion.mavlink_io.telemetry`) to :meth:`SwingFeed.ingest`, the commanded
thrust to :meth:`SwingFeed.commanded`, and asks :meth:`SwingFeed.choose` for the swing of each tick.

``--swing-input``:

============================  ==================================================================================
``auto``                      the cable-angle sensor where the vehicle has one (the bundled vehicle), else the
                              estimator on whatever arrives (IMU, payload fixes, velocity); says which
``cable_sensor``              only the sensor (DEBUG_FLOAT_ARRAY "SWING")
``estimate``                  the estimator on everything available, even where a sensor exists (its truth
                              is then logged beside the estimate, with the error)
``estimate_imu``              sensorless: the vehicle's own IMU, attitude, velocity and commanded thrust
``estimate_fixes``            the payload's position fixes (and the vehicle's velocity), no IMU
``payload_position``          the payload's fixes inverted directly (eqs. 3–4): envelope only, no feed-forward
``none``                      no swing: full-cable envelope, no feed-forward
============================  ==================================================================================

The estimator starts once the payload hangs: the vehicle airborne and a cable's length above where it stood (the
model is of a flying vehicle with a taut cable: on the ground the ground's reaction, and with a slack cable the
missing pull, would be read as forces). Before that the flight core flies on the full-cable envelope, as for a
vehicle without any swing input; payload fixes nearer than the cable's length (a payload on the ground) are
skipped.

Message mapping (vehicle unless said): ATTITUDE → attitude; LOCAL_POSITION_NED → velocity (and the position
history payload positions are taken against); HIGHRES_IMU (m/s²) and SCALED_IMU (mG) → specific force; the
vehicle's GLOBAL_POSITION_INT → a short history the payload's GLOBAL_POSITION_INT fixes are differenced against
(ArduPilot's slung-payload convention, interpolated at the fix's time); the payload's LOCAL_POSITION_NED → a
payload position fix.
"""

from __future__ import annotations

import bisect
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from companion.core.mission import Mission
from companion.core.vehicle_params import VehicleParams
from companion.estimation.estimate import Estimate
from companion.estimation.swing_config import SwingEstimate, SwingEstimatorConfig
from companion.estimation.swing_estimator import SwingEstimator
from companion.estimation.swing_model import payload_offset_from_global, swing_from_offset
from companion.estimation.two_model import TwoModelEstimator
from companion.mavlink_io.telemetry import (
    MG_TO_MPS2,  # noqa: F401  (re-exported: SCALED_IMU's unit, used to be defined here)
    Attitude,
    GlobalPositionInt,
    HighresImu,
    LocalPositionNed,
    ScaledImu,
    TelemetryEvent,
)

if TYPE_CHECKING:
    from companion.estimation.vehicle_state import VehicleState

Estimator = SwingEstimator | TwoModelEstimator

log = logging.getLogger(__name__)

SLACK_FRACTION = 0.95  # a payload fix nearer than this fraction of the cable: the payload lies on the ground
START_SWING_SIGMA_RAD = 0.15  # 1σ of the swing when the estimator starts (just after the cable went taut)
SLACK_MARGIN_M = 0.1  # the estimator starts this far above a cable's length over the ground it stood on
# ... and once the take-off climb has slowed below this vertical speed (or START_MAX_WAIT_S after the cable went
# taut, whichever is first). Measured on the bundled vehicle's forest flight replayed from its .tlog (sensorless,
# IMU + attitude + velocity + commanded thrust): started right after the cable snapped taut mid-climb (1.2 m/s up,
# the airframe jerked by the payload) the estimator settles on a wrong force/bias split it never leaves, RMS 0.13
# rad; started once the climb slowed below 0.6 m/s, 0.016 rad. The flight core flies on the full-cable envelope
# until then, as without a swing input.
START_MAX_CLIMB_MPS = 0.6
START_MAX_WAIT_S = 3.0
ESTIMATOR_INPUTS = ("estimate", "estimate_imu", "estimate_fixes")
_GLOBAL_HISTORY = 64
# An estimate beyond these has diverged (a payload hanging under a flying vehicle does not swing past 80° or
# at 15 rad/s): it is dropped and a fresh estimator started, never handed to the controller
MAX_SWING_RAD = 1.4
MAX_SWING_RATE_RAD_S = 15.0
_PLAUSIBLE = np.array([MAX_SWING_RAD, MAX_SWING_RAD, MAX_SWING_RATE_RAD_S, MAX_SWING_RATE_RAD_S])
# what a numerical failure of the estimator raises (an overflow, a singular innovation covariance)
_NUMERIC_FAILURES = (ArithmeticError, np.linalg.LinAlgError)
_USED_HISTORY = 1000  # estimates kept for scoring fixes (2-4 s at 250 Hz)
_PENDING_FIXES = 16  # payload fixes waiting for a vehicle fix after them (1.6 s at 10 Hz)


def estimator_config(mission: Mission) -> SwingEstimatorConfig:
    """The estimator's configuration a mission asks for: the defaults, with the payload's drag coefficient from
    its ``[payload]`` table."""
    return SwingEstimatorConfig(init_payload_drag=mission.payload.drag_n_per_mps2)


@dataclass
class SwingFeed:
    """One flight's swing input. ``params``: the model the estimator uses (the mission's, with ``[payload]``);
    ``swing_input``: see the module docstring; ``config``: the estimator's noise model."""

    params: VehicleParams
    swing_input: str = "auto"
    config: SwingEstimatorConfig = field(default_factory=SwingEstimatorConfig)
    estimator: SwingEstimator | TwoModelEstimator | None = None
    last: SwingEstimate | None = None
    ran: SwingEstimator | TwoModelEstimator | None = None  # this flight's estimator, kept after it stopped (report)
    last_seen: SwingEstimate | None = None  # its newest estimate, kept after it stopped
    counts: dict[str, int] = field(default_factory=dict)
    _ground_z: float | None = None  # where the vehicle stood (local NED z, m), seen while on the ground
    _taut_since_s: float | None = None  # when the vehicle first was a cable's length up (vehicle time, s)
    payload_offset: tuple[float, np.ndarray] | None = None  # (t, payload − airframe NED m) of the newest fix
    fresh_offsets: list[tuple[float, np.ndarray, np.ndarray]] = field(default_factory=list)
    _pending_fixes: list[tuple[float, tuple[float, float, float], np.ndarray]] = field(default_factory=list)
    _vglobal_t: list[float] = field(default_factory=list)
    _vglobal: list[tuple[float, float, float]] = field(default_factory=list)
    # the estimates the controller got, (t s, α rad, β rad), the last ~2 s: to score each payload fix against the
    # estimate of its own time (the fix arrives 0.1-0.2 s after it; held until then it is a stale "truth")
    _used_t: list[float] = field(default_factory=list)
    _used_ab: list[tuple[float, float]] = field(default_factory=list)
    fix_errors_rad: list[float] = field(default_factory=list)  # |estimate(t_fix) − angles of the fix|, taut fixes

    @property
    def wants_estimator(self) -> bool:
        """Whether this swing input may run the estimator at all (``auto`` only without a cable sensor)."""
        return self.swing_input in ("auto", *ESTIMATOR_INPUTS)

    @property
    def use_imu(self) -> bool:
        return self.swing_input in ("auto", "estimate", "estimate_imu")

    @property
    def use_fixes(self) -> bool:
        return self.swing_input in ("auto", "estimate", "estimate_fixes")

    def _count(self, what: str) -> None:
        self.counts[what] = self.counts.get(what, 0) + 1

    def _failed(self, exc: Exception) -> None:
        """The estimator broke (a numerical failure on inputs its model cannot explain): drop it, fly on without
        its swing until :meth:`maybe_start` starts a fresh one (the next tick, if still airborne)."""
        self._count("estimator_failed")
        log.warning("swing estimator failed (%r, %d times): restarting it", exc, self.counts["estimator_failed"])
        self.estimator = None

    def use_payload(self, params: VehicleParams) -> None:
        """The estimator's model from now on (an identified payload): a running estimator is dropped and
        :meth:`maybe_start` starts a fresh one on ``params`` at the next tick (its feed-forward fades in again)."""
        self.params = params
        if self.estimator is not None:
            self.estimator = None
            self._count("restarted_for_identified_payload")

    # ------------------------------------------------------------------------------------------ start
    def maybe_start(self, state: VehicleState) -> None:
        """Start the estimator at lift-off (airborne and armed), if this swing input wants it and — for
        ``auto`` — the vehicle has no cable sensor; stop it once the payload is down again (the vehicle on the
        ground, or lower than a cable's length over where it took off: the cable is slack, there is no swing)."""
        if self.estimator is not None:
            low = (self._ground_z is not None and state.pos_ned_m is not None
                   and float(state.pos_ned_m[2]) > self._ground_z - self.params.l)
            if state.on_ground or low:
                self.estimator = None
                self._taut_since_s = None
                self._count("stopped_payload_down")
            return
        if not self.wants_estimator or state.vel_ned_mps is None:
            return
        if self.swing_input == "auto" and state.swing_sensor is not None:
            return
        if state.on_ground and state.pos_ned_m is not None:
            self._ground_z = float(state.pos_ned_m[2])
        if not state.armed or state.on_ground:
            return
        if self._ground_z is not None and state.pos_ned_m is not None and \
                float(state.pos_ned_m[2]) > self._ground_z - (self.params.l + SLACK_MARGIN_M):
            return  # not a cable's length up yet: the payload may still lie on the ground
        if self._taut_since_s is None:
            self._taut_since_s = state.t_s
        if abs(float(state.vel_ned_mps[2])) > START_MAX_CLIMB_MPS and \
                state.t_s - self._taut_since_s < START_MAX_WAIT_S:
            return  # still in the take-off climb (see START_MAX_CLIMB_MPS)
        # the cable has just snapped taut: the payload may already swing, so the start is uncertain
        # with payload fixes, a second filter on the fixes alone stands by for a payload whose pull on the airframe
        # is not our model's (two_model.py)
        kind = TwoModelEstimator if self.use_fixes else SwingEstimator
        self.estimator = kind(self.params, self.config, t0_s=state.t_s, vel0_ned_mps=state.vel_ned_mps,
                              swing_sigma0_rad=START_SWING_SIGMA_RAD)
        self.ran = self.estimator
        if state.euler_rad is not None:
            self.estimator.set_attitude_euler(state.t_s, state.euler_rad, state.rates_frd_rad_s)

    # ------------------------------------------------------------------------------------------ messages
    def ingest(self, ev: TelemetryEvent, state: VehicleState) -> None:
        """One event ``state`` accepted (its ``ingest`` did not answer ``REJECTED``)."""
        cls = ev.__class__
        src = ev.src_system
        if cls is GlobalPositionInt:
            if src == state.vehicle_sysid:
                self._vehicle_global(ev)
            elif src == state.payload_sysid:
                self._payload_global(ev)
            return
        est = self.estimator
        if est is None:
            return
        if src == state.vehicle_sysid:
            handler = _VEHICLE_INPUTS.get(cls)
        elif src == state.payload_sysid and cls is LocalPositionNed:
            handler = SwingFeed._payload_position
        else:
            return
        if handler is None:
            return
        try:
            handler(self, est, ev, state)
        except _NUMERIC_FAILURES as exc:
            self._failed(exc)

    def _vehicle_global(self, ev: GlobalPositionInt) -> None:
        """The vehicle's own GLOBAL_POSITION_INT: the history payload fixes are differenced against."""
        t = ev.t_boot_s
        if not self._vglobal_t or t > self._vglobal_t[-1]:
            self._vglobal_t.append(t)
            self._vglobal.append((ev.lat_deg, ev.lon_deg, ev.alt_amsl_m))
            if len(self._vglobal_t) > _GLOBAL_HISTORY:
                del self._vglobal_t[0], self._vglobal[0]
            self._complete_payload_fixes()

    def _attitude(self, est: Estimator, ev: Attitude, state: VehicleState) -> None:
        est.set_attitude_euler(ev.t_boot_s, state.euler_rad, state.rates_frd_rad_s)

    def _velocity(self, est: Estimator, ev: LocalPositionNed, state: VehicleState) -> None:
        est.update_velocity(ev.t_boot_s, state.vel_ned_mps, state.pos_ned_m)

    def _highres_imu(self, est: Estimator, ev: HighresImu, state: VehicleState) -> None:
        if self.use_imu:
            est.update_imu(ev.t_s, ev.accel_frd_mps2)
            self._count("imu")

    def _scaled_imu(self, est: Estimator, ev: ScaledImu, state: VehicleState) -> None:
        if self.use_imu:
            est.update_imu(ev.t_boot_s, ev.accel_frd_mps2)
            self._count("imu")

    def _payload_position(self, est: Estimator, ev: LocalPositionNed, state: VehicleState) -> None:
        """The payload's own position stream (a fix), skipped while the cable is slack."""
        if not self.use_fixes:
            return
        p = ev.pos_ned_m
        if state.pos_ned_m is not None and math.dist(p, state.pos_ned_m) < SLACK_FRACTION * self.params.l:
            self._count("slack_fix")
            return
        if est.update_payload_position(ev.t_boot_s, p):
            self._count("payload_fix")

    def _payload_global(self, ev: GlobalPositionInt) -> None:
        """A payload GLOBAL_POSITION_INT (ArduPilot's convention): kept until the vehicle's own GLOBAL_POSITION_INT
        brackets its time, then differenced against the vehicle's position interpolated there.

        Both arrive at 10 Hz from ArduCopter, the payload's ~80 ms after the vehicle's: differenced against the
        newest vehicle fix instead, the offset was off by the vehicle's travel in between (0.4 m at 5 m/s)."""
        t = ev.t_boot_s
        fix = (t, (ev.lat_deg, ev.lon_deg, ev.alt_amsl_m), np.array(ev.vel_ned_mps))
        self._pending_fixes.append(fix)
        if len(self._pending_fixes) > _PENDING_FIXES:
            del self._pending_fixes[0]
            self._count("payload_fix_unpaired")
        self._complete_payload_fixes()

    def _complete_payload_fixes(self) -> None:
        """Difference the pending payload fixes the vehicle's history now covers (see :meth:`_payload_global`)."""
        ts = self._vglobal_t
        while self._pending_fixes and ts and self._pending_fixes[0][0] <= ts[-1]:
            t, (lat, lon, alt), vel = self._pending_fixes.pop(0)
            v = self._vehicle_global_at(t)
            if v is None:
                self._count("payload_fix_unpaired")
                continue
            off = payload_offset_from_global(lat, lon, alt, *v)
            if not np.all(np.isfinite(off)):
                continue
            self.payload_offset = (t, off)
            self.fresh_offsets.append((t, off, vel))
            self._use_payload_offset(t, off)

    def _use_payload_offset(self, t: float, off: np.ndarray) -> None:
        """One differenced payload fix for the estimator (skipped while the cable is slack)."""
        if self.estimator is None:
            return
        if float(np.linalg.norm(off)) < SLACK_FRACTION * self.params.l:
            self._count("slack_fix")
            return
        self._score_fix(t, off)  # also when the estimate does not use the fixes (estimate_imu)
        if not self.use_fixes:
            return
        try:
            self.estimator.update_payload_offset(t, off)
        except _NUMERIC_FAILURES as exc:
            self._failed(exc)
            return
        self._count("payload_fix")

    def _score_fix(self, t: float, off: np.ndarray) -> None:
        """Error of the estimate the controller had at the fix's time t (interpolated between ticks) against the
        fix's own angles; nothing when no estimate brackets t."""
        ts = self._used_t
        i = bisect.bisect_left(ts, t)
        if i == 0 or i >= len(ts) or ts[i] - ts[i - 1] > 0.1:
            return
        w = (t - ts[i - 1]) / (ts[i] - ts[i - 1]) if ts[i] > ts[i - 1] else 0.0
        (a0, b0), (a1, b1) = self._used_ab[i - 1], self._used_ab[i]
        a, b = swing_from_offset(off)
        self.fix_errors_rad.append(math.hypot(a0 + w * (a1 - a0) - a, b0 + w * (b1 - b0) - b))

    def fix_error_summary(self) -> dict[str, float | int] | None:
        """RMS and max (rad) of :attr:`fix_errors_rad` and how many fixes, or None without any."""
        e = self.fix_errors_rad
        if not e:
            return None
        return {"fixes": len(e), "rms_rad": math.sqrt(sum(v * v for v in e) / len(e)), "max_rad": max(e)}

    def take_fresh_offsets(self) -> list[tuple[float, np.ndarray, np.ndarray]]:
        """The payload fixes differenced since the last call: (t s, payload − airframe NED m, payload NED m/s)."""
        out, self.fresh_offsets = self.fresh_offsets, []
        return out

    def _vehicle_global_at(self, t: float) -> tuple[float, float, float] | None:
        """The vehicle's (lat, lon, alt) at ``t``, linearly interpolated; None outside the history (+0.2 s)."""
        ts = self._vglobal_t
        if not ts or t < ts[0] or t > ts[-1] + 0.2:
            return None
        i = bisect.bisect_right(ts, t)
        if i >= len(ts):
            return self._vglobal[-1]
        if i == 0:
            return self._vglobal[0]
        t0, t1 = ts[i - 1], ts[i]
        w = (t - t0) / (t1 - t0) if t1 > t0 else 0.0
        a, b = self._vglobal[i - 1], self._vglobal[i]
        return (a[0] + w * (b[0] - a[0]), a[1] + w * (b[1] - a[1]), a[2] + w * (b[2] - a[2]))

    def commanded(self, t_s: float, thrust_n: float) -> None:
        """The collective thrust (N) the companion commanded at ``t_s`` (an input of the estimator's model)."""
        if self.estimator is not None and math.isfinite(thrust_n):
            try:
                self.estimator.set_thrust(t_s, thrust_n)
            except _NUMERIC_FAILURES as exc:
                self._failed(exc)

    # ------------------------------------------------------------------------------------------ choice
    def choose(self, est: Estimate) -> Estimate:
        """The tick's estimate with the swing this input gives the flight core (the vehicle state chose among
        the sensor and the direct payload inversion already)."""
        if self.estimator is None:
            self.last = None
            if self.swing_input in (*ESTIMATOR_INPUTS,) or (self.swing_input == "auto"
                                                             and est.swing_source != "cable_sensor"):
                return replace(est, swing=None, swing_source="none")
            return est
        if self.swing_input == "auto" and est.swing_source == "cable_sensor":
            return est
        try:
            se = self.estimator.estimate(est.t_s)
        except _NUMERIC_FAILURES as exc:
            self._failed(exc)
            self.last = None
            return replace(est, swing=None, swing_source="none")
        if not np.all(np.abs(se.swing) <= _PLAUSIBLE):  # NaN and inf fail this too
            self._failed(FloatingPointError(f"implausible swing estimate {np.round(se.swing, 3).tolist()}"))
            self.last = None
            return replace(est, swing=None, swing_source="none")
        self.last = self.last_seen = se
        if not self._used_t or est.t_s > self._used_t[-1]:
            self._used_t.append(float(est.t_s))
            self._used_ab.append((float(se.swing[0]), float(se.swing[1])))
            if len(self._used_t) > _USED_HISTORY:
                del self._used_t[:_USED_HISTORY // 2], self._used_ab[:_USED_HISTORY // 2]
        return replace(est, swing=se.swing, swing_source="estimate", swing_fade=se.fade,
                       swing_bound_rad=se.bound_rad)


#: The vehicle's events the running estimator takes, and how.
_VEHICLE_INPUTS: dict[type, Callable[[SwingFeed, Estimator, Any, VehicleState], None]] = {
    Attitude: SwingFeed._attitude,
    LocalPositionNed: SwingFeed._velocity,
    HighresImu: SwingFeed._highres_imu,
    ScaledImu: SwingFeed._scaled_imu,
}
