"""Zenoh streams between real processes over loopback: no gaps, obstacles in, queryable, liveliness, router.

The publisher is ``python -m companion.cli.bench_zenoh drive`` (ZenohTelemetry used as the flight app uses it);
this test process is the subscriber. Every wait is bounded; ports are free ones, never 7447.
"""

from __future__ import annotations

import faulthandler
import json
import os
import selectors
import signal
import subprocess
import sys
import threading
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
import zenoh

from companion.cli.bench_zenoh import free_tcp_port
from companion.zenoh_io import schema as ts
from companion.zenoh_io.session import zenoh_config

pytestmark = pytest.mark.paired  # wall clock, light: may run beside one other such test (tests/conftest.py)

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(autouse=True)
def hard_timeout() -> Iterator[None]:
    """A hang anywhere (even inside Zenoh) ends the run with tracebacks instead of blocking CI."""
    faulthandler.dump_traceback_later(90, exit=True)
    yield
    faulthandler.cancel_dump_traceback_later()


class Proc:
    """A child process whose stdout JSON lines are read with deadlines."""

    def __init__(self, args: list[str]) -> None:
        self.p = subprocess.Popen([sys.executable, *args], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                  text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
        self._sel = selectors.DefaultSelector()
        self._sel.register(self.p.stdout, selectors.EVENT_READ)

    def line(self, timeout_s: float = 20.0) -> dict:
        """The next JSON line of stdout (skipping non-JSON), or fail after ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self._sel.select(timeout=max(0.0, deadline - time.monotonic())):
                text = self.p.stdout.readline()
                if not text:
                    raise AssertionError(f"process ended: rc={self.p.wait()} stderr={self.p.stderr.read()[-2000:]}")
                try:
                    return json.loads(text)
                except ValueError:
                    continue
        raise AssertionError(f"no output line within {timeout_s} s")

    def wait_event(self, event: str, timeout_s: float = 20.0) -> dict:
        deadline = time.monotonic() + timeout_s
        while True:
            d = self.line(max(0.1, deadline - time.monotonic()))
            if d.get("event") == event:
                return d

    def stop(self, sig: int = signal.SIGTERM) -> None:
        if self.p.poll() is None:
            self.p.send_signal(sig)

    def close(self) -> None:
        if self.p.poll() is None:
            self.p.kill()
        self.p.wait(timeout=10)
        self.p.stdout.close()
        self.p.stderr.close()


@contextmanager
def driver(*args: str) -> Iterator[Proc]:
    proc = Proc(["-m", "companion.cli.bench_zenoh", "drive", *args])
    try:
        yield proc
    finally:
        proc.close()


@contextmanager
def session(**kw: object) -> Iterator[zenoh.Session]:
    with zenoh.open(zenoh_config("listener", **kw)) as s:
        yield s


class Collector:
    """Samples by key, filled from Zenoh's threads."""

    def __init__(self) -> None:
        self.by_key: dict[str, list[dict]] = defaultdict(list)
        self.encodings: dict[str, str] = {}
        self.lock = threading.Lock()

    def __call__(self, s: zenoh.Sample) -> None:
        d = json.loads(s.payload.to_bytes())
        with self.lock:
            self.by_key[str(s.key_expr)].append(d)
            self.encodings[str(s.key_expr)] = str(s.encoding)

    def get(self, key: str) -> list[dict]:
        with self.lock:
            return list(self.by_key.get(key, []))


def wait_until(cond: Callable[[], object], timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if cond():
            return
        time.sleep(0.02)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")


def wait_matching(pub: zenoh.Publisher, timeout_s: float = 15.0) -> None:
    wait_until(lambda: pub.matching_status.matching, timeout_s, f"a subscriber of {pub.key_expr}")


def test_swing_stream_reaches_another_process_without_gaps() -> None:
    ep = f"tcp/127.0.0.1:{free_tcp_port()}"
    col = Collector()
    ticks = 750
    with driver("--zenoh-listen", ep, "--vehicle-id", "1", "--ticks", str(ticks), "--wait-match-s", "15",
                "--pause-s", "0.001") as d, session(connect=[ep]) as s:
        s.declare_subscriber("slungpilot/1/**", col)
        d.wait_event("ready")
        done = d.wait_event("done", timeout_s=40)
        assert done["matched"] and done["ticks"] == ticks
        wait_until(lambda: len(col.get("slungpilot/1/swing")) >= ticks, 10, "all swing samples")
        time.sleep(0.2)
    swing = col.get("slungpilot/1/swing")
    assert [x["seq"] for x in swing] == list(range(ticks))  # in order, no gap, no duplicate
    assert [x["t_s"] for x in swing[:3]] == [0.0, 0.004, 0.008]
    first = swing[10]
    assert first["schema"] == ts.SWING and first["version"] == ts.SCHEMA_VERSION and first["vehicle_id"] == "1"
    assert first["valid"] is True and first["envelope_mode"] == "live"
    assert {"alpha_rad", "beta_rad", "alpha_rate_radps", "beta_rate_radps", "r_max_m", "wall_s"} <= set(first)
    assert abs(first["wall_s"] - time.time()) < 120
    assert col.encodings["slungpilot/1/swing"] == "application/json;slungpilot.swing/v1"
    # state decimated to 50 Hz of sim time: one sample per 5 ticks of 4 ms, no gaps either
    state = col.get("slungpilot/1/state")
    assert [x["seq"] for x in state] == list(range(ticks // 5))
    assert state[1]["t_s"] == pytest.approx(0.02) and len(state[1]["pos_ned_m"]) == 3
    assert len(col.get("slungpilot/1/setpoint")) == ticks // 5
    # status at 1 Hz, obstacles at least 1 Hz over 3 s of sim time
    assert [x["seq"] for x in col.get("slungpilot/1/status")] == [0, 1, 2]
    obs = col.get("slungpilot/1/obstacles")
    assert len(obs) == 3 and obs[0]["count"] == 2 and obs[0]["sources"] == ["mission"]
    assert done["seq"]["swing"] == ticks


def test_live_obstacles_are_used_bad_ones_counted_and_ignored() -> None:
    ep = f"tcp/127.0.0.1:{free_tcp_port()}"
    col = Collector()
    bad = [b"not json", b'{"obstacles": [{"x_m": NaN, "y_m": 0, "radius_m": 0.3}]}',
           b'{"obstacles": [{"x_m": 6, "y_m": 0, "radius_m": -0.3}]}', b'{"trunks": []}',
           b'{"obstacles": [{"x_m": 6, "y_m": 0, "radius_m": 9000}]}']
    trunk = {"x_m": 6.0, "y_m": 0.1, "radius_m": 0.3, "height_m": 4.0, "safe_distance_m": 0.1}
    with driver("--zenoh-listen", ep, "--vehicle-id", "7", "--realtime") as d, session(connect=[ep]) as s:
        s.declare_subscriber("slungpilot/7/obstacles", col)
        d.wait_event("ready")
        cam = s.declare_publisher("slungpilot/7/obstacles/in/cam")
        lidar = s.declare_publisher("slungpilot/world/obstacles/lidar")
        # one bad sample per publisher: only a publisher's newest unread sample is parsed (a flood sheds the rest)
        broken = [s.declare_publisher(f"slungpilot/7/obstacles/in/broken{i}") for i in range(len(bad))]
        for pub in (cam, lidar, *broken):
            wait_matching(pub)
        for pub, raw in zip(broken, bad, strict=True):
            pub.put(raw)
        lidar.put(json.dumps({"obstacles": [trunk]}))

        def latest() -> dict:
            got = col.get("slungpilot/7/obstacles")
            return got[-1] if got else {}

        wait_until(lambda: "slungpilot/world/obstacles/lidar" in latest().get("sources", []), 10, "live trunk")
        wait_until(lambda: latest().get("rejected_count") == len(bad), 10, "rejected count")
        cur = latest()
        assert cur["count"] == 3 and cur["sources"] == ["mission", "slungpilot/world/obstacles/lidar"]
        (live,) = [o for o in cur["obstacles"] if o["source"] != "mission"]
        assert live["x_m"] == 6.0 and live["vx_mps"] == 0.0
        # a second publisher with an expiry: appears, then goes by itself
        cam.put(json.dumps({"obstacles": [{**trunk, "x_m": 9.0}], "expires_s": 0.3}))
        wait_until(lambda: latest().get("count") == 4, 10, "cam obstacle")
        wait_until(lambda: latest().get("count") == 3, 10, "cam obstacle expiry")
        # an empty list clears that publisher
        lidar.put(json.dumps({"obstacles": []}))
        wait_until(lambda: latest().get("sources") == ["mission"], 10, "lidar cleared")
        d.stop()
        done = d.wait_event("done")
    assert done["rejected"] == len(bad) and done["accepted"] == 3 and done["live_sources"] == []


def test_config_queryable_answers_and_liveliness_token_goes_when_the_process_stops() -> None:
    ep = f"tcp/127.0.0.1:{free_tcp_port()}"
    events: list[tuple[str, str]] = []
    lock = threading.Lock()

    def on_alive(s: zenoh.Sample) -> None:
        with lock:
            events.append((str(s.key_expr), "put" if s.kind == zenoh.SampleKind.PUT else "delete"))

    def seen(ev: tuple[str, str]) -> bool:
        with lock:
            return ev in events

    with session(listen=[ep]) as s:
        s.liveliness().declare_subscriber("slungpilot/*/alive", on_alive, history=True)
        with driver("--zenoh-connect", ep, "--vehicle-id", "3", "--realtime") as d3, \
                driver("--zenoh-connect", ep, "--vehicle-id", "4", "--realtime") as d4:
            d3.wait_event("ready")
            d4.wait_event("ready")
            wait_until(lambda: seen(("slungpilot/3/alive", "put")) and seen(("slungpilot/4/alive", "put")), 15,
                       "both tokens")
            replies = list(s.get("slungpilot/3/config", timeout=10.0))
            assert len(replies) == 1 and replies[0].ok is not None
            body = json.loads(replies[0].ok.payload.to_bytes())
            assert body["schema"] == ts.CONFIG and body["vehicle_id"] == "3"
            assert body["config"]["vehicle"]["id"] == "3" and len(body["config"]["mission"]["obstacles"]) == 2
            assert str(replies[0].ok.encoding) == "application/json;slungpilot.config/v1"
            both = {str(r.ok.key_expr) for r in s.get("slungpilot/*/config", timeout=10.0) if r.ok is not None}
            assert both == {"slungpilot/3/config", "slungpilot/4/config"}
            # graceful stop: the app closes the session and the token is undeclared
            d3.stop(signal.SIGTERM)
            d3.wait_event("done")
            wait_until(lambda: seen(("slungpilot/3/alive", "delete")), 10, "token 3 gone after SIGTERM")
            assert not seen(("slungpilot/4/alive", "delete"))
            # a crash: the transport closes and the token goes too
            d4.stop(signal.SIGKILL)
            wait_until(lambda: seen(("slungpilot/4/alive", "delete")), 15, "token 4 gone after SIGKILL")


def test_two_vehicles_through_a_router_seen_by_one_subscriber() -> None:
    ep = f"tcp/127.0.0.1:{free_tcp_port()}"
    router = Proc(["-m", "companion.cli.zenoh_cmds", "zenoh-router", "--zenoh-listen", ep, "--duration", "50"])
    col = Collector()
    try:
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            if router._sel.select(timeout=0.5):
                assert "router" in router.p.stdout.readline()
                break
        common = ["--zenoh-connect", ep, "--zenoh-mode", "client", "--ticks", "250", "--wait-match-s", "15",
                  "--pause-s", "0.002"]
        with session(connect=[ep], mode="client") as s:
            s.declare_subscriber("slungpilot/*/swing", col)
            with driver(*common, "--vehicle-id", "1") as d1, driver(*common, "--vehicle-id", "2") as d2:
                r1, r2 = d1.wait_event("done", 40), d2.wait_event("done", 40)
                assert r1["matched"] and r2["matched"]
                wait_until(lambda: len(col.get("slungpilot/1/swing")) == 250 == len(col.get("slungpilot/2/swing")),
                           10, "both vehicles' swing")
        for vid in ("1", "2"):
            got = col.get(f"slungpilot/{vid}/swing")
            assert [x["seq"] for x in got] == list(range(250))
            assert {x["vehicle_id"] for x in got} == {vid}
    finally:
        router.close()
