"""``slungpilot bench sitl``: lockstep real-time factor of the bundled vehicle.

Starts the vehicle (``python -m sim_bridge --lockstep``, 1 kHz physics, 4 ms control period) as a
subprocess and drives it from this process over real UDP with a minimal 250 Hz hover client: it decodes
only the SYSTEM_TIME marker and the vehicle's LOCAL_POSITION_NED (other frames are skipped by message id;
``companion.mavlink_io.codec.decode_fields``, CRC checked) and answers
each marker with a level-attitude SET_ATTITUDE_TARGET whose thrust holds 2 m. Prints and returns simulated
seconds per wall second and the CPU time per control step of either side (less sensitive than the
real-time factor to other processes competing for the cores). Nothing is asserted.
"""

from __future__ import annotations

import os
import time

from pymavlink.dialects.v20 import common as mavlink2

from companion.autopilots import px4_modes
from companion.mavlink_io.codec import (
    CRC_SET_ATTITUDE_TARGET,
    ID_SET_ATTITUDE_TARGET,
    P_SET_ATTITUDE_TARGET,
    decode_fields,
    frame_v2,
    send_set_attitude_target,
)
from sim_bridge.link import MavUdpLink
from sim_bridge.mavclient import MavClient, spawn_vehicle, stop_vehicle
from sim_bridge.vehicle import SitlConfig, SitlVehicle

M = mavlink2
_ID_SYSTEM_TIME = M.MAVLINK_MSG_ID_SYSTEM_TIME
_ID_LOCAL_POSITION_NED = M.MAVLINK_MSG_ID_LOCAL_POSITION_NED
_STX = M.PROTOCOL_MARKER_V2


_LEVEL = (1.0, 0.0, 0.0, 0.0)


def _hover_thrust(z: float, vz: float, z_sp: float = -2.0) -> float:
    return min(0.9, max(0.05, 0.4 + 0.12 * (z - z_sp) + 0.12 * vz))


def run_bench_sitl(seconds: float = 3.0) -> dict[str, float]:
    """Fly a lockstep hover for ``seconds`` of wall time; returns real-time factor and step timings."""
    proc, port, _ = spawn_vehicle("--lockstep", "--control-period-ms", "4")
    try:
        with MavClient(port) as c:
            c.heartbeat()
            c.wait_marker(10.0)
            for _ in range(20):
                c.step(thrust=0.0)
            if c.set_mode(6) != M.MAV_RESULT_ACCEPTED or c.arm() != M.MAV_RESULT_ACCEPTED:
                raise RuntimeError("bench: vehicle refused OFFBOARD or arming")
            user0, sys0 = _proc_cpu_s(proc.pid)
            res = _fast_loop(c, seconds)
            steps = max(res["control_steps"], 1.0)
            user1, sys1 = _proc_cpu_s(proc.pid)
            res["vehicle_cpu_us_per_step"] = (user1 + sys1 - user0 - sys0) / steps * 1e6
            res["vehicle_sys_us_per_step"] = (sys1 - sys0) / steps * 1e6
    finally:
        stop_vehicle(proc)
    return res


def _fast_loop(c: MavClient, seconds: float) -> dict[str, float]:
    sock = c.sock
    sock.settimeout(5.0)
    sysid = c.target_sysid
    z, vz = 0.0, 0.0
    t_ms = c.sim_time_ms
    t_start_ms = t_ms
    steps = 0
    cpu0 = time.process_time()
    wall0 = time.perf_counter()
    deadline = wall0 + seconds
    c.send_attitude_target(thrust=_hover_thrust(z, vz))
    while True:
        try:
            data = sock.recv(65536)
        except TimeoutError:
            c.send_attitude_target(thrust=_hover_thrust(z, vz))  # lost datagram: answer again
            continue
        new_step = False
        i, n = 0, len(data)
        while i + 12 <= n and data[i] == _STX:  # walk the frames of the datagram
            end = i + 12 + data[i + 1]
            msgid = data[i + 7] | (data[i + 8] << 8) | (data[i + 9] << 16)
            if msgid == _ID_LOCAL_POSITION_NED and data[i + 5] == sysid:
                f = decode_fields(data[i:end])  # (time_boot_ms, x, y, z, vx, vy, vz)
                z, vz = f[3], f[6]
            elif msgid == _ID_SYSTEM_TIME:
                t_boot_ms = decode_fields(data[i:end])[1]  # (time_unix_usec, time_boot_ms)
                if t_boot_ms > t_ms:
                    t_ms = t_boot_ms
                    new_step = True
            i = end
        if not new_step:
            continue
        c.sim_time_ms = t_ms
        steps += 1
        if time.perf_counter() >= deadline:
            break
        send_set_attitude_target(c.mav, t_ms, c.target_sysid, 1, 7, _LEVEL, 0.0, 0.0, 0.0, _hover_thrust(z, vz))
    wall = time.perf_counter() - wall0
    cpu = time.process_time() - cpu0
    sim_s = (t_ms - t_start_ms) * 1e-3
    return {
        "realtime_factor": sim_s / wall,
        "sim_s": sim_s,
        "wall_s": wall,
        "control_steps": float(steps),
        "us_per_control_step": wall / max(steps, 1) * 1e6,
        "final_altitude_m": -z,
        "client_cpu_us_per_step": cpu / max(steps, 1) * 1e6,
    }


class _Discard:
    """A transport that drops what the links send (the in-process step cost leaves the kernel's UDP out)."""

    def __init__(self) -> None:
        self.datagrams = 0

    def sendto(self, buf: bytes, addr: tuple[str, int]) -> None:
        self.datagrams += 1

    def close(self) -> None:
        pass


def run_bench_step_inprocess(steps: int = 5000) -> dict[str, float]:
    """The vehicle's own CPU per lockstep control step, in this process and without sockets: a hover client's
    SET_ATTITUDE_TARGET frames go straight into the onboard link's ``datagram_received`` and what the vehicle
    sends is dropped. Physics, mode logic, telemetry packing and framing, as in ``--lockstep``; the UDP system
    calls (and the wake-ups they cause) are what the subprocess bench adds on top."""
    v = SitlVehicle(SitlConfig(lockstep=True))
    v.warm_up()
    sink = _Discard()
    links = [MavUdpLink(name, ("127.0.0.1", 9), 1, 1, v.counters, v.on_message, None, link_id=k)
             for k, name in enumerate(("onboard", "gcs"))]
    for lk in links:
        lk.transport = sink
    v.attach_links(*links)
    v.start()
    addr = ("127.0.0.1", 40000)
    handle = links[0].datagram_received

    def answer(k: int, thrust: float) -> bytes:
        payload = P_SET_ATTITUDE_TARGET.pack(v.t_us // 1000, *_LEVEL, 0.0, 0.0, 0.0, thrust, 1, 1, 7)
        return frame_v2(k & 0xFF, 255, 190, ID_SET_ATTITUDE_TARGET, CRC_SET_ATTITUDE_TARGET, payload)

    handle(answer(0, 0.0), addr)
    v.set_mode(px4_modes.OFFBOARD)
    v.arm()
    x = v.sim.x
    cpu0 = time.process_time()
    for k in range(steps):
        handle(answer(k, _hover_thrust(float(x[2]), float(x[10]))), addr)
    cpu = time.process_time() - cpu0
    cpu0 = time.process_time()
    for k in range(steps):  # what the client's side of that loop cost, to take off
        answer(k, _hover_thrust(float(x[2]), float(x[10])))
    cpu -= time.process_time() - cpu0
    return {"control_steps": float(steps), "vehicle_cpu_us_per_step": cpu / steps * 1e6,
            "datagrams_per_step": sink.datagrams / (steps + 1), "final_altitude_m": -float(v.sim.x[2])}


def _proc_cpu_s(pid: int) -> tuple[float, float]:
    """(user, system) CPU time (s) of process ``pid`` so far (Linux /proc; NaN elsewhere)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        tck = os.sysconf("SC_CLK_TCK")
        return int(fields[11]) / tck, int(fields[12]) / tck
    except (OSError, ValueError, IndexError):
        return float("nan"), float("nan")


def main(seconds: float = 3.0) -> int:
    """Print the benchmark (CLI helper for ``slungpilot bench sitl``)."""
    print("slungpilot bench sitl: lockstep vehicle subprocess, 1 kHz physics, 250 Hz hover client over UDP")
    res = run_bench_sitl(seconds)
    print(f"  real-time factor (sim s / wall s): {res['realtime_factor']:8.1f}x")
    print(f"  control steps: {res['control_steps']:.0f} in {res['wall_s']:.2f} s wall "
          f"({res['us_per_control_step']:.0f} µs each), {res['sim_s']:.2f} s simulated")
    print(f"  CPU per control step: vehicle {res['vehicle_cpu_us_per_step']:.0f} µs "
          f"(in the kernel {res['vehicle_sys_us_per_step']:.0f} µs), client {res['client_cpu_us_per_step']:.0f} µs")
    print(f"  hover altitude at the end: {res['final_altitude_m']:.2f} m")
    return 0


if __name__ == "__main__":
    import sys

    sys.exit(main(float(sys.argv[1]) if len(sys.argv) > 1 else 3.0))
