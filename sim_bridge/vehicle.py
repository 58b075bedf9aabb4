"""The bundled SITL vehicle: VehicleSim physics behind two PX4-like MAVLink 2 UDP links.

Owns the vehicle's state, its links and what goes out on them (telemetry, STATUSTEXT, mission answers) and
the two clocks:
real time (physics on a monotonic wall clock) and lockstep (one control period per SET_ATTITUDE_TARGET
from the onboard link, then the due telemetry, then SYSTEM_TIME as end-of-step marker). See docs/sitl.md.
Its settings: :mod:`sim_bridge.sitl_config`; what it does when commanded: :mod:`sim_bridge.vehicle_control`;
what its modes fly by themselves each control period (position hold, landing, offboard position setpoints, the
offboard-loss failsafe, land detection): :mod:`sim_bridge.flight_modes`; its stream rates:
:mod:`sim_bridge.stream_rates`.
"""

from __future__ import annotations

import dataclasses
import gc
import logging
import time

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from companion.autopilots import px4_modes
from companion.core.model import rotation_body_to_ned
from companion.core.vehicle_params import VehicleParams
from companion.core.wind import WindConfig
from companion.errors import ModelError
from sim_bridge import commands, mission_server, stream_rates, telemetry
from sim_bridge.flight_modes import FlightModes
from sim_bridge.imu import ImuModel
from sim_bridge.link import MavUdpLink, RejectCounters
from sim_bridge.params import build_param_table, gains_from_params
from sim_bridge.physics import InnerLoopGains, VehicleSim
from sim_bridge.position_hold import PositionHoldGains
from sim_bridge.sitl_config import LIVE_WIND_PARAMS, SitlConfig, live_wind_problem
from sim_bridge.vehicle_control import VehicleControl

log = logging.getLogger(__name__)
M = mavlink2

MARKER_RESEND_S = 0.2  # lockstep: re-send SYSTEM_TIME after this much wall time without an answer


class SitlVehicle(VehicleControl, FlightModes):
    """The running vehicle. Create, then ``run()`` (returns the exit code): lockstep runs a plain blocking loop
    (:mod:`sim_bridge.lockstep`), real time an asyncio loop (:mod:`sim_bridge.realtime`); both drive the same
    vehicle logic here through :meth:`attach_links`, :meth:`on_message` and :meth:`advance`."""

    def __init__(self, cfg: SitlConfig) -> None:
        self.cfg = cfg
        self.sysid = cfg.sysid
        self.origin = cfg.home  # geodetic origin of the local NED frame (the first home)
        self.home_local_ned_m = np.zeros(3)  # home: moved to where the vehicle arms on the ground, as PX4
        self.home_yaw_rad = 0.0
        self.home_time_us = 0
        self.counters = RejectCounters()
        self.params = build_param_table(
            thr_hover=cfg.thr_hover or 1.0 / cfg.rotor.thrust_to_weight,
            offboard_timeout_s=cfg.offboard_timeout_s, wind_scale=cfg.wind.scale,
            wind_model="none" if cfg.wind.model == "none" else "paper",  # SIM_WIND_MODEL 1: the configured wind
            payload_mass_kg=cfg.params.m, cable_length_m=cfg.params.l, takeoff_alt_m=cfg.takeoff_alt_m,
            gains=InnerLoopGains(), counters=self.counters.counts, obl_action=cfg.obl_action,
            fail_act_t_s=cfg.fail_act_t_s, imu_noise_scale=cfg.imu.scale, air_mode=cfg.air_mode,
        )
        self.imu = ImuModel(dataclasses.replace(cfg.imu, sample_dt_s=cfg.control_period_us * 1e-6))
        self.params.on_change = self._param_changed
        self.params.check = self._param_check
        self.sim = self._new_sim(cfg.params, 0.0)
        self.hold_gains = PositionHoldGains()
        self.t_us = 0
        self.mode = px4_modes.AUTO_LOITER
        self.hold_pos_ned_m = np.zeros(3)
        self.hold_yaw_rad = 0.0
        self._sp_time_us: int | None = None  # newest offboard setpoint (attitude or position), sim time
        self._sp_kind: str | None = None  # "attitude" or "position"
        self._last_sp: tuple[np.ndarray | None, float | None, np.ndarray | None] | None = None
        self._pos_sp: tuple | None = None  # (pos, vel, acc NED with NaN = free, yaw, yaw rate)
        self._yaw_sp_rad = 0.0
        self._failsafe_since_us: int | None = None
        self._failsafe_mode: px4_modes.Px4Mode | None = None
        self._airborne = False
        self._landed_since_us: int | None = None
        self._next_payload_us = 0
        self._payload_hb_count = 0
        self._statustext_id = 0
        self.onboard: MavUdpLink | None = None
        self.gcs: MavUdpLink | None = None
        self._link_list: list[MavUdpLink] = []  # the attached links: onboard, GCS
        self._payload_mavs: list = []
        self.stop_requested = False  # set by SIGINT/SIGTERM or --duration; the runner then returns
        self._last_marker_wall = 0.0
        self._last_hb_wall = 0.0
        self._last_step_wall = 0.0  # lockstep: when a client last stepped the simulation
        self.steps = 0
        self.missions = mission_server.MissionServer()  # mission, fence, rally (docs/sitl.md)
        self.scanner = None  # the world's LiDAR (sim_bridge.scan_sender.ScanSender; `sitl --world`), else None

    # ------------------------------------------------------------------ construction helpers
    def _new_sim(self, params: VehicleParams, t0_s: float) -> VehicleSim:
        gains = gains_from_params(self.params, InnerLoopGains())
        sim = VehicleSim(params, wind=self._wind_from_params(), rotor=self.cfg.rotor, gains=gains,
                         dt_s=self.cfg.physics_dt_us * 1e-6, t0_s=t0_s)
        sim.air_mode = int(self.params.value("MC_AIRMODE"))
        return sim

    def _wind_from_params(self) -> WindConfig:
        """The configured wind (``cfg.wind``, all its physical-wind settings) switched by SIM_WIND_MODEL
        (0 none; 1 the configured model, eq. 49 when that is none) and scaled by SIM_WIND_SCALE (eq. 49)."""
        on = self.params.value("SIM_WIND_MODEL") >= 0.5
        model = (self.cfg.wind.model if self.cfg.wind.model != "none" else "paper") if on else "none"
        return dataclasses.replace(self.cfg.wind, model=model, scale=self.params.value("SIM_WIND_SCALE"))

    def _param_check(self, name: str, value: float) -> str | None:
        """A live change refused as the start would be (:func:`sim_bridge.sitl_config.live_wind_problem`)."""
        vals = {n: self.params.value(n) for n in LIVE_WIND_PARAMS} | {name: value}
        return live_wind_problem(self.cfg, vals) if name in LIVE_WIND_PARAMS else None

    def _param_changed(self, prm) -> None:
        if prm.name.startswith("SIM_WIND"):
            self.sim.wind = self._wind_from_params()
        elif prm.name == "MC_AIRMODE":
            self.sim.air_mode = int(prm.value)
        elif prm.name.startswith("SMC_"):
            try:
                g = gains_from_params(self.params, self.sim.gains)
                g.validate()
                self.sim.gains = g
            except ValueError as exc:
                self.statustext(M.MAV_SEVERITY_WARNING, f"gains not applied: {exc}")

    # ------------------------------------------------------------------ small views
    @property
    def mode(self) -> px4_modes.Px4Mode:
        """The flight mode (PX4's main/sub mode)."""
        return self._mode

    @mode.setter
    def mode(self, mode: px4_modes.Px4Mode) -> None:
        self._mode = mode
        # asked every control period: kept as flags (a frozen dataclass's == compares field by field)
        self._offboard = mode == px4_modes.OFFBOARD
        self._takeoff = mode == px4_modes.AUTO_TAKEOFF

    @property
    def armed(self) -> bool:
        return bool(self.sim.armed)

    @property
    def base_mode(self) -> int:
        b = M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | M.MAV_MODE_FLAG_STABILIZE_ENABLED
        if self.mode.main in (px4_modes.MAIN_AUTO, px4_modes.MAIN_OFFBOARD):
            b |= M.MAV_MODE_FLAG_GUIDED_ENABLED | M.MAV_MODE_FLAG_AUTO_ENABLED
        if self.armed:
            b |= M.MAV_MODE_FLAG_SAFETY_ARMED
        return b

    @property
    def landed_state(self) -> int:
        if self.sim.landed:
            return M.MAV_LANDED_STATE_ON_GROUND
        if self.mode == px4_modes.AUTO_TAKEOFF:
            return M.MAV_LANDED_STATE_TAKEOFF
        if self.mode == px4_modes.AUTO_LAND:
            return M.MAV_LANDED_STATE_LANDING
        return M.MAV_LANDED_STATE_IN_AIR

    @property
    def hover_thrust_n(self) -> float:
        """The hover thrust (N) the thrust calibration (MPC_THR_HOVER) refers to (``cfg.thrust_ref_n``, else the
        simulated vehicle's true (M + m)·g)."""
        ref = self.cfg.thrust_ref_n
        return self.sim.params.hover_thrust_n if ref is None else ref

    @property
    def prearm_ok(self) -> bool:
        """Whether arming is possible now (SYS_STATUS PREARM_CHECK health bit; always true when armed)."""
        return self.armed or self.mode != px4_modes.OFFBOARD or self._stream_ok()

    @property
    def carried_mass_kg(self) -> float:
        """What the rotors lift: M + m, or M while the payload rests on the ground (what PX4's hover-thrust
        estimator would learn)."""
        p = self.sim.params
        return p.M if self.sim.payload_on_ground else p.M + p.m

    def imu_sample(self, snap: telemetry.Snapshot | None = None) -> tuple[tuple, tuple, np.ndarray, float, float,
                                                                           float]:
        """(accelerometer m/s² FRD, gyro rad/s FRD, magnetometer gauss FRD, pressure hPa, pressure altitude m,
        temperature °C) at the current simulated time. ``snap``: this instant's :class:`telemetry.Snapshot`
        if the caller has one (its floats and body rates are the same numbers as the simulation's)."""
        sim = self.sim
        self.imu.scale = self.params.value("SIM_IMU_NSCALE")
        if snap is None:
            snap = telemetry.Snapshot(self)
        x = snap.x
        r_t = rotation_body_to_ned(x[3], x[4], x[5]).T  # NED → body, once for accelerometer and magnetometer
        a = sim.accel_ned_mps2
        a[2] -= sim.params.g
        acc, gyro = self.imu.sample(self.t_us, (r_t @ a).tolist(), snap.rates)  # = specific_force_frd_mps2
        mag = r_t @ telemetry.EARTH_FIELD_NED_GAUSS
        alt = self.origin[2] - x[2]
        return acc, gyro, mag, telemetry.isa_pressure_hpa(alt), alt, 15.0 - 0.0065 * alt

    def normalized_thrust(self, thrust_n: float) -> float:
        """Newtons → PX4's normalized thrust (MPC_THR_HOVER at hover)."""
        return thrust_n * self.params.value("MPC_THR_HOVER") / self.hover_thrust_n

    def _links(self) -> list[MavUdpLink]:
        return self._link_list

    # ------------------------------------------------------------------ messages out
    def statustext(self, severity: int, text: str) -> None:
        """STATUSTEXT on both links (chunked by MAVLink 2's id/chunk_seq when longer than 50 chars)."""
        log.info("STATUSTEXT: %s", text)
        raw = text.encode("utf-8", errors="replace")
        chunks = [raw[i : i + 50] for i in range(0, len(raw), 50)] or [b""]
        self._statustext_id = self._statustext_id % 65535 + 1
        sid = self._statustext_id if len(chunks) > 1 else 0
        for lk in self._links():
            for k, c in enumerate(chunks):
                lk.mav.statustext_send(severity, c, sid, k)

    def can_send(self, msgid: int) -> bool:
        return stream_rates.sendable(msgid)

    def send_message(self, msgid: int, link: MavUdpLink) -> None:
        telemetry.send_vehicle_message(msgid, link.mav, self)

    def _send_due_telemetry(self) -> None:
        hb = False
        snap = None  # the state of this instant, made when the first message is due; each message packed once
        t_us = self.t_us
        for lk in self._links():
            due = lk.scheduler.due(t_us)
            if not due:
                continue
            if snap is None:
                snap = telemetry.Snapshot(self)
            telemetry.send_due(due, lk.mav, self, snap)
            hb = hb or M.MAVLINK_MSG_ID_HEARTBEAT in due
        if self.t_us >= self._next_payload_us:
            self._next_payload_us += self.cfg.payload_interval_us
            hb = self._payload_hb_count % max(1, 1_000_000 // self.cfg.payload_interval_us) == 0
            self._payload_hb_count += 1
            if snap is None:
                snap = telemetry.Snapshot(self)
            for pm in self._payload_mavs:
                telemetry.send_payload_messages(pm, self, hb, snap)
        if hb:
            self._last_hb_wall = time.monotonic()

    # ------------------------------------------------------------------ one control period
    def advance(self) -> None:
        """Fly one control period: internal controller, physics, mode logic, due telemetry."""
        sim = self.sim
        if sim.armed:
            self._control()
        try:
            sim.step(self.cfg.control_period_us // self.cfg.physics_dt_us)
        except (ModelError, FloatingPointError) as exc:  # e.g. flipped to pitch 90°: crash, restart at home
            log.error("physics failed at t = %.3f s: %s", self.t_us * 1e-6, exc)
            self.sim = self._new_sim(sim.params, self.t_us * 1e-6)
            self.mode = px4_modes.AUTO_LOITER
            self._hold_here()
            self._airborne = False
            self.statustext(M.MAV_SEVERITY_CRITICAL, "Crashed (simulation diverged): reset at home, disarmed")
        self.t_us += self.cfg.control_period_us
        self.steps += 1
        self._after_step()
        self._send_due_telemetry()
        if self.scanner is not None:  # a scan, when due, as part of this instant's telemetry
            self.scanner.on_step(self)
        if self.missions.busy:  # a mission transfer's retries and timeout
            self.send_mission_outputs(self.missions.tick(time.monotonic()))
        if self.cfg.duration_s is not None and self.t_us >= self.cfg.duration_s * 1e6:
            self.stop_requested = True

    # ------------------------------------------------------------------ incoming messages
    def on_message(self, link: MavUdpLink, msg) -> None:
        tgt = getattr(msg, "target_system", None)
        if tgt is not None and tgt not in (0, self.sysid):
            self.counters.reject("other_target", f"{msg.get_type()} for system {tgt}")
            return
        comp = getattr(msg, "target_component", None)
        t = msg.get_type()
        if comp is not None and comp not in (0, self.cfg.compid) and not (
                comp == M.MAV_COMP_ID_MISSIONPLANNER and t.startswith("MISSION_")):  # PX4 takes the planner's too
            self.counters.reject("other_target", f"{t} for component {comp}")
            return
        if t == "SET_ATTITUDE_TARGET":
            self.on_attitude_target(link, msg)
        elif t == "SET_POSITION_TARGET_LOCAL_NED":
            self.on_position_target(msg)
        elif t == "SETUP_SIGNING":
            self.on_setup_signing(link, msg)
        elif t == "COMMAND_LONG":
            commands.handle_command(self, link, msg, is_int=False)
        elif t == "COMMAND_INT":
            commands.handle_command(self, link, msg, is_int=True)
        elif t == "PARAM_REQUEST_LIST":
            commands.handle_param_request_list(self, link)
        elif t == "PARAM_REQUEST_READ":
            commands.handle_param_request_read(self, link, msg)
        elif t == "PARAM_SET":
            commands.handle_param_set(self, link, msg)
        elif t == "SET_MODE":
            self.set_mode(px4_modes.Px4Mode.from_custom_mode(msg.custom_mode))
        elif t == "TIMESYNC" and msg.tc1 == 0:
            link.mav.timesync_send(self.t_us * 1000, msg.ts1)
        elif t.startswith("MISSION_"):
            self.send_mission_outputs(self.missions.handle(
                msg, mission_server.Peer(link, msg.get_srcSystem(), msg.get_srcComponent()), time.monotonic()))

    def send_mission_outputs(self, outs: list) -> None:
        """Send the mission service's answers (its retries and timeouts run on the wall clock, as a ground
        station's do, also in lockstep)."""
        if outs:
            mission_server.send_outputs(outs, self._links(), self.statustext)

    # ------------------------------------------------------------------ links and clocks (shared by both runners)
    def warm_up(self) -> None:
        """Load the compiled physics kernels before the clock starts (a throw-away airframe, two steps)."""
        warm = self._new_sim(self.sim.params, 0.0)
        warm.armed = True
        warm.step(2)
        # what start-up made (modules, numba's and pymavlink's tables) lives as long as the process: out of the
        # garbage collector's sight, so a full collection during a flight walks only the flight's objects
        gc.freeze()

    def attach_links(self, onboard: MavUdpLink, gcs: MavUdpLink) -> None:
        """Take the two bound links: per-link telemetry schedules (PX4's onboard and normal stream modes),
        signing if configured, and the payload system's senders."""
        cfg = self.cfg
        self.onboard, self.gcs = onboard, gcs
        self._link_list = [onboard, gcs]
        onboard.on_attitude_fields = gcs.on_attitude_fields = self.on_attitude_fields
        onboard.scheduler = stream_rates.RateScheduler(stream_rates.default_intervals_us(cfg.control_period_us))
        gcs.scheduler = stream_rates.RateScheduler(stream_rates.default_intervals_us(cfg.control_period_us, "normal"))
        if cfg.signing_key is not None:
            self._enable_signing(cfg.signing_key)
        self._payload_mavs = [lk.sender(cfg.payload_sysid, cfg.payload_compid) for lk in self._links()]

    def start(self) -> None:
        """The first telemetry of time 0 (and, in lockstep, the first marker): call once the links are
        attached and the runner is about to wait for input."""
        self._send_due_telemetry()
        if self.cfg.lockstep:
            self._send_marker()

    def _lockstep_step(self) -> None:
        """Lockstep: one control period, its telemetry and the end-of-step marker, as few datagrams."""
        links = self._links()
        for lk in links:
            lk.begin_batch()
        self.advance()
        self._send_marker()
        self._last_step_wall = self._last_marker_wall
        for lk in links:
            lk.flush()

    def _send_marker(self) -> None:
        if self.onboard is not None:
            telemetry.send_marker(self.onboard.mav, self.t_us)
        self._last_marker_wall = time.monotonic()

    def wall_clock_duties(self, now: float) -> None:
        """Lockstep, on the wall clock (``now`` = ``time.monotonic()``; call every ≲ 50 ms): re-send the marker
        when no answer came for :data:`MARKER_RESEND_S` (the answer or the marker was lost), and HEARTBEAT
        once a second while nobody steps the simulation."""
        if now - self._last_marker_wall >= MARKER_RESEND_S:
            self._send_marker()
        if self.missions.busy:
            self.send_mission_outputs(self.missions.tick(now))
        # While a client steps the simulation, HEARTBEATs come on simulated time only (a wall-clock one
        # would show the client a state change at a wall-time-dependent moment: lockstep runs must repeat bit
        # for bit). Only an idle vehicle (no step for 1 s) heartbeats on the wall clock, to be discovered and
        # to tell a client that comes back that it is alive.
        if now - self._last_hb_wall >= 1.0 and now - self._last_step_wall >= 1.0:
            self._last_hb_wall = now
            for lk in self._links():
                telemetry.send_vehicle_message(M.MAVLINK_MSG_ID_HEARTBEAT, lk.mav, self)
            for pm in self._payload_mavs:
                telemetry.send_payload_messages(pm, self, heartbeat=True)

    def run(self, ready_cb=None) -> int:
        """Bind both links, fly until SIGINT/SIGTERM or ``duration_s``; returns 0. ``ready_cb(vehicle)`` is
        called once both ports are bound. Raises OSError when a port cannot be bound."""
        if self.cfg.lockstep:
            from sim_bridge.lockstep import run_lockstep

            code = run_lockstep(self, ready_cb)
        else:
            import asyncio

            from sim_bridge.realtime import run_realtime

            code = asyncio.run(run_realtime(self, ready_cb))
        log.info("stopped at t = %.3f s sim after %d control periods; rejected %s", self.t_us * 1e-6,
                 self.steps, {k: v for k, v in self.counters.counts.items() if v})
        return code
