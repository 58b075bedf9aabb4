"""Mission items of the bundled vehicle's mission service (:mod:`sim_bridge.mission_server`): which frames and
commands are stored for the mission, fence and rally lists (PX4's mavlink_mission.cpp lists), how an incoming
MISSION_ITEM_INT / MISSION_ITEM is checked (the MAV_MISSION_RESULT of each refusal) and how a stored item is
sent back. Pure: no I/O; pymavlink only for its constants.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import common as M

MISSION, FENCE, RALLY, ALL = (M.MAV_MISSION_TYPE_MISSION, M.MAV_MISSION_TYPE_FENCE, M.MAV_MISSION_TYPE_RALLY,
                              M.MAV_MISSION_TYPE_ALL)
TYPE_NAMES = {MISSION: "mission", FENCE: "fence", RALLY: "rally"}
GLOBAL_FRAMES = {M.MAV_FRAME_GLOBAL, M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_FRAME_GLOBAL_INT,
                 M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT}
FLOAT_TO_INT_FRAME = {M.MAV_FRAME_GLOBAL: M.MAV_FRAME_GLOBAL_INT,
                      M.MAV_FRAME_GLOBAL_RELATIVE_ALT: M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT}
INT_TO_FLOAT_FRAME = {v: k for k, v in FLOAT_TO_INT_FRAME.items()}
LOCAL_SCALE = 1e4  # MISSION_ITEM_INT x/y in local frames: metres × 1e4

_C = M
# commands with a position, as PX4's parse_mavlink_mission_item takes them in global frames (here also in
# MAV_FRAME_LOCAL_NED, for missions planned in the local frame)
POSITION_COMMANDS = frozenset({
    _C.MAV_CMD_NAV_WAYPOINT, _C.MAV_CMD_NAV_LOITER_UNLIM, _C.MAV_CMD_NAV_LOITER_TIME, _C.MAV_CMD_NAV_LAND,
    _C.MAV_CMD_NAV_TAKEOFF, _C.MAV_CMD_NAV_LOITER_TO_ALT, _C.MAV_CMD_NAV_ROI, _C.MAV_CMD_DO_SET_ROI,
    _C.MAV_CMD_DO_SET_ROI_LOCATION, _C.MAV_CMD_NAV_VTOL_TAKEOFF, _C.MAV_CMD_NAV_VTOL_LAND,
    _C.MAV_CMD_CONDITION_GATE, _C.MAV_CMD_NAV_FENCE_RETURN_POINT, _C.MAV_CMD_COMPONENT_ARM_DISARM,
    _C.MAV_CMD_DO_AUTOTUNE_ENABLE})
# commands without a position (MAV_FRAME_MISSION), PX4's list
MISSION_FRAME_COMMANDS = frozenset({
    _C.MAV_CMD_DO_JUMP, _C.MAV_CMD_NAV_ROI, _C.MAV_CMD_DO_SET_ROI, _C.MAV_CMD_DO_WINCH, _C.MAV_CMD_DO_GRIPPER,
    _C.MAV_CMD_DO_CHANGE_SPEED, _C.MAV_CMD_DO_SET_HOME, _C.MAV_CMD_DO_LAND_START, _C.MAV_CMD_DO_TRIGGER_CONTROL,
    _C.MAV_CMD_DO_DIGICAM_CONTROL, _C.MAV_CMD_DO_MOUNT_CONFIGURE, _C.MAV_CMD_DO_MOUNT_CONTROL,
    _C.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW, _C.MAV_CMD_SET_CAMERA_FOCUS, _C.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE,
    _C.MAV_CMD_IMAGE_START_CAPTURE, _C.MAV_CMD_IMAGE_STOP_CAPTURE, _C.MAV_CMD_VIDEO_START_CAPTURE,
    _C.MAV_CMD_VIDEO_STOP_CAPTURE, _C.MAV_CMD_DO_CONTROL_VIDEO, _C.MAV_CMD_DO_SET_CAM_TRIGG_DIST,
    _C.MAV_CMD_OBLIQUE_SURVEY, _C.MAV_CMD_DO_SET_CAM_TRIGG_INTERVAL, _C.MAV_CMD_SET_CAMERA_MODE,
    _C.MAV_CMD_SET_CAMERA_SOURCE, _C.MAV_CMD_DO_VTOL_TRANSITION, _C.MAV_CMD_NAV_DELAY,
    _C.MAV_CMD_NAV_RETURN_TO_LAUNCH, _C.MAV_CMD_DO_SET_ROI_WPNEXT_OFFSET, _C.MAV_CMD_DO_SET_ROI_NONE,
    _C.MAV_CMD_CONDITION_DELAY, _C.MAV_CMD_CONDITION_DISTANCE, _C.MAV_CMD_DO_SET_ACTUATOR,
    _C.MAV_CMD_DO_AUTOTUNE_ENABLE, _C.MAV_CMD_COMPONENT_ARM_DISARM})
POLYGON_COMMANDS = frozenset({_C.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
                              _C.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION})
CIRCLE_COMMANDS = frozenset({_C.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, _C.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION})
FENCE_COMMANDS = POLYGON_COMMANDS | CIRCLE_COMMANDS | {_C.MAV_CMD_NAV_FENCE_RETURN_POINT}

@dataclass(frozen=True)
class Item:
    """One stored item, in MISSION_ITEM_INT form: x/y are degrees × 1e7 in global frames, metres × 1e4 in
    MAV_FRAME_LOCAL_NED, the integer param5/param6 in MAV_FRAME_MISSION; z in m (or param7)."""

    seq: int
    frame: int
    command: int
    current: int
    autocontinue: int
    param1: float
    param2: float
    param3: float
    param4: float
    x: int
    y: int
    z: float
    mission_type: int


def _bad_param(index: int) -> int:
    """MAV_MISSION_INVALID_PARAM1..4 for param ``index`` 1..4, PARAM5_X, PARAM6_Y, PARAM7 for 5..7."""
    return M.MAV_MISSION_INVALID_PARAM1 + index - 1


def parse_item(msg: Any, is_int: bool, mission_type: int) -> tuple[int, Item | None]:
    """Check one MISSION_ITEM_INT (``is_int``) or MISSION_ITEM of ``mission_type`` as PX4 and ArduPilot do;
    returns (MAV_MISSION_RESULT, the item in integer form or None). Refusals: a frame other than the global
    ones, MAV_FRAME_MISSION (mission only) and MAV_FRAME_LOCAL_NED (mission only) → UNSUPPORTED_FRAME
    (MAV_FRAME_GLOBAL_INT/RELATIVE_ALT_INT in a float MISSION_ITEM too, as PX4); a command not stored for
    that type and frame → UNSUPPORTED; ±inf in param1..4 (NaN means "default" in MAVLink and is kept) →
    INVALID_PARAMn; a latitude outside ±90° or NaN → INVALID_PARAM5_X, a longitude outside ±180° or NaN →
    INVALID_PARAM6_Y, a non-finite z → INVALID_PARAM7; a polygon of fewer than 3 vertices or a circle radius
    that is not > 0 → INVALID_PARAM1."""
    frame, cmd = int(msg.frame), int(msg.command)
    params = [float(msg.param1), float(msg.param2), float(msg.param3), float(msg.param4)]
    for i, p in enumerate(params):
        if math.isinf(p):
            return _bad_param(i + 1), None
    if not is_int and frame in INT_TO_FLOAT_FRAME:
        return M.MAV_MISSION_UNSUPPORTED_FRAME, None
    frame = FLOAT_TO_INT_FRAME.get(frame, frame)  # stored, and sent back, as PX4 does: in the _INT frames
    positional = frame in GLOBAL_FRAMES or (frame == M.MAV_FRAME_LOCAL_NED and mission_type == MISSION)
    if not positional and not (frame == M.MAV_FRAME_MISSION and mission_type == MISSION):
        return M.MAV_MISSION_UNSUPPORTED_FRAME, None
    allowed = ({MISSION: POSITION_COMMANDS, FENCE: FENCE_COMMANDS, RALLY: {M.MAV_CMD_NAV_RALLY_POINT}}[mission_type]
               if positional else MISSION_FRAME_COMMANDS)
    if cmd not in allowed:
        return M.MAV_MISSION_UNSUPPORTED, None
    z = float(msg.z)
    if frame == M.MAV_FRAME_MISSION:
        x, y = (int(msg.x), int(msg.y)) if is_int else (_round_or_none(msg.x, 1.0), _round_or_none(msg.y, 1.0))
    elif frame == M.MAV_FRAME_LOCAL_NED:
        x, y = (int(msg.x), int(msg.y)) if is_int else (_round_or_none(msg.x, LOCAL_SCALE),
                                                        _round_or_none(msg.y, LOCAL_SCALE))
    else:
        x, y = (int(msg.x), int(msg.y)) if is_int else (_round_or_none(msg.x, 1e7), _round_or_none(msg.y, 1e7))
        if x is None or not -900_000_000 <= x <= 900_000_000:
            return M.MAV_MISSION_INVALID_PARAM5_X, None
        if y is None or not -1_800_000_000 <= y <= 1_800_000_000:
            return M.MAV_MISSION_INVALID_PARAM6_Y, None
    if x is None:
        return M.MAV_MISSION_INVALID_PARAM5_X, None
    if y is None:
        return M.MAV_MISSION_INVALID_PARAM6_Y, None
    if positional and not math.isfinite(z):
        return M.MAV_MISSION_INVALID_PARAM7, None
    if (cmd in POLYGON_COMMANDS and not params[0] >= 2.5) or (cmd in CIRCLE_COMMANDS and not params[0] > 0.0):
        return M.MAV_MISSION_INVALID_PARAM1, None
    return M.MAV_MISSION_ACCEPTED, Item(int(msg.seq), frame, cmd, int(msg.current), int(msg.autocontinue),
                                        *params, x, y, z, mission_type)


def _round_or_none(v: float, scale: float) -> int | None:
    v = float(v) * scale
    return round(v) if math.isfinite(v) and abs(v) < 2**31 else None


def item_fields(item: Item, target: tuple[int, int], as_int: bool, current_seq: int) -> dict:
    """The fields of a MISSION_ITEM_INT (``as_int``) or MISSION_ITEM (float: global frames back to
    MAV_FRAME_GLOBAL/GLOBAL_RELATIVE_ALT in degrees, local frames in metres) for ``target`` (system,
    component); ``current`` set on the mission's ``current_seq``."""
    frame, x, y = item.frame, item.x, item.y
    if not as_int:
        if frame in INT_TO_FLOAT_FRAME:
            frame, x, y = INT_TO_FLOAT_FRAME[frame], x * 1e-7, y * 1e-7
        elif frame == M.MAV_FRAME_LOCAL_NED:
            x, y = x / LOCAL_SCALE, y / LOCAL_SCALE
        else:
            x, y = float(x), float(y)
    current = int(item.mission_type == MISSION and item.seq == current_seq)
    return {"target_system": target[0], "target_component": target[1], "seq": item.seq, "frame": frame,
            "command": item.command, "current": current, "autocontinue": item.autocontinue,
            "param1": item.param1, "param2": item.param2, "param3": item.param3, "param4": item.param4,
            "x": x, "y": y, "z": item.z, "mission_type": item.mission_type}


def fence_polygon_error(items: tuple[Item, ...]) -> str | None:
    """Why a fence list's polygons are malformed (each polygon: vertex_count consecutive vertices of one kind
    with the same vertex_count, as ArduPilot's AC_PolyFence_loader checks), or None."""
    i = 0
    while i < len(items):
        it = items[i]
        if it.command in POLYGON_COMMANDS:
            n = round(it.param1)
            run = items[i:i + n]
            if len(run) < n or any(v.command != it.command or round(v.param1) != n for v in run):
                return f"Fence polygon at item {i}: {n} vertices announced, not that many follow"
            i += n
        else:
            i += 1
    return None


def result_name(result: int) -> str:
    entry = M.enums["MAV_MISSION_RESULT"].get(result)
    return entry.name if entry is not None else str(result)


