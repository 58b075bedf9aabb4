"""The bundled vehicle's MAVLink mission micro-service: upload, download and clear of the mission, the geofence
and the rally points (https://mavlink.io/en/services/mission.html), as PX4's MavlinkMissionManager
(mavlink_mission.cpp) and ArduPilot's MissionItemProtocol answer it.

A pure state machine: :meth:`MissionServer.handle` takes one received message (a pymavlink message object, read
by attribute), who sent it (:class:`Peer`) and the time (s, any monotonic clock); :meth:`MissionServer.tick`
takes the time alone. Both return what to send (:class:`Out`); nothing here touches a socket or a clock.
:func:`send_outputs` hands the answers to the vehicle's links. docs/sitl.md ("Mission protocol") lists the
answers; in short:

- one transfer at a time for the whole vehicle (PX4's ``_transfer_in_progress``); any other partner (link,
  system, component) that starts or joins one meanwhile gets MISSION_ACK ``MAV_MISSION_DENIED`` (ArduPilot);
  the same partner starting anew replaces its own transfer;
- upload: MISSION_COUNT → MISSION_REQUEST_INT per item (re-sent every :data:`RETRY_S` of silence, PX4's
  250 ms) → MISSION_ITEM_INT (or MISSION_ITEM, float, accepted as PX4 does) → MISSION_ACK; an item out of
  sequence or repeated is ignored and the expected one requested again; an invalid item ends the upload with
  its MAV_MISSION_RESULT; :data:`TIMEOUT_S` (PX4's 5 s) without a message from the partner ends it with
  ``MAV_MISSION_OPERATION_CANCELLED`` (ArduPilot) and a STATUSTEXT. The stored list changes only when the
  last item is accepted;
- download: MISSION_REQUEST_LIST → MISSION_COUNT → MISSION_REQUEST_INT (answered with MISSION_ITEM_INT) or
  MISSION_REQUEST (answered with MISSION_ITEM, as PX4) → MISSION_ACK;
- clear: MISSION_CLEAR_ALL (one type or ``MAV_MISSION_TYPE_ALL``) → MISSION_ACK;
- MISSION_SET_CURRENT → MISSION_CURRENT on every link.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from pymavlink.dialects.v20 import common as M

from sim_bridge.mission_items import (
    ALL,
    FENCE,
    MISSION,
    RALLY,
    TYPE_NAMES,
    Item,
    fence_polygon_error,
    item_fields,
    parse_item,
    result_name,
)

MAX_ITEMS = {MISSION: 1000, FENCE: 256, RALLY: 32}  # items stored per type (a 10,000-item mission: NO_SPACE)
RETRY_S = 0.25  # PX4's MAVLINK_MISSION_RETRY_TIMEOUT_DEFAULT: re-request an item after this much silence
IDLE, UPLOAD, DOWNLOAD = "idle", "upload", "download"  # the transfer running
TIMEOUT_S = 5.0  # PX4's MAVLINK_MISSION_PROTOCOL_TIMEOUT_DEFAULT: abandon a transfer after this much silence


@dataclass(frozen=True)
class Peer:
    """Who a message came from: the link (any object; the vehicle's :class:`sim_bridge.link.MavUdpLink`) and the
    sender's system and component ids."""

    link: Any
    sysid: int
    compid: int


@dataclass(frozen=True)
class Out:
    """One message to send: ``name`` is pymavlink's lower-case message name (``link.mav.<name>_send(**fields)``)
    or ``"statustext"`` (fields severity, text: on every link); ``peer`` None = every link."""

    peer: Peer | None
    name: str
    fields: dict = field(default_factory=dict)


def _ack(peer: Peer, result: int, mission_type: int) -> Out:
    return Out(peer, "mission_ack", {"target_system": peer.sysid, "target_component": peer.compid,
                                     "type": result, "mission_type": mission_type})


def _text(severity: int, text: str) -> Out:
    return Out(None, "statustext", {"severity": severity, "text": text})


class MissionServer:
    """The mission, fence and rally stores of one vehicle and the one transfer that may be running."""

    def __init__(self, max_items: dict[int, int] | None = None) -> None:
        self.max_items = dict(MAX_ITEMS if max_items is None else max_items)
        self.stores: dict[int, tuple[Item, ...]] = {MISSION: (), FENCE: (), RALLY: ()}
        self.current_seq = 0
        self.state = IDLE
        self.partner: Peer | None = None
        self.mtype = MISSION
        self.count = 0  # items of the running transfer
        self.next_seq = 0  # upload: the item expected; download: the highest requested + 1
        self._received: list[Item] = []
        self._last_recv_s = 0.0
        self._last_sent_s = 0.0
        self._last_upload: tuple[Peer, int, int] | None = None  # (partner, type, count) of the last completed upload

    @property
    def busy(self) -> bool:
        """Whether a transfer is running (:meth:`tick` has work to do)."""
        return self.state != IDLE

    def items(self, mission_type: int = MISSION) -> tuple[Item, ...]:
        """The stored list of ``mission_type``."""
        return self.stores[mission_type]

    def current_fields(self) -> dict:
        """MISSION_CURRENT's fields: the current item, the mission's size (UINT16_MAX if empty, as PX4) and its
        state (no mission / not started: the bundled vehicle does not fly the stored mission itself)."""
        n = len(self.stores[MISSION])
        return {"seq": self.current_seq, "total": n if n else 65535,
                "mission_state": M.MISSION_STATE_NOT_STARTED if n else M.MISSION_STATE_NO_MISSION,
                "mission_mode": 0}

    # ------------------------------------------------------------------ input
    def handle(self, msg: Any, peer: Peer, now_s: float) -> list[Out]:
        """Answer one mission-protocol message from ``peer`` received at ``now_s`` (s); others give []."""
        t = msg.get_type()
        handler = _HANDLERS.get(t)
        if handler is None:
            return []
        if self.state != IDLE and peer == self.partner:
            self._last_recv_s = now_s
        return handler(self, msg, peer, now_s)

    def _deny_if_busy(self, peer: Peer, mission_type: int) -> list[Out] | None:
        if self.state == DOWNLOAD and self.next_seq >= self.count:
            self.state = IDLE  # every item was sent, the client's ACK never came: done (PX4's "maybe completed")
        if self.state == IDLE or peer == self.partner:
            return None
        return [_ack(peer, M.MAV_MISSION_DENIED, mission_type),
                _text(M.MAV_SEVERITY_WARNING, f"Mission transfer denied: busy with system {self.partner.sysid}")]

    def _on_count(self, msg: Any, peer: Peer, now_s: float) -> list[Out]:
        mtype, count = int(msg.mission_type), int(msg.count)
        denied = self._deny_if_busy(peer, mtype)
        if denied is not None:
            return denied
        self.state = IDLE  # the same partner starting anew replaces its own transfer (ArduPilot)
        if mtype not in self.stores:
            return [_ack(peer, M.MAV_MISSION_INVALID, mtype)]
        if count > self.max_items[mtype]:
            return [_ack(peer, M.MAV_MISSION_NO_SPACE, mtype),
                    _text(M.MAV_SEVERITY_WARNING, f"Only {self.max_items[mtype]} {TYPE_NAMES[mtype]} items are "
                                                  f"supported, {count} refused")]
        if count == 0:
            self._store(mtype, ())
            self._last_upload = (peer, mtype, 0)
            return [_ack(peer, M.MAV_MISSION_ACCEPTED, mtype), *self._current_changed(mtype)]
        self.state, self.partner, self.mtype, self.count, self.next_seq = UPLOAD, peer, mtype, count, 0
        self._received = []
        self._last_recv_s = now_s
        return [self._request(now_s)]

    def _request(self, now_s: float) -> Out:
        self._last_sent_s = now_s
        p = self.partner
        return Out(p, "mission_request_int", {"target_system": p.sysid, "target_component": p.compid,
                                              "seq": self.next_seq, "mission_type": self.mtype})

    def _on_item(self, msg: Any, peer: Peer, now_s: float) -> list[Out]:
        mtype = int(msg.mission_type)
        if self.state == UPLOAD and peer == self.partner:
            if mtype != self.mtype:
                return [_ack(peer, M.MAV_MISSION_ERROR, mtype)]  # PX4: answered, the upload goes on
            if int(msg.seq) != self.next_seq:  # out of sequence or repeated: ask again for the expected one
                return [self._request(now_s)]
            result, item = parse_item(msg, msg.get_type() == "MISSION_ITEM_INT", mtype)
            if item is None:
                self.state = IDLE
                return [_ack(peer, result, mtype), _text(
                    M.MAV_SEVERITY_WARNING, f"{TYPE_NAMES[mtype].capitalize()} item {msg.seq} refused "
                                            f"({result_name(result)}): upload abandoned, the old list kept")]
            self._received.append(item)
            self.next_seq += 1
            if self.next_seq < self.count:
                return [self._request(now_s)]
            return self._upload_done(peer)
        denied = self._deny_if_busy(peer, mtype)
        if denied is not None:
            return denied
        last = self._last_upload
        if last is not None and last[0] == peer and last[1] == mtype and int(msg.seq) == last[2] - 1:
            return [_ack(peer, M.MAV_MISSION_ACCEPTED, mtype)]  # the last item again: our ACK was lost (PX4)
        return [_ack(peer, M.MAV_MISSION_ERROR, mtype)]  # no upload running (PX4: "IGN MISSION_ITEM: No transfer")

    def _upload_done(self, peer: Peer) -> list[Out]:
        items = tuple(self._received)
        if self.mtype == FENCE:
            bad = fence_polygon_error(items)
            if bad is not None:
                self.state = IDLE
                return [_ack(peer, M.MAV_MISSION_INVALID_PARAM1, FENCE), _text(M.MAV_SEVERITY_WARNING, bad)]
        self._store(self.mtype, items)
        self.state = IDLE
        self._last_upload = (peer, self.mtype, len(items))
        return [_ack(peer, M.MAV_MISSION_ACCEPTED, self.mtype), *self._current_changed(self.mtype)]

    def _store(self, mtype: int, items: tuple[Item, ...]) -> None:
        self.stores[mtype] = items
        if mtype == MISSION:
            marked = [it.seq for it in items if it.current]
            self.current_seq = marked[0] if marked else 0

    def _current_changed(self, mtype: int) -> list[Out]:
        return [Out(None, "mission_current", self.current_fields())] if mtype in (MISSION, ALL) else []

    def _on_request_list(self, msg: Any, peer: Peer, now_s: float) -> list[Out]:
        mtype = int(msg.mission_type)
        denied = self._deny_if_busy(peer, mtype)
        if denied is not None:
            return denied
        self.state = IDLE
        if mtype not in self.stores:
            return [_ack(peer, M.MAV_MISSION_INVALID, mtype)]
        n = len(self.stores[mtype])
        if n:
            self.state, self.partner, self.mtype, self.count, self.next_seq = DOWNLOAD, peer, mtype, n, 0
            self._last_recv_s = now_s
        return [Out(peer, "mission_count", {"target_system": peer.sysid, "target_component": peer.compid,
                                            "count": n, "mission_type": mtype})]

    def _on_request(self, msg: Any, peer: Peer, now_s: float) -> list[Out]:
        mtype, seq = int(msg.mission_type), int(msg.seq)
        if self.state == IDLE:
            return []  # PX4: silently ignored (some OSDs request without a list)
        denied = self._deny_if_busy(peer, mtype)
        if denied is not None:
            return denied
        if self.state != DOWNLOAD or mtype != self.mtype:
            return []  # PX4: "Unexpected mission type", ignored
        if seq >= self.count:
            self.state = IDLE
            return [_ack(peer, M.MAV_MISSION_INVALID_SEQUENCE, mtype)]
        self.next_seq = max(self.next_seq, seq + 1)
        as_int = msg.get_type() == "MISSION_REQUEST_INT"
        fields = item_fields(self.stores[mtype][seq], (peer.sysid, peer.compid), as_int, self.current_seq)
        return [Out(peer, "mission_item_int" if as_int else "mission_item", fields)]

    def _on_ack(self, msg: Any, peer: Peer, now_s: float) -> list[Out]:
        if (self.state != IDLE and peer == self.partner and int(msg.mission_type) == self.mtype
                and (self.state == DOWNLOAD or int(msg.type) == M.MAV_MISSION_OPERATION_CANCELLED)):
            self.state = IDLE  # the download over (whatever the answer), or the upload cancelled by its client
        return []

    def _on_clear(self, msg: Any, peer: Peer, now_s: float) -> list[Out]:
        mtype = int(msg.mission_type)
        denied = self._deny_if_busy(peer, mtype)
        if denied is not None:
            return denied
        self.state = IDLE
        if mtype != ALL and mtype not in self.stores:
            return [_ack(peer, M.MAV_MISSION_INVALID, mtype)]
        for t in (self.stores if mtype == ALL else (mtype,)):
            self._store(t, ())
        return [_ack(peer, M.MAV_MISSION_ACCEPTED, mtype), *self._current_changed(mtype)]

    def _on_set_current(self, msg: Any, peer: Peer, now_s: float) -> list[Out]:
        outs = self.set_current(int(msg.seq))
        if outs is None:
            return [_text(M.MAV_SEVERITY_WARNING, f"MISSION_SET_CURRENT {msg.seq}: not in the mission"),
                    *self._current_changed(MISSION)]
        return outs

    def set_current(self, seq: int) -> list[Out] | None:
        """Make mission item ``seq`` the current one (−1: keep it, as MAV_CMD_DO_SET_MISSION_CURRENT's param1);
        returns the MISSION_CURRENT to send, or None (and nothing changed) when ``seq`` is not in the mission."""
        if seq != -1 and not 0 <= seq < len(self.stores[MISSION]):
            return None
        if seq != -1:
            self.current_seq = seq
        return self._current_changed(MISSION)

    # ------------------------------------------------------------------ time
    def tick(self, now_s: float) -> list[Out]:
        """Retries and timeouts at ``now_s`` (s, the clock of :meth:`handle`): call every ≲ 50 ms while
        :attr:`busy`. Upload: the expected item requested again after :data:`RETRY_S` without it; any transfer
        abandoned after :data:`TIMEOUT_S` without a message from its partner (an upload's items discarded)."""
        if self.state == IDLE:
            return []
        if now_s - self._last_recv_s > TIMEOUT_S:
            what = "upload" if self.state == UPLOAD else "download"
            self.state = IDLE
            out = [_text(M.MAV_SEVERITY_WARNING, f"{TYPE_NAMES[self.mtype].capitalize()} {what} timed out"
                                                 + (": the old list kept" if what == "upload" else ""))]
            if what == "upload":
                out.insert(0, _ack(self.partner, M.MAV_MISSION_OPERATION_CANCELLED, self.mtype))
            return out
        if self.state == UPLOAD and now_s - self._last_sent_s > RETRY_S:
            return [self._request(now_s)]
        return []


_HANDLERS = {
    "MISSION_COUNT": MissionServer._on_count,
    "MISSION_ITEM_INT": MissionServer._on_item,
    "MISSION_ITEM": MissionServer._on_item,
    "MISSION_REQUEST_LIST": MissionServer._on_request_list,
    "MISSION_REQUEST_INT": MissionServer._on_request,
    "MISSION_REQUEST": MissionServer._on_request,
    "MISSION_ACK": MissionServer._on_ack,
    "MISSION_CLEAR_ALL": MissionServer._on_clear,
    "MISSION_SET_CURRENT": MissionServer._on_set_current,
}


def send_outputs(outs: list[Out], links: list[Any], statustext: Any) -> None:
    """Send ``outs``: to their peer's link (``link.mav.<name>_send``), to every link in ``links`` when the peer
    is None, STATUSTEXT through the vehicle's ``statustext(severity, text)``."""
    for o in outs:
        if o.name == "statustext":
            statustext(o.fields["severity"], o.fields["text"])
            continue
        for lk in ([o.peer.link] if o.peer is not None else links):
            getattr(lk.mav, o.name + "_send")(**o.fields)


