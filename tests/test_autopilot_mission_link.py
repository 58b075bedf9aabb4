"""``fly --mission autopilot`` against a real peer over real UDP on 127.0.0.1: a pymavlink process playing the
autopilot's mission service (tests/helpers/mission_peer.py), well-behaved or not. The companion's download finds the
vehicle, gets home, downloads mission and fence, and either yields the mission to fly or refuses before take-off
with a clear reason: 10,000 items (refused without asking for one), NaN coordinates, a fence that excludes the
start, a download that stops half-way, duplicate and out-of-order items (flown all the same), no vehicle, no home.
The command line's own refusal (exit 4, report written, nothing flown) is checked once end to end."""

from __future__ import annotations

import json
import math
import os
import select
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from companion.core.autopilot_mission import earth_radii_m
from companion.core.mission import Mission
from companion.flight.setup import FlightSetup
from companion.launch.autopilot_mission import Refusal, fetch_autopilot_mission

pytestmark = pytest.mark.paired  # wall clock, light: may run beside one other such test (tests/conftest.py)

PEER = Path(__file__).parent / "helpers" / "mission_peer.py"
HOME = (47.397742, 8.545594, 488.0)
BASE = Mission(name="base", start_ned_m=np.array([0.0, 0.0, -2.0]), goal_ned_m=np.array([10.0, 0.0, -2.0]),
               planner="safe", controller="smc_ff", timeout_s=40.0)
ROUTE = [(4.0, 1.0, 2.0), (8.0, -1.0, 0.0), (12.0, 2.0, 0.0), (16.0, 0.0, 0.0)]


def _ll(n: float, e: float) -> tuple[int, int]:
    r_n, r_e = earth_radii_m("px4", HOME[0])
    return (round((HOME[0] + math.degrees(n / r_n)) * 1e7),
            round((HOME[1] + math.degrees(e / (r_e * math.cos(math.radians(HOME[0]))))) * 1e7))


def _wp(n: float, e: float, z: float = 3.0, hold: float = 0.0, cmd: int = 16) -> dict:
    x, y = _ll(n, e)
    return {"frame": 6, "command": cmd, "params": [hold, 0, 0, "nan"], "x": x, "y": y, "z": z}


def _mission() -> list[dict]:
    return [{"frame": 6, "command": 22, "params": [0, 0, 0, "nan"], "x": 0, "y": 0, "z": 3.0}] + \
        [_wp(n, e, hold=h) for n, e, h in ROUTE] + [{"frame": 6, "command": 21, "params": [0] * 4, "x": 0, "y": 0,
                                                      "z": 0.0}]


def _fence() -> list[dict]:
    square = [(-5.0, -6.0), (22.0, -6.0), (22.0, 6.0), (-5.0, 6.0)]
    out = [dict(_wp(n, e, 0.0), command=5001, params=[4, 0, 0, 0]) for n, e in square]
    return [*out, dict(_wp(10.0, 4.0, 0.0), command=5004, params=[1.0, 0, 0, 0])]


class _Peer:
    """The peer process, sending to the port of ``sock`` (bound here, as fly --sitl binds the companion's)."""

    def __init__(self, tmp_path: Path, spec: dict) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        f = tmp_path / "peer.json"
        f.write_text(json.dumps({"home": list(HOME), **spec}))
        self.proc = subprocess.Popen([sys.executable, str(PEER), str(self.port), str(f)], stdout=subprocess.PIPE,
                                     bufsize=0)
        self._out = b""
        assert self._read_until("PEER READY")

    def setup(self, **kw) -> FlightSetup:
        return FlightSetup(connect=f"udpin://127.0.0.1:{self.port}", sock=self.sock, **kw)

    def _read_until(self, line: str, timeout_s: float = 10.0) -> bool:
        """Read the peer's output (unbuffered) until it printed ``line``; False after ``timeout_s``."""
        end = time.monotonic() + timeout_s
        while line not in self._out.decode().splitlines() and time.monotonic() < end:
            if select.select([self.proc.stdout], [], [], 0.1)[0]:
                self._out += os.read(self.proc.stdout.fileno(), 65536)
        return line in self._out.decode().splitlines()

    def lines(self, until: str | None = None) -> list[str]:
        """What the peer printed (requests, ACKs): up to the line ``until`` (waited for, 10 s at most: the peer
        may still be reading what was sent last), else what it printed before it was stopped."""
        if until is not None:
            self._read_until(until)
        self.proc.terminate()
        out, _ = self.proc.communicate(timeout=5)
        self.sock.close()
        return (self._out + out).decode().splitlines()


@pytest.fixture
def peer(tmp_path):
    made: list[_Peer] = []

    def start(**spec) -> _Peer:
        made.append(_Peer(tmp_path, spec))
        return made[-1]

    yield start
    for p in made:
        if p.proc.poll() is None:
            p.proc.kill()
            p.proc.wait()
        p.sock.close()


def _fetch(p: _Peer, **kw):
    return fetch_autopilot_mission(p.setup(heartbeat_timeout_s=5.0), BASE, **kw)


@pytest.mark.parametrize("mode", ["normal", "duplicate", "out_of_order"])
def test_the_mission_and_fence_come_down_alike_however_the_items_arrive(peer, mode):
    p = peer(mission=_mission(), fence=_fence(), mode=mode)
    m, facts = _fetch(p)
    got = np.array([w.pos_ned_m for w in m.waypoints] + [m.goal_ned_m])
    assert np.allclose(got, [[n, e, -3.0] for n, e, _ in ROUTE], atol=0.02)
    assert [w.hold_s for w in m.waypoints] == [2.0, 0.0, 0.0] and m.land
    assert m.fence is not None and len(m.fence.polygons) == 1 and not m.fence.circles[0].inclusion
    dl = facts["download"]["mission"]
    assert dl["state"] == "done" and dl["received"] == 6
    if mode == "duplicate":
        assert dl["duplicates"] >= 5
    if mode == "out_of_order":
        assert dl["out_of_order"] >= 4
    assert facts["home"]["lat_deg"] == pytest.approx(HOME[0]) and facts["origin"] is not None
    acks = [ln for ln in p.lines(until="ACK 1 0") if ln.startswith("ACK")]
    assert acks == ["ACK 0 0", "ACK 1 0"]  # both downloads acknowledged ACCEPTED


def test_ten_thousand_items_are_refused_before_take_off_without_downloading_them(peer):
    p = peer(mission=_mission(), count=10_000)
    t0 = time.monotonic()
    with pytest.raises(Refusal) as e:
        _fetch(p)
    took = time.monotonic() - t0
    assert e.value.outcome == "refused" and "10000 items, more than the 1000" in e.value.detail
    lines = p.lines(until="ACK 0 15")
    assert not [ln for ln in lines if ln.startswith("REQ")] and "ACK 0 15" in lines  # none asked; cancelled
    assert took < 5.0  # the refusal does not wait for a timeout (the limit is generous for a loaded machine)


def test_a_download_that_stops_half_way_is_refused_naming_the_item(peer):
    p = peer(mission=_mission(), stall_at=3)
    with pytest.raises(Refusal) as e:
        _fetch(p, timeout_s=0.2, retries=3)
    assert e.value.outcome == "refused"
    assert "the mission download stopped at item 3 of 6: no MISSION_ITEM_INT 3 after 4 requests" in e.value.detail
    assert e.value.facts["download"]["mission"]["received"] == 3
    lines = p.lines(until="ACK 0 15")  # the download cancelled, after the last request
    assert lines.count("REQ 0 3") == 4


def test_nan_coordinates_are_refused_naming_the_item(peer):
    items = _mission()
    items[2]["z"] = "nan"
    with pytest.raises(Refusal, match=r"autopilot mission: item 2: a coordinate is not a number"):
        _fetch(peer(mission=items))


def test_a_fence_that_excludes_the_start_is_refused(peer):
    fence = [dict(_wp(0.0, 0.0, 0.0), command=5004, params=[3.0, 0, 0, 0])]
    with pytest.raises(Refusal, match=r"the start .* is inside the fence's exclusion circle 0"):
        _fetch(peer(mission=_mission(), fence=fence))


def test_an_unsupported_item_is_refused_naming_it(peer):
    items = _mission()
    items.insert(3, {"frame": 2, "command": 183, "params": [1, 1500, 0, 0], "x": 0, "y": 0, "z": 0})
    with pytest.raises(Refusal, match=r"item 3: MAV_CMD_DO_SET_SERVO \(183\) is not supported; supported: "):
        _fetch(peer(mission=items))


def test_no_home_is_not_ready(peer):
    with pytest.raises(Refusal) as e:
        _fetch(peer(mission=_mission(), no_home=True), home_timeout_s=1.5)
    assert e.value.outcome == "not_ready" and "no HOME_POSITION" in e.value.detail


def test_no_vehicle_is_no_vehicle():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        setup = FlightSetup(connect=f"udpin://127.0.0.1:{s.getsockname()[1]}", sock=s, heartbeat_timeout_s=0.5)
        with pytest.raises(Refusal) as e:
            fetch_autopilot_mission(setup, BASE)
    assert e.value.outcome == "no_vehicle" and "no autopilot HEARTBEAT within 0.5 s" in e.value.detail


def test_fly_refuses_before_take_off_with_exit_4_and_a_report(peer, tmp_path):
    items = _mission()
    items.insert(3, {"frame": 2, "command": 183, "params": [1, 1500, 0, 0], "x": 0, "y": 0, "z": 0})
    p = peer(mission=items)
    port = p.port
    p.sock.close()  # the command line binds it itself (udpin)
    run = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m", "companion.cli", "-q", "fly", "--connect", f"udpin://127.0.0.1:{port}",
                        "--mission", "autopilot", "--no-zenoh", "--no-plots", "--no-recording", "--run-dir", str(run),
                        "--heartbeat-timeout", "10"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 4, r.stderr
    assert "refused" in r.stderr and "item 3: MAV_CMD_DO_SET_SERVO (183) is not supported" in r.stderr
    report = json.loads((run / "report.json").read_text())
    assert report["outcome"] == "refused" and report["autopilot_mission"]["items"] == 7
    assert not report.get("reached_goal") and report["loop"]["ticks"] == 0  # nothing flown
