"""OBSTACLE_DISTANCE over real UDP into the flight's own input path: a pymavlink sender on loopback, the runner's
link and frame handler, the typed decode, the pilot's perception map. Scans become trunks the planner is given
(each with its source), a 1 kHz flood neither stalls the decode nor floods the map, bad messages are counted."""

from __future__ import annotations

import math
import socket
import time

import numpy as np
from pymavlink.dialects.v20 import common as M

from companion.config import resolve_mission
from companion.core.mission import load_mission
from companion.flight.facts import pilot_facts
from companion.flight.lockstep import LockstepRunner
from companion.flight.pilot import Pilot
from companion.flight.setup import FlightSetup
from lab.bench_perception import obstacle_distance_parts, raycast

TRUNKS = [(4.0, 1.0, 0.3), (6.0, -2.0, 0.25)]


def _runner(perception: bool | None = None) -> tuple[LockstepRunner, int]:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    port = sock.getsockname()[1]
    mission = load_mission(resolve_mission("forest"))
    setup = FlightSetup(connect=f"udpin://127.0.0.1:{port}", lockstep=True, sock=sock, perception=perception)
    run = LockstepRunner(Pilot(mission, setup), None)
    run.link.open_blocking()
    return run, port


class _Udp:
    """A pymavlink MAVLink 2 sender writing each frame as one UDP datagram to the companion's port."""

    def __init__(self, port: int, sysid: int) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.addr = ("127.0.0.1", port)
        self.mav = M.MAVLink(self, srcSystem=sysid, srcComponent=1)

    def write(self, buf: bytes) -> None:
        self.sock.sendto(bytes(buf), self.addr)

    def close(self) -> None:
        self.sock.close()


def _sender(port: int) -> _Udp:
    return _Udp(port, 1)


def _pump(run: LockstepRunner, until, timeout_s: float = 5.0) -> None:
    """Read the link (as the runner does) until ``until()`` or the timeout."""
    end = time.monotonic() + timeout_s
    while not until() and time.monotonic() < end:
        run.link.poll(0.02)


def _pose(tx: _Udp, t_s: float) -> None:
    ms = round(t_s * 1e3)
    tx.mav.attitude_send(ms, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    tx.mav.local_position_ned_send(ms, 0.0, 0.0, -2.0, 0.0, 0.0, 0.0)


def _scan(tx: _Udp, t_s: float, trunks=TRUNKS, seed: int = 0) -> None:
    rays = raycast((0.0, 0.0), 0.0, trunks, noise_m=0.01, rng=np.random.default_rng(seed))
    for p in obstacle_distance_parts(rays, round(t_s * 1e6)):
        tx.mav.obstacle_distance_send(p.time_usec, M.MAV_DISTANCE_SENSOR_LASER, list(p.distances_cm), 0,
                                      p.min_distance_cm, p.max_distance_cm, p.increment_deg, p.angle_offset_deg,
                                      p.frame)


def _heartbeat(tx: _Udp) -> None:
    tx.mav.heartbeat_send(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_PX4, 0, 0, M.MAV_STATE_STANDBY)


def test_scans_over_udp_become_trunks_the_planner_is_given_beside_the_missions():
    run, port = _runner()
    pilot = run.pilot
    tx = _sender(port)
    try:
        _heartbeat(tx)
        _pump(run, lambda: pilot.state.vehicle_sysid == 1)
        for k in range(4):
            t = 1.0 + 0.1 * k
            _pose(tx, t - 0.01)
            _pose(tx, t + 0.01)
            _scan(tx, t, seed=k)
        _pump(run, lambda: pilot.state.counts["OBSTACLE_DISTANCE"] == 20)
        assert pilot.state.counts["OBSTACLE_DISTANCE"] == 20  # 4 scans of 5 parts, each decoded to its event
        assert pilot.perception is not None and pilot.perception.assembler.parts == 20
        seen = pilot.obstacles.around(1.5, 0.0, 0.0)
        mission = [o for o in seen if o.source == "mission"]
        perceived = sorted((o for o in seen if o.source == "perception"), key=lambda o: o.x_m)
        assert len(mission) == len(pilot.mission.obstacles) and len(perceived) == 2
        for o, (x, y, _r) in zip(perceived, TRUNKS, strict=True):
            assert math.hypot(o.x_m - x, o.y_m - y) < 0.08  # 6 m away, 4 scans of 1 cm noise and cm steps
        facts = pilot_facts(pilot)["perception"]
        # on by itself at the first scan, which has no poses yet: refused (counted), the next three are mapped
        assert facts["scans_mapped"] == 3 and facts["refused"] == {"no_pose": 1}
    finally:
        tx.close()
        run.link.close()


def test_a_1khz_flood_is_decoded_as_it_comes_and_the_map_keeps_50hz():
    """1000 OBSTACLE_DISTANCE messages (whole 72 × 5° scans) 1 ms of vehicle time apart, sent as fast as the
    socket takes them: every one that arrives is decoded (none is left in the socket when the position sent after
    them arrives), at most 50 per second of vehicle time reach the map, the rest are counted."""
    run, port = _runner(perception=True)
    pilot = run.pilot
    tx = _sender(port)
    try:
        _heartbeat(tx)
        _pump(run, lambda: pilot.state.vehicle_sysid == 1)
        for k in range(0, 1100, 10):
            _pose(tx, 1.0 + 1e-3 * k)
        _pump(run, lambda: pilot.state.counts["ATTITUDE"] >= 100)
        for k in range(1000):
            t_us = 1_000_000 + 1000 * k
            tx.mav.obstacle_distance_send(t_us, 0, [500 + (k % 7)] * 72, 5, 10, 1200, 0.0, 0.0, 12)
            if k % 50 == 0:
                run.link.poll(0.0)  # the receiver keeps reading, as the runner's loop would
        tx.mav.local_position_ned_send(3000, 1.0, 2.0, -2.0, 0.0, 0.0, 0.0)  # after the flood
        _pump(run, lambda: pilot.state.pos_t_s == 3.0)
        decoded = pilot.state.counts["OBSTACLE_DISTANCE"]
        assert pilot.state.pos_t_s == 3.0  # the input after the flood got through
        assert decoded >= 900  # loopback may drop a few datagrams under the burst; the decode kept up
        p = pilot.perception
        assert p is not None and p.assembler.parts == decoded
        assert 0 < p.gate.passed <= 51 and p.gate.passed + p.gate.refused["rate_limit"] == decoded
    finally:
        tx.close()
        run.link.close()


def test_bad_scans_are_counted_in_the_report():
    run, port = _runner()
    pilot = run.pilot
    tx = _sender(port)
    other = M.MAVLink(tx, srcSystem=9, srcComponent=1)  # another system behind the same router (same address)
    try:
        _heartbeat(tx)
        _pump(run, lambda: pilot.state.vehicle_sysid == 1)
        _pose(tx, 1.0)
        d = [500] * 72
        tx.mav.obstacle_distance_send(1_000_000, 0, d, 0, 10, 1200, math.nan, 0.0, 12)  # non-finite: no map yet
        tx.mav.obstacle_distance_send(1_000_000, 0, d, 0, 10, 1200, 0.0, 0.0, 12)  # increment 0: starts the map
        tx.mav.obstacle_distance_send(1_000_000, 0, d, 0, 10, 1200, 6.0, 0.0, 12)  # 72 × 6° > 360°
        tx.mav.obstacle_distance_send(1_000_000, 0, d, 0, 10, 1200, math.nan, 0.0, 12)  # counted now
        tx.mav.obstacle_distance_send(1_000_000, 0, d, 0, 10, 1200, 1.0, math.inf, 12)
        tx.mav.obstacle_distance_send(1_000_000, 0, d, 0, 10, 1200, 1.0, 0.0, 7)  # a frame it cannot place
        other.obstacle_distance_send(1_000_000, 0, d, 5, 10, 1200, 0.0, 0.0, 12)  # another vehicle's
        _pump(run, lambda: pilot.state.counts["OBSTACLE_DISTANCE"] >= 7)
        refused = pilot_facts(pilot)["perception"]["refused"]
        assert refused == {"part_increment": 1, "part_coverage": 1, "part_nonfinite": 2, "part_frame": 1,
                           "wrong_vehicle": 1}, refused
        assert pilot.state.rejected["nonfinite"] == 3  # the non-finite ones, as every decoder's are counted
        assert pilot.perception is not None and pilot.perception.obstacles == ()
    finally:
        tx.close()
        run.link.close()


def test_without_scans_or_with_perception_off_there_is_no_map():
    for perception, scans in ((None, False), (False, True)):
        run, port = _runner(perception)
        tx = _sender(port)
        try:
            _heartbeat(tx)
            _pose(tx, 1.0)
            if scans:
                _scan(tx, 1.0)
            _pump(run, lambda r=run, n=5 if scans else 0: r.pilot.state.counts["OBSTACLE_DISTANCE"] >= n
                  and r.pilot.state.counts["LOCAL_POSITION_NED"] >= 1)
            assert run.pilot.perception is None and run.pilot.obstacles.perceived is None
            assert pilot_facts(run.pilot)["perception"] is None
        finally:
            tx.close()
            run.link.close()


def test_scans_from_zenoh_reach_the_pilots_map_between_ticks():
    """The pilot's ``on_scan`` (what the Zenoh scan input hands over): scans on the vehicle's clock are placed at
    their time, a ROS-stamped one at the newest pose (counted); with perception off, nothing."""
    from companion.mavlink_io import telemetry as tm
    from companion.perception.scan import Scan

    for perception in (None, False):
        pilot = Pilot(load_mission(resolve_mission("forest")), FlightSetup(lockstep=True, perception=perception))
        pilot.on_telemetry(tm.Heartbeat(1, 1, 0, 2, 12, 0, 0, 3), 0.0)
        ang = np.radians(np.arange(360.0))
        for k in range(4):
            t = 1.0 + 0.1 * k
            for dt in (-0.01, 0.01):
                pilot.on_telemetry(tm.Attitude(1, 1, 0, t + dt, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)), 0.0)
                pilot.on_telemetry(tm.LocalPositionNed(1, 1, 0, t + dt, (0.0, 0.0, -2.0), (0.0, 0.0, 0.0)), 0.0)
            rays = raycast((0.0, 0.0), 0.0, TRUNKS, noise_m=0.01, rng=np.random.default_rng(k))
            scan = Scan(t if k < 3 else 1e9, ang, rays, 0.1, 12.0, math.radians(1.0), source="zenoh")
            pilot.on_scan(scan, vehicle_clock=k < 3)
        if perception is False:
            assert pilot.perception is None
            continue
        p = pilot.perception
        # on by itself at the first scan (no poses yet: refused), then three mapped, the ROS-stamped one at the
        # newest pose
        assert p is not None and p.scans_mapped == 3 and p.refused == {"no_pose": 1} and p.restamped == 1
        assert len(p.obstacles) == 2


def test_in_real_time_a_scan_is_mapped_between_ticks_a_slice_at_a_time():
    """A real-time pilot defers a scan that passed the gate: nothing is mapped on arrival; each ``work`` call with
    a deadline already passed does one slice (points, then a few circle fits, then the map); the scan is mapped
    after a few calls, and a newer scan before the older is done replaces it (counted)."""
    from companion.mavlink_io import telemetry as tm
    from companion.perception.scan import Scan

    pilot = Pilot(load_mission(resolve_mission("forest")), FlightSetup(lockstep=False, perception=True))
    pilot.on_telemetry(tm.Heartbeat(1, 1, 0, 2, 12, 0, 0, 3), 0.0)
    ang = np.radians(np.arange(360.0))
    trunks = [(3.0 + k, 2.0 * (-1) ** k, 0.25) for k in range(6)]
    for k in range(3):
        t = 1.0 + 0.1 * k
        for dt in (-0.01, 0.01):
            pilot.on_telemetry(tm.Attitude(1, 1, 0, t + dt, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)), 0.0)
            pilot.on_telemetry(tm.LocalPositionNed(1, 1, 0, t + dt, (0.0, 0.0, -2.0), (0.0, 0.0, 0.0)), 0.0)
        rays = raycast((0.0, 0.0), 0.0, trunks, noise_m=0.01, rng=np.random.default_rng(k))
        pilot.on_scan(Scan(t, ang, rays, 0.1, 12.0, math.radians(1.0), source="zenoh"))
        p = pilot.perception
        assert p is not None and p.pending and p.scans_mapped == k
        slices = 0
        while not p.work(-math.inf, lambda: 0.0):  # every slice overruns the deadline: one slice per call
            slices += 1
        assert slices >= 2 and p.scans_mapped == k + 1 and not p.pending  # points | 4 fits | 2 fits, map
    assert len(p.obstacles) == 6
    for t in (2.0, 2.1):
        pilot.on_telemetry(tm.Attitude(1, 1, 0, t, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)), 0.0)
        pilot.on_telemetry(tm.LocalPositionNed(1, 1, 0, t, (0.0, 0.0, -2.0), (0.0, 0.0, 0.0)), 0.0)
        pilot.on_scan(Scan(t, ang, raycast((0.0, 0.0), 0.0, trunks), 0.1, 12.0, math.radians(1.0), source="zenoh"))
    assert p.superseded == 1
