"""What the bundled vehicle's modes fly by themselves each control period, as PX4 does: the internal position
controller (POSCTL, AUTO.LOITER, AUTO.TAKEOFF, AUTO.LAND), OFFBOARD position/velocity setpoints through PX4's
multicopter limits, the offboard-loss failsafe (hold, then land after COM_FAIL_ACT_T), take-off completion, and
land detection with the automatic disarm. A mixin of :class:`~sim_bridge.vehicle.SitlVehicle`, whose state
(``sim``, ``params``, ``mode``, the hold and setpoint fields) it uses; times in µs of simulated time.
"""

from __future__ import annotations

import math

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from companion.autopilots import px4_modes
from companion.core.rotations import wrap_pi
from sim_bridge.position_hold import PositionHoldGains, position_control_target

M = mavlink2
_NAN3 = np.full(3, np.nan)

DISARM_LAND_S = 2.0  # PX4's COM_DISARM_LAND: disarm after this long on the ground after a flight
TAKEOFF_DONE_M = 0.15  # AUTO.TAKEOFF switches to AUTO.LOITER within this distance of the takeoff altitude
# OFFBOARD position/velocity setpoints fly with PX4's multicopter limits: MPC_XY_VEL_MAX 12 m/s,
# MPC_Z_VEL_MAX_UP 3 m/s, MPC_Z_VEL_MAX_DN 1.5 m/s, MPC_TILTMAX_AIR 45°
OFFBOARD_GAINS = PositionHoldGains(vmax_xy_mps=12.0, vmax_up_mps=3.0, vmax_down_mps=1.5,
                                   tilt_max_rad=math.radians(45.0))


class FlightModes:
    """The control period's mode logic of :class:`~sim_bridge.vehicle.SitlVehicle` (:meth:`_control` before the
    physics step, :meth:`_after_step` after it)."""

    def _control(self) -> None:
        """The armed vehicle's own control for this period: the internal controller in every mode but OFFBOARD,
        the position controller for OFFBOARD position setpoints (attitude setpoints go straight to the sim)."""
        if not self._offboard:
            self._internal_control()
        elif self._sp_kind == "position":
            self._offboard_position_control()

    def _internal_control(self) -> None:
        sim = self.sim
        target = self.hold_pos_ned_m.copy()
        descent = None
        if self.mode == px4_modes.AUTO_LAND:
            target[2] = sim.pos_ned_m[2] + 5.0
            descent = 0.7
        q, thrust = position_control_target(sim.pos_ned_m, sim.vel_ned_mps, target, _NAN3, _NAN3, self.hold_yaw_rad,
                                            self.carried_mass_kg, sim.params.g, self.hold_gains, descent)
        near_ground = sim.pos_ned_m[2] > -0.02 and sim.vel_ned_mps[2] > -0.1
        if (sim.landed or near_ground) and (self.mode == px4_modes.AUTO_LAND or target[2] > -0.3):
            # Ground contact (PX4's land detector): idle thrust, so the payload's tug cannot keep the airframe
            # bobbing a micrometre above the ground and the disarm timer can run.
            thrust = 0.5 * self.hover_thrust_n
        sim.set_attitude_target(q, thrust)

    def _offboard_position_control(self) -> None:
        """Fly the newest SET_POSITION_TARGET_LOCAL_NED through the position controller (PX4's limits)."""
        sim = self.sim
        pos, vel, acc, yaw, yaw_rate = self._pos_sp
        if math.isfinite(yaw):
            self._yaw_sp_rad = yaw
        elif math.isfinite(yaw_rate):
            self._yaw_sp_rad = wrap_pi(self._yaw_sp_rad + yaw_rate * self.cfg.control_period_us * 1e-6)
        q, thrust = position_control_target(sim.pos_ned_m, sim.vel_ned_mps, pos, vel, acc, self._yaw_sp_rad,
                                            self.carried_mass_kg, sim.params.g, OFFBOARD_GAINS)
        z = sim.pos_ned_m[2]
        wants_up = ((math.isfinite(pos[2]) and pos[2] < z - 0.3) or (math.isfinite(vel[2]) and vel[2] < -0.1)
                    or (math.isfinite(acc[2]) and acc[2] < -0.5))
        if (sim.landed or (z > -0.02 and sim.vel_ned_mps[2] > -0.1)) and not wants_up:
            thrust = 0.5 * self.hover_thrust_n  # on the ground and not asked to climb: idle, as PX4's land detector
        sim.set_attitude_target(q, thrust)

    def _after_step(self) -> None:
        sim = self.sim
        if self._offboard and not self._stream_ok():
            act = round(self.params.value("COM_OBL_RC_ACT"))
            hold = px4_modes.POSCTL if act <= 2 else px4_modes.AUTO_LOITER
            self._hold_here()
            self.mode = hold
            self._failsafe_since_us, self._failsafe_mode = self.t_us, hold
            self.statustext(M.MAV_SEVERITY_WARNING, f"Offboard setpoints lost: switching to {hold.name} hold, "
                            f"landing in {self.params.value('COM_FAIL_ACT_T'):g} s")
        if self._failsafe_since_us is not None:
            if self.mode != self._failsafe_mode or not sim.armed:
                self._failsafe_since_us = None  # the user took over (or it is over)
            elif self.t_us - self._failsafe_since_us >= self.params.value("COM_FAIL_ACT_T") * 1e6:
                self._failsafe_since_us = None
                self._hold_here()
                self.mode = px4_modes.AUTO_LAND
                self.statustext(M.MAV_SEVERITY_CRITICAL, "Failsafe: offboard setpoints lost, landing")
        if self._takeoff and sim.armed and abs(
            sim.pos_ned_m[2] - self.hold_pos_ned_m[2]) < TAKEOFF_DONE_M:
            self.mode = px4_modes.AUTO_LOITER
            self.statustext(M.MAV_SEVERITY_INFO, "Takeoff done: AUTO.LOITER")
        if not sim.armed:
            return
        if not sim.landed:
            self._airborne = True
            self._landed_since_us = None
        elif self._airborne:
            if self._landed_since_us is None:
                self._landed_since_us = self.t_us
            elif self.t_us - self._landed_since_us >= DISARM_LAND_S * 1e6:
                self._do_disarm("Landing detected: disarmed")
