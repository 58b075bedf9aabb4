"""The flight sequence's requests (:class:`companion.flight.requests.Request`) as MAVLink, and the autopilot's
answers back (typed telemetry events, :mod:`companion.mavlink_io.telemetry`) as (request key, result) pairs.
Sending never waits: the sequence tracks answers and retries.

=========================  ==========================================  ==============================
request key                sent as                                     answered by
=========================  ==========================================  ==============================
``arm`` / ``disarm``       COMMAND_LONG MAV_CMD_COMPONENT_ARM_DISARM   COMMAND_ACK (result)
``mode:land``              COMMAND_LONG MAV_CMD_NAV_LAND               COMMAND_ACK
``mode:<what>``            COMMAND_LONG MAV_CMD_DO_SET_MODE with the   COMMAND_ACK
                           autopilot family's mode numbers
``takeoff``                COMMAND_LONG MAV_CMD_NAV_TAKEOFF (value:    COMMAND_ACK
                           altitude above home, m)
``message_interval:NAME``  COMMAND_LONG MAV_CMD_SET_MESSAGE_INTERVAL   COMMAND_ACK
                           (value: interval, µs)
``request_message:NAME``   COMMAND_LONG MAV_CMD_REQUEST_MESSAGE        COMMAND_ACK (the message follows)
``data_stream:ID``         REQUEST_DATA_STREAM (value: rate, Hz)       nothing: answered at once
``param_read:NAME``        PARAM_REQUEST_READ                          PARAM_VALUE (the value)
``param_set:NAME``         PARAM_SET (value)                           PARAM_VALUE (the new value)
=========================  ==========================================  ==============================

The COMMAND_LONG ``confirmation`` field counts the attempt (0 for the first), as MAVLink asks.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from typing import Any

from pymavlink.dialects.v20 import common as mavlink2

from companion.flight.requests import Request
from companion.mavlink_io.telemetry import CommandAck, ParamValue, TelemetryEvent

log = logging.getLogger(__name__)
M = mavlink2


def message_id(name: str) -> int:
    """MAVLink message id of a common-dialect message name (``"ATTITUDE"`` → 30); ValueError if unknown."""
    try:
        return int(getattr(M, f"MAVLINK_MSG_ID_{name}"))
    except AttributeError:
        raise ValueError(f"unknown MAVLink message {name!r}") from None


class RequestLink:
    """Sends requests through ``mav`` (a pymavlink ``MAVLink`` encoder) to the autopilot ``target()`` returns.

    ``mode_params(what)`` gives DO_SET_MODE's [base_mode, custom_mode, custom_sub_mode] for the sequence's mode
    words (``offboard``, ``hold``, ``land``) in the autopilot family's numbers.
    """

    def __init__(self, mav: Any, target: Callable[[], tuple[int | None, int]],
                 mode_params: Callable[[str], list[float]]) -> None:
        self.mav = mav
        self.target = target
        self.mode_params = mode_params
        self._by_command: dict[int, str] = {}  # command id in flight → request key
        self.instant_answers: list[tuple[str, int]] = []  # requests MAVLink never answers: answered on sending

    def send(self, req: Request) -> None:
        """Send one request (unknown keys are logged and answered as FAILED at once)."""
        kind, _, arg = req.key.partition(":")
        sysid, compid = self.target()
        sysid = sysid or 1
        if kind in ("arm", "disarm"):
            self._command(req, M.MAV_CMD_COMPONENT_ARM_DISARM, [1.0 if kind == "arm" else 0.0])
        elif kind == "mode" and arg == "land":
            self._command(req, M.MAV_CMD_NAV_LAND, [0, 0, 0, math.nan, math.nan, math.nan, math.nan])
        elif kind == "mode":
            self._command(req, M.MAV_CMD_DO_SET_MODE, self.mode_params(arg))
        elif kind == "takeoff":
            self._command(req, M.MAV_CMD_NAV_TAKEOFF, [0, 0, 0, math.nan, math.nan, math.nan, req.value])
        elif kind == "message_interval":
            self._command(req, M.MAV_CMD_SET_MESSAGE_INTERVAL, [float(message_id(arg)), req.value])
        elif kind == "request_message":
            self._command(req, M.MAV_CMD_REQUEST_MESSAGE, [float(message_id(arg))])
        elif kind == "data_stream":
            self.mav.request_data_stream_send(sysid, compid, int(arg), max(1, round(req.value)), 1)
            self.instant_answers.append((req.key, M.MAV_RESULT_ACCEPTED))
        elif kind == "param_read":
            self.mav.param_request_read_send(sysid, compid, arg.encode(), -1)
        elif kind == "param_set":
            self.mav.param_set_send(sysid, compid, arg.encode(), float(req.value), M.MAV_PARAM_TYPE_REAL32)
        else:
            log.error("unknown request %r", req.key)
            self.instant_answers.append((req.key, M.MAV_RESULT_FAILED))
        if req.attempt > 1:
            log.warning("no answer to %s yet: asking again (attempt %d)", req.key, req.attempt)

    def _command(self, req: Request, command: int, params: list[float]) -> None:
        p = list(params) + [0.0] * (7 - len(params))
        sysid, compid = self.target()
        self._by_command[command] = req.key
        self.mav.command_long_send(sysid or 1, compid, command, req.attempt - 1, *p)

    def answer_of(self, ev: TelemetryEvent) -> tuple[str, int | float] | None:
        """The (request key, result) a COMMAND_ACK or PARAM_VALUE event from the target answers, else None (a
        PARAM_VALUE's non-finite value never reaches here: decoding refused it)."""
        cls = ev.__class__
        if cls is CommandAck:
            if ev.src_system != self.target()[0]:
                return None
            key = self._by_command.get(ev.command)
            return None if key is None else (key, ev.result)
        if cls is ParamValue:
            if ev.src_system != self.target()[0]:
                return None
            return (f"param:{ev.param_id}", ev.value)
        return None
