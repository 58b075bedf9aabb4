"""The MAVLink mission download as a pure state machine (https://mavlink.io/en/services/mission.html).

The client (here: the companion) asks the autopilot for what it holds of one mission type (the flight plan, the
geofence, the rally points)::

    client                                   autopilot
    MISSION_REQUEST_LIST(mission_type)  →
                                        ←    MISSION_COUNT(n)
    MISSION_REQUEST_INT(0)              →
                                        ←    MISSION_ITEM_INT(0)
    ...                                      ...
    MISSION_REQUEST_INT(n-1)            →
                                        ←    MISSION_ITEM_INT(n-1)
    MISSION_ACK(ACCEPTED)               →

No I/O and no clock here: :class:`MissionDownload` consumes typed events
(:class:`~companion.mavlink_io.telemetry.MissionCount`, :class:`~companion.mavlink_io.telemetry.MissionItemInt`,
:class:`~companion.mavlink_io.telemetry.MissionAck`) and the time (s, any monotonic clock) and answers with the
typed requests to send (:class:`RequestList`, :class:`RequestItem`, :class:`SendAck`); the caller sends them and
calls :meth:`MissionDownload.on_time` whenever :attr:`MissionDownload.deadline_s` passes.

Robustness as QGroundControl and MAVSDK do it:

* a request unanswered for ``timeout_s`` (default 1.5 s) is sent again, at most ``retries`` times (default 5) in a
  row; any progress resets the count; past it the download fails naming the item it stopped at;
* an item already received (a duplicate: the answer to a re-sent request) is ignored;
* an item other than the one asked for (out of order) is dropped and the expected one is asked for again;
* a count above ``max_items`` (default 1000) is refused at once, before a single item is asked for, and the
  autopilot is told the transfer is cancelled (MISSION_ACK OPERATION_CANCELLED);
* a MISSION_ACK with an error from the autopilot ends the download with that error named.
"""

from __future__ import annotations

from dataclasses import dataclass

from companion.mavlink_io.telemetry import MissionAck, MissionCount, MissionItemInt

MAV_MISSION_TYPE_MISSION = 0
MAV_MISSION_TYPE_FENCE = 1
MAV_MISSION_TYPE_RALLY = 2
MISSION_TYPE_NAMES = {0: "mission", 1: "fence", 2: "rally"}
MAV_MISSION_ACCEPTED = 0
MAV_MISSION_OPERATION_CANCELLED = 15
#: MAV_MISSION_RESULT names for the messages (common.xml)
MISSION_RESULT_NAMES = {
    0: "ACCEPTED", 1: "ERROR", 2: "UNSUPPORTED_FRAME", 3: "UNSUPPORTED", 4: "NO_SPACE", 5: "INVALID",
    6: "INVALID_PARAM1", 7: "INVALID_PARAM2", 8: "INVALID_PARAM3", 9: "INVALID_PARAM4", 10: "INVALID_PARAM5_X",
    11: "INVALID_PARAM6_Y", 12: "INVALID_PARAM7", 13: "INVALID_SEQUENCE", 14: "DENIED", 15: "OPERATION_CANCELLED",
}

DEFAULT_TIMEOUT_S = 1.5
DEFAULT_RETRIES = 5
DEFAULT_MAX_ITEMS = 1000


@dataclass(frozen=True, slots=True)
class RequestList:
    """Send MISSION_REQUEST_LIST for ``mission_type``."""

    mission_type: int


@dataclass(frozen=True, slots=True)
class RequestItem:
    """Send MISSION_REQUEST_INT for item ``seq`` of ``mission_type``."""

    seq: int
    mission_type: int


@dataclass(frozen=True, slots=True)
class SendAck:
    """Send MISSION_ACK with MAV_MISSION_RESULT ``result`` for ``mission_type``."""

    result: int
    mission_type: int


Outgoing = RequestList | RequestItem | SendAck


class MissionDownload:
    """One download of ``mission_type`` (see the module docstring). States: ``idle`` → ``count`` (waiting for
    MISSION_COUNT) → ``items`` (waiting for item :attr:`expected`) → ``done`` or ``failed`` (:attr:`error` says why).
    """

    def __init__(self, mission_type: int = MAV_MISSION_TYPE_MISSION, *, max_items: int = DEFAULT_MAX_ITEMS,
                 timeout_s: float = DEFAULT_TIMEOUT_S, retries: int = DEFAULT_RETRIES) -> None:
        self.mission_type = mission_type
        self.max_items = max_items
        self.timeout_s = timeout_s
        self.retries = retries
        self.state = "idle"
        self.count = 0
        self.items: list[MissionItemInt] = []
        self.error = ""
        self.deadline_s = float("inf")  # when the pending request is due again (s, the caller's clock)
        self.duplicates = 0  # items received again and ignored
        self.out_of_order = 0  # items other than the one asked for (dropped, the expected one asked again)
        self.resent = 0  # requests sent again after a timeout
        self.nack: int | None = None  # the MAV_MISSION_RESULT of an error MISSION_ACK from the autopilot
        self._tries = 0  # timeouts in a row on the pending request

    # ------------------------------------------------------------------ views
    @property
    def name(self) -> str:
        """The mission type's name (``mission``, ``fence``, ``rally``)."""
        return MISSION_TYPE_NAMES.get(self.mission_type, f"type {self.mission_type}")

    @property
    def finished(self) -> bool:
        """True once ``done`` or ``failed``."""
        return self.state in ("done", "failed")

    @property
    def expected(self) -> int:
        """The sequence number of the next item wanted."""
        return len(self.items)

    def facts(self) -> dict[str, object]:
        """For the report: state, count, items received, duplicates, out-of-order items, re-sent requests, error."""
        return {"state": self.state, "count": self.count, "received": len(self.items), "duplicates": self.duplicates,
                "out_of_order": self.out_of_order, "resent": self.resent, "error": self.error}

    # ------------------------------------------------------------------ input
    def start(self, now_s: float) -> list[Outgoing]:
        """Begin: the MISSION_REQUEST_LIST to send."""
        self.state = "count"
        return self._pending(now_s)

    def on_event(self, ev: object, now_s: float) -> list[Outgoing]:
        """One event from the autopilot at ``now_s`` (s); what to send in answer (often nothing). Events of other
        mission types and other messages are ignored."""
        if self.finished or getattr(ev, "mission_type", None) != self.mission_type:
            return []
        if isinstance(ev, MissionCount):
            return self._on_count(ev, now_s)
        if isinstance(ev, MissionItemInt):
            return self._on_item(ev, now_s)
        if isinstance(ev, MissionAck) and self.state != "idle" and ev.result != MAV_MISSION_ACCEPTED:
            name = MISSION_RESULT_NAMES.get(ev.result, str(ev.result))
            self.nack = ev.result
            return self._fail(f"the autopilot ended the {self.name} download with MISSION_ACK {name} "
                              f"after {len(self.items)} of {self.count} items", cancel=False)
        return []

    def on_time(self, now_s: float) -> list[Outgoing]:
        """The clock at ``now_s`` (s): the pending request again when its answer is overdue, or the failure."""
        if self.finished or self.state == "idle" or now_s < self.deadline_s:
            return []
        self._tries += 1
        if self._tries > self.retries:
            waited = f"{self.retries + 1} requests {self.timeout_s:g} s apart"
            if self.state == "count":
                return self._fail(f"the autopilot did not answer MISSION_REQUEST_LIST ({self.name}) to "
                                  f"{waited}", cancel=False)
            return self._fail(f"the {self.name} download stopped at item {self.expected} of {self.count}: no "
                              f"MISSION_ITEM_INT {self.expected} after {waited}", cancel=True)
        self.resent += 1
        return self._pending(now_s, reset=False)

    # ------------------------------------------------------------------ steps
    def _pending(self, now_s: float, reset: bool = True) -> list[Outgoing]:
        """The request the state waits on, (re)armed with a new deadline."""
        if reset:
            self._tries = 0
        self.deadline_s = now_s + self.timeout_s
        if self.state == "count":
            return [RequestList(self.mission_type)]
        return [RequestItem(self.expected, self.mission_type)]

    def _on_count(self, ev: MissionCount, now_s: float) -> list[Outgoing]:
        if self.state != "count":
            return []  # a second answer to a re-sent MISSION_REQUEST_LIST
        if ev.count > self.max_items:
            self.count = ev.count
            return self._fail(f"the autopilot's {self.name} has {ev.count} items, more than the {self.max_items} "
                              "the companion downloads: refused before downloading any", cancel=True)
        self.count = ev.count
        if ev.count == 0:
            return self._done()
        self.state = "items"
        return self._pending(now_s)

    def _on_item(self, ev: MissionItemInt, now_s: float) -> list[Outgoing]:
        if self.state != "items":
            return []
        seq = ev.item_seq
        if seq < self.expected:
            self.duplicates += 1
            return []
        if seq != self.expected:
            self.out_of_order += 1  # ask for the one we want again; the deadline stays (a sender that never
            return [RequestItem(self.expected, self.mission_type)]  # sends it still times out)
        self.items.append(ev)
        if len(self.items) == self.count:
            return self._done()
        return self._pending(now_s)

    def _done(self) -> list[Outgoing]:
        self.state = "done"
        self.deadline_s = float("inf")
        return [SendAck(MAV_MISSION_ACCEPTED, self.mission_type)]

    def _fail(self, error: str, cancel: bool) -> list[Outgoing]:
        self.state = "failed"
        self.error = error
        self.deadline_s = float("inf")
        return [SendAck(MAV_MISSION_OPERATION_CANCELLED, self.mission_type)] if cancel else []
