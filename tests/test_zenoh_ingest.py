"""Live obstacle input is parsed outside the control tick, and a list re-sent byte for byte is adopted again
without parsing (a static map re-published, or a flood): real Zenoh sessions on loopback."""

from __future__ import annotations

import json
import time

import zenoh

from companion.cli.bench_zenoh import free_tcp_port
from companion.zenoh_io.session import zenoh_config
from companion.zenoh_io.telemetry import INBOX_RING, ZenohTelemetry
from companion.zenoh_io.telemetry_options import TelemetryOptions

KEY = "slungpilot/6/obstacles/in/cam"


def _payload(x_m: float, n: int = 40) -> bytes:
    return json.dumps({"obstacles": [{"x_m": x_m + 2.0 * i, "y_m": 3.0, "radius_m": 0.3} for i in range(n)]}).encode()


def _ingest_until(zt: ZenohTelemetry, t_s: float, done, timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not done():
        assert time.monotonic() < deadline, "sample never ingested"
        zt.ingest(t_s)
        time.sleep(0.01)


def test_parsed_after_the_tick_and_same_bytes_adopted_without_parsing():
    ep = f"tcp/127.0.0.1:{free_tcp_port()}"
    with ZenohTelemetry(zenoh_config("companion", listen=[ep]), TelemetryOptions(vehicle_id="6")) as zt, \
            zenoh.open(zenoh_config("listener", connect=[ep])) as s:
        pub = s.declare_publisher(KEY)
        deadline = time.monotonic() + 15
        while not pub.matching_status.matching and time.monotonic() < deadline:
            time.sleep(0.02)
        assert zt.obstacles_current(0.0) == (), "nothing adopted before anything was published"

        pub.put(_payload(10.0))
        _ingest_until(zt, 0.1, lambda: zt.store.accepted_count == 1)
        first = zt.obstacles_current(0.1)
        version = zt.store.version
        assert len(first) == 40 and first[0].x_m == 10.0
        assert zt.obstacles_current(0.2) is first, "reading the set parses nothing and changes nothing"

        pub.put(_payload(10.0))  # the same bytes again
        _ingest_until(zt, 0.3, lambda: zt.store.accepted_count == 2)
        assert zt.unchanged == 1 and zt.store.version == version
        assert zt.obstacles_current(0.3) is first

        pub.put(_payload(11.0))  # a different list is parsed and replaces the old one
        _ingest_until(zt, 0.4, lambda: zt.store.accepted_count == 3)
        assert zt.unchanged == 1 and zt.store.version == version + 1
        assert zt.obstacles_current(0.4)[0].x_m == 11.0

        pub.put(b'{"obstacles": [{"x_m": "nan"}]}')  # refused: the last good list stays, and is re-parsed if re-sent
        _ingest_until(zt, 0.5, lambda: zt.store.rejected_count == 1)
        assert zt.obstacles_current(0.5)[0].x_m == 11.0
        pub.put(_payload(11.0))
        _ingest_until(zt, 0.6, lambda: zt.store.accepted_count == 4)
        assert zt.unchanged == 1, "after a refused sample the same bytes are parsed again, not taken on trust"


def test_a_burst_keeps_each_publishers_newest_and_counts_the_rest():
    """Samples wait in Zenoh's ring (no Python runs per sample) until the app drains them after a tick: a burst
    from one publisher is reduced to its newest sample, and another publisher's sample in between survives."""
    ep = f"tcp/127.0.0.1:{free_tcp_port()}"
    with ZenohTelemetry(zenoh_config("companion", listen=[ep]), TelemetryOptions(vehicle_id="6")) as zt, \
            zenoh.open(zenoh_config("listener", connect=[ep])) as s:
        cam, flood = s.declare_publisher(KEY), s.declare_publisher("slungpilot/6/obstacles/in/flood")
        deadline = time.monotonic() + 15
        while not (cam.matching_status.matching and flood.matching_status.matching) and time.monotonic() < deadline:
            time.sleep(0.02)
        burst = 30
        assert burst + 1 < INBOX_RING
        flood.put(_payload(100.0, n=8))
        cam.put(_payload(10.0, n=8))
        for i in range(1, burst):
            flood.put(_payload(100.0 + i, n=8))
        time.sleep(1.0)  # all of it waits in the ring: nothing has been drained yet
        assert zt.superseded == 0 and zt.store.accepted_count == 0
        zt.ingest(0.1)
        assert zt.superseded == burst - 1, "the burst's older samples are counted as superseded, never parsed"
        assert zt.ring_full == 0
        _ingest_until(zt, 0.2, lambda: zt.store.accepted_count == 2)
        xs = sorted(o.x_m for o in zt.obstacles_current(0.2))
        assert xs[0] == 10.0 and 100.0 + burst - 1 in xs and 100.0 not in xs


def test_a_burst_beyond_the_ring_keeps_the_newest_and_says_the_ring_was_full():
    ep = f"tcp/127.0.0.1:{free_tcp_port()}"
    with ZenohTelemetry(zenoh_config("companion", listen=[ep]), TelemetryOptions(vehicle_id="6")) as zt, \
            zenoh.open(zenoh_config("listener", connect=[ep])) as s:
        flood = s.declare_publisher("slungpilot/6/obstacles/in/flood")
        deadline = time.monotonic() + 15
        while not flood.matching_status.matching and time.monotonic() < deadline:
            time.sleep(0.02)
        burst = INBOX_RING + 36
        for i in range(burst):
            flood.put(_payload(100.0 + i, n=4))
        time.sleep(1.0)
        zt.ingest(0.1)
        assert zt.ring_full == 1 and zt.superseded == INBOX_RING - 1, "only the ring's newest samples were drained"
        _ingest_until(zt, 0.2, lambda: zt.store.accepted_count == 1)
        assert zt.obstacles_current(0.2)[0].x_m == 100.0 + burst - 1
