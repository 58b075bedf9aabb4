"""How the bundled vehicle packs and sends each message it streams (the hot ones packed once per instant).

Every message carries simulated time (time_boot_ms / time_usec). Which messages are due on a link and how
often: :mod:`sim_bridge.stream_rates` (its message ids are re-exported here).
"""

from __future__ import annotations

import functools
import math
import struct
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from companion.core.rotations import quat_from_euler
from companion.mavlink_io import codec as mf
from sim_bridge.stream_rates import (  # the message ids (also read from here by tests)
    MSG_ATTITUDE,
    MSG_ATTITUDE_QUATERNION,
    MSG_ATTITUDE_TARGET,
    MSG_AUTOPILOT_VERSION,
    MSG_DEBUG_FLOAT_ARRAY,
    MSG_EXTENDED_SYS_STATE,
    MSG_GLOBAL_POSITION_INT,
    MSG_GPS_GLOBAL_ORIGIN,
    MSG_HEARTBEAT,
    MSG_HIGHRES_IMU,
    MSG_HOME_POSITION,
    MSG_LOCAL_POSITION_NED,
    MSG_MISSION_CURRENT,
    MSG_PROTOCOL_VERSION,
    MSG_SCALED_IMU,
    MSG_SYS_STATUS,
    MSG_SYSTEM_TIME,
)

SWING_NAME = b"SWING"
SWING_ARRAY_ID = 1

CAPABILITIES = (
    mavlink2.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    | mavlink2.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    | mavlink2.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
    | mavlink2.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    | mavlink2.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT  # the mission service (sim_bridge.mission_server)
    | mavlink2.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    | mavlink2.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE
    | mavlink2.MAV_PROTOCOL_CAPABILITY_MISSION_RALLY
)
SW_VERSION = (0 << 24) | (1 << 16) | (0 << 8) | 255  # slungpilot 0.1.0, release

_WGS84_A = 6378137.0
_WGS84_E2 = 6.69437999014e-3


def ned_to_geodetic(ned_m: np.ndarray, lat0_deg: float, lon0_deg: float, alt0_m: float) -> tuple[float, float, float]:
    """Latitude, longitude (deg) and altitude AMSL (m) of a NED offset from home (WGS-84 local radii)."""
    lat_div, lon_div = _geodetic_divisors(lat0_deg, alt0_m)
    lat = lat0_deg + math.degrees(float(ned_m[0]) / lat_div)
    lon = lon0_deg + math.degrees(float(ned_m[1]) / lon_div)
    return lat, lon, alt0_m - float(ned_m[2])


@functools.lru_cache(maxsize=8)
def _geodetic_divisors(lat0_deg: float, alt0_m: float) -> tuple[float, float]:
    """(r_N + h, (r_E + h)·cos φ0) in m: what a north and an east offset are divided by (WGS-84 local radii)."""
    lat0 = math.radians(lat0_deg)
    s2 = math.sin(lat0) ** 2
    r_n = _WGS84_A * (1.0 - _WGS84_E2) / (1.0 - _WGS84_E2 * s2) ** 1.5  # meridian radius
    r_e = _WGS84_A / math.sqrt(1.0 - _WGS84_E2 * s2)  # prime vertical radius
    return r_n + alt0_m, (r_e + alt0_m) * math.cos(lat0)


class ProtocolVersionMessage(mavlink2.MAVLink_message):
    """PROTOCOL_VERSION (id 300), missing from pymavlink's common dialect; CRC extra 217."""

    id = MSG_PROTOCOL_VERSION
    msgname = "PROTOCOL_VERSION"
    crc_extra = 217

    def __init__(self, version: int, min_version: int, max_version: int) -> None:
        mavlink2.MAVLink_message.__init__(self, self.id, self.msgname)
        self.version, self.min_version, self.max_version = version, min_version, max_version

    def pack(self, mav: Any, force_mavlink1: bool = False) -> bytes:
        payload = np.array([self.version, self.min_version, self.max_version], "<u2").tobytes() + bytes(16)
        return self._pack(mav, self.crc_extra, payload, force_mavlink1=False)


_SWING_PREFIX = struct.Struct("<QH10s5f")


class SwingMessage(mavlink2.MAVLink_debug_float_array_message):
    """DEBUG_FLOAT_ARRAY "SWING" with data[5:] = 0, packed without its 53 zero floats.

    MAVLink 2 strips trailing zero bytes from every payload anyway; packing only the used prefix gives the
    same bytes on the wire and skips pymavlink's byte-by-byte trimming of 212 zeros (the hot path).
    """

    def pack(self, mav: Any, force_mavlink1: bool = False) -> bytes:
        d = self.data
        payload = _SWING_PREFIX.pack(self.time_usec, self.array_id, self._name_raw, d[0], d[1], d[2], d[3], d[4])
        return self._pack(mav, self.crc_extra, payload, force_mavlink1=False)


class Snapshot:
    """The vehicle's state at one simulated instant as Python floats, shared by the messages of that instant.

    Built once per control period (``x.tolist()``: no numpy scalars in the packing); derived values (body rates,
    attitude quaternion) are computed on first use with the same floating-point operations, in the same order,
    as :class:`sim_bridge.physics.VehicleSim`'s properties, so the packed bytes do not change.
    """

    __slots__ = ("_quat", "_rates", "payloads", "sim", "t_ms", "t_us", "v", "x")

    def __init__(self, v: Any) -> None:
        self.v = v
        self.sim = v.sim
        self.x = v.sim.x.tolist()
        self.t_us = v.t_us
        self.t_ms = v.t_us // 1000
        self._rates: tuple[float, float, float] | None = None
        self._quat: tuple[float, float, float, float] | None = None
        self.payloads: dict[int, tuple[int, bytes]] = {}  # msgid → (CRC extra, payload) packed at this instant

    @property
    def rates(self) -> tuple[float, float, float]:
        """Body rates FRD (rad/s), as ``VehicleSim.body_rates_frd_rad_s``."""
        r = self._rates
        if r is None:
            x = self.x
            phi, th = x[3], x[4]
            dphi, dth, dpsi = x[11], x[12], x[13]
            sf, cf, ct = math.sin(phi), math.cos(phi), math.cos(th)
            r = self._rates = (dphi - math.sin(th) * dpsi, cf * dth + sf * ct * dpsi, -sf * dth + cf * ct * dpsi)
        return r

    @property
    def quat(self) -> tuple[float, float, float, float]:
        """Attitude quaternion [w x y z], as ``VehicleSim.quat_wxyz``."""
        q = self._quat
        if q is None:
            x = self.x
            q = self._quat = quat_tuple(x[3], x[4], x[5])
        return q


def quat_tuple(phi: float, theta: float, psi: float) -> tuple[float, float, float, float]:
    """:func:`companion.core.rotations.quat_from_euler` as a tuple of floats (the same operations in the same
    order, so the same bits; no array for a quaternion that is only packed)."""
    cr, sr = math.cos(0.5 * phi), math.sin(0.5 * phi)
    cp, sp = math.cos(0.5 * theta), math.sin(0.5 * theta)
    cy, sy = math.cos(0.5 * psi), math.sin(0.5 * psi)
    return (cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy)


def hot_payload(msgid: int, v: Any, snap: Snapshot | None = None) -> tuple[int, bytes] | None:
    """(CRC extra, payload) of a streamed vehicle message at the vehicle's current time; None for others.

    ``snap``: the :class:`Snapshot` of the current instant (made here if not given)."""
    if msgid == MSG_SYSTEM_TIME:  # the lockstep marker: nothing but the time
        return mf.CRC_SYSTEM_TIME, mf.P_SYSTEM_TIME.pack(0, (v.t_us // 1000) & 0xFFFFFFFF)
    s = snap if snap is not None else Snapshot(v)
    x = s.x
    t_ms = s.t_ms
    if msgid == MSG_DEBUG_FLOAT_ARRAY:
        sim = s.sim
        # data[4]: the cable's length while it is taut; while the payload rests on the ground (cable slack) the
        # airframe-payload distance, shorter: a slack cable has no swing angle worth the name
        reach = sim.params.l if not sim.payload_on_ground else float(
            np.linalg.norm(sim.payload_pos_ned_m - sim.pos_ned_m))
        return mf.CRC_DEBUG_FLOAT_ARRAY, mf.P_SWING.pack(s.t_us, SWING_ARRAY_ID, SWING_NAME, x[6], x[7], x[14],
                                                         x[15], reach)
    if msgid == MSG_ATTITUDE:
        w = s.rates
        # the model's Euler angles are unwrapped (a spinning vehicle's yaw runs past ±π); MAVLink's are in ±π
        return mf.CRC_ATTITUDE, mf.P_ATTITUDE.pack(t_ms, math.remainder(x[3], math.tau), x[4],
                                                   math.remainder(x[5], math.tau), w[0], w[1], w[2])
    if msgid == MSG_LOCAL_POSITION_NED:
        return mf.CRC_LOCAL_POSITION_NED, mf.P_LOCAL_POSITION_NED.pack(t_ms, x[0], x[1], x[2], x[8], x[9], x[10])
    if msgid == MSG_ATTITUDE_QUATERNION:
        q = s.quat
        w = s.rates
        return mf.CRC_ATTITUDE_QUATERNION, mf.P_ATTITUDE_QUATERNION.pack(t_ms, q[0], q[1], q[2], q[3], w[0], w[1],
                                                                         w[2])
    if msgid == MSG_GLOBAL_POSITION_INT:
        return mf.CRC_GLOBAL_POSITION_INT, _global_payload(t_ms, x[0:3], x[8:11], x[5], v.origin,
                                                           v.home_local_ned_m[2])
    sim = s.sim
    if msgid == MSG_ATTITUDE_TARGET:
        e = sim.target_euler_rad
        q = quat_tuple(float(e[0]), float(e[1]), float(e[2]))
        r = sim.target_rates_frd_rad_s if sim.target_rates_frd_rad_s is not None else _ZERO3
        return mf.CRC_ATTITUDE_TARGET, mf.P_ATTITUDE_TARGET.pack(
            t_ms, q[0], q[1], q[2], q[3], r[0], r[1], r[2], v.normalized_thrust(sim.target_thrust_n), 0)
    if msgid == MSG_HIGHRES_IMU:
        acc, gyro, mag, press_hpa, alt_m, temp_c = v.imu_sample(s)
        return CRC_HIGHRES_IMU, P_HIGHRES_IMU.pack(
            s.t_us, acc[0], acc[1], acc[2], gyro[0], gyro[1], gyro[2], mag[0], mag[1], mag[2], press_hpa, 0.0,
            alt_m, temp_c, HIGHRES_FIELDS, 0)
    if msgid == MSG_EXTENDED_SYS_STATE:
        return mf.CRC_EXTENDED_SYS_STATE, mf.P_EXTENDED_SYS_STATE.pack(mavlink2.MAV_VTOL_STATE_UNDEFINED,
                                                                       v.landed_state)
    return None


def send_marker(mav: mavlink2.MAVLink, t_us: int) -> None:
    """The lockstep end-of-step marker: SYSTEM_TIME with time_boot_ms = simulated ms, time_unix_usec 0."""
    mf.send_system_time(mav, 0, (t_us // 1000) & 0xFFFFFFFF)


def send_due(due: list[int], mav: mavlink2.MAVLink, v: Any, snap: Snapshot) -> None:
    """Send the messages ``due`` on one link at the instant of ``snap`` (:func:`send_vehicle_message` for each,
    with the hot messages' payloads packed once per instant for all links)."""
    payloads = snap.payloads
    send = mf.send_payload
    for msgid in due:
        hot = payloads.get(msgid)
        if hot is None:
            hot = hot_payload(msgid, v, snap)
            if hot is None:
                send_vehicle_message(msgid, mav, v, snap)
                continue
            payloads[msgid] = hot
        send(mav, msgid, hot[0], hot[1])


def send_vehicle_message(msgid: int, mav: mavlink2.MAVLink, v: Any, snap: Snapshot | None = None) -> bool:
    """Send one message of the vehicle system, ``v`` being the running vehicle; False if unknown here.

    ``snap`` (a :class:`Snapshot` the caller keeps for one instant of simulated time only) lets the links of
    one control period share the packing work: each message is packed once per instant.
    """
    if snap is None:
        hot = hot_payload(msgid, v)
    else:
        hot = snap.payloads.get(msgid)
        if hot is None:
            hot = hot_payload(msgid, v, snap)
            if hot is not None:
                snap.payloads[msgid] = hot
    if hot is not None:
        mf.send_payload(mav, msgid, hot[0], hot[1])
    elif msgid == MSG_HEARTBEAT:
        mf.send_heartbeat(
            mav, mavlink2.MAV_TYPE_QUADROTOR, mavlink2.MAV_AUTOPILOT_PX4, v.base_mode, v.mode.custom_mode,
            mavlink2.MAV_STATE_ACTIVE if v.armed else mavlink2.MAV_STATE_STANDBY,
        )
    elif msgid == MSG_SYS_STATUS:
        present, enabled, health = sys_status_bits(v.prearm_ok, v.cfg.prearm_checks)
        # no battery (PX4 without one: voltage UINT16_MAX, current -1, remaining -1); load 10 %
        mav.sys_status_send(present, enabled, health, 100, 65535, -1, -1, 0, min(v.counters.total, 65535),
                            0, 0, 0, 0)
    elif msgid == MSG_HOME_POSITION:
        h = v.home_local_ned_m
        lat, lon, alt = ned_to_geodetic(h, *v.origin)
        mav.home_position_send(round(lat * 1e7), round(lon * 1e7), round(alt * 1000.0), float(h[0]), float(h[1]),
                               float(h[2]), list(quat_from_euler(0.0, 0.0, v.home_yaw_rad)), 0.0, 0.0, 0.0,
                               v.home_time_us)
    elif msgid == MSG_GPS_GLOBAL_ORIGIN:  # the local NED frame's origin (LOCAL_POSITION_NED's zero)
        mav.gps_global_origin_send(round(v.origin[0] * 1e7), round(v.origin[1] * 1e7), round(v.origin[2] * 1000.0),
                                   v.t_us)
    elif msgid == MSG_MISSION_CURRENT:
        mav.mission_current_send(**v.missions.current_fields())
    elif msgid == MSG_SCALED_IMU:
        acc, gyro, mag, _, _, temp_c = v.imu_sample()
        mav.scaled_imu_send(v.t_us // 1000 & 0xFFFFFFFF, *(_i16(a / G_STD * 1000.0) for a in acc),
                            *(_i16(w * 1000.0) for w in gyro), *(_i16(b * 1000.0) for b in mag),
                            _i16(temp_c * 100.0))
    elif msgid == MSG_AUTOPILOT_VERSION:
        mav.autopilot_version_send(CAPABILITIES, SW_VERSION, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0,
                                   v.sysid)
    elif msgid == MSG_PROTOCOL_VERSION:
        mav.send(ProtocolVersionMessage(200, 100, 200))
    else:
        return False
    return True


def send_payload_messages(mav: mavlink2.MAVLink, v: Any, heartbeat: bool, snap: Snapshot | None = None) -> None:
    """The payload as ArduPilot's SITL slung payload (SIM_SlungPayload.cpp) announces itself: HEARTBEAT (if
    ``heartbeat``) with type AIRSHIP, autopilot INVALID, base_mode 0, status 0; GLOBAL_POSITION_INT (altitude
    above home in relative_alt, heading 0) and ATTITUDE (all zero: a point mass); plus our LOCAL_POSITION_NED
    of the payload point (same local frame as the vehicle's). ``snap``: as in :func:`send_vehicle_message`
    (the payloads are packed once per instant for all links)."""
    if heartbeat:
        mf.send_heartbeat(mav, mavlink2.MAV_TYPE_AIRSHIP, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 0)
    packed = snap.payloads.get(_PAYLOAD_KEY) if snap is not None else None
    if packed is None:
        sim = v.sim
        t_ms = v.t_us // 1000
        p, vel = sim.payload_pos_ned_m, sim.payload_vel_ned_mps
        packed = (_global_payload(t_ms, p, vel, 0.0, v.origin, v.home_local_ned_m[2]),
                  mf.P_ATTITUDE.pack(t_ms, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
                  mf.P_LOCAL_POSITION_NED.pack(t_ms, p[0], p[1], p[2], vel[0], vel[1], vel[2]))
        if snap is not None:
            snap.payloads[_PAYLOAD_KEY] = packed
    mf.send_payload(mav, mf.ID_GLOBAL_POSITION_INT, mf.CRC_GLOBAL_POSITION_INT, packed[0])
    mf.send_payload(mav, mf.ID_ATTITUDE, mf.CRC_ATTITUDE, packed[1])
    mf.send_payload(mav, mf.ID_LOCAL_POSITION_NED, mf.CRC_LOCAL_POSITION_NED, packed[2])


_PAYLOAD_KEY = -1  # Snapshot.payloads key of the payload system's three packed payloads


# SYS_STATUS, as PX4's SYS_STATUS stream fills it from its health report: a component is *present* if the
# vehicle has it, *healthy* unless it reports an error (also when absent), *enabled* if present or unhealthy;
# MAV_SYS_STATUS_PREARM_CHECK is set in health only, when arming is possible in the current mode.
_S = mavlink2
SENSORS_PRESENT = (_S.MAV_SYS_STATUS_SENSOR_3D_GYRO | _S.MAV_SYS_STATUS_SENSOR_3D_ACCEL
                   | _S.MAV_SYS_STATUS_SENSOR_3D_MAG | _S.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
                   | _S.MAV_SYS_STATUS_SENSOR_GPS | _S.MAV_SYS_STATUS_AHRS)
SENSORS_REPORTED = (SENSORS_PRESENT | _S.MAV_SYS_STATUS_SENSOR_BATTERY | _S.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
                    | _S.MAV_SYS_STATUS_RECOVERY_SYSTEM | _S.MAV_SYS_STATUS_OBSTACLE_AVOIDANCE
                    | _S.MAV_SYS_STATUS_SENSOR_RC_RECEIVER | _S.MAV_SYS_STATUS_SENSOR_DIFFERENTIAL_PRESSURE)


def sys_status_bits(prearm_ok: bool, checks: bool = True) -> tuple[int, int, int]:
    """(present, enabled, health) of SYS_STATUS for a healthy simulated vehicle; ``checks`` False: as ArduCopter
    with ARMING_CHECK 0, the pre-arm bit present but neither enabled nor healthy."""
    if not checks:
        return SENSORS_PRESENT | _S.MAV_SYS_STATUS_PREARM_CHECK, SENSORS_PRESENT, SENSORS_REPORTED
    health = SENSORS_REPORTED | (_S.MAV_SYS_STATUS_PREARM_CHECK if prearm_ok else 0)
    enabled = SENSORS_PRESENT | (SENSORS_REPORTED & ~health)
    return SENSORS_PRESENT, enabled, health


# HIGHRES_IMU: hand-packed (hot path, 50 Hz), byte-identical to pymavlink (tests/test_mavlink_fast.py)
CRC_HIGHRES_IMU = 93
P_HIGHRES_IMU = struct.Struct("<Q13fHB")
HIGHRES_FIELDS = 0x1FFF & ~(0x400)  # accel, gyro, mag, abs pressure, pressure alt, temperature (no diff pressure)
G_STD = 9.80665
EARTH_FIELD_NED_GAUSS = np.array([0.21, 0.015, 0.43])  # about Zurich (the default home)


def isa_pressure_hpa(alt_amsl_m: float) -> float:
    """International Standard Atmosphere pressure (hPa) at an altitude (m), troposphere."""
    return 1013.25 * (1.0 - 2.25577e-5 * alt_amsl_m) ** 5.25588


def _global_payload(t_ms: int, p, vel, yaw_rad: float, origin: tuple[float, float, float],
                    home_z_m: float = 0.0) -> bytes:
    """GLOBAL_POSITION_INT payload; ``origin`` is the local frame's geodetic origin, ``home_z_m`` the home's
    local z (relative_alt is the altitude above home, as PX4's)."""
    lat, lon, alt = ned_to_geodetic(p, *origin)
    hdg = round(math.degrees(yaw_rad) * 100.0) % 36000
    return mf.P_GLOBAL_POSITION_INT.pack(
        t_ms, round(lat * 1e7), round(lon * 1e7), round(alt * 1000.0),
        round((home_z_m - float(p[2])) * 1000.0),
        _i16(vel[0] * 100.0), _i16(vel[1] * 100.0), _i16(vel[2] * 100.0), hdg,
    )


def _i16(x: float) -> int:
    return int(max(-32768, min(32767, round(float(x)))))


_ZERO3 = (0.0, 0.0, 0.0)
