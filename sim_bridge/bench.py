"""``slungpilot bench sitl`` and ``python -m sim_bridge.bench``: lockstep speed of the bundled vehicle.

Starts the vehicle (``python -m sim_bridge --lockstep``, 1 kHz physics, 4 ms control period) as a
subprocess and drives it from this process over real UDP with a minimal 250 Hz hover client: it decodes
only the SYSTEM_TIME marker and the vehicle's LOCAL_POSITION_NED (other frames are skipped by message id;
``companion.mavlink_io.codec.decode_fields``, CRC checked) and answers
each marker with a level-attitude SET_ATTITUDE_TARGET whose thrust holds 2 m. Prints and returns simulated
seconds per wall second and the CPU time per control step of either side (less sensitive than the
real-time factor to other processes competing for the cores), the kernel's share of it, and the CPU the
vehicle spends starting (to ``SITL READY``). ``--against DIR`` runs another checkout's vehicle round by round
with this one (same client, same moment: the fair comparison on a shared machine);
:func:`run_bench_step_inprocess` gives the vehicle's own per-step cost without sockets. Nothing is asserted.
"""

from __future__ import annotations

import argparse
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
from sim_bridge.sitl_config import SitlConfig
from sim_bridge.vehicle import SitlVehicle

M = mavlink2
_ID_SYSTEM_TIME = M.MAVLINK_MSG_ID_SYSTEM_TIME
_ID_LOCAL_POSITION_NED = M.MAVLINK_MSG_ID_LOCAL_POSITION_NED
_STX = M.PROTOCOL_MARKER_V2


_LEVEL = (1.0, 0.0, 0.0, 0.0)


def _hover_thrust(z: float, vz: float, z_sp: float = -2.0) -> float:
    return min(0.9, max(0.05, 0.4 + 0.12 * (z - z_sp) + 0.12 * vz))


FLIGHT_STREAMS = (M.MAVLINK_MSG_ID_ATTITUDE, M.MAVLINK_MSG_ID_LOCAL_POSITION_NED, M.MAVLINK_MSG_ID_HIGHRES_IMU,
                  M.MAVLINK_MSG_ID_DEBUG_FLOAT_ARRAY)  # what the companion asks for every control period


def run_bench_sitl(seconds: float = 3.0, vehicle_root: str | None = None, flight_rates: bool = False,
                   ) -> dict[str, float]:
    """Fly a lockstep hover for ``seconds`` of wall time; returns real-time factor and step timings.

    ``vehicle_root``: run the vehicle of another checkout (its directory goes first on the child's PYTHONPATH),
    e.g. to compare with an older version on the same machine at the same time. ``flight_rates``: ask for
    ATTITUDE, LOCAL_POSITION_NED, HIGHRES_IMU and the swing every control period, as the companion does in a
    flight (default: the vehicle's own onboard rates)."""
    env = None
    if vehicle_root is not None:
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in (vehicle_root, os.environ.get("PYTHONPATH"))
                                                          if p))
    proc, port, _ = spawn_vehicle("--lockstep", "--control-period-ms", "4", env=env, cwd=vehicle_root)
    try:
        start_cpu = sum(_proc_cpu_s(proc.pid))
        with MavClient(port) as c:
            c.heartbeat()
            c.wait_marker(10.0)
            for _ in range(20):
                c.step(thrust=0.0)
            if c.set_mode(6) != M.MAV_RESULT_ACCEPTED or c.arm() != M.MAV_RESULT_ACCEPTED:
                raise RuntimeError("bench: vehicle refused OFFBOARD or arming")
            for msgid in FLIGHT_STREAMS if flight_rates else ():
                c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, msgid, 4000)
            user0, sys0 = _proc_cpu_s(proc.pid)
            res = _fast_loop(c, seconds)
            steps = max(res["control_steps"], 1.0)
            user1, sys1 = _proc_cpu_s(proc.pid)
            res["vehicle_cpu_us_per_step"] = (user1 + sys1 - user0 - sys0) / steps * 1e6
            res["vehicle_sys_us_per_step"] = (sys1 - sys0) / steps * 1e6
            res["vehicle_start_cpu_s"] = start_cpu
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


def run_bench_step_inprocess(steps: int = 5000, scanner=None) -> dict[str, float]:
    """The vehicle's own CPU per lockstep control step, in this process and without sockets: a hover client's
    SET_ATTITUDE_TARGET frames go straight into the onboard link's ``datagram_received`` and what the vehicle
    sends is dropped. Physics, mode logic, telemetry packing and framing, as in ``--lockstep``; the UDP system
    calls (and the wake-ups they cause) are what the subprocess bench adds on top. ``scanner``: a world's LiDAR
    (:class:`sim_bridge.scan_sender.ScanSender`) on the vehicle, as ``sitl --world`` attaches it."""
    v = SitlVehicle(SitlConfig(lockstep=True))
    v.scanner = scanner
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


def _median(rows: list[dict[str, float]], key: str) -> float:
    vals = sorted(r[key] for r in rows)
    return vals[len(vals) // 2]


def main(argv: list[str] | None = None) -> int:
    """Print the benchmark (``python -m sim_bridge.bench [SECONDS] [--against DIR] [--rounds N]``)."""
    ap = argparse.ArgumentParser(prog="python -m sim_bridge.bench", description=__doc__.split("\n")[0])
    ap.add_argument("seconds", nargs="?", type=float, default=3.0, help="wall seconds per measured hover")
    ap.add_argument("--against", metavar="DIR", help="also run the vehicle of this checkout (e.g. an older "
                    "one), interleaved round by round with this one; medians are printed side by side")
    ap.add_argument("--rounds", type=int, default=3, help="hovers per vehicle (default 3)")
    ap.add_argument("--default-rates", action="store_true",
                    help="the vehicle's own onboard rates instead of the flight's (ATTITUDE, LOCAL_POSITION_NED, "
                         "HIGHRES_IMU and the swing every control period)")
    args = ap.parse_args(argv)
    rates = "default onboard rates" if args.default_rates else "flight rates"
    print(f"slungpilot bench sitl: lockstep vehicle subprocess, 1 kHz physics, 250 Hz hover client over UDP, {rates}")
    variants = [("this checkout", None)] + ([(args.against, args.against)] if args.against else [])
    rows: dict[str, list[dict[str, float]]] = {name: [] for name, _ in variants}
    for _ in range(args.rounds):
        for name, root in variants:
            rows[name].append(run_bench_sitl(args.seconds, root, flight_rates=not args.default_rates))
    lines = [("real-time factor (sim s / wall s)", "realtime_factor", "{:.1f}x"),
             ("vehicle CPU per control step, µs", "vehicle_cpu_us_per_step", "{:.0f}"),
             ("  of which in the kernel, µs", "vehicle_sys_us_per_step", "{:.0f}"),
             ("client CPU per control step, µs", "client_cpu_us_per_step", "{:.0f}"),
             ("vehicle start-up CPU (to READY), s", "vehicle_start_cpu_s", "{:.2f}")]
    print(f"  medians of {args.rounds} rounds of {args.seconds:g} s" + "".join(f" | {n:>16.16s}" for n, _ in variants))
    for label, key, fmt in lines:
        print(f"  {label:38s}" + "".join(f" | {fmt.format(_median(rows[n], key)):>16s}" for n, _ in variants))
    inproc = min((run_bench_step_inprocess(3000) for _ in range(3)), key=lambda r: r["vehicle_cpu_us_per_step"])
    print(f"  this checkout's step in-process, no sockets (best of 3): {inproc['vehicle_cpu_us_per_step']:.1f} µs "
          f"(default rates)")
    return 0


if __name__ == "__main__":
    import sys

    sys.exit(main())
