"""The companion's own STATUSTEXT to the ground station: its phases, warnings, failsafes and answers, from its own
system and component (the vehicle's system id, component 191), rate-limited.

MAVLink 2 chunking: a text longer than 50 characters goes out in chunks of 50 with one ``id`` (1..65535) and
``chunk_seq`` 0, 1, ...; the last chunk is shorter (NUL-padded) or, when the text fills its chunks exactly, an
empty chunk ends it (so a receiver need not time out). A text of 50 characters or less is one message with id 0.
Texts are cut at :data:`MAX_TEXT` characters.

Rate: a token bucket (:data:`BURST` messages at once, :data:`RATE_HZ` a second after that). Texts waiting for a
token queue up to :data:`QUEUE_MAX` (the oldest dropped first, counted); :meth:`StatusTextOut.pump` sends what the
bucket allows and is cheap when nothing waits. Every chunk counts as a message.
"""

from __future__ import annotations

import logging
from collections import deque
from typing import Any

log = logging.getLogger(__name__)

CHUNK = 50
MAX_TEXT = 200
BURST = 6.0  # messages
RATE_HZ = 2.0  # messages a second, sustained
QUEUE_MAX = 20  # texts


def chunks(text: str) -> list[bytes]:
    """``text`` (ASCII, unencodable characters replaced, cut at :data:`MAX_TEXT`) as STATUSTEXT chunks of 50 bytes
    at most; a text that fills its chunks exactly gets an empty last chunk when it needs more than one."""
    raw = text.encode("ascii", errors="replace")[:MAX_TEXT]
    if len(raw) <= CHUNK:
        return [raw]
    out = [raw[i:i + CHUNK] for i in range(0, len(raw), CHUNK)]
    if len(out[-1]) == CHUNK:
        out.append(b"")
    return out


class StatusTextOut:
    """Rate-limited, chunked STATUSTEXT through a pymavlink ``MAVLink`` object (``mav.statustext_send``)."""

    def __init__(self, mav: Any, burst: float = BURST, rate_hz: float = RATE_HZ) -> None:
        self.mav = mav
        self.burst, self.rate_hz = burst, rate_hz
        self._tokens = burst
        self._t_s: float | None = None
        self._queue: deque[tuple[int, str]] = deque()
        self._id = 0
        self.sent = 0  # messages (chunks) sent
        self.dropped = 0  # texts dropped from a full queue

    def say(self, severity: int, text: str, wall_s: float) -> None:
        """Queue ``text`` at MAV_SEVERITY ``severity`` and send what the rate allows now (``wall_s``: monotonic s)."""
        if len(self._queue) >= QUEUE_MAX:
            self._queue.popleft()
            self.dropped += 1
        self._queue.append((severity, text))
        self.pump(wall_s)

    def pump(self, wall_s: float) -> None:
        """Send the waiting texts the bucket has tokens for (a text's chunks go out together)."""
        if not self._queue:
            return
        if self._t_s is not None:
            self._tokens = min(self.burst, self._tokens + (wall_s - self._t_s) * self.rate_hz)
        self._t_s = wall_s
        while self._queue:
            severity, text = self._queue[0]
            parts = chunks(text)
            if self._tokens < len(parts):
                return
            self._queue.popleft()
            self._tokens -= len(parts)
            sid = 0
            if len(parts) > 1:
                self._id = self._id % 65535 + 1
                sid = self._id
            for k, part in enumerate(parts):
                self.mav.statustext_send(severity, part, sid, k)
                self.sent += 1

    @property
    def waiting(self) -> int:
        """Texts queued, not sent yet."""
        return len(self._queue)
