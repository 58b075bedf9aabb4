"""Request/answer exchanges with the autopilot: COMMAND_LONG → COMMAND_ACK and PARAM_REQUEST_READ →
PARAM_VALUE, with retries and timeouts, over a :class:`~companion.mavlink_io.link.MavlinkLink`.

The link's message handler calls :meth:`MavCommander.on_message` for every message; it resolves the
waiting request and tells the caller whether it did (the app then lets the waiting coroutine run before the
next lockstep tick).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable, Sequence
from typing import Any

from companion.errors import LinkError
from companion.mavlink_io.link import MavlinkLink

log = logging.getLogger(__name__)


class MavCommander:
    """Commands and parameter reads addressed to the autopilot ``target()`` returns (system, component)."""

    def __init__(self, link: MavlinkLink, target: Callable[[], tuple[int | None, int]]) -> None:
        self.link = link
        self.target = target
        self._acks: dict[int, asyncio.Future] = {}
        self._params: dict[str, asyncio.Future] = {}

    def on_message(self, msg: Any) -> bool:
        """Resolve a waiting request from COMMAND_ACK / PARAM_VALUE of the target; True if one was resolved."""
        mtype = msg.get_type()
        if mtype not in ("COMMAND_ACK", "PARAM_VALUE") or msg.get_srcSystem() != self.target()[0]:
            return False
        if mtype == "COMMAND_ACK":
            fut = self._acks.get(int(msg.command))
            value: Any = int(msg.result)
        else:
            pid = msg.param_id.rstrip("\x00") if isinstance(msg.param_id, str) else str(msg.param_id)
            fut = self._params.pop(pid, None)
            value = float(msg.param_value)
        if fut is None or fut.done():
            return False
        fut.set_result(value)
        return True

    async def command(self, command: int, params: Sequence[float], retries: int = 3, timeout_s: float = 1.0) -> int:
        """COMMAND_LONG with retries (confirmation counts up); returns MAV_RESULT. LinkError if never ACKed."""
        p = list(params) + [0.0] * (7 - len(params))
        for attempt in range(retries):
            fut: asyncio.Future = asyncio.get_running_loop().create_future()
            self._acks[command] = fut
            sysid, compid = self.target()
            self.link.mav.command_long_send(sysid or 1, compid, command, attempt, *p)
            try:
                async with asyncio.timeout(timeout_s):
                    return await fut
            except TimeoutError:
                log.warning("no COMMAND_ACK for command %d (attempt %d)", command, attempt + 1)
            finally:
                self._acks.pop(command, None)
        raise LinkError(f"vehicle never acknowledged MAVLink command {command}")

    async def read_param(self, name: str, timeout_s: float = 1.0) -> float | None:
        """PARAM_REQUEST_READ by name (asked twice); the value, or None when the autopilot does not answer."""
        fut: asyncio.Future = asyncio.get_running_loop().create_future()
        self._params[name] = fut
        for _ in range(2):
            sysid, compid = self.target()
            self.link.mav.param_request_read_send(sysid or 1, compid, name.encode(), -1)
            try:
                async with asyncio.timeout(timeout_s):
                    return float(await asyncio.shield(fut))
            except TimeoutError:
                continue
        self._params.pop(name, None)
        return None
