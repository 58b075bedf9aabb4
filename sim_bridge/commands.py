"""COMMAND_LONG / COMMAND_INT, the PARAM protocol and SET_ATTITUDE_TARGET checks of the bundled vehicle.

Every command addressed to the vehicle gets exactly one COMMAND_ACK: ACCEPTED, DENIED (with a STATUSTEXT
that says why), or UNSUPPORTED. The functions here take the running :class:`sim_bridge.vehicle.SitlVehicle`
(``v``) and the link the request came in on; they never raise on bad input.
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from companion.autopilots import px4_modes
from sim_bridge.params import param_id_str

log = logging.getLogger(__name__)

M = mavlink2
FORCE_DISARM_MAGIC = 21196
ACCEPTED, DENIED, UNSUPPORTED, FAILED = (
    M.MAV_RESULT_ACCEPTED, M.MAV_RESULT_DENIED, M.MAV_RESULT_UNSUPPORTED, M.MAV_RESULT_FAILED,
)

# SET_ATTITUDE_TARGET.type_mask bits
RATE_IGNORE_BITS = (1, 2, 4)
THRUST_IGNORE = 64
ATTITUDE_IGNORE = 128
TICK_ONLY_MASK = 1 | 2 | 4 | THRUST_IGNORE | ATTITUDE_IGNORE

# SET_POSITION_TARGET_LOCAL_NED.type_mask bits (POSITION_TARGET_TYPEMASK)
POS_IGNORE = (1, 2, 4)
VEL_IGNORE = (8, 16, 32)
ACC_IGNORE = (64, 128, 256)
FORCE_SET = 512
YAW_IGNORE = 1024
YAW_RATE_IGNORE = 2048
_NAN = math.nan


def parse_position_target(msg: Any, yaw_now_rad: float) -> tuple[str | None, tuple | None]:
    """Check a SET_POSITION_TARGET_LOCAL_NED as PX4's mavlink_receiver reads it.

    Returns (rejection kind or None, (position, velocity, acceleration, yaw, yaw rate)) with NED arrays in
    which NaN means "not controlled on this axis" (ignored by type_mask, or sent as NaN, as PX4 treats it).
    MAV_FRAME_LOCAL_NED is taken as is; MAV_FRAME_BODY_NED (velocity/acceleration only) is rotated by the
    current heading ``yaw_now_rad``. Rejections: ``nonfinite`` (±inf), ``bad_setpoint`` (another frame,
    FORCE_SET with an acceleration, or nothing to control).
    """
    mask = int(msg.type_mask)
    raw = [float(v) for v in (msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz, msg.afx, msg.afy, msg.afz)]
    yaw = _NAN if mask & YAW_IGNORE else float(msg.yaw)
    yaw_rate = _NAN if mask & YAW_RATE_IGNORE else float(msg.yaw_rate)
    if any(math.isinf(v) for v in (*raw, yaw, yaw_rate)):
        return "nonfinite", None
    frame = int(msg.coordinate_frame)
    if frame == M.MAV_FRAME_LOCAL_NED:
        pos = np.array([_NAN if mask & b else v for b, v in zip(POS_IGNORE, raw[0:3], strict=True)])
        vel = np.array([_NAN if mask & b else v for b, v in zip(VEL_IGNORE, raw[3:6], strict=True)])
        acc = np.array([_NAN if mask & b else v for b, v in zip(ACC_IGNORE, raw[6:9], strict=True)])
    elif frame == M.MAV_FRAME_BODY_NED:
        c, s = math.cos(yaw_now_rad), math.sin(yaw_now_rad)
        pos = np.full(3, _NAN)
        vel = np.full(3, _NAN)
        acc = np.full(3, _NAN)
        if not mask & (8 | 16 | 32):
            vel = np.array([c * raw[3] - s * raw[4], s * raw[3] + c * raw[4], raw[5]])
        if not mask & (64 | 128 | 256):
            acc = np.array([c * raw[6] - s * raw[7], s * raw[6] + c * raw[7], raw[8]])
    else:
        return "bad_setpoint", None
    has_acc = not np.all(np.isnan(acc))
    if has_acc and mask & FORCE_SET:
        return "bad_setpoint", None
    if np.all(np.isnan(pos)) and np.all(np.isnan(vel)) and not has_acc:
        return "bad_setpoint", None
    return None, (pos, vel, acc, yaw, yaw_rate)


def parse_attitude_target(msg: Any) -> tuple[str | None, Any, np.ndarray | None, float | None]:
    """Check a SET_ATTITUDE_TARGET; returns (rejection kind or None, q, body rates, normalized thrust).

    Ignored fields (type_mask) are returned as None and not checked (they may be NaN, as some senders do).
    Rejection kinds: ``nonfinite``, ``bad_quaternion`` (|‖q‖ − 1| > 1e-3), ``thrust_range`` (outside 0..1).
    """
    q = msg.q
    return parse_attitude_fields(int(msg.type_mask), q[0], q[1], q[2], q[3], msg.body_roll_rate,
                                 msg.body_pitch_rate, msg.body_yaw_rate, msg.thrust)


def parse_attitude_fields(mask: int, c0: float, c1: float, c2: float, c3: float, roll_rate: float,
                          pitch_rate: float, yaw_rate: float, thrust_n1: float,
                          ) -> tuple[str | None, tuple[float, float, float, float] | None, np.ndarray | None,
                                     float | None]:
    """:func:`parse_attitude_target` on the message's fields (the lockstep hot path decodes no message
    object): q [w x y z] as a tuple of floats, body rates (rad/s) as an array, normalized thrust."""
    q = None
    rates = None
    thrust = None
    isfinite = math.isfinite
    if not mask & ATTITUDE_IGNORE:
        q0, q1, q2, q3 = float(c0), float(c1), float(c2), float(c3)
        if not (isfinite(q0) and isfinite(q1) and isfinite(q2) and isfinite(q3)):
            return "nonfinite", None, None, None
        if abs(math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3) - 1.0) > 1e-3:
            return "bad_quaternion", None, None, None
        q = (q0, q1, q2, q3)
    if (mask & 7) != 7:
        r = [0.0 if mask & b else float(x) for b, x in
             zip(RATE_IGNORE_BITS, (roll_rate, pitch_rate, yaw_rate), strict=True)]
        if not (isfinite(r[0]) and isfinite(r[1]) and isfinite(r[2])):
            return "nonfinite", None, None, None
        rates = np.array(r)
    if not mask & THRUST_IGNORE:
        thrust = float(thrust_n1)
        if not isfinite(thrust):
            return "nonfinite", None, None, None
        if not 0.0 <= thrust <= 1.0:
            return "thrust_range", None, None, None
    return None, q, rates, thrust


# ------------------------------------------------------------------------------------------------ commands
def handle_command(v: Any, link: Any, msg: Any, is_int: bool) -> None:
    """Execute a COMMAND_LONG/COMMAND_INT for the vehicle and ACK it on ``link``."""
    cmd = int(msg.command)
    if is_int:
        p = [msg.param1, msg.param2, msg.param3, msg.param4, float(msg.x), float(msg.y), float(msg.z)]
    else:
        p = [msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7]
    after: list = []
    try:
        result, why = _dispatch(v, link, cmd, p, after)
    except Exception:  # a handler bug must still give the client an answer
        log.exception("command %d failed", cmd)
        result, why = FAILED, "internal error"
    if why:
        v.statustext(M.MAV_SEVERITY_WARNING if result != ACCEPTED else M.MAV_SEVERITY_INFO, why)
    link.mav.command_ack_send(cmd, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())
    for fn in after:  # messages requested by the command go out after the ACK
        fn()


def _dispatch(v: Any, link: Any, cmd: int, p: list[float], after: list) -> tuple[int, str]:
    if cmd == M.MAV_CMD_COMPONENT_ARM_DISARM:
        if p[0] >= 0.5:
            return v.arm()
        return v.disarm(force=round(p[1]) == FORCE_DISARM_MAGIC)
    if cmd == M.MAV_CMD_DO_SET_MODE:
        if not int(p[0]) & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return DENIED, "Only custom (PX4) modes are supported"
        mode = px4_modes.Px4Mode(int(p[1]), int(p[2]) if int(p[1]) == px4_modes.MAIN_AUTO else 0)
        return v.set_mode(mode)
    if cmd == M.MAV_CMD_NAV_TAKEOFF:
        return v.takeoff(p[6])
    if cmd == M.MAV_CMD_NAV_LAND:
        return v.set_mode(px4_modes.AUTO_LAND)
    if cmd == M.MAV_CMD_SET_MESSAGE_INTERVAL:
        if not link.scheduler.set_interval(int(p[0]), p[1], v.t_us):
            return DENIED, f"Cannot stream message {int(p[0])}"
        return ACCEPTED, ""
    if cmd in (M.MAV_CMD_REQUEST_MESSAGE, M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES,
               M.MAV_CMD_REQUEST_PROTOCOL_VERSION):
        if cmd == M.MAV_CMD_REQUEST_MESSAGE:
            msgid = int(p[0])
        elif cmd == M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            msgid = M.MAVLINK_MSG_ID_AUTOPILOT_VERSION
        else:
            msgid = 300
        if not v.can_send(msgid):
            return DENIED, f"Message {msgid} not available"
        after.append(lambda: v.send_message(msgid, link))
        return ACCEPTED, ""
    if cmd == M.MAV_CMD_GET_HOME_POSITION:  # deprecated in favour of REQUEST_MESSAGE(242); PX4 still answers
        after.append(lambda: v.send_message(M.MAVLINK_MSG_ID_HOME_POSITION, link))
        return ACCEPTED, ""
    if cmd == M.MAV_CMD_DO_SET_MISSION_CURRENT:  # MAVSDK's mission_raw.set_current_mission_item
        outs = v.missions.set_current(round(p[0]))
        if outs is None:
            return DENIED, f"Mission item {p[0]:g} not in the mission"
        after.append(lambda: v.send_mission_outputs(outs))
        return ACCEPTED, ""
    if cmd == M.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN:
        if round(p[0]) != 1:
            return DENIED, "Only autopilot reboot (param1=1) is simulated"
        return v.reboot()
    return UNSUPPORTED, ""


# ------------------------------------------------------------------------------------------------ params
def send_param(v: Any, link: Any, index: int) -> None:
    """PARAM_VALUE of the parameter at ``index``."""
    prm = v.params.by_index(index)
    if prm is not None:
        link.mav.param_value_send(prm.name.encode(), prm.current(), prm.mav_type, len(v.params), index)


def handle_param_request_list(v: Any, link: Any) -> None:
    """All parameters, in index order."""
    for i in range(len(v.params)):
        send_param(v, link, i)


def handle_param_request_read(v: Any, link: Any, msg: Any) -> None:
    """One parameter by index (param_index >= 0) or by name."""
    if msg.param_index >= 0:
        if v.params.by_index(msg.param_index) is None:
            v.counters.reject("bad_param", f"no parameter at index {msg.param_index}")
            return
        send_param(v, link, msg.param_index)
        return
    name = param_id_str(msg.param_id)
    if v.params.get(name) is None:
        v.counters.reject("bad_param", f"unknown parameter {name!r}")
        return
    send_param(v, link, v.params.index_of(name))


def handle_param_set(v: Any, link: Any, msg: Any) -> None:
    """Set and echo the (possibly unchanged) value; refusals also get a STATUSTEXT."""
    name = param_id_str(msg.param_id)
    prm = v.params.get(name)
    if prm is None:
        v.counters.reject("bad_param", f"PARAM_SET of unknown {name!r}")
        v.statustext(M.MAV_SEVERITY_WARNING, f"Unknown parameter {name}")
        return
    ok, why = v.params.set(name, float(msg.param_value))
    if not ok:
        v.counters.reject("bad_param", why)
        v.statustext(M.MAV_SEVERITY_WARNING, why)
    elif prm.reboot:
        v.statustext(M.MAV_SEVERITY_NOTICE, f"{name} takes effect at next start/reboot")
    send_param(v, link, v.params.index_of(name))
