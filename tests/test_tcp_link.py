"""TCP links (issue 27): ``--connect tcp://HOST:PORT`` (ArduPilot SITL's and mavlink-router's TCP servers) and
``tcpin://HOST:PORT`` (listen for one peer at a time), on real sockets on 127.0.0.1, against pymavlink as the other
implementation and, for whole flights, the bundled vehicle behind a serial-to-TCP bridge (what mavlink-router does
with a TELEM port): handshake, lock, resets, reconnection. Opt-in (SLUNGPILOT_ARDUPILOT): ArduCopter SITL over its
own TCP server and over a serial pty.
"""

from __future__ import annotations

import contextlib
import json
import os
import select
import socket
import struct
import subprocess
import sys
import threading
import time
import tty
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as M

from companion.errors import LinkError
from companion.mavlink_io.framing import StreamFramer
from companion.mavlink_io.link import MavlinkLink
from lab.procs import free_tcp_port
from lab.pty_pair import PtyPair

ROOT = Path(__file__).resolve().parents[1]


def _poll_until(link: MavlinkLink, cond, timeout_s: float = 5.0) -> bool:
    end = time.monotonic() + timeout_s
    while not cond() and time.monotonic() < end:
        link.poll(0.02)
    return bool(cond())


def _heartbeat_frames(n: int, sysid: int = 1) -> bytes:
    mav = M.MAVLink(None, srcSystem=sysid, srcComponent=1)
    return b"".join(bytes(mav.heartbeat_encode(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_PX4, 0, 0, 3).pack(mav))
                    for _ in range(n))


def test_handshake_and_lock_with_pymavlink_as_the_autopilot():
    """pymavlink's own TCP server as the vehicle: its HEARTBEATs reach the companion, the companion's reach it."""
    port = free_tcp_port()
    peer = mavutil.mavlink_connection(f"tcpin:127.0.0.1:{port}", source_system=1, source_component=1)
    got: list = []
    link = MavlinkLink(f"tcp://127.0.0.1:{port}", got.append)
    try:
        link.open_blocking()
        assert link.connected
        end = time.monotonic() + 5
        while not got and time.monotonic() < end:
            peer.recv_msg()  # pymavlink's tcpin accepts its client when it reads
            peer.mav.heartbeat_send(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_PX4, 0, 0, M.MAV_STATE_STANDBY)
            link.poll(0.05)
        assert got and got[0].get_type() == "HEARTBEAT" and got[0].get_srcSystem() == 1
        link.lock_to_last_sender()
        assert link.locked is not None and link.locked[1] == 1
        link.mav.heartbeat_send(M.MAV_TYPE_ONBOARD_CONTROLLER, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        msg = peer.recv_match(type="HEARTBEAT", blocking=True, timeout=5)
        assert msg is not None and msg.get_srcComponent() == 191 and msg.type == M.MAV_TYPE_ONBOARD_CONTROLLER
    finally:
        link.close()
        peer.close()


def test_a_refused_connection_is_a_link_error_naming_the_url():
    port = free_tcp_port()
    with pytest.raises(LinkError, match=f"cannot open tcp://127.0.0.1:{port}: Connection refused"):
        MavlinkLink(f"tcp://127.0.0.1:{port}", print).open_blocking()


def test_a_reset_connection_is_link_closed_then_the_client_reconnects():
    """The server resets the connection (RST): counted once, not connected, nothing sent; the link connects again
    by itself within about a second and reads the new connection's frames (split anywhere)."""
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    got: list = []
    link = MavlinkLink(f"tcp://127.0.0.1:{port}", got.append)
    try:
        link.open_blocking()
        conn, _ = server.accept()
        conn.sendall(_heartbeat_frames(2))
        assert _poll_until(link, lambda: len(got) == 2)
        conn.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        conn.close()  # RST
        assert _poll_until(link, lambda: link.rejected["link_closed"] == 1, 2.0) and not link.connected
        link.mav.heartbeat_send(M.MAV_TYPE_ONBOARD_CONTROLLER, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        assert link.sent == 0
        t0 = time.monotonic()
        assert _poll_until(link, lambda: link.connected, 3.0)
        assert time.monotonic() - t0 < 2.0
        conn, _ = server.accept()
        blob = b"\x00\x01junk" + _heartbeat_frames(3)
        for i in range(0, len(blob), 5):
            conn.sendall(blob[i : i + 5])
            time.sleep(0.001)
        assert _poll_until(link, lambda: len(got) == 5)
        assert link.rejected["garbage_bytes"] == 6 and link.rejected["link_closed"] == 1
        conn.close()
    finally:
        link.close()
        server.close()


def test_tcpin_takes_one_peer_at_a_time():
    """A listening link takes the first client; while it is connected the port does not listen (a second client
    is refused by the kernel); when it leaves, the port listens again and the next client is read."""
    port = free_tcp_port()
    got: list = []
    link = MavlinkLink(f"tcpin://127.0.0.1:{port}", got.append)
    try:
        link.open_blocking()
        assert not link.connected
        first = socket.create_connection(("127.0.0.1", port))
        assert _poll_until(link, lambda: link.connected)
        with pytest.raises(ConnectionRefusedError):
            socket.create_connection(("127.0.0.1", port), timeout=2).close()
        first.sendall(_heartbeat_frames(1, sysid=1))
        assert _poll_until(link, lambda: len(got) == 1)
        link.lock_to_last_sender()
        link.mav.heartbeat_send(M.MAV_TYPE_ONBOARD_CONTROLLER, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        first.settimeout(5)
        assert StreamFramer().feed(first.recv(4096))[0][7] == M.MAVLINK_MSG_ID_HEARTBEAT
        first.close()
        assert _poll_until(link, lambda: link.rejected["link_closed"] == 1) and not link.connected
        second = socket.create_connection(("127.0.0.1", port), timeout=2)
        second.sendall(_heartbeat_frames(1, sysid=1))
        assert _poll_until(link, lambda: len(got) == 2) and link.connected
        second.close()
    finally:
        link.close()


# ------------------------------------------------------------------------------------------------ whole flights
class TcpBridge(threading.Thread):
    """A serial-to-TCP router in miniature (what mavlink-router's TCP server does with a TELEM port): one client
    at a time on a port of 127.0.0.1, bytes copied both ways with a pty device. ``reset(down_s)`` drops the client
    (RST) and accepts the next one only ``down_s`` later (a router restarting)."""

    def __init__(self, device: Path) -> None:
        super().__init__(daemon=True)
        self.fd = os.open(device, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(self.fd)
        self.server = socket.create_server(("127.0.0.1", 0))
        self.port = self.server.getsockname()[1]
        self.conn: socket.socket | None = None
        self.stopped = False
        self.accept_after = 0.0  # monotonic time (s) before which no new client is accepted

    def run(self) -> None:
        while not self.stopped:
            conn = self.conn
            fds = [self.fd] if conn is None and time.monotonic() < self.accept_after else \
                [self.fd, conn if conn is not None else self.server]
            readable, _, _ = select.select(fds, (), (), 0.1)
            try:
                for r in readable:
                    if r is self.server:
                        self.conn, _ = self.server.accept()
                        self.conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                    elif r == self.fd:
                        data = os.read(self.fd, 65536)
                        if self.conn is not None:
                            self.conn.sendall(data)
                    else:
                        data = r.recv(65536)
                        if not data:
                            self.conn = None
                        else:
                            os.write(self.fd, data)
            except OSError:
                self.conn = None

    def reset(self, down_s: float = 0.0) -> None:
        self.accept_after = time.monotonic() + down_s
        conn, self.conn = self.conn, None
        if conn is not None:
            conn.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            conn.close()

    def stop(self) -> None:
        self.stopped = True
        self.join(5)
        self.reset()
        self.server.close()
        os.close(self.fd)


def _vehicle_on_pty(tmp_path: Path, device: Path) -> subprocess.Popen:
    from companion.core.mission import load_mission
    from companion.launch.sitl import vehicle_toml
    from lab.procs import free_udp_port

    vfile = tmp_path / "vehicle.toml"
    vfile.write_text(vehicle_toml(load_mission(ROOT / "config" / "missions" / "forest.toml")))
    with open(tmp_path / "sitl.log", "wb") as log:
        proc = subprocess.Popen([sys.executable, "-m", "sim_bridge", "--lockstep", "--serial", f"{device}:921600",
                                 "--gcs-port", str(free_udp_port()), "--vehicle", str(vfile)],
                                stdout=subprocess.PIPE, stderr=log, text=True, cwd=ROOT)
    assert proc.stdout is not None and proc.stdout.readline().startswith("SITL READY")
    return proc


def _fly(run_dir: Path, port: int) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "companion.cli", "-v", "fly", "--no-zenoh", "--no-plots",
                             "--no-recording", "--run-dir", str(run_dir), "--connect", f"tcp://127.0.0.1:{port}",
                             "--lockstep", "--profile", "bundled", "--planner", "safe"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=ROOT)


@pytest.mark.slow
@pytest.mark.parametrize("reset", [False, True], ids=["completes", "reset_mid_flight"])
def test_forest_over_tcp_through_a_serial_bridge(tmp_path, reset):
    """The bundled vehicle on a pty, a serial-to-TCP bridge, the companion with ``--connect tcp://``: the Table 2
    forest flies as ``fly --sitl`` over UDP does, bit for bit; a reset mid-flight with the bridge back only 3 s later is
    link_lost (exit 3), counted (back within the lockstep limit, 1.5 s, the flight goes on)."""
    with PtyPair(tmp_path / "fc", tmp_path / "cc"):
        sim = _vehicle_on_pty(tmp_path, tmp_path / "fc")
        bridge = TcpBridge(tmp_path / "cc")
        bridge.start()
        try:
            fly = _fly(tmp_path / "tcp", bridge.port)
            assert fly.stderr is not None
            if reset:
                for line in fly.stderr:
                    if "takeover → mission" in line:
                        break
                time.sleep(0.5)
                bridge.reset(down_s=3.0)  # longer than the lockstep telemetry limit (1.5 s): link_lost
            fly.communicate(timeout=300)
        finally:
            if fly.poll() is None:
                fly.kill()
            sim.terminate()
            sim.wait(10)
            bridge.stop()
    rep = json.loads((tmp_path / "tcp" / "report.json").read_text())
    if reset:
        assert fly.returncode == 3 and rep["outcome"] == "link_lost", rep["outcome"]
        assert rep["link"]["rejected"].get("link_closed") == 1, rep["link"]
        return
    assert fly.returncode == 0 and rep["outcome"] == "completed" and rep["reached_goal"], rep["outcome"]
    udp = subprocess.run([sys.executable, "-m", "companion.cli", "-q", "fly", "--sitl", "--no-zenoh", "--no-plots",
                          "--no-recording", "--planner", "safe", "--run-dir", str(tmp_path / "udp")],
                         capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert udp.returncode == 0, udp.stderr[-2000:]
    la, lb = (np.load(tmp_path / d / "flight_log.npz") for d in ("udp", "tcp"))
    for k in la.files:
        assert np.array_equal(la[k], lb[k], equal_nan=True), k


def test_fly_refuses_a_taken_tcpin_port_before_anything_starts(tmp_path):
    with socket.create_server(("127.0.0.1", 0)) as taken:
        port = taken.getsockname()[1]
        proc = subprocess.run([sys.executable, "-m", "companion.cli", "fly", "--connect", f"tcpin://127.0.0.1:{port}",
                               "--no-zenoh", "--run-dir", str(tmp_path / "run")],
                              capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert proc.returncode == 3 and f"MAVLink port {port}" in proc.stderr and "is in use" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_tcpin_on_the_event_loop_follows_its_peers():
    """The real-time runner's path for a listening link: the loop watches the listener, then the peer's socket, then
    the listener again when the peer leaves (the descriptor changes under ``loop.add_reader``)."""
    import asyncio

    port = free_tcp_port()
    got: list = []

    async def until(cond, timeout_s: float = 5.0) -> bool:
        end = time.monotonic() + timeout_s
        while not cond() and time.monotonic() < end:
            await asyncio.sleep(0.01)
        return bool(cond())

    async def main() -> MavlinkLink:
        link = MavlinkLink(f"tcpin://127.0.0.1:{port}", got.append)
        async with link:
            for k in range(2):
                peer = socket.create_connection(("127.0.0.1", port), timeout=2)
                assert await until(lambda: link.connected)
                peer.sendall(_heartbeat_frames(2))
                assert await until(lambda k=k: len(got) == 2 * (k + 1))
                peer.close()
                assert await until(lambda k=k: link.rejected["link_closed"] == k + 1 and not link.connected)
        return link

    link = asyncio.run(main())
    assert len(got) == 4 and link.rejected["link_closed"] == 2


# ------------------------------------------------------------------------------------------------ a real autopilot
def _arducopter_on_tcp(workdir: Path, instance: int = 7, serial0: str = "tcp:0") -> tuple[subprocess.Popen, int]:
    """ArduCopter SITL (quad, no payload) with SERIAL0 a TCP server, as ``sim_vehicle.py`` starts it (or ``serial0``,
    e.g. ``uart:DEVICE:BAUD``); its TCP port."""
    from lab import sitl_external

    root, why = sitl_external.find_arducopter()
    if root is None:
        pytest.skip(why)
    (workdir / "sim.parm").write_text("SIM_SLUP_ENABLE 0\n")
    defaults = f"{root / 'Tools/autotest/default_params/copter.parm'},{workdir / 'sim.parm'}"
    with open(workdir / "arducopter.log", "w") as log:
        proc = subprocess.Popen([str(root / "build/sitl/bin/arducopter"), "--model", "quad", "-I", str(instance),
                                 "--wipe", "--home", sitl_external.ARDUCOPTER_HOME, "--defaults", defaults,
                                 "--serial0", serial0], cwd=workdir, stdout=log, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, start_new_session=True)
    return proc, 5760 + 10 * instance


@pytest.mark.slow
@pytest.mark.parametrize("kill", [False, True], ids=["completes", "killed_mid_flight"])
def test_arducopter_sitl_over_tcp(tmp_path, kill):
    """Opt-in (SLUNGPILOT_ARDUPILOT): ArduCopter SITL's own TCP server, as ``--connect tcp://`` is used with it; the
    forest completes; SIGKILLed mid-flight the connection dies under the companion: link_lost, counted once."""
    import signal as sig

    ac, port = _arducopter_on_tcp(tmp_path)
    try:
        time.sleep(1.0)  # its TCP server is up within a second; a refused connect is a LinkError, not a wait
        fly = subprocess.Popen([sys.executable, "-m", "companion.cli", "-v", "fly", "--connect",
                                f"tcp://127.0.0.1:{port}", "--mission", "forest_arducopter_sitl", "--no-zenoh",
                                "--no-recording", "--no-plots", "--run-dir", str(tmp_path / "run")],
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=ROOT)
        assert fly.stderr is not None
        if kill:
            for line in fly.stderr:
                if "arm → mission" in line:
                    break
            time.sleep(2.0)
            os.killpg(ac.pid, sig.SIGKILL)
        _out, err = fly.communicate(timeout=420)
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(ac.pid, sig.SIGKILL)
        ac.wait(10)
    rep = json.loads((tmp_path / "run" / "report.json").read_text())
    if kill:
        assert fly.returncode == 3 and rep["outcome"] == "link_lost", rep["outcome"]
        assert rep["link"]["rejected"].get("link_closed") == 1, rep["link"]
    else:
        assert fly.returncode == 0, err[-3000:]
        assert rep["outcome"] == "completed" and rep["collisions"] == 0 and rep["autopilot"]["family"] == "ardupilot"
        assert "locked onto the autopilot (system 1) on tcp://" in err


@pytest.mark.slow
def test_arducopter_sitl_on_a_serial_pty(tmp_path):
    """Opt-in (SLUNGPILOT_ARDUPILOT): ArduCopter SITL's SERIAL0 on one end of a pty pair at 921600 baud (its
    ``uart:`` device), the companion on the other with ``--connect serial://``: the forest completes, nothing lost.
    SERIAL0 is ArduPilot's console too: at boot it prints "Init Gyro", a '*' per calibration step and a newline
    between its MAVLink frames (seen here: 12 bytes in 4 runs, 2026-12-03). The companion skips and counts those;
    nothing else may be rejected."""
    import signal as sig

    with PtyPair(tmp_path / "fc", tmp_path / "cc"):
        ac, _ = _arducopter_on_tcp(tmp_path, serial0=f"uart:{tmp_path / 'fc'}:921600")
        try:
            out = subprocess.run([sys.executable, "-m", "companion.cli", "-v", "fly", "--connect",
                                  f"serial://{tmp_path / 'cc'}:921600", "--mission", "forest_arducopter_sitl",
                                  "--no-zenoh", "--no-recording", "--no-plots", "--run-dir", str(tmp_path / "run")],
                                 capture_output=True, text=True, cwd=ROOT, timeout=420)
        finally:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(ac.pid, sig.SIGKILL)
            ac.wait(10)
    assert out.returncode == 0, out.stderr[-3000:]
    rep = json.loads((tmp_path / "run" / "report.json").read_text())
    assert rep["outcome"] == "completed" and rep["collisions"] == 0 and rep["autopilot"]["family"] == "ardupilot"
    rejected = rep["link"]["rejected"]
    assert rep["link"]["lost"] == 0 and set(rejected) <= {"garbage", "garbage_bytes"}, rep["link"]
    assert rejected.get("garbage_bytes", 0) <= len("Init Gyro") + 16, rep["link"]  # the boot text, no more
    assert "locked onto the autopilot (system 1) on serial://" in out.stderr
