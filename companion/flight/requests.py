"""Requests to the autopilot that want an answer, tracked without I/O: sent, answered, retried, given up.

A :class:`Request` names what is asked in the autopilot-neutral words of the flight sequence
(``arm``, ``mode:offboard``, ``land``, ``param_read:MPC_THR_HOVER`` ...); the flight app turns it into
MAVLink (COMMAND_LONG, PARAM_REQUEST_READ, ...) through the autopilot family's tables and feeds the answer
back with :meth:`RequestTracker.answer`. Time is whatever clock the caller uses (the sequence's clock: vehicle
time in lockstep, so a flight is repeatable; wall time otherwise).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field


@dataclass(frozen=True, slots=True)
class Request:
    """One question for the autopilot.

    key: what is asked, e.g. ``"arm"``, ``"mode:hold"``, ``"param_read:MPC_THR_HOVER"``,
    ``"param_set:GUID_OPTIONS"``, ``"message_interval:ATTITUDE"``; value: an argument (interval in µs,
    parameter value) or NaN; attempt: 1 for the first send.
    """

    key: str
    value: float = math.nan
    attempt: int = 1


@dataclass
class _Pending:
    request: Request
    sent_s: float
    result: int | float | None = None


@dataclass
class RequestTracker:
    """Pending requests by key, with a bounded number of attempts each ``timeout_s`` apart.

    :meth:`ask` registers a request (re-asking a key that is still pending does nothing) and returns it to be
    sent; :meth:`due` returns the retries whose answer is late; :meth:`answer` stores an answer;
    :meth:`result` pops it (None while pending); :meth:`failed` tells a request that used all its attempts.
    """

    timeout_s: float = 1.0
    attempts: int = 3
    _pending: dict[str, _Pending] = field(default_factory=dict)
    _given_up: set[str] = field(default_factory=set)

    def ask(self, key: str, now_s: float, value: float = math.nan) -> list[Request]:
        """Ask ``key`` unless it is already waiting for an answer (an unread answer is dropped); returns what must
        be sent now (0 or 1 request)."""
        if self.pending(key):
            return []
        self._given_up.discard(key)
        req = Request(key, value, 1)
        self._pending[key] = _Pending(req, now_s)
        return [req]

    def due(self, now_s: float) -> list[Request]:
        """Requests to send again (no answer within ``timeout_s``); the ones out of attempts are given up."""
        out = []
        for key, p in list(self._pending.items()):
            if p.result is not None or now_s - p.sent_s < self.timeout_s:
                continue
            if p.request.attempt >= self.attempts:
                del self._pending[key]
                self._given_up.add(key)
                continue
            req = Request(key, p.request.value, p.request.attempt + 1)
            self._pending[key] = _Pending(req, now_s)
            out.append(req)
        return out

    def answer(self, key: str, result: int | float) -> bool:
        """Store the autopilot's answer to ``key``; False if nobody asked (a stray or duplicate answer)."""
        p = self._pending.get(key)
        if p is None or p.result is not None:
            return False
        p.result = result
        return True

    def result(self, key: str) -> int | float | None:
        """The answer to ``key`` (and forget the request), or None while it is pending or was never asked."""
        p = self._pending.get(key)
        if p is None or p.result is None:
            return None
        del self._pending[key]
        return p.result

    def pending(self, key: str) -> bool:
        """True while ``key`` waits for an answer."""
        p = self._pending.get(key)
        return p is not None and p.result is None

    def failed(self, key: str) -> bool:
        """True once ``key`` used all its attempts without an answer (cleared by asking again)."""
        return key in self._given_up

    def cancel(self, key: str) -> None:
        """Forget ``key`` (pending or answered)."""
        self._pending.pop(key, None)
        self._given_up.discard(key)

    def tracked_keys(self) -> tuple[str, ...]:
        """Keys asked and not yet read (waiting, or answered and unread)."""
        return tuple(self._pending)
