"""Shared by the tests where an operator's ground station meets the companion (issue 27): the route and fence a
ground station uploads about the bundled vehicle's home, MAVSDK's upload of them, a pymavlink ground station that
talks to the companion (component 191) through a router, the real-time flight behind MAVProxy, and the fence
margins of a flight log (airframe and payload).

Used by tests/test_autopilot_mission_fly.py, tests/test_autopilot_mission_real.py, tests/test_gcs_beside.py and
tests/test_operator_mission_e2e.py.
"""

from __future__ import annotations

import contextlib
import math
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as M

from companion.core.autopilot_mission import earth_radii_m
from companion.core.fence import Fence, FenceCircle, FencePolygon, fence_margin_m
from lab.procs import free_udp_port

ROOT = Path(__file__).resolve().parents[1]
MAVPROXY = Path(sys.executable).parent / "mavproxy.py"
COMPANION = (1, 191)  # the companion's system and component on the vehicle's MAVLink network

ROUTE = [(2.0, 1.6, 2.0, 0.0), (5.5, 2.6, 2.5, 2.0), (9.0, 1.2, 2.0, 0.0), (10.0, 0.0, 2.0, 0.0)]  # n, e, alt, hold
FENCE_SQUARE = [(-3.0, -4.0), (14.0, -4.0), (14.0, 5.0), (-3.0, 5.0)]
KEEP_OUT = (7.5, 3.8, 0.5)  # north, east, radius (m): beside the leg from the clearing to the east gap
DEFAULT_HOME = (47.397742, 8.545594, 488.0)  # the bundled vehicle's home without --home


def ll_deg(home: tuple[float, float, float], n: float, e: float) -> tuple[float, float]:
    """Latitude and longitude (deg) of (north, east) m from ``home`` (the bundled vehicle's WGS-84 local radii)."""
    r_n, r_e = earth_radii_m("wgs84", home[0], home[2])
    return home[0] + math.degrees(n / r_n), home[1] + math.degrees(e / (r_e * math.cos(math.radians(home[0]))))


def route_fence() -> Fence:
    """The uploaded fence in the mission frame (m): the inclusion square and the exclusion circle."""
    return Fence((FencePolygon(tuple(FENCE_SQUARE), True),), (FenceCircle(KEEP_OUT[:2], KEEP_OUT[2], False),))


def fence_margins_m(log: dict, fence: Fence) -> tuple[int, float]:
    """(airframe samples, the smallest margin inside ``fence`` (m) of the airframe's and the payload's logged
    positions, NaN payload samples left out): positive means neither ever left it."""
    pos, payload = log["pos_ned_m"], log["payload_pos_ned_m"]
    margins = [fence_margin_m(fence, p[:2]) for p in pos] + \
        [fence_margin_m(fence, p[:2]) for p in payload if np.all(np.isfinite(p))]
    assert len(margins) > len(pos), "no payload positions in the log"
    return len(pos), min(margins)


async def mavsdk_upload(connection: str, home: tuple[float, float, float]):
    """MAVSDK as the ground station on ``connection`` (the vehicle's GCS link): mission_raw uploads take-off,
    :data:`ROUTE` and a landing, the geofence plugin the fence; returns the connected ``Mavsdk`` (destroy it)."""
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.geofence import GeofenceAsync
    from mavsdk.asyncio.plugins.mission_raw import MissionRawAsync
    from mavsdk.plugins.geofence import Circle, FenceType, GeofenceData, Point, Polygon
    from mavsdk.plugins.mission_raw import MissionItem

    drone = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    await drone.add_any_connection(connection)
    system = None
    async for _ in drone.on_new_system():
        for s in await drone.get_systems():
            if await s.has_autopilot() and await s.is_connected():
                system = s
        if system is not None:
            break
    rel = M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    items = [MissionItem(0, rel, M.MAV_CMD_NAV_TAKEOFF, 1, 1, 0.0, 0.0, 0.0, math.nan, 0, 0, 2.0, 0)]
    for k, (n, e, alt, hold) in enumerate(ROUTE):
        lat, lon = ll_deg(home, n, e)
        items.append(MissionItem(k + 1, rel, M.MAV_CMD_NAV_WAYPOINT, 0, 1, hold, 0.0, 0.0, math.nan,
                                 round(lat * 1e7), round(lon * 1e7), alt, 0))
    items.append(MissionItem(len(items), rel, M.MAV_CMD_NAV_LAND, 0, 1, 0.0, 0.0, 0.0, math.nan, 0, 0, 0.0, 0))
    await MissionRawAsync(system).upload_mission(items)
    square = [Point(*ll_deg(home, n, e)) for n, e in FENCE_SQUARE]
    keep_out = Circle(Point(*ll_deg(home, *KEEP_OUT[:2])), KEEP_OUT[2], FenceType.EXCLUSION)
    await GeofenceAsync(system).upload_geofence(GeofenceData([Polygon(square, FenceType.INCLUSION)], [keep_out]))
    return drone


class Gcs:
    """A ground station on a pymavlink UDP connection: heartbeats once a second, keeps what the companion says."""

    def __init__(self, port: int, sysid: int = 255) -> None:
        self.conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=sysid, source_component=190)
        self.texts: list[tuple[float, int, str]] = []
        self.acks: list[tuple[float, int, int, int]] = []  # (time, command, result, target system)
        self.companion_hb: list[int] = []  # MAV_TYPE of the companion's heartbeats
        self._hb_at = 0.0

    def pump(self, seconds: float, until: Callable[[], bool] | None = None) -> bool:
        """Read for ``seconds`` (or until ``until()``), heartbeating; True if ``until`` came true."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            now = time.monotonic()
            if now - self._hb_at > 1.0:
                self.conn.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE)
                self._hb_at = now
            msg = self.conn.recv_match(blocking=True, timeout=0.05)
            if msg is not None and (msg.get_srcSystem(), msg.get_srcComponent()) == COMPANION:
                t = msg.get_type()
                if t == "STATUSTEXT":
                    self.texts.append((now, msg.severity, msg.text))
                elif t == "COMMAND_ACK":
                    self.acks.append((now, msg.command, msg.result, msg.target_system))
                elif t == "HEARTBEAT":
                    self.companion_hb.append(msg.type)
            if until is not None and until():
                return True
        return False

    def said(self, fragment: str) -> bool:
        return any(fragment in text for _, _, text in self.texts)

    def command(self, param1: float, as_sysid: int | None = None) -> tuple[int, int]:
        """MAV_CMD_DO_PAUSE_CONTINUE to the companion (as another system if ``as_sysid``): (result, to system).
        Sent again without an answer (as the command protocol says: a loaded MAVProxy can drop a datagram)."""
        n = len(self.acks)
        own = self.conn.mav.srcSystem
        for confirmation in range(5):
            self.conn.mav.srcSystem = as_sysid or own
            self.conn.mav.command_long_send(*COMPANION, M.MAV_CMD_DO_PAUSE_CONTINUE, confirmation, param1, 0, 0, 0, 0,
                                            0, 0)
            self.conn.mav.srcSystem = own
            if self.pump(1.5, lambda: len(self.acks) > n):
                break
        assert len(self.acks) > n, ("no COMMAND_ACK from the companion", param1, as_sysid, self.acks, self.texts)
        _, cmd, result, to = self.acks[n]
        assert cmd == M.MAV_CMD_DO_PAUSE_CONTINUE
        return result, to


class MissionGcs:
    """A ground station's mission upload on raw UDP (blocking pymavlink), to system ``target`` (component 1): it
    sends to ``port``, or with ``listen`` binds ``port`` and answers whoever sends there (ArduCopter's SERIAL0).
    ``resend_s`` (s): MISSION_COUNT again after that much silence; ``timeout_s`` (s): the upload's bound."""

    def __init__(self, port: int, target: int = 1, listen: bool = False, resend_s: float = 1.0,
                 timeout_s: float = 20.0) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", port if listen else 0))
        self.sock.settimeout(0.05)
        self.addr: tuple[str, int] | None = None if listen else ("127.0.0.1", port)
        self.listen, self.target, self.resend_s, self.timeout_s = listen, target, resend_s, timeout_s
        self.mav = M.MAVLink(self, srcSystem=255, srcComponent=190)
        self.parser = M.MAVLink(None)
        self.parser.robust_parsing = True

    def write(self, buf: bytes) -> None:
        if self.addr is not None:
            self.sock.sendto(bytes(buf), self.addr)

    def recv(self) -> list:
        """The target system's messages in the next datagram (none after 50 ms)."""
        try:
            data, peer = self.sock.recvfrom(65536)
        except TimeoutError:
            return []
        if self.listen:
            self.addr = peer
        return [m for m in self.parser.parse_buffer(data) or []
                if m.get_type() != "BAD_DATA" and m.get_srcSystem() == self.target]

    def home(self, timeout_s: float = 90.0) -> tuple[float, float, float]:
        """(lat deg, lon deg, alt m) of HOME_POSITION, asked for once a second with a GCS HEARTBEAT."""
        end = time.monotonic() + timeout_s
        asked = 0.0
        while time.monotonic() < end:
            if time.monotonic() - asked > 1.0:
                self.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                self.mav.command_long_send(self.target, 1, M.MAV_CMD_REQUEST_MESSAGE, 0, 242, 0, 0, 0, 0, 0, 0)
                asked = time.monotonic()
            for m in self.recv():
                if m.get_type() == "HOME_POSITION":
                    return m.latitude * 1e-7, m.longitude * 1e-7, m.altitude * 1e-3
        raise AssertionError(f"no HOME_POSITION from system {self.target}")

    def upload(self, mtype: int, items: list[tuple]) -> int:
        """Upload ``items`` (frame, command, params, x, y, z) as ``mtype``; the autopilot's MISSION_ACK result."""
        end = time.monotonic() + self.timeout_s
        last = 0.0
        while time.monotonic() < end:
            if time.monotonic() - last > self.resend_s:
                self.mav.mission_count_send(self.target, 1, len(items), mtype)
                last = time.monotonic()
            for m in self.recv():
                t = m.get_type()
                if t in ("MISSION_REQUEST_INT", "MISSION_REQUEST") and m.mission_type == mtype:
                    frame, cmd, params, x, y, z = items[m.seq]
                    self.mav.mission_item_int_send(self.target, 1, m.seq, frame, cmd, 0, 1, *params, x, y, z, mtype)
                    last = time.monotonic()
                elif t == "MISSION_ACK" and m.mission_type == mtype:
                    return m.type
        raise AssertionError(f"system {self.target} did not finish the upload")


@contextlib.contextmanager
def mavproxy_flight(tmp_path: Path, fly_args: list[str],
                    before_fly: Callable[[int], None] | None = None) -> Iterator[tuple[Gcs, subprocess.Popen, Path]]:
    """The bundled vehicle (real time), MAVProxy with the companion as its master, ``fly --connect ... --gcs-sysid
    255 <fly_args>`` and a GCS on MAVProxy's other output; ``before_fly(port)`` runs before ``fly`` starts, with the
    UDP port the vehicle's own GCS link sends to (a ground station's upload). Yields (gcs, fly process, run folder)
    once the companion says its mission is in the cruise; everything stopped after.

    Topology: MAVProxy forwards between its master and its outputs, never between two outputs, so the companion is
    its master and the vehicle and the GCS are outputs (docs/autopilots.md, *Beside a ground station*)::

        vehicle (sim_bridge) ──udp── MAVProxy ──udp── companion (fly --connect udpin)
              │                         └─────udp── GCS (pymavlink, system 255)
              └── its own GCS link ── before_fly's ground station (an upload)
    """
    comp, vside, gside, vgcs = free_udp_port(), free_udp_port(), free_udp_port(), free_udp_port()
    procs = []
    try:
        sim = subprocess.Popen([sys.executable, "-m", "sim_bridge", "--onboard-port", str(free_udp_port()),
                                "--onboard-remote", f"127.0.0.1:{vside}", "--gcs-port", str(free_udp_port()),
                                "--gcs-remote", f"127.0.0.1:{vgcs}"],
                               cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        procs.append(sim)
        assert sim.stdout is not None and sim.stdout.readline().startswith("SITL READY")
        procs.append(subprocess.Popen(
            [sys.executable, str(MAVPROXY), "--master", f"udpout:127.0.0.1:{comp}", "--out", f"udpin:127.0.0.1:{vside}",
             "--out", f"udpin:127.0.0.1:{gside}", "--non-interactive", "--daemon", "--nowait", "--default-modules",
             "", "--state-basedir", str(tmp_path)],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=tmp_path))
        if before_fly is not None:
            before_fly(vgcs)
        run = tmp_path / "run"
        fly = subprocess.Popen([sys.executable, "-m", "companion.cli", "-q", "fly", "--connect",
                                f"udpin://127.0.0.1:{comp}", "--profile", "bundled", "--gcs-sysid", "255",
                                "--no-zenoh", "--no-recording", "--no-plots", "--run-dir", str(run), *fly_args],
                               cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        procs.append(fly)
        gcs = Gcs(gside)
        assert gcs.pump(180.0, lambda: gcs.said("slungpilot mission")), gcs.texts
        assert gcs.pump(90.0, lambda: gcs.said("phase: cruise")), gcs.texts
        yield gcs, fly, run
    finally:
        for p in reversed(procs):
            p.terminate()
            try:
                p.wait(20)
            except subprocess.TimeoutExpired:
                p.kill()
