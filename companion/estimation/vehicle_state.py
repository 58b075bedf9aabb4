"""What the companion knows about the vehicle, folded from incoming MAVLink messages.

``VehicleState.ingest(msg)`` takes decoded pymavlink messages (any object with ``get_type()`` and the
message's fields); ``estimate()`` turns the latest ones into a :class:`~companion.estimation.estimate.Estimate`.

Swing input, in order of preference:

1. the cable-angle sensor: ``DEBUG_FLOAT_ARRAY`` named ``"SWING"`` (data = [α, β, α̇, β̇, l]) from the
   vehicle — used while it is fresher than ``swing_max_age_s`` (default 0.05 s of vehicle time);
2. the payload's own position stream (``LOCAL_POSITION_NED`` from the payload system, as ArduPilot's
   slung-payload simulation sends it), inverted through eqs. 3–4 — used while fresher than 0.3 s;
3. none: the estimate carries ``swing=None``; the flight core then flies without feed-forward and with
   the full-cable-length envelope, and says so in its commands.

``swing_input`` restricts the choice: ``"auto"`` (the order above), ``"cable_sensor"``, ``"payload_position"``
or ``"none"`` (ignore both, e.g. to fly as a vehicle without any swing measurement would).
"""

from __future__ import annotations

import logging
from collections import Counter
from dataclasses import dataclass, field
from math import isfinite

import numpy as np

from companion.estimation.estimate import Estimate, swing_from_payload

SWING_INPUTS = ("auto", "cable_sensor", "payload_position", "none")

log = logging.getLogger(__name__)

MAV_STATE_NAMES = {0: "UNINIT", 1: "BOOT", 2: "CALIBRATING", 3: "STANDBY", 4: "ACTIVE", 5: "CRITICAL",
                   6: "EMERGENCY", 7: "POWEROFF", 8: "FLIGHT_TERMINATION"}
MAV_LANDED_STATE_ON_GROUND = 1
MAV_MODE_FLAG_SAFETY_ARMED = 128
PX4_MAIN_MODE_NAMES = {1: "MANUAL", 2: "ALTCTL", 3: "POSCTL", 4: "AUTO", 5: "ACRO", 6: "OFFBOARD", 7: "STABILIZED"}
PX4_AUTO_SUB_MODE_NAMES = {1: "READY", 2: "TAKEOFF", 3: "LOITER", 4: "MISSION", 5: "RTL", 6: "LAND"}


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
    """Latest vehicle telemetry. ``vehicle_sysid`` is learned from the first autopilot HEARTBEAT."""

    cable_length_m: float
    payload_sysid: int | None = None
    swing_input: str = "auto"
    swing_max_age_s: float = 0.05
    payload_max_age_s: float = 0.3
    vehicle_sysid: int | None = None
    vehicle_compid: int = 1
    autopilot: int = 0  # MAV_AUTOPILOT of the vehicle's HEARTBEAT
    armed: bool = False
    custom_mode: int = 0
    system_status: int = 0
    landed_state: int = 0
    t_s: float = 0.0
    pos_ned_m: np.ndarray | None = None
    vel_ned_mps: np.ndarray | None = None
    euler_rad: np.ndarray | None = None
    rates_frd_rad_s: np.ndarray | None = None
    swing_sensor: np.ndarray | None = None
    swing_sensor_t_s: float = -1e9
    payload_pos_ned_m: np.ndarray | None = None
    payload_vel_ned_mps: np.ndarray | None = None
    payload_t_s: float = -1e9
    heartbeats: int = 0
    step_markers: int = 0
    counts: Counter = field(default_factory=Counter)
    statustext: list[str] = field(default_factory=list)

    @property
    def mode_name(self) -> str:
        """The vehicle's flight mode (PX4 names; ArduPilot's as its custom mode number)."""
        if self.autopilot == 3:
            return f"ArduPilot mode {self.custom_mode}"
        return px4_mode_name(self.custom_mode)

    @property
    def on_ground(self) -> bool:
        """EXTENDED_SYS_STATE says landed."""
        return self.landed_state == MAV_LANDED_STATE_ON_GROUND

    def ingest(self, msg) -> str:
        """Fold one message in; returns its type name. Messages from unknown systems are ignored."""
        mtype = msg.get_type()
        src = msg.get_srcSystem()
        self.counts[mtype] += 1
        if mtype == "HEARTBEAT":
            if msg.autopilot == 8:  # MAV_AUTOPILOT_INVALID: a GCS, a companion or the payload system
                return mtype
            if self.vehicle_sysid is None:
                self.vehicle_sysid = src
                self.vehicle_compid = msg.get_srcComponent()
                self.autopilot = int(msg.autopilot)
                log.info("vehicle found: system %d component %d", src, self.vehicle_compid)
            if src == self.vehicle_sysid:
                self.heartbeats += 1
                self.armed = bool(msg.base_mode & MAV_MODE_FLAG_SAFETY_ARMED)
                self.custom_mode = int(msg.custom_mode)
                self.system_status = int(msg.system_status)
            return mtype
        if self.payload_sysid is not None and src == self.payload_sysid:
            if mtype == "LOCAL_POSITION_NED":
                self.payload_pos_ned_m = np.array([msg.x, msg.y, msg.z])
                self.payload_vel_ned_mps = np.array([msg.vx, msg.vy, msg.vz])
                self.payload_t_s = msg.time_boot_ms * 1e-3
            return mtype
        if self.vehicle_sysid is None or src != self.vehicle_sysid:
            return mtype
        if mtype == "ATTITUDE":
            self.euler_rad = np.array([msg.roll, msg.pitch, msg.yaw])
            self.rates_frd_rad_s = np.array([msg.rollspeed, msg.pitchspeed, msg.yawspeed])
            self.t_s = max(self.t_s, msg.time_boot_ms * 1e-3)
        elif mtype == "LOCAL_POSITION_NED":
            self.pos_ned_m = np.array([msg.x, msg.y, msg.z])
            self.vel_ned_mps = np.array([msg.vx, msg.vy, msg.vz])
            self.t_s = max(self.t_s, msg.time_boot_ms * 1e-3)
        elif mtype == "DEBUG_FLOAT_ARRAY":
            name = msg.name.rstrip("\x00") if isinstance(msg.name, str) else msg.name
            if name == "SWING" and len(msg.data) >= 4:
                d0, d1, d2, d3 = (float(x) for x in msg.data[:4])
                if isfinite(d0) and isfinite(d1) and isfinite(d2) and isfinite(d3):
                    self.swing_sensor = np.array((d0, d1, d2, d3))
                    self.swing_sensor_t_s = msg.time_usec * 1e-6
                else:
                    self.counts["SWING_nonfinite"] += 1
        elif mtype == "EXTENDED_SYS_STATE":
            self.landed_state = int(msg.landed_state)
        elif mtype == "SYSTEM_TIME":
            self.step_markers += 1
            self.t_s = max(self.t_s, msg.time_boot_ms * 1e-3)
        elif mtype == "STATUSTEXT":
            text = msg.text.rstrip("\x00") if isinstance(msg.text, str) else str(msg.text)
            self.statustext.append(text)
            log.info("vehicle says: %s", text)
        return mtype

    def ready(self) -> bool:
        """True once position, velocity and attitude have all been received."""
        return self.pos_ned_m is not None and self.euler_rad is not None

    def measured_swing(self) -> np.ndarray | None:
        """The best swing measurement available, whatever ``swing_input`` says (for logs and metrics)."""
        if self.swing_sensor is not None and self.t_s - self.swing_sensor_t_s <= self.swing_max_age_s:
            return self.swing_sensor
        if self.pos_ned_m is None or self.payload_pos_ned_m is None or self.payload_vel_ned_mps is None:
            return None
        if self.vel_ned_mps is None or self.t_s - self.payload_t_s > self.payload_max_age_s:
            return None
        try:
            return swing_from_payload(self.pos_ned_m, self.payload_pos_ned_m, self.vel_ned_mps,
                                      self.payload_vel_ned_mps, self.cable_length_m)
        except ValueError:
            return None

    def estimate(self) -> Estimate | None:
        """The current :class:`Estimate`, or None before the first position and attitude."""
        if not self.ready():
            return None
        assert self.pos_ned_m is not None and self.vel_ned_mps is not None
        assert self.euler_rad is not None and self.rates_frd_rad_s is not None
        swing = None
        source = "none"
        use_cable = self.swing_input in ("auto", "cable_sensor")
        use_payload = self.swing_input in ("auto", "payload_position")
        if (
            use_cable
            and self.swing_sensor is not None
            and self.t_s - self.swing_sensor_t_s <= self.swing_max_age_s
        ):
            swing, source = self.swing_sensor, "cable_sensor"
        elif (
            use_payload
            and self.payload_pos_ned_m is not None
            and self.payload_vel_ned_mps is not None
            and self.t_s - self.payload_t_s <= self.payload_max_age_s
        ):
            try:
                swing = swing_from_payload(
                    self.pos_ned_m, self.payload_pos_ned_m, self.vel_ned_mps, self.payload_vel_ned_mps,
                    self.cable_length_m,
                )
                source = "payload_position"
            except ValueError:
                swing = None
        if swing is not None and not np.all(np.isfinite(swing)):
            swing, source = None, "none"
        return Estimate(
            t_s=self.t_s,
            pos_ned_m=self.pos_ned_m,
            vel_ned_mps=self.vel_ned_mps,
            euler_rad=self.euler_rad,
            rates_frd_rad_s=self.rates_frd_rad_s,
            swing=swing,
            swing_source=source,
        )

