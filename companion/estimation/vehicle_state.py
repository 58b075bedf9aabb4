"""What the companion knows about the vehicle, folded from incoming MAVLink messages, and how much to trust it.

``VehicleState.ingest(event, wall_s)`` takes typed telemetry events (:mod:`companion.mavlink_io.telemetry`:
``decode(msg)`` of each received message) with the wall time they arrived; ``estimate()`` turns the
latest ones into a :class:`~companion.estimation.estimate.Estimate`. Pure: no sockets, no clocks.

Trust. The vehicle is the system of the first autopilot HEARTBEAT (``autopilot`` not INVALID); only its
messages update the state (the link also drops datagrams from any other address). Every value is checked
before it is believed, and what fails is counted in ``rejected`` by kind:

* ``nonfinite``: NaN or ±inf in a field the companion uses (position, velocity, attitude, swing, IMU, home,
  estimator accuracy, parameter value): refused while decoding
  (:class:`~companion.mavlink_io.telemetry.Rejected`), counted here;
* ``time_backwards`` / ``time_jump``: a ``time_boot_ms`` more than 0.5 s behind the vehicle clock, or ahead
  of it by more than 1 s plus what the wall clock allows (``max_time_rate`` vehicle seconds per wall second:
  ~1 in real time, large in lockstep where the simulator runs ahead of the wall clock);
* ``position_jump``: a position farther from the last than ``max_speed_mps`` allows in the time between;
* ``attitude_range``: roll or yaw outside ±π, pitch outside ±π/2;
* ``out_of_order``: a position, attitude or cable-angle sample older than the one already held (a reordered
  datagram): the newer one stays. (A reordered swing sample used to be taken: under 50 ± 25 ms of jitter the
  swing the feed-forward saw jumped back and forth in time, and its derivative terms shook the vehicle.)

A rejected sample leaves the state as it was, so a spoofed or broken sample can make telemetry stale (the
flight sequence then holds) but never becomes a setpoint.

Swing input: the cable-angle sensor, else the payload's position stream, else none, as ``swing_input`` allows
(:mod:`companion.estimation.swing_measurement`).
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from math import isfinite
from typing import Any

import numpy as np

from companion.estimation import (
    SWING_INPUTS,  # noqa: F401  (re-exported: the inputs this state chooses from)
    readiness,
)
from companion.estimation.estimate import Estimate
from companion.estimation.swing_measurement import SLACK_FRACTION, ZERO_SWING, chosen_swing, measured_swing
from companion.mavlink_io import telemetry as tm

log = logging.getLogger(__name__)

MAV_AUTOPILOT_INVALID = 8
MAV_LANDED_STATE_UNDEFINED = 0
MAV_LANDED_STATE_ON_GROUND = 1
MAV_MODE_FLAG_SAFETY_ARMED = 128
MAV_SYS_STATUS_PREARM_CHECK = 0x10000000
PX4_MAIN_MODE_NAMES = {1: "MANUAL", 2: "ALTCTL", 3: "POSCTL", 4: "AUTO", 5: "ACRO", 6: "OFFBOARD", 7: "STABILIZED"}
PX4_AUTO_SUB_MODE_NAMES = {1: "READY", 2: "TAKEOFF", 3: "LOITER", 4: "MISSION", 5: "RTL", 6: "LAND"}
BACKWARDS_TOL_S = 0.5
FORWARD_TOL_S = 1.0


def px4_mode_name(custom_mode: int) -> str:
    """PX4 mode name from HEARTBEAT.custom_mode (main mode in bits 16–23, sub mode in bits 24–31)."""
    main = (custom_mode >> 16) & 0xFF
    sub = (custom_mode >> 24) & 0xFF
    name = PX4_MAIN_MODE_NAMES.get(main, f"MODE{main}")
    if main == 4:
        name += "." + PX4_AUTO_SUB_MODE_NAMES.get(sub, str(sub))
    return name


@dataclass
class VehicleState:
    """Latest trusted vehicle telemetry. ``vehicle_sysid`` is learned from the first autopilot HEARTBEAT.

    ``mode_class(custom_mode)`` names the mode in the flight sequence's words (``offboard``, ``hold``,
    ``land``, ``takeoff``, ``other``); the app sets it from the autopilot family once the vehicle is known.
    """

    cable_length_m: float
    payload_sysid: int | None = None
    swing_input: str = "auto"
    swing_max_age_s: float = 0.05
    payload_max_age_s: float = 0.3
    max_time_rate: float = 2.0  # vehicle seconds per wall second the clock may advance (lockstep: large)
    max_speed_mps: float = 30.0  # faster than this between two positions is a jump, not flight
    vehicle_sysid: int | None = None
    vehicle_compid: int = 1
    autopilot: int = 0  # MAV_AUTOPILOT of the vehicle's HEARTBEAT
    vehicle_type: int = 0
    armed: bool = False
    custom_mode: int = 0
    base_mode: int = 0
    system_status: int = 0
    landed_state: int = MAV_LANDED_STATE_UNDEFINED
    t_s: float = 0.0
    pos_ned_m: np.ndarray | None = None
    vel_ned_mps: np.ndarray | None = None
    pos_t_s: float = -1e9
    euler_rad: np.ndarray | None = None
    rates_frd_rad_s: np.ndarray | None = None
    att_t_s: float = -1e9
    swing_sensor: np.ndarray | None = None
    swing_sensor_t_s: float = -1e9
    pos_accuracy_m: float | None = None  # ESTIMATOR_STATUS.pos_horiz_accuracy (PX4), m
    payload_pos_ned_m: np.ndarray | None = None
    payload_vel_ned_mps: np.ndarray | None = None
    payload_t_s: float = -1e9
    heartbeats: int = 0
    heartbeat_wall_s: float | None = None
    pos_wall_s: float | None = None
    att_wall_s: float | None = None
    sensors_present: int = 0
    sensors_health: int = 0
    sensors_enabled: int = 0
    sys_status_seen: bool = False
    autopilot_version: dict | None = None  # from AUTOPILOT_VERSION, when the autopilot sent it
    home_ned_m: np.ndarray | None = None  # HOME_POSITION's local x, y, z (m, the autopilot's local NED frame)
    step_markers: int = 0
    counts: Counter = field(default_factory=Counter)
    rejected: Counter = field(default_factory=Counter)
    statustext: list[str] = field(default_factory=list)
    _chunks: dict[int, dict[int, str]] = field(default_factory=dict, repr=False)  # STATUSTEXT id -> chunks so far
    mode_class: Callable[[int], str] = field(default=lambda custom_mode: "other", repr=False)
    _mode_memo: tuple[Callable[[int], str] | None, int, str] = field(default=(None, 0, "other"), repr=False)
    _clock_wall_s: float | None = None

    @property
    def mode_name(self) -> str:
        """The vehicle's flight mode (PX4 names; ArduPilot's as its custom mode number)."""
        if self.autopilot == 3:
            return f"ArduPilot mode {self.custom_mode}"
        return px4_mode_name(self.custom_mode)

    @property
    def mode(self) -> str:
        """The mode in the flight sequence's words (``offboard``, ``hold``, ``land``, ``takeoff``, ``other``).
        Classified again only when the custom mode (or the classifier) changed: the tick asks every period."""
        cls, custom, mode = self._mode_memo
        if cls is not self.mode_class or custom != self.custom_mode:
            mode = self.mode_class(self.custom_mode)
            self._mode_memo = (self.mode_class, self.custom_mode, mode)
        return mode

    @property
    def on_ground(self) -> bool:
        """EXTENDED_SYS_STATE says landed; without it, disarmed counts as on the ground."""
        if self.landed_state == MAV_LANDED_STATE_UNDEFINED:
            return not self.armed
        return self.landed_state == MAV_LANDED_STATE_ON_GROUND

    @property
    def telemetry_wall_s(self) -> float | None:
        """Wall time of the older of the last position and the last attitude (None until both arrived)."""
        if self.pos_wall_s is None or self.att_wall_s is None:
            return None
        return min(self.pos_wall_s, self.att_wall_s)

    @property
    def last_words(self) -> str:
        """The vehicle's last STATUSTEXT ("" if it said nothing)."""
        return self.statustext[-1] if self.statustext else ""

    def ready_to_arm(self, prearm_bit: bool = True) -> bool:
        """The autopilot's own readiness (:mod:`companion.estimation.readiness`): SYS_STATUS's pre-arm bit in
        *health* with ``prearm_bit`` (no SYS_STATUS yet: not ready); with the bit present but not enabled
        (ArduCopter's ``ARMING_CHECK 0``) or without ``prearm_bit``, the HEARTBEAT state and the position
        estimate."""
        if prearm_bit and not self.sensors_present & MAV_SYS_STATUS_PREARM_CHECK:  # PX4, the bundled vehicle
            return self.sys_status_seen and bool(self.sensors_health & MAV_SYS_STATUS_PREARM_CHECK)
        return not readiness.unmet(self, prearm_bit)

    def unready(self, prearm_bit: bool = True) -> tuple[str, ...]:
        """What keeps the autopilot from being ready to arm, in words (empty: ready)."""
        return readiness.unmet(self, prearm_bit)

    # ------------------------------------------------------------------------------------------ ingest
    def _reject(self, kind: str) -> str:
        self.rejected[kind] += 1
        return "REJECTED"

    def _time_ok(self, t_s: float, wall_s: float | None) -> bool:
        """Check a vehicle time stamp against the vehicle clock; advances the clock when good."""
        if t_s < self.t_s - BACKWARDS_TOL_S:
            self._reject("time_backwards")
            return False
        if self._clock_wall_s is not None and wall_s is not None and self.t_s > 0.0:
            allowed = FORWARD_TOL_S + max(0.0, wall_s - self._clock_wall_s) * self.max_time_rate
            if t_s > self.t_s + allowed:
                self._reject("time_jump")
                return False
        if t_s >= self.t_s:
            self.t_s = t_s
            self._clock_wall_s = wall_s
        return True

    def ingest(self, ev: tm.TelemetryEvent, wall_s: float | None = None) -> str:
        """Fold one decoded message in (``wall_s``: monotonic arrival time); returns its message type name, or
        ``"REJECTED"`` when a check refused it (also a ``Rejected`` event from the vehicle or, for a
        position, its payload). Events from systems other than the vehicle (and its payload) are ignored."""
        name = ev.message
        self.counts[name] += 1
        cls = ev.__class__
        if cls is tm.Heartbeat:
            return self._on_heartbeat(ev, wall_s)
        src = ev.src_system
        if src == self.payload_sysid:
            return self._on_payload(ev)
        if src != self.vehicle_sysid:  # also while the vehicle is not known yet
            return name
        handler = _VEHICLE_HANDLERS.get(cls)
        return name if handler is None else handler(self, ev, wall_s)

    def _on_heartbeat(self, ev: tm.Heartbeat, wall_s: float | None) -> str:
        if ev.autopilot == MAV_AUTOPILOT_INVALID:  # a GCS, a companion or the payload system
            return ev.message
        src = ev.src_system
        if self.vehicle_sysid is None:
            self.vehicle_sysid = src
            self.vehicle_compid = ev.src_component
            self.autopilot = ev.autopilot
            self.vehicle_type = ev.mav_type
            log.info("vehicle found: system %d component %d", src, self.vehicle_compid)
        if src == self.vehicle_sysid and ev.src_component == self.vehicle_compid:
            self.heartbeats += 1
            self.heartbeat_wall_s = wall_s
            self.base_mode = ev.base_mode
            self.armed = bool(ev.base_mode & MAV_MODE_FLAG_SAFETY_ARMED)
            self.custom_mode = ev.custom_mode
            self.system_status = ev.system_status
        return ev.message

    def _on_payload(self, ev: tm.TelemetryEvent) -> str:
        """The payload system: only its position stream is read (a non-finite one is counted)."""
        if ev.__class__ is tm.LocalPositionNed:
            self.payload_pos_ned_m = np.array(ev.pos_ned_m)
            self.payload_vel_ned_mps = np.array(ev.vel_ned_mps)
            self.payload_t_s = ev.t_boot_s
        elif ev.__class__ is tm.Rejected and ev.message == "LOCAL_POSITION_NED":
            return self._reject(ev.kind)
        return ev.message

    def _on_rejected(self, ev: tm.Rejected, wall_s: float | None) -> str:
        return self._reject(ev.kind)

    def _on_attitude(self, ev: tm.Attitude, wall_s: float | None) -> str:
        r, p, y = ev.euler_rad
        if abs(r) > math.pi + 1e-6 or abs(p) > math.pi / 2 + 1e-6 or abs(y) > math.pi + 1e-6:
            return self._reject("attitude_range")
        t = ev.t_boot_s
        if t < self.att_t_s:
            return self._reject("out_of_order")
        if not self._time_ok(t, wall_s):
            return "REJECTED"
        self.euler_rad = np.array(ev.euler_rad)
        self.rates_frd_rad_s = np.array(ev.rates_frd_rad_s)
        self.att_t_s = t
        self.att_wall_s = wall_s
        return ev.message

    def _on_local_position(self, ev: tm.LocalPositionNed, wall_s: float | None) -> str:
        t = ev.t_boot_s
        if t < self.pos_t_s:
            return self._reject("out_of_order")
        q = self.pos_ned_m
        if q is not None and math.dist(ev.pos_ned_m, (q[0], q[1], q[2])) > \
                self.max_speed_mps * abs(t - self.pos_t_s) + 1.0:
            return self._reject("position_jump")
        if not self._time_ok(t, wall_s):
            return "REJECTED"
        self.pos_ned_m = np.array(ev.pos_ned_m)
        self.vel_ned_mps = np.array(ev.vel_ned_mps)
        self.pos_t_s = t
        self.pos_wall_s = wall_s
        return ev.message

    def _on_swing_sensor(self, ev: tm.SwingSensor, wall_s: float | None) -> str:
        if ev.t_s < self.swing_sensor_t_s:
            return self._reject("out_of_order")
        reach = ev.reach_m  # shorter than the cable: the payload rests on the ground, the cable is slack
        slack = isfinite(reach) and reach < SLACK_FRACTION * self.cable_length_m
        self.swing_sensor = ZERO_SWING if slack else np.array(ev.swing)
        self.swing_sensor_t_s = ev.t_s
        return ev.message

    def _on_system_time(self, ev: tm.SystemTime, wall_s: float | None) -> str:
        if not self._time_ok(ev.t_boot_ms * 1e-3, wall_s):
            return "REJECTED"
        self.step_markers += 1
        return ev.message

    def _on_ext_state(self, ev: tm.ExtendedSysState, wall_s: float | None) -> str:
        self.landed_state = ev.landed_state
        return ev.message

    def _on_home(self, ev: tm.HomePosition, wall_s: float | None) -> str:
        self.home_ned_m = np.array(ev.pos_ned_m)
        return ev.message

    def _on_sys_status(self, ev: tm.SysStatus, wall_s: float | None) -> str:
        self.sys_status_seen = True
        self.sensors_present = ev.sensors_present
        self.sensors_health = ev.sensors_health
        self.sensors_enabled = ev.sensors_enabled
        return ev.message

    def _on_estimator_status(self, ev: tm.EstimatorStatus, wall_s: float | None) -> str:
        """PX4: the estimator's own horizontal position accuracy (1σ, m), when plausible."""
        if 0.0 < ev.pos_horiz_accuracy_m < 100.0:
            self.pos_accuracy_m = ev.pos_horiz_accuracy_m
        return ev.message

    def _on_version(self, ev: tm.AutopilotVersion, wall_s: float | None) -> str:
        v = ev.flight_sw_version
        self.autopilot_version = {
            "flight_sw_version": f"{v >> 24 & 0xFF}.{v >> 16 & 0xFF}.{v >> 8 & 0xFF}",
            "release_type": v & 0xFF, "vendor_id": ev.vendor_id, "product_id": ev.product_id,
            "capabilities": ev.capabilities, "flight_custom_version": ev.flight_custom_version.hex(),
        }
        return ev.message

    def _on_statustext(self, ev: tm.StatusText, wall_s: float | None) -> str:
        """Keep the text; a chunked one (MAVLink 2 ``id``, as PX4 sends texts over 50 characters) once its last
        chunk (shorter than 50) arrived, joined, so the last words are whole."""
        text = ev.text
        if ev.id:
            parts = self._chunks.setdefault(ev.id, {})
            parts[ev.chunk_seq] = text
            if len(text) >= 50:
                while len(self._chunks) > 8:  # texts whose last chunk never came
                    del self._chunks[next(iter(self._chunks))]
                return ev.message
            text = "".join(parts[k] for k in sorted(parts))
            del self._chunks[ev.id]
        text = text.strip()
        self.statustext.append(text)
        if len(self.statustext) > 200:
            del self.statustext[:100]
        log.info("vehicle says: %s", text)
        return ev.message

    def set_payload_fix(self, t_s: float, payload_pos_ned_m: np.ndarray, payload_vel_ned_mps: np.ndarray) -> None:
        """A payload position (local NED, m) and velocity (m/s) at ``t_s`` worked out elsewhere (ArduPilot's
        payload GLOBAL_POSITION_INT differenced against the vehicle's: companion.estimation.swing_feed)."""
        if np.all(np.isfinite(payload_pos_ned_m)) and np.all(np.isfinite(payload_vel_ned_mps)):
            self.payload_pos_ned_m = np.asarray(payload_pos_ned_m, dtype=np.float64)
            self.payload_vel_ned_mps = np.asarray(payload_vel_ned_mps, dtype=np.float64)
            self.payload_t_s = float(t_s)

    def ready(self) -> bool:
        """True once position, velocity and attitude have all been received."""
        return self.pos_ned_m is not None and self.euler_rad is not None

    def measured_swing(self) -> np.ndarray | None:
        """The best swing measurement available, whatever ``swing_input`` says (for logs and metrics)."""
        return measured_swing(self)

    def estimate(self) -> Estimate | None:
        """The current :class:`Estimate`, or None before the first position and attitude."""
        if not self.ready():
            return None
        assert self.pos_ned_m is not None and self.vel_ned_mps is not None
        assert self.euler_rad is not None and self.rates_frd_rad_s is not None
        swing, source = chosen_swing(self)
        return Estimate(
            t_s=self.t_s,
            pos_ned_m=self.pos_ned_m,
            vel_ned_mps=self.vel_ned_mps,
            euler_rad=self.euler_rad,
            rates_frd_rad_s=self.rates_frd_rad_s,
            swing=swing,
            swing_source=source,
            pos_accuracy_m=self.pos_accuracy_m,
        )


#: The vehicle's events and what folds each in (others are counted and otherwise ignored).
_VEHICLE_HANDLERS: dict[type, Callable[[VehicleState, Any, float | None], str]] = {
    tm.Attitude: VehicleState._on_attitude,
    tm.LocalPositionNed: VehicleState._on_local_position,
    tm.SwingSensor: VehicleState._on_swing_sensor,
    tm.SystemTime: VehicleState._on_system_time,
    tm.ExtendedSysState: VehicleState._on_ext_state,
    tm.HomePosition: VehicleState._on_home,
    tm.SysStatus: VehicleState._on_sys_status,
    tm.EstimatorStatus: VehicleState._on_estimator_status,
    tm.AutopilotVersion: VehicleState._on_version,
    tm.StatusText: VehicleState._on_statustext,
    tm.Rejected: VehicleState._on_rejected,
}
