"""Which messages the bundled vehicle streams on a link, and how often (simulated time).

Rates are kept per message id in integer microseconds of simulated time, so lockstep runs are exact.
``set_interval`` follows MAV_CMD_SET_MESSAGE_INTERVAL: -1 disables, 0 restores the default, > 0 sets µs.
The defaults follow PX4's onboard and normal stream modes (:func:`default_intervals_us`). How each message is
packed: :mod:`sim_bridge.telemetry`.
"""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mavlink2

MSG_HEARTBEAT = mavlink2.MAVLINK_MSG_ID_HEARTBEAT
MSG_SYS_STATUS = mavlink2.MAVLINK_MSG_ID_SYS_STATUS
MSG_SYSTEM_TIME = mavlink2.MAVLINK_MSG_ID_SYSTEM_TIME
MSG_ATTITUDE = mavlink2.MAVLINK_MSG_ID_ATTITUDE
MSG_ATTITUDE_QUATERNION = mavlink2.MAVLINK_MSG_ID_ATTITUDE_QUATERNION
MSG_LOCAL_POSITION_NED = mavlink2.MAVLINK_MSG_ID_LOCAL_POSITION_NED
MSG_GLOBAL_POSITION_INT = mavlink2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT
MSG_ATTITUDE_TARGET = mavlink2.MAVLINK_MSG_ID_ATTITUDE_TARGET
MSG_EXTENDED_SYS_STATE = mavlink2.MAVLINK_MSG_ID_EXTENDED_SYS_STATE
MSG_AUTOPILOT_VERSION = mavlink2.MAVLINK_MSG_ID_AUTOPILOT_VERSION
MSG_DEBUG_FLOAT_ARRAY = mavlink2.MAVLINK_MSG_ID_DEBUG_FLOAT_ARRAY
MSG_HOME_POSITION = mavlink2.MAVLINK_MSG_ID_HOME_POSITION
MSG_HIGHRES_IMU = mavlink2.MAVLINK_MSG_ID_HIGHRES_IMU
MSG_SCALED_IMU = mavlink2.MAVLINK_MSG_ID_SCALED_IMU
MSG_MISSION_CURRENT = mavlink2.MAVLINK_MSG_ID_MISSION_CURRENT
MSG_GPS_GLOBAL_ORIGIN = mavlink2.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN
MSG_PROTOCOL_VERSION = 300  # not in pymavlink's common dialect; packed by ProtocolVersionMessage


def default_intervals_us(control_period_us: int, mode: str = "onboard") -> dict[int, int]:
    """Default telemetry intervals (µs of simulated time) of the vehicle system on one link.

    ``mode`` "onboard" (the companion's link) or "normal" (the ground-station link), after PX4's stream
    lists of the same names in mavlink_main.cpp (v1.15): HIGHRES_IMU 50 Hz, SYS_STATUS and
    EXTENDED_SYS_STATE 5 Hz and HOME_POSITION 0.5 Hz on onboard; normal mode has PX4's slower rates and no
    IMU stream; MISSION_CURRENT at 1 Hz on the normal link only (the onboard link gets it when the mission
    changes, or on request). Onboard keeps faster position/attitude-target rates than PX4 (50 Hz, for the companion) and
    the simulator's cable-angle sensor every control period.
    """
    if mode == "normal":
        return {
            MSG_HEARTBEAT: 1_000_000,
            MSG_SYS_STATUS: 1_000_000,
            MSG_ATTITUDE: 66_667,
            MSG_ATTITUDE_QUATERNION: 100_000,
            MSG_LOCAL_POSITION_NED: 1_000_000,
            MSG_GLOBAL_POSITION_INT: 200_000,
            MSG_EXTENDED_SYS_STATE: 1_000_000,
            MSG_ATTITUDE_TARGET: 500_000,
            MSG_HOME_POSITION: 2_000_000,
            MSG_MISSION_CURRENT: 1_000_000,
            MSG_DEBUG_FLOAT_ARRAY: max(control_period_us, 100_000),
        }
    return {
        MSG_HEARTBEAT: 1_000_000,
        MSG_SYS_STATUS: 200_000,
        MSG_ATTITUDE: 10_000,
        MSG_ATTITUDE_QUATERNION: 20_000,
        MSG_LOCAL_POSITION_NED: 20_000,
        MSG_GLOBAL_POSITION_INT: 20_000,
        MSG_EXTENDED_SYS_STATE: 200_000,
        MSG_ATTITUDE_TARGET: 20_000,
        MSG_HOME_POSITION: 2_000_000,
        MSG_HIGHRES_IMU: 20_000,
        MSG_DEBUG_FLOAT_ARRAY: control_period_us,
    }


class RateScheduler:
    """Which messages are due at a simulated time; intervals in µs, 0 = disabled."""

    def __init__(self, defaults_us: dict[int, int]) -> None:
        self.defaults_us = dict(defaults_us)
        self.intervals_us = dict(defaults_us)
        self._next_us: dict[int, int] = dict.fromkeys(defaults_us, 0)
        self._earliest_us = 0  # no message is due before this time (recomputed by due())

    def set_interval(self, msgid: int, interval_us: float, now_us: int) -> bool:
        """MAV_CMD_SET_MESSAGE_INTERVAL semantics; returns False for a message this vehicle cannot stream."""
        if msgid not in self.defaults_us and msgid not in STREAMABLE:
            return False
        if interval_us < 0:
            self.intervals_us[msgid] = 0
        elif interval_us == 0:
            self.intervals_us[msgid] = self.defaults_us.get(msgid, 0)
        else:
            self.intervals_us[msgid] = max(1, int(interval_us))
        self._next_us[msgid] = now_us
        self._earliest_us = min(self._earliest_us, now_us)
        return True

    def due(self, now_us: int) -> list[int]:
        """Message ids due at ``now_us`` (each at most once per call; no catch-up bursts)."""
        if now_us < self._earliest_us:  # nothing due yet: the common case between rate ticks
            return []
        out = []
        nxt_get = self._next_us.get
        earliest = None
        for msgid, iv in self.intervals_us.items():
            if iv <= 0:
                continue
            t_next = nxt_get(msgid, 0)
            if t_next <= now_us:
                out.append(msgid)
                t_next += iv
                if t_next <= now_us:
                    t_next = now_us + iv
                self._next_us[msgid] = t_next
            if earliest is None or t_next < earliest:
                earliest = t_next
        self._earliest_us = now_us + 1 if earliest is None else earliest
        return out


#: Messages sent only on request (MAV_CMD_SET_MESSAGE_INTERVAL / REQUEST_MESSAGE), not in the default streams
STREAMABLE = {MSG_SYSTEM_TIME, MSG_AUTOPILOT_VERSION, MSG_HIGHRES_IMU, MSG_SCALED_IMU, MSG_HOME_POSITION,
               MSG_MISSION_CURRENT, MSG_GPS_GLOBAL_ORIGIN}


def sendable(msgid: int) -> bool:
    """Whether the vehicle system can send message ``msgid`` at all (streamed by default, or on request)."""
    return msgid in default_intervals_us(1) or msgid in (
        MSG_AUTOPILOT_VERSION, MSG_PROTOCOL_VERSION, MSG_SYSTEM_TIME, MSG_SCALED_IMU, MSG_MISSION_CURRENT,
        MSG_GPS_GLOBAL_ORIGIN)
