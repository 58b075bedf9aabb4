"""The mission download's state machine on its own (no sockets, no clock: the time is an argument): the happy path
to MISSION_ACK, duplicates ignored, an item out of order re-requested, retries on silence and a failure naming the
item a stalled download stopped at, a count over the limit refused before a single item is asked for, an error
MISSION_ACK from the autopilot, and events of another mission type left alone."""

from __future__ import annotations

import pytest

from companion.mavlink_io.mission_client import (
    MAV_MISSION_ACCEPTED,
    MAV_MISSION_OPERATION_CANCELLED,
    MissionDownload,
    RequestItem,
    RequestList,
    SendAck,
)
from companion.mavlink_io.telemetry import MissionAck, MissionCount, MissionItemInt


def _count(n: int, mtype: int = 0) -> MissionCount:
    return MissionCount(1, 1, 0, n, mtype)


def _item(seq: int, mtype: int = 0) -> MissionItemInt:
    return MissionItemInt(1, 1, 0, seq, 6, 16, 0, 1, (0.0, 0.0, 0.0, float("nan")), 473977420 + seq, 85455940,
                          5.0, mtype)


def _serve(d: MissionDownload, n: int, t: float = 0.0) -> list:
    """Answer every request like a well-behaved autopilot; everything the client sent."""
    sent = d.start(t)
    log = list(sent)
    while sent:
        req, sent = sent[0], []
        if isinstance(req, RequestList):
            sent = d.on_event(_count(n, d.mission_type), t)
        elif isinstance(req, RequestItem):
            sent = d.on_event(_item(req.seq, d.mission_type), t)
        log += sent
    return log


def test_happy_path_requests_each_item_once_in_order_and_acks():
    d = MissionDownload()
    log = _serve(d, 4)
    assert log == [RequestList(0), RequestItem(0, 0), RequestItem(1, 0), RequestItem(2, 0), RequestItem(3, 0),
                   SendAck(MAV_MISSION_ACCEPTED, 0)]
    assert d.state == "done" and [it.item_seq for it in d.items] == [0, 1, 2, 3]
    assert d.facts()["duplicates"] == d.facts()["resent"] == 0


def test_an_empty_mission_is_done_at_once_and_acked():
    d = MissionDownload(1)
    assert _serve(d, 0) == [RequestList(1), SendAck(MAV_MISSION_ACCEPTED, 1)]
    assert d.state == "done" and d.items == []


def test_duplicates_are_ignored():
    d = MissionDownload()
    d.start(0.0)
    assert d.on_event(_count(3), 0.0) == [RequestItem(0, 0)]
    assert d.on_event(_item(0), 0.1) == [RequestItem(1, 0)]
    assert d.on_event(_item(0), 0.1) == []  # the answer to a re-sent request: already held
    assert d.on_event(_count(3), 0.1) == []  # a second MISSION_COUNT mid-download: ignored too
    assert d.on_event(_item(1), 0.2) == [RequestItem(2, 0)]
    assert d.on_event(_item(2), 0.3) == [SendAck(MAV_MISSION_ACCEPTED, 0)]
    assert d.duplicates == 1 and [it.item_seq for it in d.items] == [0, 1, 2]


def test_an_item_out_of_order_is_dropped_and_the_expected_one_asked_again():
    d = MissionDownload()
    d.start(0.0)
    d.on_event(_count(3), 0.0)
    assert d.on_event(_item(1), 0.1) == [RequestItem(0, 0)]  # not what was asked: ask again
    assert d.items == [] and d.out_of_order == 1
    assert d.on_event(_item(0), 0.2) == [RequestItem(1, 0)]
    assert d.on_event(_item(2), 0.3) == [RequestItem(1, 0)]
    assert d.on_event(_item(1), 0.4) == [RequestItem(2, 0)]
    assert d.on_event(_item(2), 0.5) == [SendAck(MAV_MISSION_ACCEPTED, 0)]
    assert [it.item_seq for it in d.items] == [0, 1, 2] and d.out_of_order == 2


def test_a_sender_that_only_ever_sends_the_wrong_item_still_times_out():
    d = MissionDownload(timeout_s=1.5, retries=2)
    d.start(0.0)
    d.on_event(_count(3), 0.0)
    t = 0.0
    while not d.finished and t < 30.0:
        d.on_event(_item(2), t)
        d.on_time(t)
        t += 0.1
    assert d.state == "failed" and "stopped at item 0 of 3" in d.error and t < 5.0


def test_silence_is_answered_with_the_same_request_then_a_failure_naming_the_item():
    d = MissionDownload(timeout_s=1.5, retries=5)
    d.start(0.0)
    d.on_event(_count(10), 0.0)
    for k in range(4):
        d.on_event(_item(k), 0.1 * k)
    assert d.on_time(0.3 + 1.49) == []  # not yet due
    sent = []
    t = 0.3
    while not d.finished:
        t += 0.5
        sent += d.on_time(t)
    assert sent[:5] == [RequestItem(4, 0)] * 5 and sent[5:] == [SendAck(MAV_MISSION_OPERATION_CANCELLED, 0)]
    assert d.state == "failed" and d.resent == 5
    assert "stopped at item 4 of 10" in d.error and "no MISSION_ITEM_INT 4 after 6 requests 1.5 s apart" in d.error
    assert 0.3 + 6 * 1.5 <= t < 0.3 + 6 * 1.5 + 0.5  # gave up after 6 requests, 1.5 s apart


def test_progress_resets_the_retry_count():
    d = MissionDownload(timeout_s=1.0, retries=1)
    d.start(0.0)
    d.on_event(_count(3), 0.0)
    assert d.on_time(1.0) == [RequestItem(0, 0)]  # one retry allowed
    d.on_event(_item(0), 1.5)
    assert d.on_time(2.5) == [RequestItem(1, 0)]  # a fresh allowance for the next item
    d.on_event(_item(1), 3.0)
    d.on_event(_item(2), 3.1)
    assert d.state == "done"


def test_no_answer_to_the_list_request_fails_without_cancelling():
    d = MissionDownload(timeout_s=1.5, retries=5)
    d.start(0.0)
    out = []
    for k in range(1, 10):
        out += d.on_time(1.5 * k)
    assert out == [RequestList(0)] * 5
    assert d.state == "failed" and "did not answer MISSION_REQUEST_LIST (mission)" in d.error


def test_ten_thousand_items_are_refused_before_any_is_requested():
    d = MissionDownload(max_items=1000)
    d.start(0.0)
    assert d.on_event(_count(10_000), 0.01) == [SendAck(MAV_MISSION_OPERATION_CANCELLED, 0)]
    assert d.state == "failed" and d.items == [] and d.count == 10_000
    assert "10000 items, more than the 1000" in d.error and "before downloading any" in d.error
    assert d.on_event(_item(0), 0.02) == [] and d.on_time(100.0) == []  # finished: nothing more happens


def test_an_error_ack_from_the_autopilot_ends_the_download_naming_it():
    d = MissionDownload(1)
    d.start(0.0)
    assert d.on_event(MissionAck(1, 1, 0, 3, 1), 0.1) == []
    assert d.state == "failed" and d.nack == 3 and "MISSION_ACK UNSUPPORTED" in d.error


@pytest.mark.parametrize("ev", [_count(5, 1), _item(0, 1), MissionAck(1, 1, 0, 1, 1)])
def test_events_of_another_mission_type_are_left_alone(ev):
    d = MissionDownload(0)
    d.start(0.0)
    d.on_event(_count(2), 0.0)
    assert d.on_event(ev, 0.1) == [] and d.state == "items" and d.items == []
