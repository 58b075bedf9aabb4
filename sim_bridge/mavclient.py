"""A minimal blocking MAVLink 2 UDP client for the bundled vehicle (tests, benchmark, docs example).

Plain sockets + pymavlink's generated ``MAVLink`` class; no asyncio. It drives the lockstep handshake
(docs/sitl.md): send SET_ATTITUDE_TARGET, read until the SYSTEM_TIME marker of the next step arrives,
re-send the answer if only the old marker comes back (lost datagram).
"""

from __future__ import annotations

import select
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from typing import Any

from pymavlink.dialects.v20 import common as mavlink2

from companion import proclife

M = mavlink2


class _SockWriter:
    def __init__(self, client: MavClient) -> None:
        self.client = client

    def write(self, buf: bytes) -> None:
        self.client.sock.sendto(bytes(buf), self.client.vehicle_addr)


class MavClient:
    """Talks to one vehicle at ``127.0.0.1:port`` as system ``sysid`` / component ``compid``."""

    def __init__(self, port: int, target_sysid: int = 1, sysid: int = 255, compid: int = 190,
                 host: str = "127.0.0.1") -> None:
        self.vehicle_addr = (host, port)
        self.target_sysid = target_sysid
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
        self.mav = mavlink2.MAVLink(_SockWriter(self), srcSystem=sysid, srcComponent=compid)
        self._parser = mavlink2.MAVLink(None)
        self._parser.robust_parsing = True
        self.last: dict[str, Any] = {}
        self.on_message: Callable[[Any], None] | None = None
        self.sim_time_ms = -1
        self.statustexts: list[str] = []

    def close(self) -> None:
        self.sock.close()

    def __enter__(self) -> MavClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---------------------------------------------------------------- receiving
    def poll(self, timeout_s: float) -> list[Any]:
        """Messages of the datagrams arriving within ``timeout_s`` (at least one datagram if any comes)."""
        self.sock.settimeout(max(timeout_s, 1e-4))
        try:
            data = self.sock.recv(65536)
        except TimeoutError:
            return []
        out = []
        for m in self._parser.parse_buffer(data) or []:
            if m.get_type() == "BAD_DATA":
                continue
            if m.get_srcSystem() == self.target_sysid:
                self.last[m.get_type()] = m  # the vehicle's latest of each type (not the payload's)
                if m.get_type() == "STATUSTEXT":
                    self.statustexts.append(m.text)
            if m.get_type() == "SYSTEM_TIME" and m.get_srcSystem() == self.target_sysid:
                self.sim_time_ms = max(self.sim_time_ms, m.time_boot_ms)
            if self.on_message is not None:
                self.on_message(m)
            out.append(m)
        return out

    def wait_for(self, mtype: str, cond: Callable[[Any], bool] = lambda m: True, timeout_s: float = 5.0,
                 sysid: int | None = None) -> Any:
        """First ``mtype`` message from ``sysid`` (default: the vehicle) with ``cond``; TimeoutError if none."""
        sysid = self.target_sysid if sysid is None else sysid
        end = time.monotonic() + timeout_s
        while (left := end - time.monotonic()) > 0:
            for m in self.poll(left):
                if m.get_type() == mtype and m.get_srcSystem() == sysid and cond(m):
                    return m
        raise TimeoutError(f"no {mtype} from system {sysid} within {timeout_s} s")

    # ---------------------------------------------------------------- sending
    def heartbeat(self) -> None:
        self.mav.heartbeat_send(M.MAV_TYPE_ONBOARD_CONTROLLER, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE)

    def command(self, cmd: int, *params: float, timeout_s: float = 5.0) -> int:
        """COMMAND_LONG; returns the COMMAND_ACK result."""
        p = [*params, 0, 0, 0, 0, 0, 0, 0][:7]
        self.mav.command_long_send(self.target_sysid, 1, cmd, 0, *p)
        return self.wait_for("COMMAND_ACK", lambda m: m.command == cmd, timeout_s).result

    def set_mode(self, main: int, sub: int = 0) -> int:
        return self.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main, sub)

    def arm(self, arm: bool = True, force: bool = False) -> int:
        return self.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1.0 if arm else 0.0, 21196.0 if force else 0.0)

    def send_attitude_target(self, q=(1.0, 0.0, 0.0, 0.0), thrust: float = 0.4, type_mask: int = 7,
                             rates=(0.0, 0.0, 0.0)) -> None:
        self.mav.set_attitude_target_send(max(self.sim_time_ms, 0), self.target_sysid, 1, type_mask,
                                          list(q), rates[0], rates[1], rates[2], thrust)

    # ---------------------------------------------------------------- lockstep
    def wait_marker(self, timeout_s: float = 5.0) -> int:
        """Wait for any SYSTEM_TIME marker (e.g. the first one); returns its time_boot_ms."""
        return self.wait_for("SYSTEM_TIME", timeout_s=timeout_s).time_boot_ms

    def step(self, q=(1.0, 0.0, 0.0, 0.0), thrust: float = 0.4, type_mask: int = 7, rates=(0.0, 0.0, 0.0),
             timeout_s: float = 5.0) -> int:
        """Answer with SET_ATTITUDE_TARGET and wait for the next step's marker; returns its time_boot_ms."""
        before = self.sim_time_ms
        self.send_attitude_target(q, thrust, type_mask, rates)
        end = time.monotonic() + timeout_s
        resend_at = time.monotonic() + 0.3
        while time.monotonic() < end:
            for m in self.poll(0.05):
                if m.get_type() == "SYSTEM_TIME" and m.get_srcSystem() == self.target_sysid:
                    if m.time_boot_ms > before:
                        return m.time_boot_ms
                    if time.monotonic() > resend_at:  # our answer was lost: the old marker came again
                        self.send_attitude_target(q, thrust, type_mask, rates)
                        resend_at = time.monotonic() + 0.3
        raise TimeoutError(f"lockstep: no marker after t = {before} ms within {timeout_s} s")


def free_udp_port() -> int:
    """A UDP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def spawn_vehicle(*extra_args: str, ready_timeout_s: float = 30.0,
                  env: dict[str, str] | None = None, cwd: str | None = None) -> tuple[subprocess.Popen, int, int]:
    """Start ``python -m sim_bridge`` on free ports (GCS telemetry to a free port nobody reads); ``env`` and
    ``cwd``: the child's environment and directory (default this process's; another checkout's directory as
    both ``cwd`` and first on PYTHONPATH runs that checkout's vehicle).

    Returns (process, onboard port, gcs port) once it printed ``SITL READY``; the caller terminates it.
    """
    onboard, gcs, sink = free_udp_port(), free_udp_port(), free_udp_port()
    cmd = [sys.executable, "-m", "sim_bridge", "--onboard-port", str(onboard), "--gcs-port", str(gcs),
           "--gcs-remote", f"127.0.0.1:{sink}", "--onboard-remote", f"127.0.0.1:{sink}", *extra_args]
    # a file, not a pipe: a chatty vehicle must never block; closed with the process object
    errlog = tempfile.TemporaryFile(mode="w+")  # noqa: SIM115
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=errlog, text=True, env=env, cwd=cwd,
                            preexec_fn=proclife.preexec())  # dies with whoever spawned it, SIGKILL included
    proc.errlog = errlog  # type: ignore[attr-defined]
    end = time.monotonic() + ready_timeout_s
    line = ""
    while time.monotonic() < end and proc.poll() is None:
        r, _, _ = select.select([proc.stdout], [], [], 0.1)
        if r:
            line = proc.stdout.readline()
            break
    if not line.startswith("SITL READY"):
        proc.kill()
        proc.wait(5)
        err = vehicle_stderr(proc)
        raise RuntimeError(f"vehicle did not start: {line!r} {err[-2000:]}")
    return proc, onboard, gcs


def stop_vehicle(proc: subprocess.Popen, timeout_s: float = 10.0) -> int:
    """SIGTERM the vehicle and return its exit code (kills it if it does not stop)."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout_s)
    if proc.stdout is not None:
        proc.stdout.close()
    return proc.returncode


def vehicle_stderr(proc: subprocess.Popen) -> str:
    """What a vehicle from :func:`spawn_vehicle` wrote to stderr so far."""
    f = getattr(proc, "errlog", None)
    if f is None:
        return ""
    f.seek(0)
    return f.read()
