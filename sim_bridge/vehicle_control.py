"""What the bundled vehicle does when told: arming, modes, take-off and reboot (as PX4 answers them), the offboard
setpoints (attitude and position, PX4's offboard rule) and MAVLink signing set-up. A mixin of
:class:`~sim_bridge.vehicle.SitlVehicle`, whose state (``sim``, ``params``, the setpoint fields, links) it uses."""

from __future__ import annotations

import dataclasses
import math

from pymavlink.dialects.v20 import common as mavlink2

from companion.autopilots import px4_modes
from companion.mavlink_io.signing import SigningVerifier
from sim_bridge import commands
from sim_bridge.link import MavUdpLink

M = mavlink2


class VehicleControl:
    """Commands, setpoints and signing of :class:`~sim_bridge.vehicle.SitlVehicle`."""

    # ------------------------------------------------------------------ arming and modes
    def arm(self) -> tuple[int, str]:
        if self.armed:
            return commands.ACCEPTED, ""
        if self.mode == px4_modes.OFFBOARD and not self._stream_ok():
            return commands.DENIED, "Arming denied: no offboard setpoint stream"
        self.sim.armed = True
        self._airborne = not self.sim.landed
        self._landed_since_us = None
        if self.sim.landed:  # PX4 sets home where it arms on the ground
            self.home_local_ned_m = self.sim.pos_ned_m
            self.home_yaw_rad = float(self.sim.euler_rad[2])
            self.home_time_us = self.t_us
        if self.mode != px4_modes.OFFBOARD:
            self._hold_here()
        self.statustext(M.MAV_SEVERITY_INFO, "Armed")
        return commands.ACCEPTED, ""

    def disarm(self, force: bool = False) -> tuple[int, str]:
        if not self.armed:
            return commands.ACCEPTED, ""
        if not self.sim.landed and not force:
            return commands.DENIED, "Disarming denied: not landed (use force)"
        self._do_disarm("Disarmed" + (" (forced)" if force else ""))
        return commands.ACCEPTED, ""

    def _do_disarm(self, why: str) -> None:
        self.sim.armed = False
        self._airborne = False
        self._landed_since_us = None
        self.statustext(M.MAV_SEVERITY_INFO, why)

    def set_mode(self, mode: px4_modes.Px4Mode) -> tuple[int, str]:
        if mode not in px4_modes.SUPPORTED_MODES:
            return commands.DENIED, f"Mode {mode.name} not supported by the SITL vehicle"
        if mode == self.mode:
            return commands.ACCEPTED, ""
        if mode == px4_modes.OFFBOARD:
            if not self._stream_ok():
                return commands.DENIED, "Offboard denied: no setpoint stream"
            self._yaw_sp_rad = float(self.sim.euler_rad[2])
            if self._sp_kind == "attitude" and self._last_sp is not None:
                self.sim.set_attitude_target(*self._sp_newtons(self._last_sp))
        elif mode == px4_modes.AUTO_TAKEOFF:
            self._hold_here()
            self.hold_pos_ned_m[2] = float(self.home_local_ned_m[2]) - self.params.value("MIS_TAKEOFF_ALT")
        elif mode != px4_modes.AUTO_LAND:
            self._hold_here()
        else:
            self._hold_here()
        self.mode = mode
        self.statustext(M.MAV_SEVERITY_INFO, f"Mode: {mode.name}")
        return commands.ACCEPTED, ""

    def takeoff(self, alt_amsl_m: float) -> tuple[int, str]:
        """MAV_CMD_NAV_TAKEOFF: climb to param7 (AMSL, NaN = MIS_TAKEOFF_ALT above home)."""
        if not self.armed:
            return commands.DENIED, "Takeoff denied: arm first"
        alt = self.params.value("MIS_TAKEOFF_ALT")
        home_amsl = self.origin[2] - float(self.home_local_ned_m[2])
        if math.isfinite(alt_amsl_m) and alt_amsl_m > home_amsl:
            alt = alt_amsl_m - home_amsl
        res, why = self.set_mode(px4_modes.AUTO_TAKEOFF)
        if res == commands.ACCEPTED:
            self.hold_pos_ned_m[2] = float(self.home_local_ned_m[2]) - alt
        return res, why

    def reboot(self) -> tuple[int, str]:
        if self.armed:
            return commands.DENIED, "Reboot denied: disarm first"
        p = dataclasses.replace(self.sim.params, m=self.params.value("SIM_PLD_MASS"),
                                l=self.params.value("SIM_CABLE_LEN"))
        self.sim = self._new_sim(p, self.t_us * 1e-6)
        self.mode = px4_modes.AUTO_LOITER
        self._hold_here()
        return commands.ACCEPTED, f"Rebooted: payload {p.m:g} kg, cable {p.l:g} m"

    def _hold_here(self) -> None:
        self.hold_pos_ned_m = self.sim.pos_ned_m
        self.hold_yaw_rad = float(self.sim.euler_rad[2])

    # ------------------------------------------------------------------ offboard setpoints
    def _stream_ok(self) -> bool:
        """PX4's offboard rule (offboardCheck.cpp): one setpoint no older than COM_OF_LOSS_T is enough."""
        return self._sp_time_us is not None and self.t_us - self._sp_time_us <= self._timeout_us()

    def _timeout_us(self) -> int:
        return round(self.params.value("COM_OF_LOSS_T") * 1e6)

    def _sp_newtons(self, sp):
        q, n, rates = sp
        t = None if n is None else n * self.hover_thrust_n / self.params.value("MPC_THR_HOVER")
        return q, t, rates

    def on_attitude_target(self, link: MavUdpLink, msg) -> None:
        """SET_ATTITUDE_TARGET (a message object, already checked for its target)."""
        self._attitude_target(link, *commands.parse_attitude_target(msg))

    def on_attitude_fields(self, link: MavUdpLink, f: tuple) -> None:
        """SET_ATTITUDE_TARGET as the link's hot path unpacks it (``codec.P_SET_ATTITUDE_TARGET``'s fields:
        time_boot_ms, q[4], body rates[3], thrust, target_system, target_component, type_mask): the same
        target checks as :meth:`on_message`, then as :meth:`on_attitude_target`."""
        if f[9] not in (0, self.sysid):
            self.counters.reject("other_target", f"SET_ATTITUDE_TARGET for system {f[9]}")
            return
        if f[10] not in (0, self.cfg.compid):
            self.counters.reject("other_target", f"SET_ATTITUDE_TARGET for component {f[10]}")
            return
        self._attitude_target(link, *commands.parse_attitude_fields(f[11], f[1], f[2], f[3], f[4], f[5], f[6],
                                                                    f[7], f[8]))

    def _attitude_target(self, link: MavUdpLink, kind: str | None, q, rates, thrust) -> None:
        if kind is not None:
            self.counters.reject(kind, "SET_ATTITUDE_TARGET")
            return
        if q is not None or rates is not None or thrust is not None:
            self._sp_time_us = self.t_us
            self._sp_kind = "attitude"
            self._last_sp = (q, thrust, rates)
            if self._offboard:
                self.sim.set_attitude_target(*self._sp_newtons(self._last_sp))
        if self.cfg.lockstep and link is self.onboard:
            self._lockstep_step()

    def on_position_target(self, msg) -> None:
        """SET_POSITION_TARGET_LOCAL_NED: an offboard setpoint (stream and flight) as in PX4."""
        kind, sp = commands.parse_position_target(msg, float(self.sim.euler_rad[2]))
        if kind is not None:
            self.counters.reject(kind, "SET_POSITION_TARGET_LOCAL_NED")
            return
        if self._sp_kind != "position":
            self._yaw_sp_rad = float(self.sim.euler_rad[2])
        self._sp_time_us = self.t_us
        self._sp_kind = "position"
        self._pos_sp = sp

    def on_setup_signing(self, link: MavUdpLink, msg) -> None:
        """SETUP_SIGNING (as PX4's MavlinkSignControl): a 32-byte key and initial timestamp for every link;
        an all-zero key with timestamp 0 turns signing off. Only messages that passed the link's checks get
        here: from its locked peer, and signed with the current key when signing is on. No reply (none is
        defined)."""
        key = bytes(msg.secret_key)
        ts = int(msg.initial_timestamp)
        if not any(key) and ts == 0:
            for lk in self._links():
                lk.set_signing(None)
            self.statustext(M.MAV_SEVERITY_NOTICE, "MAVLink signing disabled (SETUP_SIGNING)")
            return
        self._enable_signing(key, ts)
        self.statustext(M.MAV_SEVERITY_NOTICE, "MAVLink signing key set (SETUP_SIGNING)")

    def _enable_signing(self, key: bytes, initial_timestamp: int = 0) -> None:
        verifier = SigningVerifier(key)
        verifier.newest = initial_timestamp
        for lk in self._links():
            lk.set_signing(verifier)
            lk.signer.timestamp = initial_timestamp
